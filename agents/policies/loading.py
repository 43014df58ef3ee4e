"""A saved policy as the evaluation uses it: ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 and the env config it was
trained with.

Loading a stable-baselines3 zip unpickles Python objects from it: a policy file can run code. Load only files you
trust. A zip with a current numpy export beside it (``policy.npz``, :mod:`agents.policies.numpy_policy`; the bundled
policies have one) is not unpickled: the export holds arrays only, and the policy then runs without torch or SB3.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from radar_env.env import EnvConfig, actions_to_q_m_s2
from radar_env.units import G0_M_S2

from agents.policies.bundle import policy_env_kwargs
from agents.policies.numpy_policy import load_sb3_model

__all__ = ["load_policy", "load_model", "load_sb3_model", "model_choose_q"]


def load_policy(path):
    """Load a saved stable-baselines3 model (PPO, DQN, SAC, A2C or TD3 zip) and the env config it was trained
    with (``env_config.json`` beside it, else the defaults with the model's action type).

    Returns ``(choose_q, cfg)`` where ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2, evaluated in numpy wherever the
    model's structure allows (:func:`load_model`). Raises ``ValueError`` for a file
    that is not such a model, or a model whose observation or action space does not match its env config (the
    message says which env kwargs it needs)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy file {str(path)!r} does not exist (or is not a file)")
    model = load_model(path)
    cfg_file = path.with_name("env_config.json")
    kw = policy_env_kwargs(path) if cfg_file.is_file() else {}
    from gymnasium import spaces
    discrete = isinstance(model.action_space, spaces.Discrete)
    kw.setdefault("action_type", "discrete" if discrete else "continuous")
    try:
        cfg = EnvConfig.from_kwargs(**kw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{cfg_file}: {e}") from None
    where = str(cfg_file) if cfg_file.is_file() else f"the defaults (no {cfg_file.name} beside {path.name})"
    n_obs = int(np.prod(model.observation_space.shape))
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
    choose_q = model_choose_q(model, cfg)
    return choose_q, cfg


def load_model(path):
    """The policy in the zip ``path`` as an object with ``observation_space``, ``action_space`` and SB3's
    ``predict``: its numpy export (:class:`agents.policies.numpy_policy.NumpyPolicy`) from the ``.npz`` beside it
    when that was exported from this very file (no torch, no SB3, no unpickling); else the SB3 model, exported to
    numpy in memory when its structure allows and the export reproduces its actions (checked), else the SB3 model
    itself. A damaged or out-of-date ``.npz`` is ignored with a warning on stderr."""
    from agents.policies import numpy_policy as npp
    try:
        pol = npp.load_export(path)
        if pol is not None:
            return pol
        if npp.export_path(path).is_file():
            print(f"warning: {npp.export_path(path)} was exported from another file than {path}; ignored (re-export "
                  f"with python -m agents.policies.numpy_policy {path})", file=sys.stderr)
    except ValueError as e:
        print(f"warning: {e}; loading {path} with stable-baselines3 instead", file=sys.stderr)
    model = load_sb3_model(path)
    arrays = npp.export_model(model)
    if arrays is None:
        return model
    pol = npp.NumpyPolicy(arrays)
    ok, _ = npp.check_export(pol, model)
    return pol if ok else model


def model_choose_q(model, cfg: EnvConfig):
    """``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 for a stable-baselines3 model (deterministic actions), through
    the env's action map :func:`radar_env.env.actions_to_q_m_s2`."""
    levels = np.asarray(cfg.q_levels_g) * G0_M_S2

    def choose_q(obs):
        act, _ = model.predict(obs.astype(np.float32), deterministic=True)
        return actions_to_q_m_s2(np.asarray(act).reshape(obs.shape[0], -1), cfg.action_type, levels)

    return choose_q
