"""Episodes drawn for many rows at once: compiled (numba) kernels for the random scenarios, the radars and the plots.

:func:`draw_episodes` returns an :class:`radar_env.sim.episode.EpisodeBatch` with one row per generator in ``rngs``;
the env draws through it (``draw_setup_and_episode`` is a batch of one, so row ``i`` of a vector env seeded ``s``
is the single env seeded ``s + i``). It replaces the per-episode Python chain ``random_scenario`` ->
``place_radar_site`` -> ``make_setup`` -> ``draw_episode`` (about 1.4 ms per episode) by two loops over rows in
nopython code.

What a seed determines (the random stream, changed once in this version for speed):

* Every episode of a row starts by taking **one 64-bit key** from the row's generator
  (``rng.bit_generator.random_raw()``; for a pool such as ``adsb_calibration`` the pool first picks its member
  with the generator, then the key is taken, once per attempt). All other draws of that episode come from the
  counter-based stream ``u_j = (splitmix64(key + (j + 1) * 0x9E3779B97F4A7C15) >> 11) * 2^-53`` (SplitMix64
  seeded with the key: a uniform in [0, 1) per counter ``j``); normals by Box-Muller on two uniforms. The same
  key gives the same episode bit for bit, whatever the batch it is drawn in, so a seed fixes every episode of a
  row and row ``i`` of a batch equals a batch of one with the same generator.
* Draw order inside one attempt (counter ``j`` increasing): for ``random`` / ``random_radars`` the flight
  (speed, heading, number of legs, per leg its duration and then per maneuver: speed-change flag, new speed,
  speed-change acceleration, turn g, heading change, direction; at most ``max_tries`` flights until one stays in
  range for ``min_duration_s``, as :func:`radar_env.sim.scenario.random_scenario`), the radar placement
  (``site_candidates`` pairs of distance and direction, as :func:`radar_env.sim.scenario.place_radar_site`), then the
  radar (``random_radars``: the mixture flag and :func:`radar_env.sim.catalog.random_radar`'s draws in its order).
  A fixed scenario draws only the placement, when its radar is placed per episode (a trajectory without radar).
  Then the looks: ``K`` detection uniforms (look ``k`` uses counter ``c + k``), then four uniforms per look
  (``c + K + 4k ...``) giving the range, bearing and radial-velocity normals. As before, every look consumes its
  draws whether or not it is detected (common random numbers across detection probabilities).
* An attempt too short for the track start (see :func:`radar_env.sim.looks.looks_for_track_start`) is followed by
  the next attempt on the same stream (counter after the attempt's ``5 K`` look draws), at most
  ``MAX_EPISODE_DRAWS`` attempts; only episodes that could not run are replaced. A fixed scenario whose looks
  all detected are too few is refused at once with ``ValueError``.

The distributions are those of the per-episode drawer (the same ranges and rules; tests/test_draws.py compares
both by two-sample KS tests); the numbers are not, so every evaluation result changed with this stream.

Fixed scenarios (named, :class:`~radar_env.sim.catalog.Setup`, Segment / Trajectory scenarios, pools): their truth at
their look times is the same every episode and is computed once (cached per scenario and radar); the kernel draws
the placement (if any), detections, noise and converted plots.
"""

from __future__ import annotations

import math
from collections import OrderedDict
from functools import lru_cache

import numpy as np

from .catalog import FAMILIES, RANDOM_RADAR_RANGES, Setup, family_config, make_setup
from .episode import EpisodeBatch
from .radar import Radar, atc_radar, scan_schedule
from .scenario import (RADAR_PLACEMENT_RANGE_M, RandomScenarioConfig, Segment, SegmentScenario,
                       TrajectoryScenario)
from . import looks as _lk
from numba import njit, prange
from .looks import looks_for_track_start
from .motion import _sinc
from ..common.parallel import run as _run_rows
from ..common.units import DEG, G0_M_S2, KNOT_M_S

__all__ = ["draw_episodes", "random_scenarios", "LookDrawer", "MAX_EPISODE_DRAWS", "EpisodeDrawError"]

MAX_EPISODE_DRAWS = 200
"""Attempts per episode for one long enough for the track start (see the module docstring)."""

RANDOM_SCENARIO_TRIES = 200
"""Flights tried per attempt for one that stays in range (the per-episode ``random_scenario`` tries 50). A
configuration is refused when built if one flight in :data:`PLACEMENT_PROBE` fails more often than
:data:`MAX_PLACEMENT_FAILURE` (at its 99 % upper bound): then all 200 fail with a probability below 1e-12."""

PLACEMENT_PROBE = 256
"""Flights drawn (from a stream of their own, no row's) when a random configuration is built, to estimate how often
one cannot be placed in ``range_km`` for ``min_duration_s``."""

MAX_PLACEMENT_FAILURE = 0.87
"""The most often a flight of an accepted configuration may fail to be placed (0.87^200 < 1e-12)."""

MAX_PLACEMENT_GRID = 50_000_000
"""The most grid points (one every 2 s of the uncut flight, 16 bytes each: 800 MB) the radar placement may hold for a
flight; a configuration whose longest flight needs more (turns at a ``max_turn_rate_deg_s`` of 1e-6, up to 8.6 years
long) is refused when built."""

_GRID_DT_S = 2.0            # place_radar_site's grid
_BLOCK = 256                # grid points evaluated at a time in the placement
_MANEUVER_THRESHOLD_M_S2 = 0.05 * G0_M_S2   # SegmentScenario's default

# site table columns
_SX, _SY, _PER, _SR, _SB, _SV, _PD, _RB, _BB, _FIRST = range(10)
_NCOL = 10


class EpisodeDrawError(ValueError):
    """No attempt of some row gave an episode long enough (``status`` per row: 1 too short, 2 out of range)."""


# ---------------------------------------------------------------------------------------------------- the stream
_GAMMA = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_ONE = np.uint64(1)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_INV53 = 2.0 ** -53
_TWO_PI = 2.0 * math.pi


@njit(cache=True)
def _u01(key, c):
    """Uniform in [0, 1) at counter ``c`` (int) of the stream keyed ``key`` (uint64): SplitMix64."""
    z = key + (np.uint64(c) + _ONE) * _GAMMA
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    z = z ^ (z >> _S31)
    return float(z >> _S11) * _INV53


@njit(cache=True)
def _normal_pair(key, c):
    """Two independent standard normals from counters ``c``, ``c + 1`` (Box-Muller)."""
    u1 = 1.0 - _u01(key, c)          # (0, 1]: log is finite
    u2 = _u01(key, c + 1)
    r = math.sqrt(-2.0 * math.log(u1))
    return r * math.cos(_TWO_PI * u2), r * math.sin(_TWO_PI * u2)


@njit(cache=True)
def _normal(key, c):
    """The first normal of :func:`_normal_pair` alone (its sine is not needed)."""
    u1 = 1.0 - _u01(key, c)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(_TWO_PI * _u01(key, c + 1))


def uniforms(key, start, n):
    """``n`` uniforms of the stream ``key`` from counter ``start`` (for tests and documentation)."""
    return _uniforms(np.uint64(key), int(start), int(n))


@njit(cache=True)
def _uniforms(key, start, n):
    out = np.empty(n)
    for i in range(n):
        out[i] = _u01(key, start + i)
    return out


# ---------------------------------------------------------------------------------------------------- kinematics
@njit(cache=True)
def _propagate(x0, w, a, tau, out):
    """SegmentScenario._propagate for one segment: state ``tau`` s into a segment starting at ``x0``."""
    if a != 0.0:
        s = math.hypot(x0[2], x0[3])
        ux, uy = x0[2] / s, x0[3] / s
        d = s * tau + 0.5 * a * tau * tau
        out[0] = x0[0] + ux * d
        out[1] = x0[1] + uy * d
        out[2] = ux * (s + a * tau)
        out[3] = uy * (s + a * tau)
        return
    theta = w * tau
    sn, cs = math.sin(theta), math.cos(theta)
    fa = tau * _sinc(theta / math.pi)
    sh = _sinc(theta / (2.0 * math.pi))
    fb = tau * (theta / 2.0) * sh * sh
    vx, vy = x0[2], x0[3]
    out[0] = x0[0] + fa * vx + fb * vy
    out[1] = x0[1] - fb * vx + fa * vy
    out[2] = cs * vx + sn * vy
    out[3] = -sn * vx + cs * vy


@njit(cache=True)
def _segment_starts(x0, seg, nseg, starts, t0):
    """Start time and state of every segment (SegmentScenario.__init__); returns the duration."""
    t = 0.0
    x = x0.copy()
    tmp = np.empty(4)
    for i in range(nseg):
        t0[i] = t
        for a in range(4):   # element loops, not slice assignment: its shape check compiles an error formatter
            starts[i, a] = x[a]
        _propagate(x, seg[i, 1], seg[i, 2], seg[i, 0], tmp)
        for a in range(4):
            x[a] = tmp[a]
        t += seg[i, 0]
    return t


@njit(cache=True)
def _truth_look(tk, i, seg, nseg, starts, t0, dur, x):
    """Truth at time ``tk`` into ``x`` (4,), searching the segment from ``i`` on (times sorted). Returns (segment,
    accel x, accel y, turn rate, maneuvering) (SegmentScenario.states_at / accelerations_at / turn_rates_at /
    maneuvering_at)."""
    tk = min(max(tk, 0.0), dur)
    while i + 1 < nseg and t0[i + 1] <= tk:
        i += 1
    w, a = seg[i, 1], seg[i, 2]
    _propagate(starts[i], w, a, tk - t0[i], x)
    s = math.hypot(x[2], x[3])
    ax = w * x[3] + a * x[2] / s
    ay = -w * x[2] + a * x[3] / s
    return i, ax, ay, w, math.hypot(ax, ay) > _MANEUVER_THRESHOLD_M_S2


@njit(cache=True)
def _truth_row(t, K, seg, nseg, starts, t0, dur, truth, accel, turn, man):
    """Truth at sorted times ``t[:K]`` (:func:`_truth_look` per look)."""
    i = 0
    for k in range(K):
        i, accel[k, 0], accel[k, 1], turn[k], man[k] = _truth_look(t[k], i, seg, nseg, starts, t0, dur, truth[k])


# ---------------------------------------------------------------------------------------------------- random flights
@njit(cache=True)
def _draw_segments(key, c, cf, x0, seg):
    """One flight (random_scenario's draws, same rules as scenario._draw_segments). Returns (nseg, counter)."""
    speed = cf[0] + (cf[1] - cf[0]) * _u01(key, c)
    heading = _TWO_PI * _u01(key, c + 1)
    c += 2
    x0[0], x0[1] = 0.0, 0.0
    x0[2], x0[3] = speed * math.sin(heading), speed * math.cos(heading)
    n_lo, n_hi = int(cf[2]), int(cf[3])
    n_legs = n_lo + min(int(_u01(key, c) * (n_hi - n_lo + 1)), n_hi - n_lo)
    c += 1
    n = 0
    for i in range(n_legs):
        lo, hi = (cf[20], cf[21]) if i == 0 else (cf[4], cf[5])
        leg = lo + (hi - lo) * _u01(key, c)
        c += 1
        seg[n, 0], seg[n, 1], seg[n, 2] = (max(leg, cf[6]) if i == 0 else leg), 0.0, 0.0
        n += 1
        if i == n_legs - 1:
            break
        change = _u01(key, c) < cf[11]
        new_speed = cf[0] + (cf[1] - cf[0]) * _u01(key, c + 1)
        acc = cf[12] + (cf[13] - cf[12]) * _u01(key, c + 2)
        g = cf[7] + (cf[8] - cf[7]) * _u01(key, c + 3)
        dh = cf[9] + (cf[10] - cf[9]) * _u01(key, c + 4)
        if _u01(key, c + 5) >= 0.5:
            dh = -dh
        c += 6
        turn = True
        if cf[22] < 1.0:   # the turn's own draw only when turns can be skipped (the default keeps its stream)
            turn = _u01(key, c) < cf[22]
            c += 1
        if change and abs(new_speed - speed) > 1e-6:
            seg[n, 0] = abs(new_speed - speed) / acc
            seg[n, 1], seg[n, 2] = 0.0, math.copysign(acc, new_speed - speed)
            n += 1
            speed = new_speed
        if turn:
            w = min(g * G0_M_S2 / speed, cf[14])
            seg[n, 0], seg[n, 1], seg[n, 2] = abs(dh) / w, math.copysign(w, dh), 0.0
            n += 1
    return n, c


@njit(cache=True)
def _grid_size(dur):
    n_grid = int(math.ceil((dur + 1e-9) / _GRID_DT_S))
    extra = (n_grid - 1) * _GRID_DT_S < dur
    return n_grid, extra


@njit(cache=True)
def _grid_time(k, n_grid, dur):
    return dur if k >= n_grid else k * _GRID_DT_S


@njit(cache=True)
def _first_exit(grid_xy, G, sx, sy, lo, hi, step_m):
    """First grid index whose point lies outside the annulus [lo, hi] around (sx, sy) (G if none). The distance
    changes by at most ``step_m`` between grid points (the flight's top speed times the spacing), so the points a
    margin guarantees inside are skipped; every point that decides is tested exactly."""
    k = 0
    while k < G:
        r = math.hypot(grid_xy[k, 0] - sx, grid_xy[k, 1] - sy)
        if r < lo or r > hi:
            return k
        n = int(min(r - lo, hi - r) / step_m) if step_m > 0.0 else 0
        k += max(n, 1)
    return G


@njit(cache=True)
def _place_on_grid(key, c, n_cand, lo, hi, grid_xy, n_grid, extra, dur, sites, step_m):
    """place_radar_site on grid positions: candidates (distance uniform in [lo, hi], direction uniform) around the
    first point; the one whose annulus holds the flight longest wins (ties: first drawn). Returns (site x, y,
    in_range_until_s, counter)."""
    G = n_grid + int(extra)
    x0, y0 = grid_xy[0, 0], grid_xy[0, 1]
    best, fbest = 0, -1
    for j in range(n_cand):
        d = lo + (hi - lo) * _u01(key, c + 2 * j)
        a = _TWO_PI * _u01(key, c + 2 * j + 1)
        sites[j, 0] = x0 + d * math.sin(a)
        sites[j, 1] = y0 + d * math.cos(a)
        f = _first_exit(grid_xy, G, sites[j, 0], sites[j, 1], lo, hi, step_m)
        if f > fbest:
            best, fbest = j, f
    until = dur if fbest == G else _grid_time(max(fbest - 1, 0), n_grid, dur)
    return sites[best, 0], sites[best, 1], until, c + 2 * n_cand


@njit(cache=True)
def _place_on_flight(key, c, n_cand, lo, hi, seg, nseg, starts, t0, dur, sites):
    """place_radar_site for a segment flight (grid positions evaluated exactly, then :func:`_place_on_grid`)."""
    n_grid, extra = _grid_size(dur)
    G = n_grid + int(extra)
    grid_xy = np.empty((G, 2))
    x = np.empty(4)
    i = 0
    vmax = 0.0
    for m in range(nseg):   # speed is constant in turns and monotone in speed changes: the top is at an end
        v = math.hypot(starts[m, 2], starts[m, 3])
        vmax = max(vmax, v, abs(v + seg[m, 2] * seg[m, 0]))
    for k in range(G):
        tk = _grid_time(k, n_grid, dur)
        while i + 1 < nseg and t0[i + 1] <= tk:
            i += 1
        _propagate(starts[i], seg[i, 1], seg[i, 2], tk - t0[i], x)
        grid_xy[k, 0], grid_xy[k, 1] = x[0], x[1]
    step_m = vmax * _GRID_DT_S * (1.0 + 1e-9) + 1e-6
    return _place_on_grid(key, c, n_cand, lo, hi, grid_xy, n_grid, extra, dur, sites, step_m)


# ---------------------------------------------------------------------------------------------------- radars, looks
@njit(cache=True)
def _logu(key, c, lo, hi):
    return math.exp(math.log(lo) + (math.log(hi) - math.log(lo)) * _u01(key, c))


@njit(cache=True)
def _random_site(key, c, rr, x, y, first_site, out):
    """catalog.random_radar's site draws (period, range, bearing, radial-velocity noise, Pd, first scan)."""
    per = _logu(key, c, rr[0], rr[1])
    out[_SX], out[_SY], out[_PER] = x, y, per
    out[_SR] = _logu(key, c + 1, rr[2], rr[3])
    out[_SB] = _logu(key, c + 2, rr[4], rr[5]) * DEG
    out[_SV] = _logu(key, c + 3, rr[6], rr[7])
    out[_PD] = rr[8] + (rr[9] - rr[8]) * _u01(key, c + 4)
    out[_RB], out[_BB] = 0.0, 0.0
    out[_FIRST] = 0.0 if first_site else per * _u01(key, c + 5)
    return c + 6


@njit(cache=True)
def _n_looks(sites, ns, dur):
    K = 0
    for i in range(ns):
        n = int(math.floor((dur - sites[i, _FIRST]) / sites[i, _PER] + 1e-9)) + 1
        if n > 0:
            K += n
    return K


@njit(cache=True)
def _schedule(sites, ns, dur, t, idx):
    """radar.scan_schedule: looks of every site in [0, dur], sorted by time (ties: lower site first)."""
    cnt = np.zeros(ns, dtype=np.int64)
    nmax = np.zeros(ns, dtype=np.int64)
    K = 0
    for i in range(ns):
        n = int(math.floor((dur - sites[i, _FIRST]) / sites[i, _PER] + 1e-9)) + 1
        nmax[i] = max(n, 0)
        K += nmax[i]
    for k in range(K):
        best, tb = -1, 0.0
        for i in range(ns):
            if cnt[i] < nmax[i]:
                ti = sites[i, _FIRST] + sites[i, _PER] * cnt[i]
                if best < 0 or ti < tb:
                    best, tb = i, ti
        t[k], idx[k] = tb, best
        cnt[best] += 1
    return K


@njit(cache=True)
def _detections_ok(key, c, t, idx, sites, K, warmup):
    """Whether the looks' detections (uniform ``c + k`` < Pd of look k) allow the track start."""
    i1 = -1
    for k in range(K):
        if _u01(key, c + k) < sites[idx[k], _PD]:
            if i1 < 0:
                i1 = k
            elif t[k] > t[i1]:
                return k + 2 + warmup <= K
    return False


@njit(cache=True)
def _measure_look(key, c, K, k, site, tx, ty, tvx, tvy):
    """draw_episode's plot of look ``k`` (of K) by ``site`` (a site-table row) of the truth ``(tx, ty, tvx, tvy)``,
    from counters ``c + k`` (detection) and ``c + K + 4k ...`` (noise). Returns (detected, range, bearing, radial
    velocity, z x, z y, R00, R01, R11); the plot values are NaN where missed."""
    if not _u01(key, c + k) < site[_PD]:
        # a missed look's noise counters are reserved but not evaluated (counter-based: the stream is the same)
        return False, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan, np.nan
    sx, sy = site[_SX], site[_SY]
    sr, sb, sv = site[_SR], site[_SB], site[_SV]
    dx, dy = tx - sx, ty - sy
    r = math.hypot(dx, dy)
    br = math.atan2(dx, dy)
    rd = (dx * tvx + dy * tvy) / (r if r > 0 else 1.0)
    e0, e1 = _normal_pair(key, c + K + 4 * k)
    e2 = _normal(key, c + K + 4 * k + 2)
    rm = max(r + site[_RB] + sr * e0, 0.0)
    bm = br + site[_BB] + sb * e1
    bm = math.pi - ((math.pi - bm) % _TWO_PI)      # wrap to (-pi, pi]
    sn, cs = math.sin(bm), math.cos(bm)
    rsb = rm * sb
    sr2, cb2 = sr * sr, rsb * rsb
    return (True, rm, bm, rd + sv * e2, sx + rm * sn, sy + rm * cs, sr2 * sn * sn + cb2 * cs * cs,
            (sr2 - cb2) * sn * cs, sr2 * cs * cs + cb2 * sn * sn)


@njit(cache=True)
def _measure_row(b, key, c, K, Kmax, sites, t_s, site_index, site_xy, truth, accel, turn, man, det, rng_m, brg,
                 rdot_m, z, R, sr_o, sb_o, sv_o, valid):
    """draw_episode's plots for row ``b`` (truth and schedule already in the row; :func:`_measure_look`), then the
    padding of stack_episodes (repeat the last look, not detected, NaN plots)."""
    for k in range(K):
        s = site_index[b, k]
        site = sites[s]
        site_xy[b, k, 0], site_xy[b, k, 1] = site[_SX], site[_SY]
        sr_o[b, k], sb_o[b, k], sv_o[b, k] = site[_SR], site[_SB], site[_SV]
        valid[b, k] = True
        (det[b, k], rng_m[b, k], brg[b, k], rdot_m[b, k], z[b, k, 0], z[b, k, 1], R[b, k, 0, 0], R[b, k, 0, 1],
         R[b, k, 1, 1]) = _measure_look(key, c, K, k, site, truth[b, k, 0], truth[b, k, 1], truth[b, k, 2],
                                        truth[b, k, 3])
        R[b, k, 1, 0] = R[b, k, 0, 1]
    for k in range(K, Kmax):
        t_s[b, k], site_index[b, k] = t_s[b, K - 1], site_index[b, K - 1]
        for a in range(4):
            truth[b, k, a] = truth[b, K - 1, a]
        for a in range(2):
            site_xy[b, k, a] = site_xy[b, K - 1, a]
            accel[b, k, a] = accel[b, K - 1, a]
            z[b, k, a] = np.nan
            R[b, k, a, 0] = R[b, k, a, 1] = np.nan
        turn[b, k] = turn[b, K - 1]
        sr_o[b, k], sb_o[b, k], sv_o[b, k] = sr_o[b, K - 1], sb_o[b, K - 1], sv_o[b, K - 1]
        man[b, k] = det[b, k] = valid[b, k] = False
        rng_m[b, k] = brg[b, k] = rdot_m[b, k] = np.nan


@njit(cache=True)
def _measure_looks(r, key, c, K, sites, idx, looks, old_n):
    """The plots of row ``r`` straight into the tracker's packed looks ``looks (B, K_cap, W_LOOK)`` (time, truth
    and its acceleration, turn rate and maneuvering flag already there; :func:`_measure_look`), then the padding:
    the last look repeated, not detected, over the ``old_n`` looks of the row's previous episode and one look
    beyond. Looks past those are left as they are: padding of an earlier episode, not detected, never read (the
    chain reads a row's looks up to its ``n_looks``; rewriting the whole capacity cost a quarter of the draw)."""
    for k in range(K):
        lk = looks[r, k]
        site = sites[idx[k]]
        lk[_lk.L_SITE], lk[_lk.L_SITE + 1] = site[_SX], site[_SY]
        lk[_lk.L_RSTD], lk[_lk.L_BSTD], lk[_lk.L_RDSTD] = site[_SR], site[_SB], site[_SV]
        tr = _lk.L_TRUTH
        (d, lk[_lk.L_RANGE], lk[_lk.L_BEAR], lk[_lk.L_RDOT], lk[_lk.L_Z], lk[_lk.L_Z + 1], lk[_lk.L_R], lk[_lk.L_R + 1],
         lk[_lk.L_R + 3]) = _measure_look(key, c, K, k, site, lk[tr], lk[tr + 1], lk[tr + 2], lk[tr + 3])
        lk[_lk.L_R + 2] = lk[_lk.L_R + 1]
        lk[_lk.L_DET] = 1.0 if d else 0.0
    for k in range(K, min(looks.shape[1], max(K, old_n) + 1)):
        for col in range(looks.shape[2]):
            looks[r, k, col] = looks[r, K - 1, col]
        looks[r, k, _lk.L_DET] = 0.0


@njit(cache=True)
def k_fill_random_looks(rows, keys, x0, segs, nseg, sites, nsites, K, cdet, looks, it, chunks):
    """The accepted random draws (:func:`_random_rows`) of ``rows`` written straight into a tracker's packed looks
    and look counts (``it[:, I_N]``): schedule, truth, plots, padding. ``chunks``: as :func:`_random_rows`."""
    smax = segs.shape[1]
    for blk in prange(chunks):   # each block of rows with its own scratch
        starts = np.empty((smax, 4))
        t0 = np.empty(smax)
        t = np.empty(looks.shape[1])
        idx = np.empty(looks.shape[1], dtype=np.int64)
        for j in range(blk * rows.size // chunks, (blk + 1) * rows.size // chunks):
            r = rows[j]
            dur = _segment_starts(x0[j], segs[j], nseg[j], starts, t0)
            _schedule(sites[j], nsites[j], dur, t, idx)
            i = np.int64(0)   # not the literal 0 (another compilation of _truth_look)
            for k in range(K[j]):
                lk = looks[r, k]
                lk[_lk.L_T] = t[k]
                i, lk[_lk.L_TACC], lk[_lk.L_TACC + 1], lk[_lk.L_TTURN], man = _truth_look(
                    t[k], i, segs[j], nseg[j], starts, t0, dur, lk[_lk.L_TRUTH:_lk.L_TRUTH + 4])
                lk[_lk.L_MAN] = 1.0 if man else 0.0
            _measure_looks(r, keys[j], cdet[j], K[j], sites[j], idx, looks, it[r, _lk.I_N])
            it[r, _lk.I_N] = K[j]


@njit(cache=True)
def k_fill_fixed_looks(rows, keys, sites, cdet, t, idx, truth0, accel0, turn0, man0, looks, it, chunks):
    """The accepted draws of a fixed scenario (:func:`_fixed_rows`) of ``rows`` written straight into a tracker's
    packed looks and look counts. ``chunks``: as :func:`_random_rows` (no scratch here)."""
    K = t.size
    for blk in prange(chunks):
        for j in range(blk * rows.size // chunks, (blk + 1) * rows.size // chunks):
            r = rows[j]
            for k in range(K):
                lk = looks[r, k]
                lk[_lk.L_T] = t[k]
                for a in range(4):
                    lk[_lk.L_TRUTH + a] = truth0[k, a]
                lk[_lk.L_TACC], lk[_lk.L_TACC + 1] = accel0[k, 0], accel0[k, 1]
                lk[_lk.L_TTURN] = turn0[k]
                lk[_lk.L_MAN] = 1.0 if man0[k] else 0.0
            _measure_looks(r, keys[j], cdet[j], K, sites[j], idx, looks, it[r, _lk.I_N])
            it[r, _lk.I_N] = K


# ---------------------------------------------------------------------------------------------------- random kernels
@njit(cache=True)
def _random_rows(keys, cf, rr, mode, user_sites, warmup, max_draws, max_tries, smax, chunks):
    """Phase 1 for the random scenarios: per row the accepted flight, radar and look counter (no look arrays).

    mode: 0 ATC radar at the drawn site, 1 random_radars (mixture), 2 a user radar moved to the drawn site.
    chunks: blocks of rows, each with its own scratch (1: serial; :mod:`radar_env.common.parallel` runs the blocks
    of its parallel build on threads)."""
    B = keys.size
    x0 = np.zeros((B, 4))
    segs = np.zeros((B, smax, 3))
    nseg = np.zeros(B, dtype=np.int64)
    sites = np.zeros((B, max(user_sites.shape[0], 2), _NCOL))
    nsites = np.zeros(B, dtype=np.int64)
    K = np.zeros(B, dtype=np.int64)
    cdet = np.zeros(B, dtype=np.int64)
    status = np.zeros(B, dtype=np.int64)
    for blk in prange(chunks):   # each block of rows with its own scratch
        cand = np.empty((int(cf[17]), 2))
        starts = np.empty((smax, 4))
        t0 = np.empty(smax)
        for b in range(blk * B // chunks, (blk + 1) * B // chunks):
            key = keys[b]
            c = np.int64(0)   # not the literal 0: that compiles the callees once more for Literal[int](0)
            status[b] = 1
            for _ in range(max_draws):
                ok = False
                dur = 0.0
                sx = sy = 0.0
                for _t in range(max_tries):
                    ns, c = _draw_segments(key, c, cf, x0[b], segs[b])
                    dur = _segment_starts(x0[b], segs[b], ns, starts, t0)
                    sx, sy, until, c = _place_on_flight(key, c, int(cf[17]), cf[15], cf[16], segs[b], ns, starts,
                                                        t0, dur, cand)
                    until = min(until, cf[23])   # max_duration_s
                    if until >= cf[18]:
                        if until < dur:   # scenario._truncate: segments starting before the exit, the last cut
                            m = 0
                            while m < ns and t0[m] < until:
                                segs[b, m, 0] = min(segs[b, m, 0], until - t0[m])
                                m += 1
                            ns = m
                            dur = _segment_starts(x0[b], segs[b], ns, starts, t0)
                        nseg[b] = ns
                        ok = True
                        break
                if not ok:
                    status[b] = 2
                    break
                st = sites[b]
                if mode == 2:
                    n_s = user_sites.shape[0]
                    for i in range(n_s):
                        for col in range(_NCOL):   # (c is the stream counter)
                            st[i, col] = user_sites[i, col]
                        st[i, _SX] = user_sites[i, _SX] + (sx - user_sites[0, _SX])
                        st[i, _SY] = user_sites[i, _SY] + (sy - user_sites[0, _SY])
                elif mode == 1 and _u01(key, c) < cf[19]:
                    c += 1
                    c = _random_site(key, c, rr, sx, sy, np.bool_(True), st[0])   # np.bool_: one compilation
                    n_s = 1
                    if _u01(key, c) < rr[10]:
                        d = rr[11] + (rr[12] - rr[11]) * _u01(key, c + 1)
                        a = _TWO_PI * _u01(key, c + 2)
                        c = _random_site(key, c + 3, rr, sx + d * math.sin(a), sy + d * math.cos(a), np.bool_(False),
                                         st[1])
                        n_s = 2
                    else:
                        c += 1
                else:
                    if mode == 1:
                        c += 1
                    for col in range(_NCOL):   # the ATC site (mode 0, or mode 1's ATC branch)
                        st[0, col] = user_sites[0, col]
                    st[0, _SX], st[0, _SY] = sx, sy
                    n_s = 1
                nsites[b] = n_s
                k_b = _n_looks(st, n_s, dur)
                t = np.empty(k_b)
                idx = np.empty(k_b, dtype=np.int64)
                _schedule(st, n_s, dur, t, idx)
                if _detections_ok(key, c, t, idx, st, k_b, warmup):
                    K[b], cdet[b], status[b] = k_b, c, 0
                    break
                c += 5 * k_b
    return x0, segs, nseg, sites, nsites, K, cdet, status


@njit(cache=True)
def _fill_random(keys, x0, segs, nseg, sites, nsites, K, cdet, Kmax, out):
    (t_s, site_index, site_xy, truth, accel, turn, man, det, rng_m, brg, rdot_m, z, R, sr_o, sb_o, sv_o,
     valid) = out
    smax = segs.shape[1]
    starts = np.empty((smax, 4))
    t0 = np.empty(smax)
    for b in range(keys.size):
        dur = _segment_starts(x0[b], segs[b], nseg[b], starts, t0)
        _schedule(sites[b], nsites[b], dur, t_s[b], site_index[b])
        _truth_row(t_s[b], K[b], segs[b], nseg[b], starts, t0, dur, truth[b], accel[b], turn[b], man[b])
        _measure_row(b, keys[b], cdet[b], K[b], Kmax, sites[b], t_s, site_index, site_xy, truth, accel, turn, man,
                     det, rng_m, brg, rdot_m, z, R, sr_o, sb_o, sv_o, valid)


# ---------------------------------------------------------------------------------------------------- fixed kernel
@njit(cache=True)
def _fixed_rows(keys, t, idx, base_sites, place, grid_xy, n_grid, extra, dur, lo, hi, n_cand, warmup, max_draws):
    """Per row: the placement (if ``place``: the first site moved there, the others by the same offset) and the
    accepted look counter of a fixed scenario."""
    B = keys.size
    K = t.size
    ns = base_sites.shape[0]
    sites = np.empty((B, ns, _NCOL))
    cdet = np.zeros(B, dtype=np.int64)
    status = np.ones(B, dtype=np.int64)
    cand = np.empty((max(n_cand, 1), 2))
    for b in range(B):
        key = keys[b]
        c = 0
        for i in range(ns):
            for col in range(_NCOL):
                sites[b, i, col] = base_sites[i, col]
        for _ in range(max_draws):
            if place:
                sx, sy, _u, c = _place_on_grid(key, c, n_cand, lo, hi, grid_xy, n_grid, extra, dur, cand, 0.0)
                for i in range(ns):
                    sites[b, i, _SX] = base_sites[i, _SX] + (sx - base_sites[0, _SX])
                    sites[b, i, _SY] = base_sites[i, _SY] + (sy - base_sites[0, _SY])
            if _detections_ok(key, c, t, idx, sites[b], K, warmup):
                cdet[b], status[b] = c, 0
                break
            c += 5 * K
    return sites, cdet, status


@njit(cache=True)
def _fill_fixed(keys, sites, cdet, t, idx, truth0, accel0, turn0, man0, out):
    (t_s, site_index, site_xy, truth, accel, turn, man, det, rng_m, brg, rdot_m, z, R, sr_o, sb_o, sv_o,
     valid) = out
    K = t.size
    for b in range(keys.size):
        for k in range(K):
            t_s[b, k], site_index[b, k], turn[b, k], man[b, k] = t[k], idx[k], turn0[k], man0[k]
            for a in range(4):
                truth[b, k, a] = truth0[k, a]
            accel[b, k, 0], accel[b, k, 1] = accel0[k, 0], accel0[k, 1]
        _measure_row(b, keys[b], cdet[b], K, K, sites[b], t_s, site_index, site_xy, truth, accel, turn, man, det,
                     rng_m, brg, rdot_m, z, R, sr_o, sb_o, sv_o, valid)


# ---------------------------------------------------------------------------------------------------- Python side
def _keys(rngs):
    for r in rngs:
        if not isinstance(r, np.random.Generator):
            raise ValueError(f"rngs must be numpy.random.Generator objects, got {type(r).__name__}")
    return np.array([r.bit_generator.random_raw() for r in rngs], dtype=np.uint64)


@lru_cache(maxsize=256)
def _site_table(radar: Radar):
    """(n_sites, 10) float table of a radar's sites (cached: radars are frozen; read-only for the kernels)."""
    return np.array([[s.position_m[0], s.position_m[1], s.scan_period_s, s.range_noise_std_m,
                      s.bearing_noise_std_rad, s.radial_velocity_noise_std_m_s, s.detection_probability,
                      s.range_bias_m, s.bearing_bias_rad, s.first_scan_s] for s in radar.sites], dtype=np.float64)


@lru_cache(maxsize=64)
def _config_vector(cfg: RandomScenarioConfig, random_radars_p):
    v = [cfg.speed_kt[0] * KNOT_M_S, cfg.speed_kt[1] * KNOT_M_S, cfg.n_legs[0], cfg.n_legs[1],
         cfg.leg_duration_s[0], cfg.leg_duration_s[1], cfg.first_leg_min_s, cfg.turn_accel_g[0], cfg.turn_accel_g[1],
         cfg.turn_heading_change_deg[0] * DEG, cfg.turn_heading_change_deg[1] * DEG, cfg.speed_change_probability,
         cfg.speed_change_accel_g[0] * G0_M_S2, cfg.speed_change_accel_g[1] * G0_M_S2,
         cfg.max_turn_rate_deg_s * DEG, cfg.range_km[0] * 1e3, cfg.range_km[1] * 1e3, cfg.site_candidates,
         cfg.min_duration_s, random_radars_p, cfg.first_leg_range_s[0], cfg.first_leg_range_s[1],
         cfg.turn_probability, cfg.max_duration_s]
    return np.array(v, dtype=np.float64)


@lru_cache(maxsize=1)
def _radar_ranges():
    R = RANDOM_RADAR_RANGES
    return np.array([*R["scan_period_s"], *R["range_noise_std_m"], *R["bearing_noise_std_deg"],
                     *R["radial_velocity_noise_std_m_s"], *R["detection_probability"], R["second_site_probability"],
                     *(v * 1e3 for v in R["second_site_offset_km"])], dtype=np.float64)


def _empty_out(B, K):
    f, i, bl = np.float64, np.int64, np.bool_
    return (np.zeros((B, K), f), np.zeros((B, K), i), np.zeros((B, K, 2), f), np.zeros((B, K, 4), f),
            np.zeros((B, K, 2), f), np.zeros((B, K), f), np.zeros((B, K), bl), np.zeros((B, K), bl),
            np.zeros((B, K), f), np.zeros((B, K), f), np.zeros((B, K), f), np.zeros((B, K, 2), f),
            np.zeros((B, K, 2, 2), f), np.zeros((B, K), f), np.zeros((B, K), f), np.zeros((B, K), f),
            np.zeros((B, K), bl))


def _batch(names, out, n_looks):
    (t_s, site_index, site_xy, truth, accel, turn, man, det, rng_m, brg, rdot_m, z, R, sr_o, sb_o, sv_o,
     valid) = out
    return EpisodeBatch(names=tuple(names), valid=valid, n_looks=np.asarray(n_looks, dtype=np.int64), t_s=t_s,
                        site_index=site_index, site_xy_m=site_xy, truth=truth, truth_accel_m_s2=accel,
                        truth_turn_rate_rad_s=turn, maneuvering=man, detected=det, range_m=rng_m, bearing_rad=brg,
                        radial_velocity_m_s=rdot_m, z_m=z, R_m2=R, range_noise_std_m=sr_o, bearing_noise_std_rad=sb_o,
                        radial_velocity_noise_std_m_s=sv_o)


_ATC = atc_radar()
_DEFAULT_CONFIG = RandomScenarioConfig()   # built (validated) once, not at every reset


def _too_few_draws(name, warmup_scans, max_draws):
    return EpisodeDrawError(
        f"RadarTrack-v0: none of {max_draws} episode draws of scenario {name!r} had "
        f"enough looks for the track start with warmup_scans={warmup_scans} (two hits, the warm-up, one look to "
        "act on); lower warmup_scans, or make the flights longer (random_config min_duration_s, leg_duration_s, "
        "range_km) or the radar faster / more reliable (scan_period_s, detection_probability)")


def _random_kernel_out(name, keys, cfg, radar, warmup_scans, max_draws, num_threads=1,
                       max_tries=RANDOM_SCENARIO_TRIES):
    if radar is not None:
        mode, user = 2, _site_table(radar)
    else:
        mode, user = (1 if name == "random_radars" else 0), _site_table(_ATC)
    p = cfg.random_radar_probability if name == "random_radars" else 0.0
    smax = 3 * int(cfg.n_legs[1])
    return _run_rows(num_threads, keys.size, _random_rows, keys, _config_vector(cfg, p), _radar_ranges(), mode, user,
                     int(warmup_scans), int(max_draws), int(max_tries), smax)


def longest_uncut_flight_s(cfg):
    """An upper bound on a random flight's length before ``max_duration_s`` cuts it (s; closed form): every leg,
    speed change and turn at its longest, as :func:`max_random_looks` without the cut. The radar placement looks at
    the whole uncut flight."""
    cf = _config_vector(cfg, 0.0)
    v_lo, v_hi = cf[0], cf[1]
    w_min = min(cf[7] * G0_M_S2 / v_hi, cf[14])
    per_maneuver = cf[5] + (v_hi - v_lo) / cf[12] + cf[10] / w_min
    return max(cf[21], cf[6]) + (int(cf[3]) - 1) * per_maneuver


@lru_cache(maxsize=64)     # a reset with a scenario option builds a drawer each time: probe each configuration once
def check_placeable(name, cfg, radar, warmup_scans):
    """Refuse (``ValueError``, naming the settings) a random configuration whose flights the radar placement cannot
    handle: one whose longest flight needs more than :data:`MAX_PLACEMENT_GRID` grid points (closed form), or whose
    flights fail to stay in ``range_km`` for ``min_duration_s`` so often (estimated on :data:`PLACEMENT_PROBE`
    flights of a stream of their own) that a draw's :data:`RANDOM_SCENARIO_TRIES` tries could all fail during a run:
    the draw would otherwise raise at a reset, possibly deep into a training run."""
    longest = longest_uncut_flight_s(cfg)
    if not longest / _GRID_DT_S <= MAX_PLACEMENT_GRID:
        raise ValueError(f"random_config: its longest flight can last {longest:.3g} s (turns at "
                         f"{cfg.max_turn_rate_deg_s:g} deg/s at most, {cfg.turn_accel_g[0]:g} g at {cfg.speed_kt[1]:g} "
                         f"kt, speed changes at {cfg.speed_change_accel_g[0]:g} g), more than the radar placement can "
                         f"evaluate ({MAX_PLACEMENT_GRID * _GRID_DT_S:.3g} s); raise max_turn_rate_deg_s, turn_accel_g "
                         "or speed_change_accel_g, or shorten turn_heading_change_deg, leg_duration_s or n_legs")
    status = _random_kernel_out(name, _probe_keys(), cfg, radar, warmup_scans, 1, max_tries=1)[-1]
    n, k = status.size, int(np.count_nonzero(status == 2))
    p = k / n
    upper = p + 2.576 * math.sqrt(p * (1.0 - p) / n) + 1.0 / n
    if upper > MAX_PLACEMENT_FAILURE:
        raise ValueError(f"random_config: {k} of {n} flights did not stay in range_km={cfg.range_km} of any radar "
                         f"site for min_duration_s={cfg.min_duration_s:g} s (at up to {cfg.speed_kt[1]:g} kt): a "
                         f"draw's {RANDOM_SCENARIO_TRIES} tries could all fail during a run; widen range_km, lower "
                         "min_duration_s or slow the flights (speed_kt)")


def _probe_keys():
    """The probe's keys: a stream of their own (no row's key is drawn from it)."""
    return (np.arange(1, PLACEMENT_PROBE + 1, dtype=np.uint64) * _GAMMA) ^ np.uint64(0xD1B54A32D192ED03)


def _draw_random(name, keys, cfg, radar, warmup_scans, max_draws):
    x0, segs, nseg, sites, nsites, K, cdet, status = _random_kernel_out(name, keys, cfg, radar, warmup_scans,
                                                                        max_draws)
    _check_random_status(status, cfg, name, warmup_scans, max_draws)
    out = _empty_out(keys.size, int(K.max()))
    _fill_random(keys, x0, segs, nseg, sites, nsites, K, cdet, int(K.max()), out)
    return _batch([name if name in FAMILIES else "random"] * keys.size, out, K)


def random_scenarios(name, rngs, random_config=None, radar=None, warmup_scans=12, max_draws=MAX_EPISODE_DRAWS):
    """The flights (as :class:`SegmentScenario`) and radars :func:`draw_episodes` draws for these generators
    (each generator advanced as :func:`draw_episodes` would). For tests and inspection."""
    cfg = random_config or (family_config(name) if name in FAMILIES else _DEFAULT_CONFIG)
    keys = _keys(rngs)
    x0, segs, nseg, sites, nsites, K, cdet, status = _random_kernel_out(name, keys, cfg, radar, warmup_scans,
                                                                        max_draws)
    out = []
    for b in range(keys.size):
        sc = SegmentScenario(x0[b], [Segment(*s) for s in segs[b, :nseg[b]]],
                             name=name if name in FAMILIES else "random")
        out.append((sc, sites[b, :nsites[b]].copy(), int(K[b]), int(status[b])))
    return out


_FIXED_CACHE: OrderedDict = OrderedDict()
_FIXED_CACHE_SIZE = 64


def _fixed_truth(scenario, radar, place):
    """The look schedule and truth of a fixed scenario under ``radar`` (and the placement grid if ``place``):
    the same every episode, so computed once (cached per scenario and radar object)."""
    k = (id(scenario), id(radar), place)
    hit = _FIXED_CACHE.get(k)
    if hit is not None and hit[0] is scenario and hit[1] is radar:
        _FIXED_CACHE.move_to_end(k)
        return hit[2]
    t, idx = scan_schedule(radar, scenario.duration_s)
    K = t.size
    if K < 2:
        raise ValueError(f"scenario {scenario.name!r} ({scenario.duration_s} s) gives only {K} look(s); "
                         "at least 2 are needed")
    truth = (t, idx.astype(np.int64), np.ascontiguousarray(scenario.states_at(t)),
             np.ascontiguousarray(scenario.accelerations_at(t)),
             np.ascontiguousarray(scenario.turn_rates_at(t), dtype=np.float64),
             np.ascontiguousarray(scenario.maneuvering_at(t)))
    grid = None
    if place:
        dur = scenario.duration_s
        n_grid = int(math.ceil((dur + 1e-9) / _GRID_DT_S))
        extra = (n_grid - 1) * _GRID_DT_S < dur
        tg = np.arange(n_grid, dtype=np.float64) * _GRID_DT_S
        if extra:
            tg = np.append(tg, dur)
        grid = (np.ascontiguousarray(scenario.states_at(tg)[:, :2]), n_grid, bool(extra), float(dur))
    val = (truth, grid)
    _FIXED_CACHE[k] = (scenario, radar, val)
    if len(_FIXED_CACHE) > _FIXED_CACHE_SIZE:
        _FIXED_CACHE.popitem(last=False)
    return val


RADAR_RANGE_WARN_M = 463e3
"""250 NM, the instrumented range of a long-range air-route radar: a user flight that goes beyond it from its radar
(or beyond the placement annulus's outer radius, if that is larger) gets a warning, and one beyond it on every look
is refused. The radar model itself has no maximum range: every look keeps its detection probability."""

_RANGE_WARNED = set()


def _warn_if_out_of_range(scenario, radar, t, idx, truth, sites, place, hi):
    """Warn (once per scenario, radar and placement) when a user flight goes far outside its radar's range (beyond
    :data:`RADAR_RANGE_WARN_M`, or the placement annulus ``hi`` if larger): plausible data, unusual tracking. The
    first row's sites are checked (a placed radar: the first episode's placement)."""
    limit = max(RADAR_RANGE_WARN_M, hi if place else 0.0)
    r = np.hypot(truth[:, 0] - sites[0, idx, _SX], truth[:, 1] - sites[0, idx, _SY])
    beyond = r > limit
    if beyond.all():        # out of every radar's range on every look: no run of it would mean anything
        raise ValueError(f"RadarSite.position_m: scenario {scenario.name!r} is beyond {limit / 1e3:g} km of every "
                         f"radar site on all of its looks (nearest {r.min() / 1e3:,.0f} km); give a radar site "
                         "near the flight")
    key = (id(scenario), id(radar), place, hi)
    if key in _RANGE_WARNED:
        return
    _RANGE_WARNED.add(key)
    if beyond.any():
        import warnings
        what = f"{limit / 1e3:g} km from its radar" + (" (250 NM)" if limit == RADAR_RANGE_WARN_M else "")
        warnings.warn(f"scenario {scenario.name!r}: the flight goes beyond {what} on {beyond.mean():.0%} of its "
                      f"looks, up to {r.max() / 1e3:,.0f} km (first at t = {t[np.argmax(beyond)]:.0f} s); the radar "
                      "model has no maximum range, so those looks keep their detection probability: cut the flight "
                      "or give a radar near it", UserWarning, stacklevel=4)


def _refuse_too_short(scenario, t, warmup_scans):
    """ValueError when even every look detected is too few for the track start (then every draw is)."""
    K = t.size
    need = looks_for_track_start(np.ones(K, dtype=bool), t, warmup_scans)
    if need is None:
        raise ValueError(f"RadarTrack-v0: scenario {scenario.name!r} has no two looks at different times for "
                         "the two-hit track start")
    if K < need:
        fit = K - (need - warmup_scans)          # the largest warm-up this scenario leaves room for
        fix = (f"lower warmup_scans (valid here: <= {fit})" if fit >= 1 else
               f"no warm-up fits: even warmup_scans=1 needs {need - warmup_scans + 1} looks")
        raise ValueError(
            f"RadarTrack-v0: scenario {scenario.name!r} has {K} looks but warmup_scans={warmup_scans} needs "
            f"{need} (two hits, {warmup_scans} warm-up looks, one look to act on); {fix}, or use a longer "
            "scenario or a faster radar")


def _fixed_phase1(scenario, radar, keys, warmup_scans, max_draws, place, radar_range_m, refuse, warn=None):
    """The cached truth of a fixed scenario and, per key, its sites, look counter and status (:func:`_fixed_rows`).
    ``refuse``: refuse a scenario too short for the track start; ``warn`` (default: ``refuse``): warn if the first
    row's flight goes far beyond its radar's range (:func:`_warn_if_out_of_range`)."""
    (t, idx, truth, accel, turn, man), grid = _fixed_truth(scenario, radar, place)
    if refuse:
        _refuse_too_short(scenario, t, warmup_scans)
    if place:
        grid_xy, n_grid, extra, dur = grid
        lo, hi = (float(v) for v in radar_range_m)
        n_cand = 64
    else:
        grid_xy, n_grid, extra, dur, lo, hi, n_cand = np.zeros((1, 2)), 1, False, 0.0, 0.0, 0.0, 0
    sites, cdet, status = _fixed_rows(keys, t, idx, _site_table(radar), place, grid_xy, n_grid, extra, dur, lo, hi,
                                      n_cand, int(warmup_scans), int(max_draws))
    if (refuse if warn is None else warn) and status[0] == 0:   # a user scenario (pools are not checked)
        _warn_if_out_of_range(scenario, radar, t, idx, truth, sites, place, hi)
    return (t, idx, truth, accel, turn, man), sites, cdet, status


def _draw_fixed(scenario, radar, keys, warmup_scans, max_draws, place, radar_range_m, refuse):
    (t, idx, truth, accel, turn, man), sites, cdet, status = _fixed_phase1(scenario, radar, keys, warmup_scans,
                                                                           max_draws, place, radar_range_m, refuse)
    out = _empty_out(keys.size, t.size)
    _fill_fixed(keys, sites, cdet, t, idx, truth, accel, turn, man, out)
    return out, status


def _fixed_args(scenario, radar):
    """(scenario, radar, place) of a fixed scenario as draw_episodes resolves them, or None for a pool."""
    if isinstance(scenario, str):
        scenario = make_setup(scenario)
    if hasattr(scenario, "draw_setup"):
        return None
    if isinstance(scenario, Setup):
        return scenario.scenario, (scenario.radar if radar is None else radar), False
    if isinstance(scenario, (SegmentScenario, TrajectoryScenario)):
        return (scenario, _ATC, True) if radar is None else (scenario, radar, False)
    raise ValueError(f"scenario must be a name, a Setup, a SegmentScenario / TrajectoryScenario or a pool with "
                     f"draw_setup, got {type(scenario).__name__}")


_HEADROOM = 1.25
"""A tracker filled by :meth:`LookDrawer.draw` with random flights grows its look store to this multiple of the
longest episode: the longest of many episodes keeps growing one record at a time, and each growth copies (and
pages in) every row's looks, about a second at 4,096 rows. The padding is bounded (:func:`_measure_looks`), so the
headroom costs memory only."""


class LookDrawer:
    """Draws episodes of one scenario straight into a :class:`radar_env.filters.tracking.Tracker`'s packed looks (the env's
    resets): the same kernels and streams as :func:`draw_episodes`, so row ``r`` drawn with key ``k`` holds the
    episode ``draw_episodes`` gives for a generator whose next word is ``k`` (no :class:`EpisodeBatch`, no
    per-row Python). ``LookDrawer.of(...)`` is None for a pool (drawn by :func:`draw_episodes`).

    The constructor checks cheaply what a draw would refuse: a fixed scenario too short for ``warmup_scans``
    (its cached look times), a random configuration whose longest possible flight has too few looks
    (:func:`max_random_looks`)."""

    def __init__(self, scenario, radar, random_config, warmup_scans, radar_range_m=RADAR_PLACEMENT_RANGE_M,
                 max_draws=MAX_EPISODE_DRAWS):
        self.warmup_scans, self.max_draws, self.radar_range_m = int(warmup_scans), int(max_draws), radar_range_m
        self.random = isinstance(scenario, str) and (scenario in ("random", "random_radars") or scenario in FAMILIES)
        if self.random:
            if scenario in FAMILIES:
                if random_config is not None:
                    raise ValueError(f"random_config applies to 'random' and 'random_radars'; scenario {scenario!r} "
                                     "is a held-out family with its own (radar_env.sim.catalog.FAMILIES)")
                cfg = family_config(scenario)
            else:
                cfg = random_config or _DEFAULT_CONFIG
            self.name, self.cfg, self.radar = scenario, cfg, radar
            self.label = scenario if scenario in FAMILIES else "random"
            most = max_random_looks(scenario, cfg, radar)
            if most < self.warmup_scans + 3:
                raise _too_few_draws(scenario, self.warmup_scans, self.max_draws)
            from .radar import MAX_LOOKS
            if most > MAX_LOOKS:        # refused at construction, before any allocation
                raise ValueError(f"RadarSite.scan_period_s: {scenario!r} episodes can have up to {most:,.0f} looks "
                                 f"with this radar, more than the {MAX_LOOKS:,} per episode memory allows; give a "
                                 "longer scan_period_s")
            check_placeable(scenario, cfg, radar, self.warmup_scans)     # after the closed-form checks: it draws
        else:
            sc, rd, place = _fixed_args(scenario, radar)
            self.fixed = (sc, rd, place)
            self._range_checked = False
            self.label = sc.name
            t = _fixed_truth(sc, rd, place)[0][0]
            _refuse_too_short(sc, t, self.warmup_scans)

    @classmethod
    def of(cls, scenario, radar, random_config, warmup_scans, radar_range_m=RADAR_PLACEMENT_RANGE_M):
        """The drawer of ``scenario`` (resolved as the env does), or None for a pool."""
        if not (isinstance(scenario, str) and (scenario in ("random", "random_radars") or scenario in FAMILIES)):
            if _fixed_args(scenario, radar) is None:
                return None
        return cls(scenario, radar, random_config, warmup_scans, radar_range_m)

    def draw(self, keys, rows, tracker, num_threads=1):
        """Episodes from ``keys`` (uint64, one per row) into ``rows`` (int64) of ``tracker``: looks, look counts and
        names (the track is not started). Raises as :func:`draw_episodes`. A row's looks past its ``n_looks`` are
        not detected; the first of them repeats its last look, the others may be an earlier episode's padding.
        ``num_threads``: rows drawn on that many threads (:mod:`radar_env.common.parallel`; a fixed scenario's
        placement stays serial), the same episodes."""
        w = self.warmup_scans
        if self.random:
            x0, segs, nseg, sites, nsites, K, cdet, status = _random_kernel_out(self.name, keys, self.cfg, self.radar,
                                                                                w, self.max_draws, num_threads)
            _check_random_status(status, self.cfg, self.name, w, self.max_draws)
            tracker._ensure_capacity(int(K.max()), _HEADROOM)
            _run_rows(num_threads, rows.size, k_fill_random_looks, rows, keys, x0, segs, nseg, sites, nsites, K, cdet,
                      tracker._looks, tracker._it)
        else:
            sc, rd, place = self.fixed
            (t, idx, truth, accel, turn, man), sites, cdet, status = _fixed_phase1(
                sc, rd, keys, w, self.max_draws, place, self.radar_range_m, False, warn=not self._range_checked)
            self._range_checked = True       # refused at build (too short); warned once, at the first draw
            if np.any(status != 0):
                raise _too_few_draws(sc.name, w, self.max_draws)
            tracker._ensure_capacity(t.size)
            _run_rows(num_threads, rows.size, k_fill_fixed_looks, rows, keys, sites, cdet, t, idx, truth, accel, turn,
                      man, tracker._looks, tracker._it)
        for r in rows:
            tracker.names[r] = self.label


def max_random_looks(name, cfg, radar):
    """An upper bound on the looks of any episode of a random scenario (closed form, no draw): the longest flight
    the configuration allows (every leg, speed change and turn at its longest, capped by ``max_duration_s``)
    seen by the fastest radar it can draw (``random_radars``: up to two sites at the shortest scan period)."""
    cf = _config_vector(cfg, 0.0)
    v_lo, v_hi = cf[0], cf[1]
    first = max(cf[21], cf[6])
    w_min = min(cf[7] * G0_M_S2 / v_hi, cf[14])
    per_maneuver = cf[5] + (v_hi - v_lo) / cf[12] + cf[10] / w_min
    dur = min(first + (int(cf[3]) - 1) * per_maneuver, cf[23])
    tables = [_site_table(radar if radar is not None else _ATC)]
    if name == "random_radars" and radar is None:
        p = RANDOM_RADAR_RANGES["scan_period_s"][0]
        tables.append(np.array([[0.0, 0.0, p] + [0.0] * (_NCOL - 3)] * 2))
    return max(int(sum(math.floor(dur / s[_PER] + 1e-9) + 1 for s in tab)) for tab in tables)


def _check_random_status(status, cfg, name, warmup_scans, max_draws):
    if np.any(status == 2):
        raise EpisodeDrawError(f"random_scenario: no draw stayed in range_km={cfg.range_km} for min_duration_s="
                               f"{cfg.min_duration_s} s in {RANDOM_SCENARIO_TRIES} tries; widen range_km, lower "
                               "min_duration_s or slow the flights (speed_kt)")
    if np.any(status != 0):
        raise _too_few_draws(name, warmup_scans, max_draws)


def draw_episodes(scenario, radar, random_config, rngs, warmup_scans=12, radar_range_m=RADAR_PLACEMENT_RANGE_M,
                  max_draws=MAX_EPISODE_DRAWS) -> EpisodeBatch:
    """One episode per generator in ``rngs``, long enough for the track start, as a padded :class:`EpisodeBatch`.

    Args:
        scenario: ``"random"``, ``"random_radars"``, a name in ``radar_env.sim.catalog.SCENARIO_NAMES``, a
            :class:`Setup`, a :class:`SegmentScenario` / :class:`TrajectoryScenario`, or a pool with
            ``draw_setup(rng)`` (e.g. ``adsb_calibration``); CSV paths are resolved by the env
            (``radar_env.envs.env.resolve_scenario``).
        radar: a :class:`Radar` replacing the scenario's (for the random scenarios its first site is moved to the
            drawn position), or None.
        random_config: :class:`RandomScenarioConfig` (or None for the default) of the random scenarios.
        rngs: sequence of ``numpy.random.Generator``, one per row; each is advanced by one 64-bit word per attempt
            (module docstring).
        warmup_scans: warm-up looks of the track start (an episode must leave one look to act on after them).
        radar_range_m: ``(lo, hi)`` m, placement annulus of the ATC radar for a trajectory without ``radar``.
        max_draws: attempts per row (``MAX_EPISODE_DRAWS``).

    Raises ``ValueError`` for a fixed scenario too short for ``warmup_scans`` even with every look detected, and
    :class:`EpisodeDrawError` (a ``ValueError``) when no attempt of a row gave a long enough episode.
    """
    rngs = list(rngs)
    if not rngs:
        raise ValueError("draw_episodes needs at least one generator (rngs)")
    if isinstance(scenario, str) and scenario in ("random", "random_radars"):
        cfg = random_config or _DEFAULT_CONFIG
        return _draw_random(scenario, _keys(rngs), cfg, radar, warmup_scans, max_draws)
    if isinstance(scenario, str) and scenario in FAMILIES:   # random flights of one kind, ATC radar
        if random_config is not None:
            raise ValueError(f"random_config applies to 'random' and 'random_radars'; scenario {scenario!r} is a "
                             "held-out family with its own (radar_env.sim.catalog.FAMILIES)")
        return _draw_random(scenario, _keys(rngs), family_config(scenario), radar, warmup_scans, max_draws)
    if isinstance(scenario, str):
        scenario = make_setup(scenario)
    if hasattr(scenario, "draw_setup"):
        return _draw_pool(scenario, radar, rngs, warmup_scans, max_draws)
    sc, rd, place = _fixed_args(scenario, radar)
    out, status = _draw_fixed(sc, rd, _keys(rngs), warmup_scans, max_draws, place, radar_range_m, refuse=True)
    if np.any(status != 0):
        raise _too_few_draws(sc.name, warmup_scans, max_draws)
    return _batch([sc.name] * len(rngs), out, np.full(len(rngs), out[0].shape[1]))


def _draw_pool(pool, radar, rngs, warmup_scans, max_draws):
    """A pool: every attempt picks a member with the row's generator, then draws its plots (one attempt)."""
    B = len(rngs)
    eps = [None] * B
    todo = list(range(B))
    for _ in range(max_draws):
        groups = {}
        for r in todo:
            s = pool.draw_setup(rngs[r])
            s = s if radar is None else Setup(s.scenario, radar)
            groups.setdefault((id(s.scenario), id(s.radar)), (s, []))[1].append(r)
        todo = []
        for s, rows in groups.values():
            out, status = _draw_fixed(s.scenario, s.radar, _keys([rngs[r] for r in rows]), warmup_scans, 1, False,
                                      None, refuse=False)
            b = _batch([s.name] * len(rows), out, np.full(len(rows), out[0].shape[1]))
            for j, r in enumerate(rows):
                if status[j] == 0:
                    eps[r] = b.episode(j)
                else:
                    todo.append(r)
        if not todo:
            break
    if todo:
        raise _too_few_draws(pool.name, warmup_scans, max_draws)
    from .episode import stack_episodes
    return stack_episodes(eps)
