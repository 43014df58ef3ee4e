"""The files of a learned-tracker folder: the kinds, ``policy.json`` and the two records (the layout
:mod:`agents.policies.learned` reads; docs/training.md, "Learned trackers: one folder layout").

The bottom of :mod:`agents.policies`: JSON and numpy only, so that the savers (:mod:`.bundle`'s ``ship_policy``, the
trainers) write what the loader reads without importing it.
"""

from __future__ import annotations

import json
from pathlib import Path

__all__ = ["MANIFEST", "MANIFEST_FORMAT", "MANIFEST_VERSION", "KINDS", "Q_POLICY_KINDS", "IMM_KINDS",
           "CORRECTION_KINDS", "TRACKER_KINDS", "SB3_KINDS", "BUNDLED_DIR", "BUNDLED_LEARNED", "BUNDLED_SB3",
           "weights_file", "bundled_weights_file",
           "sb3_kind", "sb3_architecture", "write_manifest", "write_records", "read_json", "write_weights_folder"]

MANIFEST = "policy.json"
"""The file naming a learned tracker's kind, beside its weights."""
MANIFEST_FORMAT = "radar-track-learned-tracker"
"""``format`` of the ``policy.json`` of a stable-baselines3 kind (the recurrent kinds keep their own formats)."""
MANIFEST_VERSION = 1

KINDS = {
    "ppo_q_policy": "a q-policy trained with PPO (stable-baselines3 MLP; policy.zip + its numpy export policy.npz)",
    "dqn_q_policy": "a q-policy trained with DQN (stable-baselines3; policy.zip + its numpy export policy.npz)",
    "sac_q_policy": "a q-policy trained with SAC (stable-baselines3; policy.zip + its numpy export policy.npz)",
    "gru_q_policy": "a recurrent (GRU) q-policy trained by backpropagation through the tracker (policy.npz)",
    "learned_imm_gru": "a learned IMM: a GRU choosing the CV/CT IMM's parameters, trained by backpropagation "
                       "(policy.npz)",
    "learned_imm_ppo": "a learned IMM: an MLP choosing the CV/CT IMM's parameters, trained with PPO on "
                       "tracker='imm_cv_ct' (policy.zip + its numpy export policy.npz)",
    "learned_imm_sac": "a learned IMM trained with SAC on tracker='imm_cv_ct' (policy.zip + policy.npz)",
    "window_correction": "a learned window correction: an MLP reading the last plots in a base tracker's frame and "
                         "moving its reported position, trained by regression (policy.npz; the base named in "
                         "policy.json)",
}
"""Every kind :func:`load_learned` runs -> what it is."""
Q_POLICY_KINDS = ("ppo_q_policy", "dqn_q_policy", "sac_q_policy", "gru_q_policy")
"""Kinds that choose the CV filter's q (run by :func:`baselines.trackers.run_q_policy`)."""
IMM_KINDS = ("learned_imm_gru", "learned_imm_ppo", "learned_imm_sac")
"""Kinds that choose the CV/CT IMM's parameters (run by their own ``run``)."""
CORRECTION_KINDS = ("window_correction",)
"""Kinds that correct a base learned tracker's output (run by their own ``run``; the base is a q-policy or an IMM)."""
TRACKER_KINDS = IMM_KINDS + CORRECTION_KINDS
"""Kinds that run episodes themselves (``is_tracker``), as opposed to a q-policy the evaluation steps."""
SB3_KINDS = ("ppo_q_policy", "dqn_q_policy", "sac_q_policy", "learned_imm_ppo", "learned_imm_sac")
"""Kinds stored as a stable-baselines3 ``policy.zip`` beside their numpy export (loaded from the zip's path)."""


BUNDLED_DIR = Path(__file__).resolve().parents[1] / "bundled"
"""Where the bundled learned trackers live, one folder each."""
BUNDLED_LEARNED = {"policy": BUNDLED_DIR / "policy", "policy_bp": BUNDLED_DIR / "backprop",
                   "policy_imm_bp": BUNDLED_DIR / "learned_imm", "policy_imm_ppo": BUNDLED_DIR / "learned_imm_ppo",
                   "policy_bp_rdot": BUNDLED_DIR / "backprop_rdot",
                   "policy_imm_bp_rdot": BUNDLED_DIR / "learned_imm_rdot",
                   "policy_imm_bp_prior": BUNDLED_DIR / "learned_imm_prior",
                   "policy_bp_prior": BUNDLED_DIR / "backprop_prior", "policy_window": BUNDLED_DIR / "window"}
"""The registry: bundled learned tracker name -> its folder (the one list of bundled trackers; a new bundle is added
here, and :data:`agents.policies.bundle.BUNDLED_POLICIES` follows)."""
BUNDLED_SB3 = ("policy", "policy_imm_ppo")
"""Bundled trackers stored as a stable-baselines3 ``policy.zip`` (the others' weights file is ``policy.npz``)."""


def weights_file(folder, kind):
    """The weights file of a learned-tracker folder of ``kind``: ``policy.zip`` for a stable-baselines3 kind
    (:data:`SB3_KINDS`; its numpy export ``policy.npz`` beside it), else ``policy.npz``."""
    return Path(folder) / ("policy.zip" if kind in SB3_KINDS else "policy.npz")


def bundled_weights_file(name):
    """The weights file of bundled learned tracker ``name``: the path the loaders and ``--policy`` options take."""
    return BUNDLED_LEARNED[name] / ("policy.zip" if name in BUNDLED_SB3 else "policy.npz")


def sb3_kind(algo, env_kwargs):
    """The kind of a stable-baselines3 model trained with ``algo`` (``"ppo"``, ``"dqn"``, ``"sac"``) on an env with
    ``env_kwargs`` (a learned IMM when ``tracker="imm_cv_ct"``). ``ValueError`` for a pair no kind describes."""
    imm = (env_kwargs or {}).get("tracker") == "imm_cv_ct"
    kind = f"learned_imm_{algo}" if imm else f"{algo}_q_policy"
    if kind not in KINDS:
        raise ValueError(f"no learned-tracker kind for algo {algo!r} with tracker={(env_kwargs or {}).get('tracker')!r}")
    return kind


def read_json(path):
    """The JSON in ``path``; ``ValueError`` (one line, naming the file) if unreadable."""
    try:
        return json.loads(Path(path).read_text())
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{path}: not readable as JSON ({msg})") from None


def sb3_architecture(npz_path):
    """The architecture of an SB3 model's numpy export, for ``policy.json``: layer sizes, activations, head."""
    import numpy as np
    with np.load(npz_path, allow_pickle=False) as z:
        n = len(z["activation"])
        sizes = [int(z["W0"].shape[1])] + [int(z[f"W{i}"].shape[0]) for i in range(n)]
        return {"algo": str(z["algo"]), "layers": sizes, "activations": [str(a) for a in z["activation"]],
                "head": str(z["head"])}


def write_manifest(folder, kind, architecture=None):
    """Write ``policy.json`` for an SB3 kind into ``folder`` (``format``, ``version``, ``kind``, ``architecture``:
    from the numpy export ``policy.npz`` when not given). The recurrent kinds' ``policy.json`` is written by their
    own savers (with ``kind``). Returns its path."""
    if kind not in SB3_KINDS:
        raise ValueError(f"kind {kind!r}: write_manifest writes the stable-baselines3 kinds {list(SB3_KINDS)}")
    folder = Path(folder)
    if architecture is None and (folder / "policy.npz").is_file():
        architecture = sb3_architecture(folder / "policy.npz")
    meta = {"format": MANIFEST_FORMAT, "version": MANIFEST_VERSION, "kind": kind, "architecture": architecture,
            "weights": "policy.npz" if (folder / "policy.npz").is_file() else None, "sb3_model": "policy.zip"}
    (folder / MANIFEST).write_text(json.dumps(meta, indent=1) + "\n")
    return folder / MANIFEST


def write_records(folder, training=None, choice=None):
    """Write the training record (``training.json``) and the choice record (``choice.json``) into ``folder``;
    ``None`` leaves a record unwritten."""
    folder = Path(folder)
    for fname, rec in (("training.json", training), ("choice.json", choice)):
        if rec is not None:
            (folder / fname).write_text(json.dumps(rec, indent=1, allow_nan=False) + "\n")


def write_weights_folder(directory, kind, fmt, version, weights, config, env_kwargs):
    """Write a ``policy.npz`` kind's folder (the recurrent q-policy, the learned IMM, the window correction):
    ``policy.npz`` (``weights`` as float64 arrays), ``policy.json`` (``kind``, ``format`` ``fmt``, ``version`` and
    ``config``) and ``env_config.json`` (``env_kwargs``); no NaN or infinity in the JSON. Returns the ``.npz`` path."""
    import numpy as np
    d = Path(directory)
    d.mkdir(parents=True, exist_ok=True)
    np.savez(d / "policy.npz", **{k: np.asarray(v, dtype=np.float64) for k, v in weights.items()})
    meta = {"kind": kind, "format": fmt, "version": version, **config}
    (d / MANIFEST).write_text(json.dumps(meta, indent=1, allow_nan=False))
    (d / "env_config.json").write_text(json.dumps(env_kwargs, indent=1, allow_nan=False))
    return d / "policy.npz"
