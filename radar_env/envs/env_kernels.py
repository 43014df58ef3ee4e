r"""Compiled kernels of RadarTrack-v0's step and reset: the tracking chain of :mod:`radar_env.filters.kernels` (called, not
copied), then the observation (:class:`radar_env.envs.observation.ObservationLayout`'s scaling, frame stacking), the
reward's position and track-loss terms and the end flags, written into the caller's arrays in one call for all rows.

Layouts (module constants):

* the env parameter vector ``ep`` (``EP_*``): the action map, the reward, the warm-up and the frame stack, then the
  q levels (from ``ep[EP_LEVELS]``) and the observation plan (from ``ep[EP_PLAN]``, ``W_PLAN`` floats per entry);
* the outputs of one call: ``obs (n, frame_stack * F)`` float32, ``fo (n, W_FO)`` float (the info's vectors:
  ``FO_*``), ``fs (W_FS, n)`` float and ``bo (W_BO, n)`` bool (per-row scalars, one contiguous row per quantity:
  ``FS_*``, ``BO_*``).

An observation entry of the plan is ``(special, column, divisor, kind, scale, low, high)``: ``special`` 0 reads
feature column ``column`` of the step's feature row (:data:`radar_env.filters.kernels.BANK_FLOAT_KEYS` +
``PREVIEW_KEYS``) over ``divisor``; the other ``SP_*`` values are the entries that are not a feature over a divisor
(degrees and Kim & Lee's q of feature ``column``, dt, the position-std ratio from the range in ``column``, the
previous q, the detection flag). ``kind`` is the scaling (``KIND_*``): linear ``x / scale``, ``log10(1 + max(x, 0)) / scale`` or the action map of q; NaN -> 0, then clipped
to ``[low, high]`` and rounded to float32: the operations of the numpy scaling, in its order (bit for bit).
"""

from __future__ import annotations

import math
import sys
from pathlib import Path

import numpy as np
from numba import njit, prange

from ..common.numba_cache import drop_stale_kernels, package_sources
from ..filters import kernels as _k
from ..filters.kernels import _scratch, _step_row, _track_start_row
from ..common.units import G0_M_S2

# ---------------------------------------------------------------------------------------------------- layouts
EP_ACT_CONT, EP_NLEV, EP_L0, EP_L1, EP_LQ0, EP_LQ1, EP_WARM_Q, EP_GATE, EP_CLIP, EP_RKIND = range(10)
EP_MAX_STEPS, EP_NFEAT, EP_NSTACK, EP_LEVELS, EP_PLAN, EP_WARM_N, EP_SCALE_M = range(10, 17)
W_EP_HEAD = 17
RK_SQUARED, RK_ABSOLUTE, RK_SQUARED_M = 0, 1, 2
REWARD_KINDS = {"squared": RK_SQUARED, "absolute": RK_ABSOLUTE, "squared_m": RK_SQUARED_M}

PL_SPECIAL, PL_COL, PL_DIV, PL_KIND, PL_SCALE, PL_LOW, PL_HIGH = range(7)
W_PLAN = 7
SP_COLUMN, SP_DEGREES, SP_KIM_LEE_Q, SP_DT, SP_POS_STD, SP_Q_PREV, SP_DETECTED = range(7)
KIND_LINEAR, KIND_LOG10P, KIND_LOGQ = 0, 1, 2

FO_TRUTH, FO_X, FO_P, FO_Z, FO_R, FO_POLAR = 0, 4, 8, 24, 26, 30
W_FO = 33
FS_REWARD, FS_POS, FS_LOST, FS_Q, FS_DT, FS_T = range(6)
W_FS = 6
BO_DET, BO_MAN, BO_LOST, BO_TRUNC, BO_DONE = range(5)
W_BO = 5

ST_OK, ST_ACTION_SHAPE, ST_ACTION_RANGE, ST_ENDED = 0, 1, 2, 3

_RAD2DEG = 180.0 / math.pi   # numpy's degrees(x) is x * (180 / pi)


# ---------------------------------------------------------------------------------------------- numpy semantics
@njit(cache=True, inline="always")
def _np_max(a, b):
    """numpy.maximum of two floats: NaN propagates, b on ties (so the sign of a zero is numpy's)."""
    return a if (a > b or a != a) else b


@njit(cache=True, inline="always")
def _np_min(a, b):
    """numpy.minimum of two floats (NaN propagates, b on ties)."""
    return a if (a < b or a != a) else b


# --------------------------------------------------------------------------------------------------- observation
@njit(cache=True, inline="always")
def _meas_sigma(range_m, sr, sb):
    """observation.measurement_sigma_m: per-axis RMS noise of a plot, ``sqrt((sr^2 + (r sb)^2) / 2)``."""
    rb = range_m * sb
    return math.sqrt(0.5 * (sr * sr + rb * rb))


@njit(cache=True, inline="always")
def _physical(plan, j, of, dt, p00, p11, sr, sb, det, q_prev):
    """Physical value of observation entry ``j`` (plan row ``j``; indexed, no row view in the hot loop) from a
    step's feature row ``of`` and outputs."""
    sp = int(plan[j, PL_SPECIAL])
    if sp == SP_COLUMN:
        return of[int(plan[j, PL_COL])] / plan[j, PL_DIV]
    if sp == SP_DEGREES:
        return of[int(plan[j, PL_COL])] * _RAD2DEG
    if sp == SP_KIM_LEE_Q:
        return math.sqrt(_np_max(of[int(plan[j, PL_COL])], 0.0)) / G0_M_S2
    if sp == SP_DT:
        return dt
    if sp == SP_POS_STD:
        return math.sqrt(0.5 * (p00 + p11)) / _meas_sigma(of[int(plan[j, PL_COL])], sr, sb)
    if sp == SP_Q_PREV:
        return q_prev / G0_M_S2
    return 1.0 if det else 0.0


@njit(cache=True, inline="always")
def _scale(plan, j, v, lq0, lq1):
    """Physical value ``v`` -> observation entry ``j``: scaling, NaN -> 0, clip, float32."""
    kind = int(plan[j, PL_KIND])
    if kind == KIND_LINEAR:
        o = v / plan[j, PL_SCALE]
    elif kind == KIND_LOG10P:
        o = math.log10(1.0 + _np_max(v, 0.0)) / plan[j, PL_SCALE]
    else:
        lq = math.log10(_np_max(v, 1e-12))
        o = 2.0 * (lq - lq0) / (lq1 - lq0) - 1.0
    if o != o:
        o = 0.0
    return np.float32(_np_min(_np_max(o, plan[j, PL_LOW]), plan[j, PL_HIGH]))


@njit(cache=True, inline="always")
def _encode_row(plan, lq0, lq1, of, dt, p00, p11, sr, sb, det, q_prev, out):
    """The observation of one step into ``out`` (F,) float32."""
    for j in range(plan.shape[0]):
        out[j] = _scale(plan, j, _physical(plan, j, of, dt, p00, p11, sr, sb, det, q_prev), lq0, lq1)


@njit(cache=True)
def k_physical(plan, of, dt, p00, p11, sr, sb, det, q_prev, phys):
    """ObservationLayout.physical for n rows: ``phys (n, F)`` float."""
    for i in range(of.shape[0]):
        for j in range(plan.shape[0]):
            phys[i, j] = _physical(plan, j, of[i], dt[i], p00[i], p11[i], sr[i], sb[i], det[i], q_prev[i])


@njit(cache=True)
def k_scale(plan, lq0, lq1, phys, obs):
    """ObservationLayout.encode_physical: ``phys (n, F)`` physical values -> ``obs (n, F)`` float32."""
    for i in range(phys.shape[0]):
        for j in range(plan.shape[0]):
            obs[i, j] = _scale(plan, j, phys[i, j], lq0, lq1)


@njit(cache=True)
def k_encode(plan, lq0, lq1, of, dt, p00, p11, sr, sb, det, q_prev, obs):
    """ObservationLayout.encode for n rows of step outputs: ``obs (n, F)`` float32."""
    for i in range(of.shape[0]):
        _encode_row(plan, lq0, lq1, of[i], dt[i], p00[i], p11[i], sr[i], sb[i], det[i], q_prev[i], obs[i])


# ------------------------------------------------------------------------------------------------------ env rows
@njit(cache=True)
def _plan(ep):
    F = int(ep[EP_NFEAT])
    a = int(ep[EP_PLAN])
    return ep[a:a + F * W_PLAN].reshape((F, W_PLAN))


@njit(cache=True, inline="always")
def _reward_terms(x0, x1, lk, remaining, lost_gate, ep):
    """The reward's position and track-loss terms of the estimated position ``(x0, x1)`` at look ``lk``, with
    ``remaining`` looks after it; returns ``(position_error, track_lost, lost)`` (its NEES term:
    core._Core._inconsistency). The error over the plot noise at the true range (observation.measurement_sigma_m),
    or in units of REWARD_SCALE_M; lost (only if ``lost_gate``) when that error exceeds the gate."""
    tx, ty = lk[_k.L_TRUTH], lk[_k.L_TRUTH + 1]
    r_true = math.hypot(tx - lk[_k.L_SITE], ty - lk[_k.L_SITE + 1])
    err_m = math.hypot(x0 - tx, x1 - ty)
    e = err_m / _meas_sigma(r_true, lk[_k.L_RSTD], lk[_k.L_BSTD])
    lost = lost_gate and e > ep[EP_GATE]
    kind = int(ep[EP_RKIND])
    clip = ep[EP_CLIP]
    if kind == RK_SQUARED_M:
        e = err_m / ep[EP_SCALE_M]
    pos = -_np_min(e if kind == RK_ABSOLUTE else e * e, clip)
    tl = -clip * remaining if lost else 0.0
    return pos, tl, lost


@njit(cache=True, inline="always")
def _emit(i, r, q, t_prev, lost_gate, ep, plan, st, it, looks, of, frames, new_episode, obs, fo, fs, bo):
    """Outputs of row ``r`` (output index ``i``) after a step or a track start: observation (stacked), the info's
    vectors and scalars, the reward's position and track-loss terms; returns (lost, done)."""
    k = it[r, _k.I_K] - 1
    lk = looks[r, k]
    x = st[r, _k.S_X:_k.S_X + 4]
    P = st[r, _k.S_P:_k.S_P + 16]
    t = lk[_k.L_T]
    dt = t - t_prev
    det = lk[_k.L_DET] != 0.0
    # observation, then the frame stack (newest first; a new episode repeats its first frame)
    F = int(ep[EP_NFEAT])
    ns = int(ep[EP_NSTACK])
    o = obs[i]
    _encode_row(plan, ep[EP_LQ0], ep[EP_LQ1], of, dt, P[0], P[5], lk[_k.L_RSTD], lk[_k.L_BSTD], det, q, o)
    if ns > 1:
        fr = frames[r]
        if new_episode:
            for m in range(1, ns):
                for j in range(F):
                    o[m * F + j] = o[j]
        else:
            for m in range(1, ns):
                for j in range(F):
                    o[m * F + j] = fr[m - 1, j]
        for m in range(ns):
            for j in range(F):
                fr[m, j] = o[m * F + j]
    # info vectors
    f = fo[i]
    for a in range(4):
        f[FO_TRUTH + a] = lk[_k.L_TRUTH + a]
        f[FO_X + a] = x[a]
        f[FO_R + a] = lk[_k.L_R + a]
    for a in range(16):
        f[FO_P + a] = P[a]
    f[FO_Z], f[FO_Z + 1] = lk[_k.L_Z], lk[_k.L_Z + 1]
    f[FO_POLAR], f[FO_POLAR + 1], f[FO_POLAR + 2] = lk[_k.L_RANGE], lk[_k.L_BEAR], lk[_k.L_RDOT]
    pos, tl, lost = _reward_terms(x[0], x[1], lk, float(it[r, _k.I_N] - it[r, _k.I_K]), lost_gate, ep)
    fs[FS_POS, i] = pos
    fs[FS_LOST, i] = tl
    fs[FS_REWARD, i] = pos + tl
    fs[FS_Q, i], fs[FS_DT, i], fs[FS_T, i] = q, dt, t
    done = it[r, _k.I_K] >= it[r, _k.I_N]
    bo[BO_DET, i] = det
    bo[BO_MAN, i] = lk[_k.L_MAN] != 0.0
    bo[BO_LOST, i] = lost
    return lost, done


@njit(cache=True)
def _check_actions(act, ep):
    """Validate the actions as core._Core.action_to_q does (the checks in its order): ST_ACTION_SHAPE for a
    non-integer discrete action, ST_ACTION_RANGE for one out of range (a continuous one beyond [-1, 1] is
    ST_ACTION_SHAPE as there)."""
    n = act.shape[0]
    if ep[EP_ACT_CONT] != 0.0:
        for i in range(n):
            if not abs(act[i]) <= 1.0 + 1e-6:
                return ST_ACTION_SHAPE
        return ST_OK
    for i in range(n):
        a = act[i]
        if not (math.isfinite(a) and a == math.floor(a)):
            return ST_ACTION_SHAPE
    for i in range(n):
        if not (act[i] >= 0.0 and act[i] < ep[EP_NLEV]):
            return ST_ACTION_RANGE
    return ST_OK


@njit(cache=True)
def _continuous_q(a, l0, l1):
    """The continuous action map: ``a`` clipped to [-1, 1] -> ``10^(l0 + (a + 1) / 2 (l1 - l0))`` (l0, l1: log10
    of the first and last level)."""
    if a < -1.0:   # numpy.clip: NaN stays NaN
        a = -1.0
    elif a > 1.0:
        a = 1.0
    return 10.0 ** (l0 + 0.5 * (a + 1.0) * (l1 - l0))


@njit(cache=True)
def k_continuous_q(a, l0, l1, q):
    for i in range(a.shape[0]):
        q[i] = _continuous_q(a[i], l0, l1)


@njit(cache=True)
def _action_q(a, ep):
    """core.actions_to_q_m_s2 for one validated action."""
    if ep[EP_ACT_CONT] == 0.0:
        return ep[int(ep[EP_LEVELS]) + int(a)]
    return _continuous_q(a, ep[EP_L0], ep[EP_L1])


@njit(cache=True)
def k_action_q(act, ep, q):
    """Validated actions -> q (core._Core.action_to_q); returns a status ``ST_*``."""
    s = _check_actions(act, ep)
    if s == ST_OK:
        for i in range(act.shape[0]):
            q[i] = _action_q(act[i], ep)
    return s


@njit(cache=True)
def _init_looks(looks, r, K):
    """tracking.init_looks on the packed looks of row ``r``: the first detection and the next detection at a
    strictly later time; (-1, -1) if none."""
    i1 = -1
    for k in range(K):
        if looks[r, k, _k.L_DET] != 0.0:
            if i1 < 0:
                i1 = k
            elif looks[r, k, _k.L_T] > looks[r, i1, _k.L_T]:
                return i1, k
    return -1, -1


@njit(cache=True)
def k_env(rows, act, ep, st, it, looks, bf, bi, bb, par, frames, elapsed, ext, obs, fo, fs, bo, chunks):
    """The env's one kernel (one compilation of the chain for both uses):

    * ``rows`` empty: one step of every row: action ``act[i]`` -> q (validated), the chain's look
      (:func:`radar_env.filters.kernels._step_row`), observation, reward, end flags (``BO_LOST`` = terminated, ``BO_TRUNC``,
      ``BO_DONE`` = either) at output index i. ``elapsed`` counts steps since each row's start (``EP_MAX_STEPS``
      > 0 truncates there, as gym's TimeLimit). Returns a status ``ST_*``; nothing is changed unless ST_OK.
    * ``rows`` given: start the episodes already in their looks (two-hit start, ``warmup_scans`` looks at the
      warm-up q) and write their first observation (stack) and info at output index ``rows[j]``. Returns
      ``-1 - j`` if row ``rows[j]`` has no two hits at different times or too few looks for the warm-up (nothing
      is started then), else ST_OK.

    ``ext (n, W)`` holds row r's values of features computed outside the chain (:mod:`radar_env.envs.detectors`),
    appended to its feature row as columns ``W_FEAT ..`` for the observation plan (W = 0: none).

    ``chunks`` (>= 1): the rows are processed in that many contiguous blocks, each with its own scratch; the rows
    are independent (each reads and writes only its own state, looks, frames and output index), so the parallel
    build of this function (:func:`radar_env.common.parallel.run`) runs the blocks on several threads with the
    same numbers. This build runs them one after the other (1 block: the serial env).
    """
    start = rows.shape[0] > 0
    nw = int(ep[EP_WARM_N])
    if start:
        for j in range(rows.shape[0]):
            r = rows[j]
            i1, i2 = _init_looks(looks, r, it[r, _k.I_N])
            if i1 < 0 or it[r, _k.I_N] < i2 + 1 + nw:
                return -1 - j
        n = rows.shape[0]
    else:
        n = act.shape[0]
        s = _check_actions(act, ep)
        if s != ST_OK:
            return s
        for i in range(n):
            if it[i, _k.I_K] >= it[i, _k.I_N]:
                return ST_ENDED
    max_steps = int(ep[EP_MAX_STEPS])
    plan = _plan(ep)
    no = n < 0   # a run-time False: a literal would compile another specialisation of the chain
    # rows in ``chunks`` blocks, each with its own scratch: prange runs the blocks on numba's threads in the
    # parallel build (radar_env.common.parallel) and is range in this one (chunks = 1: one block, as before)
    for blk in prange(chunks):
        F, Q, FP, u, R, zz, xh = _scratch()
        xp, xo, nu = np.empty(4), np.empty(4), np.empty(2)
        Pp, Po, S = np.empty((4, 4)), np.empty((4, 4)), np.empty((2, 2))
        of = np.empty(_k.W_FEAT + ext.shape[1])
        ofb = np.empty(_k.W_BANK_OUTB, dtype=np.bool_)
        seed_xy, R1, R2, seed_t = np.empty((2, 2)), np.empty((2, 2)), np.empty((2, 2)), np.empty(2)
        for j in range(blk * n // chunks, (blk + 1) * n // chunks):
            if start:   # two-hit start, then the warm-up looks at the warm-up q
                r = rows[j]
                i1, i2 = _init_looks(looks, r, it[r, _k.I_N])
                _track_start_row(r, i1, i2, st, it, looks, bf, bi, bb, par, seed_xy, seed_t, R1, R2)
                q, n_rep = ep[EP_WARM_Q], nw
            else:
                r = j
                q, n_rep = _action_q(act[j], ep), 1
            t_prev = 0.0
            for _ in range(n_rep):
                t_prev = st[r, _k.S_T]
                _step_row(r, q, 0.0, no, no, st, it, looks, bf, bi, bb, par, xp, Pp, xo, Po, nu, S, of, ofb, F, Q, FP,
                          u, R, zz, xh)
            for c in range(ext.shape[1]):
                of[_k.W_FEAT + c] = ext[r, c]
            lost, done = _emit(r, r, q, t_prev, not start, ep, plan, st, it, looks, of, frames, start, obs, fo, fs,
                               bo)
            trunc = done and not lost
            elapsed[r] = 0 if start else elapsed[r] + 1
            if max_steps > 0 and elapsed[r] >= max_steps:
                trunc = True
            if start:
                trunc = False
            bo[BO_TRUNC, r] = trunc
            bo[BO_DONE, r] = lost or trunc
            if lost or trunc:
                elapsed[r] = 0
    return ST_OK


COLD_COMPILE_S = 15
"""About how long the first use compiles the env's kernels with an empty numba cache on a 2-core machine (s;
docs/speed.md)."""

_announced = False


def announce_compilation(*extra):
    """Print one line to stderr when the env's kernels (and ``extra`` dispatchers) are about to be compiled because
    numba's cache holds none of them (first run, or a changed source); silent when the cache is warm or they are
    compiled in this process already. Reads numba's cache index (an internal API: any surprise there says
    nothing)."""
    global _announced
    if _announced:
        return
    _announced = True
    from ..sim import draws
    kernels = (k_env, draws._random_rows, draws.k_fill_random_looks) + extra
    try:
        cold = any(not d.overloads and not d._cache._cache_file._load_index() for d in kernels)
    except Exception:   # noqa: BLE001 - numba internals changed: stay quiet rather than fail
        return
    if cold:
        print(f"radar_env: compiling the filter kernels (first run only, about {COLD_COMPILE_S} s)", file=sys.stderr,
              flush=True)


# numba keys each cached kernel on its own file only: drop this folder's cached kernels (env_kernels, imm_env,
# detectors import this module first) when any source of radar_env changed (radar_env.common.numba_cache)
drop_stale_kernels(k_env, package_sources(Path(__file__).parents[1]))
