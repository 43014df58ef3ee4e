"""The constant-velocity and coordinated-turn motion model: ``F_cv(dt)`` and ``F_ct(dt, omega)``.

One compiled formula (exact sinc forms, smooth at ``omega = 0``) shared by the truth generator
(:mod:`radar_env.sim.scenario`) and the filters (:mod:`radar_env.filters.kernels`, :mod:`radar_env.filters.kalman`),
so that the truth and the CT filter use the same kinematics. Equations in :mod:`radar_env.filters.kalman`.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numba import njit

from ..common.arrays import c_array
from ..common.numba_cache import drop_stale_kernels, package_sources

__all__ = ["transition_cv", "transition_ct", "k_transition"]


@njit(cache=True)
def _sinc(x):
    # numpy's sinc(x) = sin(pi x)/(pi x), 1 at 0
    if x == 0.0:
        return 1.0
    y = math.pi * x
    return math.sin(y) / y


@njit(cache=True)
def _transition(dt, w, ct, F):
    """F_cv(dt) (``ct`` False) or F_ct(dt, w) into F (4,4)."""
    for i in range(4):
        for j in range(4):
            F[i, j] = 0.0
    F[0, 0] = F[1, 1] = F[2, 2] = F[3, 3] = 1.0
    if not ct:
        F[0, 2] = F[1, 3] = dt
        return
    theta = w * dt
    s, c = math.sin(theta), math.cos(theta)
    a = dt * _sinc(theta / math.pi)
    sc = _sinc(theta / (2.0 * math.pi))
    b = dt * (theta / 2.0) * (sc * sc)
    F[0, 2], F[0, 3] = a, b
    F[1, 2], F[1, 3] = -b, a
    F[2, 2], F[2, 3] = c, s
    F[3, 2], F[3, 3] = -s, c


@njit(cache=True)
def k_transition(dt, w, ct, F):
    for b in range(dt.shape[0]):
        _transition(dt[b], w[b], ct, F[b])


def _as_batch(a) -> np.ndarray:
    return np.atleast_1d(np.asarray(a, dtype=np.float64))


def _flat(a, shape, tail):
    """``a`` broadcast to ``shape + tail``, as a C-contiguous float64 array of shape ``(-1,) + tail``."""
    return c_array(np.broadcast_to(np.asarray(a, dtype=np.float64), shape + tail)).reshape((-1,) + tail)


def transition_cv(dt_s) -> np.ndarray:
    """Constant-velocity transition matrices ``F (B,4,4)`` for time steps ``dt_s (B,)``."""
    dt = _as_batch(dt_s)
    F = np.empty((dt.size, 4, 4))
    k_transition(c_array(dt).reshape(-1), np.zeros(dt.size), False, F)
    return F.reshape(dt.shape + (4, 4))


def transition_ct(dt_s, turn_rate_rad_s) -> np.ndarray:
    """Coordinated-turn transition matrices ``F (B,4,4)``; exact kinematics of a constant-speed turn.

    Args:
        dt_s: time steps (B,) or scalar.
        turn_rate_rad_s: heading rate (B,) or scalar, positive = clockwise (right turn). Zero gives ``F_cv``.
    """
    # sin(theta)/w = dt*sinc(theta); (1-cos(theta))/w = dt*(theta/2)*sinc(theta/2)^2 -- exact, smooth at w = 0.
    dt, w = np.broadcast_arrays(_as_batch(dt_s), _as_batch(turn_rate_rad_s))
    F = np.empty((dt.size, 4, 4))
    k_transition(_flat(dt, dt.shape, ()), _flat(w, dt.shape, ()), True, F)
    return F.reshape(dt.shape + (4, 4))


# numba keys each cached kernel on its own file only: drop this folder's cached kernels (motion, draws) when any
# source of radar_env changed (radar_env.common.numba_cache), before a kernel here loads from the cache
drop_stale_kernels(k_transition, package_sources(Path(__file__).parents[1]))
