"""A saved policy as the evaluation uses it: ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 and the env config it was
trained with.

Loading a stable-baselines3 zip unpickles Python objects from it: a policy file can run code. Load only files you
trust. A recurrent policy trained by backpropagation (``.npz``, :mod:`agents.policies.recurrent`) is plain arrays
and JSON, loaded without pickle.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from radar_env.env import EnvConfig, actions_to_q_m_s2
from radar_env.units import G0_M_S2

from agents.policies.bundle import policy_env_kwargs
from agents.policies.recurrent import is_recurrent_checkpoint, load_recurrent_policy

__all__ = ["load_policy", "model_choose_q"]


def load_policy(path):
    """Load a saved policy and the env config it was trained with, by file type: a stable-baselines3 model (PPO,
    DQN, SAC, A2C or TD3 ``.zip``; ``env_config.json`` beside it, else the defaults with the model's action type)
    or a recurrent policy trained by backpropagation (``policy.npz`` with its ``policy.json`` and
    ``env_config.json``, :func:`agents.policies.recurrent.load_recurrent_policy`; no pickle).

    Returns ``(choose_q, cfg)`` where ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 (a recurrent policy is a stateful
    ``choose_q`` for :func:`baselines.trackers.run_q_policy`: ``reset(rows)``, ``choose_q(obs, rows)``). Raises
    ``ValueError`` for a file that is not such a policy, or one whose observation or action space does not match
    its env config (the message says which env kwargs it needs)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy file {str(path)!r} does not exist (or is not a file)")
    if is_recurrent_checkpoint(path):
        return load_recurrent_policy(path)
    try:
        import stable_baselines3 as sb3
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ValueError("loading a policy needs stable-baselines3: pip install -e '.[train]'") from e
    model, errors = None, []
    for algo in ("PPO", "DQN", "SAC", "A2C", "TD3"):
        try:
            model = getattr(sb3, algo).load(str(path), device="cpu")
            break
        except Exception as e:  # noqa: BLE001 - try the next algorithm class
            errors.append(f"{algo}: {type(e).__name__}")
    if model is None:
        raise ValueError(f"{path}: not a stable-baselines3 model this version can load ({'; '.join(errors)})")
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


def model_choose_q(model, cfg: EnvConfig):
    """``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 for a stable-baselines3 model (deterministic actions), through
    the env's action map :func:`radar_env.env.actions_to_q_m_s2`."""
    levels = np.asarray(cfg.q_levels_g) * G0_M_S2

    def choose_q(obs):
        act, _ = model.predict(obs.astype(np.float32), deterministic=True)
        return actions_to_q_m_s2(np.asarray(act).reshape(obs.shape[0], -1), cfg.action_type, levels)

    return choose_q
