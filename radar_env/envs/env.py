"""RadarTrack-v0: choose the Kalman filter's process-noise level every radar look.

The Gymnasium layer over the simulation and the tracking chain, split by role: the configuration
(:mod:`radar_env.envs.config`: :class:`EnvConfig`), the batched core (:mod:`radar_env.envs.core`: ``_Core``, the action map,
reward and info), the single env (:mod:`radar_env.envs.single_env`: :class:`RadarTrackEnv`) and the native batched
vector env (:mod:`radar_env.envs.vector_env`: :class:`RadarTrackVectorEnv`). Both envs run the same batched core, which
runs the one tracking chain (:class:`radar_env.filters.tracking.Tracker`). This module re-exports them, so
``radar_env.envs.env:RadarTrackEnv`` and ``from radar_env.envs.env import EnvConfig, ...`` keep working.
"""

from __future__ import annotations

from .config import (DEFAULT_Q_LEVELS_G, RENDER_MODES, REWARD_SCALE_M, REWARD_TYPES, EnvConfig,  # noqa: F401
                     resolve_scenario)
from .core import (MAX_EPISODE_DRAWS, _Core, _row, actions_to_q_m_s2,  # noqa: F401
                   draw_setup_and_episode)
from .single_env import RadarTrackEnv
from .vector_env import RadarTrackVectorEnv, _with_masks  # noqa: F401

__all__ = ["RadarTrackEnv", "RadarTrackVectorEnv", "EnvConfig", "DEFAULT_Q_LEVELS_G", "resolve_scenario",
           "draw_setup_and_episode", "actions_to_q_m_s2"]
