"""A saved policy as the evaluation uses it: ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 and the env config it was
trained with.

**A policy file is a program.** A stable-baselines3 zip holds pickled Python objects, and unpickling runs whatever
code the file's author put there (with your user's rights), before any check of this module can look at it; a torch
checkpoint is the same. Load only files you trust (your own training runs, the bundled policy); the checks below
catch mistakes, not malice. A zip with a current numpy export beside it (``policy.npz``,
:mod:`agents.policies.numpy_policy`; the bundled policies have one) is not unpickled: the export holds arrays only,
and the policy then runs without torch or SB3. A recurrent policy trained by backpropagation (``.npz`` with its
``policy.json``, :mod:`agents.policies.recurrent`) is plain arrays and JSON, loaded without pickle.

:func:`load_policy` refuses, naming the field, a model that does not fit the env config it is evaluated with: a
different observation size or action space, observation bounds that differ entry by entry from the env's (other or
reordered ``features``, another ``frame_stack``), and an ``env_config.json`` that disagrees with the record of the
training env (the copy training embeds in the zip, or the run's ``config.json`` / the bundle's
``training.json``: e.g. other ``q_levels_g`` with the same count).
"""

from __future__ import annotations

import dataclasses
import sys
from pathlib import Path

import numpy as np

from radar_env.envs.env import EnvConfig, actions_to_q_m_s2
from radar_env.envs.observation import ObservationLayout
from radar_env.common.units import G0_M_S2

from agents.policies.bundle import policy_env_kwargs, recorded_env_kwargs
from agents.policies.numpy_policy import load_sb3_model
from agents.policies.recurrent import load_recurrent_policy

__all__ = ["load_policy", "load_model", "load_sb3_model", "model_choose_q", "model_run_imm", "SB3LearnedIMM"]


def load_policy(path, allow_pickle=False):
    """Load a saved policy and the env config it was trained with, by file type: a stable-baselines3 model (PPO,
    DQN, SAC, A2C or TD3 ``.zip``; ``env_config.json`` beside it, else the defaults with the model's action type)
    or a recurrent policy trained by backpropagation (``policy.npz`` with its ``policy.json`` and
    ``env_config.json``, :func:`agents.policies.recurrent.load_recurrent_policy`; no pickle), or a learned IMM
    (the same three files, :func:`agents.policies.learned_imm.load_learned_imm`: returned as ``(LearnedIMM, cfg)``,
    a tracker with ``is_tracker`` and ``run(episodes, name)`` in place of ``choose_q``), or a window correction
    (:func:`agents.policies.window_correction.load_window_correction`: a tracker likewise, with its base's
    config). An SB3 model trained on the IMM env (``tracker="imm_cv_ct"`` in its env config) is returned likewise,
    as :class:`SB3LearnedIMM`.

    Returns ``(choose_q, cfg)`` where ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2, evaluated in numpy wherever the
    model's structure allows (:func:`load_model`; a recurrent policy is a stateful ``choose_q`` for
    :func:`baselines.trackers.run_q_policy`: ``reset(rows)``, ``choose_q(obs, rows)``). Raises ``ValueError`` for a
    file that is not such a policy, or one whose observation space (size or bounds), action space or recorded
    training env does not match its env config (the message names the field; module docstring).

    Without a current numpy export an SB3 zip would be unpickled, which runs code: refused (one line) unless
    ``allow_pickle``. Every ``.npz`` goes through :mod:`agents.policies.checks` before anything runs."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy file {str(path)!r} does not exist (or is not a file)")
    if path.suffix == ".npz":       # a recurrent policy (load_recurrent_policy says what is missing if it is not)
        from agents.policies.learned_imm import is_learned_imm_checkpoint, load_learned_imm
        from agents.policies.window_correction import is_window_correction, load_window_correction
        if is_learned_imm_checkpoint(path):
            imm = load_learned_imm(path)
            return imm, imm.cfg
        if is_window_correction(path):
            wc = load_window_correction(path, lambda base: load_policy(base, allow_pickle=allow_pickle))
            return wc, wc.cfg
        return load_recurrent_policy(path)
    cfg_file = path.with_name("env_config.json")
    kw = policy_env_kwargs(path) if cfg_file.is_file() else {}
    where = str(cfg_file) if cfg_file.is_file() else f"the defaults (no {cfg_file.name} beside {path.name})"
    _check_recorded_env(path, kw, where)     # JSON only, before anything is unpickled
    model = load_model(path, allow_pickle)
    from gymnasium import spaces
    discrete = isinstance(model.action_space, spaces.Discrete)
    kw.setdefault("action_type", "discrete" if discrete else "continuous")
    try:
        cfg = EnvConfig.from_kwargs(**kw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{cfg_file}: {e}") from None
    n_obs = int(np.prod(model.observation_space.shape))
    imm = cfg.tracker == "imm_cv_ct"           # trained on the IMM env: the IMM's parameters are the action
    if imm:
        from radar_env.envs.imm_core import make_core
        core = make_core(1, cfg)
        lo, hi = core.observation_bounds()
        n_act = core.action_map.n_par
        if n_obs != lo.size or int(np.prod(model.action_space.shape or (1,))) != n_act:
            raise ValueError(f"{path}: the model has {model.observation_space} observations and "
                             f"{model.action_space} actions, but the IMM env of {where} has {lo.size} observation "
                             f"entries and {n_act} parameters per action")
        _check_observation_bounds(path, model.observation_space, cfg, where, (lo, hi))
        return SB3LearnedIMM(model, cfg), cfg
    if n_obs != len(cfg.features) * cfg.frame_stack:
        raise ValueError(f"{path}: the model takes {n_obs} observation entries but the env config from {where} has "
                         f"{len(cfg.features)} features x frame_stack {cfg.frame_stack}; it was trained with other "
                         f"env kwargs: it needs 'features' (a list of the {n_obs} feature names it was trained "
                         f"with, or {n_obs} / k names with 'frame_stack' k), e.g. from its run's env_config.json, "
                         f"in {cfg_file}")
    if discrete != (cfg.action_type == "discrete"):
        raise ValueError(f"{path}: the model has {model.action_space} actions but the env config from {where} has "
                         f"action_type={cfg.action_type!r}; it needs action_type="
                         f"{'discrete' if discrete else 'continuous'!r}")
    if discrete and int(model.action_space.n) != len(cfg.q_levels_g):
        raise ValueError(f"{path}: the model has {model.action_space} actions but the env config from {where} has "
                         f"{len(cfg.q_levels_g)} q levels; it needs 'q_levels_g' (the {model.action_space.n} levels "
                         f"it was trained with) in {cfg_file}")
    _check_observation_bounds(path, model.observation_space, cfg, where)
    choose_q = model_choose_q(model, cfg)
    return choose_q, cfg


def load_model(path, allow_pickle=False):
    """The policy in the zip ``path`` as an object with ``observation_space``, ``action_space`` and SB3's
    ``predict``: its numpy export (:class:`agents.policies.numpy_policy.NumpyPolicy`) from the ``.npz`` beside it
    when that was exported from this very file (no torch, no SB3, no unpickling); else the SB3 model, exported to
    numpy in memory when its structure allows and the export reproduces its actions (checked), else the SB3 model
    itself. Without ``allow_pickle`` only the export is read: a missing, damaged or out-of-date one is refused
    (``ValueError``, one line); with it, such an export is ignored with a warning on stderr and the zip unpickled."""
    from agents.policies import numpy_policy as npp
    from agents.policies.checks import refuse_pickle
    try:
        pol = npp.load_export(path)
        if pol is not None:
            return pol
        if not allow_pickle:
            stale = npp.export_path(path).is_file()
            raise refuse_pickle(path, "a stable-baselines3 zip " + (
                f"whose numpy export {npp.export_path(path).name} was made from another file" if stale
                else f"with no numpy export {npp.export_path(path).name} beside it"))
        if npp.export_path(path).is_file():
            print(f"warning: {npp.export_path(path)} was exported from another file than {path}; ignored (re-export "
                  f"with python -m agents.policies.numpy_policy --allow-pickle {path})", file=sys.stderr)
    except ValueError as e:
        if not allow_pickle:
            raise
        print(f"warning: {e}; loading {path} with stable-baselines3 instead", file=sys.stderr)
    model = load_sb3_model(path, allow_pickle=True)
    arrays = npp.export_model(model)
    if arrays is None:
        return model
    pol = npp.NumpyPolicy(arrays)
    ok, _ = npp.check_export(pol, model)
    return pol if ok else model


def _check_observation_bounds(path, space, cfg, where, bounds=None):
    """The model's stored observation Box must be the env's (``bounds``, default the CV env's), entry by entry (a
    reordered or renamed feature list of the same length changes them); ``ValueError`` naming the first entry that
    differs otherwise."""
    lo, hi = cfg.observation_bounds(ObservationLayout(cfg.features)) if bounds is None else bounds
    m_lo = np.asarray(space.low, dtype=np.float64).reshape(-1)
    m_hi = np.asarray(space.high, dtype=np.float64).reshape(-1)
    lo, hi = np.asarray(lo, dtype=np.float64).reshape(-1), np.asarray(hi, dtype=np.float64).reshape(-1)
    bad = np.flatnonzero((m_lo != lo) | (m_hi != hi))
    if bad.size:
        i = int(bad[0])
        F = len(cfg.features)
        what = (f"frame {i // F + 1} feature {cfg.features[i % F]!r}" if i < F * cfg.frame_stack
                else f"IMM detector {i - F * cfg.frame_stack}")
        raise ValueError(f"{path}: the model's stored observation bounds differ from the env's in {bad.size} of "
                         f"{lo.size} entries (first: entry {i}, {what}: "
                         f"model [{m_lo[i]:g}, {m_hi[i]:g}], env [{lo[i]:g}, {hi[i]:g}]): the env config from "
                         f"{where} has other or reordered 'features' (or frame_stack) than the model was trained with")


def _check_recorded_env(path, kw, where):
    """Every argument the record of the training env names (:func:`agents.policies.bundle.recorded_env_kwargs`)
    must have the same value in the env config in use (its own, or the env's default where it names none);
    ``ValueError`` naming the first that does not."""
    rec, rec_where = recorded_env_kwargs(path)
    if rec is None:
        return
    defaults = {f.name: f.default for f in dataclasses.fields(EnvConfig)}
    for key in sorted(rec):
        if key not in kw and key not in defaults:
            continue
        used = kw.get(key, defaults.get(key))
        if not _same(rec[key], used):
            raise ValueError(f"{path}: the env config from {where} has {key}={used!r}, but the model was trained "
                             f"with {key}={rec[key]!r} (recorded in {rec_where}); give the training value")


def _same(a, b):
    """JSON-level equality with numbers compared as floats (1 == 1.0) and lists as tuples."""
    if isinstance(a, (list, tuple)) and isinstance(b, (list, tuple)):
        return len(a) == len(b) and all(_same(x, y) for x, y in zip(a, b))
    if isinstance(a, dict) and isinstance(b, dict):
        return a.keys() == b.keys() and all(_same(a[k], b[k]) for k in a)
    num = (int, float)
    if isinstance(a, num) and isinstance(b, num) and not isinstance(a, bool) and not isinstance(b, bool):
        return float(a) == float(b)
    return a == b


def model_choose_q(model, cfg: EnvConfig):
    """``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 for a stable-baselines3 model (deterministic actions), through
    the env's action map :func:`radar_env.envs.env.actions_to_q_m_s2`."""
    levels = np.asarray(cfg.q_levels_g) * G0_M_S2

    def choose_q(obs):
        act, _ = model.predict(obs.astype(np.float32), deterministic=True)
        return actions_to_q_m_s2(np.asarray(act).reshape(obs.shape[0], -1), cfg.action_type, levels)

    return choose_q


class SB3LearnedIMM:
    """A stable-baselines3 model trained on ``RadarTrack-v0`` with ``tracker="imm_cv_ct"``, as a tracker (what
    :func:`load_policy` returns for one): ``run(episodes, name)`` runs :func:`model_run_imm`."""

    is_tracker = True

    def __init__(self, model, cfg):
        self.model, self.cfg = model, cfg

    def run(self, episodes, name="policy_imm_ppo"):
        return model_run_imm(self.model, self.cfg, name)(list(episodes))


def model_run_imm(model, cfg: EnvConfig, name="policy_imm_ppo"):
    """``run(episodes) -> TrackRun`` of a stable-baselines3 model trained on ``RadarTrack-v0`` with
    ``tracker="imm_cv_ct"`` (deterministic actions): the env's lockstep
    (:func:`baselines.imm_cv_ct_runner.run_imm_lockstep`) with the model choosing the IMM's parameters from the env's
    observation (features + :func:`radar_env.envs.imm_env.detector_observation`) through the env's action map."""
    from baselines.imm_cv_ct_runner import run_imm_lockstep
    from radar_env.envs.imm_env import detector_observation, feature_q_m_s2, imm_action_map, imm_spec

    spec = imm_spec(cfg)
    amap, q = imm_action_map(cfg, spec), feature_q_m_s2(cfg)

    def choose(obs, det, rows):
        act, _ = model.predict(np.concatenate([obs, detector_observation(det)], 1), deterministic=True)
        return amap.parameters(np.asarray(act).reshape(obs.shape[0], amap.n_par))

    return lambda episodes: run_imm_lockstep(episodes, choose, cfg, spec, q, name)
