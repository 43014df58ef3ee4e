"""Adapter: the native batched :class:`radar_env.envs.env.RadarTrackVectorEnv` as a stable-baselines3 ``VecEnv``.

SB3 cannot consume a Gymnasium ``VectorEnv`` directly. Both use same-step autoreset, so the adapter only
translates the conventions:

=========================  ==========================================  ============================================
                           Gymnasium vector env (ours)                 SB3 ``VecEnv``
=========================  ==========================================  ============================================
reset                      ``reset(seed=s) -> (obs, info)``            ``seed(s)`` then ``reset() -> obs``
step                       ``obs, rew, terminated, truncated, info``   ``obs, rew, done, [info_i]``
last obs of an episode     ``info["final_obs"][i]`` (mask              ``infos[i]["terminal_observation"]``
                           ``info["_final_obs"]``)
time limit                 ``truncated[i]``                            ``infos[i]["TimeLimit.truncated"]``
=========================  ==========================================  ============================================

Seeding: ``seed(s)`` seeds row ``i`` with ``s + i`` at the next ``reset()``, as ``DummyVecEnv.seed(s)`` seeds env
``i`` with ``s + i`` and as ``RadarTrackVectorEnv.reset(seed=s)`` does, so the adapter reproduces a
``DummyVecEnv`` of single ``RadarTrackEnv``s transition for transition (tests/test_train.py checks it).

Per-row info dicts hold ``TimeLimit.truncated`` (every row, as ``DummyVecEnv``) and, for rows that ended,
``terminal_observation`` and ``track_lost``, unless ``full_info=True`` (every key of the single env's info, as ``DummyVecEnv`` would give;
slower, for tests and debugging). Episode returns/lengths for logging come from wrapping in SB3's ``VecMonitor``.
"""

from __future__ import annotations

import time

import numpy as np
from stable_baselines3.common.vec_env.base_vec_env import VecEnv

from radar_env.envs.env import RadarTrackVectorEnv, _row

__all__ = ["RadarTrackSB3VecEnv", "make_sb3_vec_env"]


def _strip(info):
    """Batched info without the Gymnasium mask keys and the final_* entries (a plain batched info dict)."""
    out = {}
    for k, v in info.items():
        if k.startswith("_") or k in ("final_obs", "final_info"):
            continue
        out[k] = _strip(v) if isinstance(v, dict) else v
    return out


class RadarTrackSB3VecEnv(VecEnv):
    """SB3 ``VecEnv`` over one :class:`RadarTrackVectorEnv` (N tracks in one set of numpy arrays).

    Args:
        venv: a ``RadarTrackVectorEnv`` (or build one from ``num_envs`` and ``env_kwargs``).
        full_info: give every row the single env's full info dict each step (slow; default only ended rows).

    ``env_time_s`` accumulates the wall time spent inside the vector env's ``step``/``reset`` (for the
    env-share-of-wall-time measurement of a training run).
    """

    def __init__(self, venv: RadarTrackVectorEnv, full_info: bool = False):
        self.venv = venv
        self.full_info = bool(full_info)
        self.env_time_s = 0.0
        self.env_steps = 0
        self._actions = None
        super().__init__(venv.num_envs, venv.single_observation_space, venv.single_action_space)

    # ---- core API
    def reset(self):
        seeds = self._seeds
        seed = None if all(s is None for s in seeds) else [None if s is None else int(s) for s in seeds]
        opts = self._options[0] if self._options and self._options[0] else None
        t0 = time.perf_counter()
        obs, info = self.venv.reset(seed=seed, options=opts)
        self.env_time_s += time.perf_counter() - t0
        plain = _strip(info)
        self.reset_infos = [_row(plain, i) if self.full_info else {} for i in range(self.num_envs)]
        self._reset_seeds()
        self._reset_options()
        return obs

    def step_async(self, actions):
        self._actions = np.asarray(actions)

    def step_wait(self):
        t0 = time.perf_counter()
        obs, rew, term, trunc, info = self.venv.step(self._actions)
        self.env_time_s += time.perf_counter() - t0
        self.env_steps += self.num_envs
        dones = term | trunc
        if self.full_info:
            plain = _strip(info)
            infos = [_row(plain, i) for i in range(self.num_envs)]
        else:
            infos = [{} for _ in range(self.num_envs)]
        tl = trunc & ~term
        for i in range(self.num_envs):
            infos[i]["TimeLimit.truncated"] = bool(tl[i])
        if np.any(dones):
            final = _strip(info["final_info"]) if self.full_info else None
            for i in np.flatnonzero(dones):
                if self.full_info:
                    infos[i] = _row(final, i)
                infos[i]["TimeLimit.truncated"] = bool(tl[i])
                infos[i]["terminal_observation"] = info["final_obs"][i]
                infos[i]["track_lost"] = bool(term[i])
        return obs, rew.astype(np.float32), dones.astype(bool), infos

    def close(self):
        self.venv.close()

    # ---- attribute access (minimal: every row shares one config)
    def get_attr(self, attr_name, indices=None):
        idx = list(self._get_indices(indices))
        if attr_name == "render_mode":
            val = self.venv.config.render_mode
        elif attr_name == "env_time_s":
            val = self.env_time_s
        else:
            val = getattr(self.venv, attr_name)
        return [val for _ in idx]

    def set_attr(self, attr_name, value, indices=None):
        setattr(self.venv, attr_name, value)

    def env_method(self, method_name, *method_args, indices=None, **method_kwargs):
        idx = list(self._get_indices(indices))
        res = getattr(self.venv, method_name)(*method_args, **method_kwargs)
        return [res for _ in idx]

    def env_is_wrapped(self, wrapper_class, indices=None):
        return [False for _ in self._get_indices(indices)]

    def get_images(self):
        return [None for _ in range(self.num_envs)]


def make_sb3_vec_env(n_envs, env_kwargs=None, seed=None, monitor=True, full_info=False):
    """``VecMonitor(RadarTrackSB3VecEnv(RadarTrackVectorEnv(n_envs, **env_kwargs)))``, seeded with ``seed``
    (row i gets ``seed + i`` at the first reset). Returns ``(vec_env, adapter)``."""
    adapter = RadarTrackSB3VecEnv(RadarTrackVectorEnv(int(n_envs), **dict(env_kwargs or {})), full_info=full_info)
    if seed is not None:
        adapter.seed(int(seed))
    env = adapter
    if monitor:
        from stable_baselines3.common.vec_env import VecMonitor
        env = VecMonitor(adapter)
    return env, adapter
