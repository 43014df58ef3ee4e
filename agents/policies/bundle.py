"""The env a saved policy was trained in, from the ``env_config.json`` beside its zip.

A policy only runs in an env with its own spaces: the bundled one (``agents/bundled/policy/policy.zip``) chooses among
15 q levels from four stacked observations (``frame_stack=4``), while ``gym.make("RadarTrack-v0")`` has 13 levels
and one observation, so ``PPO.load(...).predict`` on the default env fails on the observation size (or picks the
wrong levels). Use::

    from stable_baselines3 import PPO
    from agents.policies.bundle import BUNDLED_POLICY, make_policy_env

    model = PPO.load(BUNDLED_POLICY, device="cpu")
    env = make_policy_env()                       # gym.make("RadarTrack-v0", **env_config.json)
    obs, info = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)

``make_policy_env(scenario="bizup2002")`` changes an argument; ``make_policy_env(num_envs=64)`` returns the native
vector env with the same arguments. The bundled learned trackers' envs are also registered ids
(:data:`BUNDLED_ENV_IDS`: ``gym.make("RadarTrackContinuous-v0")`` is ``policy_bp``'s, ``gym.make("RadarTrackIMM-v0")``
the learned IMM's; docs/env_reference.md).
"""

from __future__ import annotations

import json
import zipfile
from pathlib import Path

from agents.policies.layout import BUNDLED_LEARNED, bundled_weights_file

__all__ = ["BUNDLED_POLICY", "BUNDLED_BP_POLICY", "BUNDLED_LEARNED_IMM", "BUNDLED_IMM_PPO", "BUNDLED_BP_RDOT",
           "BUNDLED_LEARNED_IMM_RDOT", "BUNDLED_LEARNED_IMM_PRIOR", "BUNDLED_BP_PRIOR", "BUNDLED_WINDOW",
           "BUNDLED_POLICIES",
           "ENV_CONFIG_ENTRY", "policy_env_kwargs", "make_policy_env", "ship_policy", "BUNDLED_ENV_IDS",
           "bundled_env_kwargs", "embed_env_config", "recorded_env_kwargs"]

ENV_CONFIG_ENTRY = "radar_track_env_config.json"
"""Name of the copy of the training env's arguments inside a policy zip (:func:`embed_env_config`; SB3 ignores it)."""

BUNDLED_POLICIES = {name: bundled_weights_file(name) for name in BUNDLED_LEARNED}
"""Learned tracker name -> its bundled weights file (run when it exists and no other file is given); derived from
the registry :data:`agents.policies.layout.BUNDLED_LEARNED`, the one list of bundled trackers."""
BUNDLED_POLICY = BUNDLED_POLICIES["policy"]
"""The bundled PPO policy (its env arguments in ``env_config.json`` beside it)."""
BUNDLED_BP_POLICY = BUNDLED_POLICIES["policy_bp"]
"""The bundled policy trained by backpropagation (``policy_bp``; a recurrent policy,
:mod:`agents.policies.recurrent`, with ``policy.json`` and ``env_config.json`` beside it)."""
BUNDLED_LEARNED_IMM = BUNDLED_POLICIES["policy_imm_bp"]
"""The bundled learned IMM trained by backpropagation (the tracker ``policy_imm_bp``;
:mod:`agents.policies.learned_imm`, with ``policy.json`` and ``env_config.json`` beside it)."""
BUNDLED_IMM_PPO = BUNDLED_POLICIES["policy_imm_ppo"]
"""The bundled learned IMM trained with PPO on ``RadarTrack-v0`` with ``tracker="imm_cv_ct"`` (the tracker
``policy_imm_ppo``; its ``env_config.json`` and numpy export ``policy.npz`` beside it)."""
BUNDLED_BP_RDOT = BUNDLED_POLICIES["policy_bp_rdot"]
"""``policy_bp``'s recipe trained on the range-rate filter (``RadarTrackDoppler-v0``): the tracker
``policy_bp_rdot``."""
BUNDLED_LEARNED_IMM_RDOT = BUNDLED_POLICIES["policy_imm_bp_rdot"]
"""``policy_imm_bp``'s recipe trained on the range-rate filter: the tracker ``policy_imm_bp_rdot``."""
BUNDLED_LEARNED_IMM_PRIOR = BUNDLED_POLICIES["policy_imm_bp_prior"]
"""``policy_imm_bp``'s recipe trained on the ``random`` suites' own flights (the laws ``rbpf`` assumes), not the
broad ones: the tracker ``policy_imm_bp_prior`` (agents/bundled/learned_imm_prior/CHOICE.md)."""
BUNDLED_BP_PRIOR = BUNDLED_POLICIES["policy_bp_prior"]
"""``policy_bp``'s recipe with a wider network (GRU 128, a tanh layer of 64) trained on the ``random`` suites' own
flights: the tracker ``policy_bp_prior`` (agents/bundled/backprop_prior/CHOICE.md)."""
BUNDLED_WINDOW = BUNDLED_POLICIES["policy_window"]
"""A window correction of ``policy_bp_prior`` (MLPs over the last 24 plots, quadratic fits through them and the base's
last 12 process-noise levels moving its reported position, trained by regression on the random suites' flights
with their first leg drawn as every leg; an ensemble of three training seeds, in float32): the tracker
``policy_window`` (agents/bundled/window/CHOICE.md)."""

BUNDLED_ENV_IDS = {"policy_bp": "RadarTrackContinuous-v0", "policy_bp_rdot": "RadarTrackContinuousDoppler-v0",
                   "policy_imm_bp": "RadarTrackIMM-v0", "policy_imm_bp_rdot": "RadarTrackIMMDoppler-v0"}
"""Bundled learned tracker -> the registered env id whose arguments are exactly its :func:`bundled_env_kwargs`, so
``gym.make(id)`` gives the observation it was trained on (tests/test_env_ids.py). The other two bundles are one
override away: ``policy`` (PPO, discrete, four stacked frames) is ``gym.make("RadarTrackContinuous-v0",
action_type="discrete", frame_stack=4)``; ``policy_imm_ppo`` observes ``RadarTrackIMM-v0``'s observation but was
trained on an earlier flight distribution (its ``random_config``; pass it to get those flights);
``policy_imm_bp_prior`` is ``gym.make("RadarTrackIMM-v0", random_config={"random_radar_probability": 0.7})`` (the
random suites' own flights), and so is ``policy_bp_prior``'s ``gym.make("RadarTrackContinuous-v0",
random_config={"random_radar_probability": 0.7})``; ``policy_window`` acts through that same base (its
``env_config.json`` is ``policy_bp_prior``'s) and adds its estimate with
:class:`agents.policies.window_correction.CorrectedEstimate`."""


def bundled_env_kwargs(name):
    """The env arguments of bundled learned tracker ``name``'s observation: its ``env_config.json`` (lists as
    tuples), plus ``tracker`` for a learned IMM trained by backpropagation, whose checkpoint keeps the CV env's
    arguments there (features, q levels, track start, training flights) and names its filter in ``policy.json``
    (``"model": "imm_cv_ct"``)."""
    if name not in BUNDLED_POLICIES:
        raise ValueError(f"bundled_env_kwargs: unknown bundled policy {name!r}; valid: {list(BUNDLED_POLICIES)}")
    path = BUNDLED_POLICIES[name]
    kw = policy_env_kwargs(path)
    meta = path.with_name("policy.json")
    if meta.is_file():
        m = json.loads(meta.read_text())
        if m.get("format") == "radar-track-learned-imm" and "tracker" not in kw:
            kw["tracker"] = m["model"]
    return kw


def policy_env_kwargs(policy_path=None):
    """The ``RadarTrack-v0`` keyword arguments a policy was trained with: ``env_config.json`` beside
    ``policy_path`` (default :data:`BUNDLED_POLICY`), lists turned into tuples. Raises ``ValueError`` if the file
    is missing or is not a JSON object."""
    path = Path(BUNDLED_POLICY if policy_path is None else policy_path)
    cfg = path.with_name("env_config.json")
    if not cfg.is_file():
        raise ValueError(f"policy_path: no env_config.json beside {str(path)!r} (looked for {str(cfg)!r})")
    from agents.policies.checks import env_kwargs_from_json, read_json_object   # the one validation path
    return env_kwargs_from_json(read_json_object(cfg, "a JSON object of RadarTrack-v0 arguments"))


def embed_env_config(zip_path, env_kwargs):
    """Store the env arguments a model was trained with inside its zip (entry :data:`ENV_CONFIG_ENTRY`, plain JSON;
    stable-baselines3 reads only its own entries), so that :func:`agents.policies.loading.load_policy` can refuse an
    ``env_config.json`` edited or swapped since. Called by training and :func:`ship_policy` after each save."""
    with zipfile.ZipFile(zip_path, "a") as z:
        if ENV_CONFIG_ENTRY not in z.namelist():
            z.writestr(ENV_CONFIG_ENTRY, json.dumps(env_kwargs, indent=1))


def recorded_env_kwargs(policy_path):
    """``(kwargs, where)``: the record of the env a policy was trained in, independent of the ``env_config.json``
    beside it: the zip's embedded copy (:func:`embed_env_config`), else the run's hyperparameters (``config.json``
    of its run folder: beside the zip, or one level up for ``best/policy.zip``; a bundle's ``training.json``).
    ``(None, None)`` if there is none. Reads JSON only (nothing is unpickled). A bundled folder's training record
    is ``training.json`` (``train_config.json`` before the one-folder layout, still read)."""
    from agents.policies.checks import env_kwargs_from_json
    path = Path(policy_path)
    try:
        with zipfile.ZipFile(path) as z:
            if ENV_CONFIG_ENTRY in z.namelist():
                kw = json.loads(z.read(ENV_CONFIG_ENTRY).decode())
                if isinstance(kw, dict):
                    return env_kwargs_from_json(kw), f"{path} (its {ENV_CONFIG_ENTRY})"
    except (OSError, zipfile.BadZipFile, UnicodeDecodeError, json.JSONDecodeError):
        pass
    for cand, key in ((path.with_name("training.json"), ("hyperparams", "env_kwargs")),
                      (path.with_name("train_config.json"), ("hyperparams", "env_kwargs")),
                      (path.with_name("config.json"), ("env_kwargs",)),
                      (path.parent.with_name("config.json"), ("env_kwargs",))):
        if not cand.is_file():
            continue
        try:
            v = json.loads(cand.read_text())
        except (OSError, UnicodeDecodeError, json.JSONDecodeError):
            continue
        for k in key:
            v = v.get(k) if isinstance(v, dict) else None
        if isinstance(v, dict):
            return env_kwargs_from_json(v), str(cand)
    return None, None


def make_policy_env(policy_path=None, num_envs=None, **overrides):
    """The env a policy was trained in: ``gym.make("RadarTrack-v0", **kwargs)`` with ``kwargs`` from
    :func:`policy_env_kwargs` updated by ``overrides``, or, with ``num_envs``, the native
    :class:`radar_env.envs.env.RadarTrackVectorEnv` with the same arguments."""
    import gymnasium as gym      # here, not at import: BUNDLED_POLICY is read by `radar-track evaluate --help`

    import radar_env  # noqa: F401 - registers RadarTrack-v0
    from radar_env.envs.env import RadarTrackVectorEnv
    kw = policy_env_kwargs(policy_path)
    kw.update(overrides)
    if num_envs is None:
        return gym.make("RadarTrack-v0", **kw)
    return RadarTrackVectorEnv(num_envs=num_envs, **kw)


def ship_policy(policy_path, dest_dir):
    """Copy a trained policy into ``dest_dir`` for shipping. A PPO zip (and the ``env_config.json`` beside it) is
    written without the optimizer's moments (a fresh optimizer state, about a third of the file): the shipped zip
    acts exactly as the trained one and still loads with ``PPO.load``; fine-tuning from it (``init_from``) restarts
    the moments, as it does for any saved model. A recurrent policy (``policy.npz``, trained by backpropagation) is
    copied with its ``policy.json`` and ``env_config.json`` (it holds no optimizer state). A PPO zip's numpy export
    (``policy.npz``, :mod:`agents.policies.numpy_policy`) is written beside it, so the evaluation runs it without
    torch, with the ``policy.json`` naming its kind (:mod:`agents.policies.learned`). Returns the new policy file's
    path."""
    import shutil

    src = Path(policy_path)
    dest = Path(dest_dir)
    dest.mkdir(parents=True, exist_ok=True)
    if src.suffix == ".npz":     # a recurrent policy (its policy.json must be there; FileNotFoundError otherwise)
        for f in (src, src.with_suffix(".json"), src.with_name("env_config.json")):
            shutil.copy(f, dest / f.name)
        return dest / src.name
    from stable_baselines3 import PPO
    model = PPO.load(str(src), device="cpu")
    opt = model.policy.optimizer
    model.policy.optimizer = type(opt)(model.policy.parameters(), **opt.defaults)
    model.save(str(dest / "policy.zip"))
    shutil.copy(src.with_name("env_config.json"), dest / "env_config.json")
    embed_env_config(dest / "policy.zip", json.loads((dest / "env_config.json").read_text()))
    from agents.policies.numpy_policy import save_export
    save_export(dest / "policy.zip", model)      # after the embedding: the export records the final zip's SHA-256
    from agents.policies.layout import sb3_kind, write_manifest
    write_manifest(dest, sb3_kind("ppo", json.loads((dest / "env_config.json").read_text())))   # its kind
    return dest / "policy.zip"

