r"""``rbpf``: a Rao-Blackwellised particle filter over the flight regime of the random-flight generator.

Each particle carries the regime of :func:`radar_env.sim.scenario.random_scenario`'s flights (a straight leg, a
coordinated turn with its rate, a speed change with its acceleration), the time spent in it and the support of its
duration, and a Kalman filter (EKF for the nonlinear regimes) on ``[x, y, vx, vy, eta]`` given that regime:
``eta`` is the turn rate (rad/s) in a turn, the longitudinal acceleration (m/s^2) in a speed change, and 0 on a
straight leg. The regime laws are read from a :class:`radar_env.sim.scenario.RandomScenarioConfig` (the prior), never
copied:

* every segment's duration is uniform given its parameters: a leg ``U(leg_duration_s)``; a turn of rate ``w``
  ``U(turn_heading_change_deg) / w``; a speed change of acceleration ``a`` ``U(0, room) / a``, ``room`` the speed
  left to the edge of ``speed_kt`` in its direction. So the regime moves on by the exact hazard of a uniform
  duration given the time already spent (no duration is stored, and copies made by resampling stay diverse);
* a leg ends in a maneuver: a speed change with ``speed_change_probability`` (up with the probability that a new
  speed from ``speed_kt`` is above the current one), then a turn with ``turn_probability`` (rate
  ``min(U(turn_accel_g) g / speed, max_turn_rate_deg_s)``, either direction); a turn or a speed change without a
  turn ends in a leg.

Sub-look timing is exact: a regime that ends between two looks is propagated to its end, then the next one from
there. Two things the prior does not cover get their own handling, for flights off the prior (real aircraft, the
+-5 g radial accelerations of ``kim_lee_accel``): a process-noise floor on every regime, and a *broad* regime (a
CV model with large noise) that any particle enters at a small rate and leaves after a uniform time.

``flight_start_known`` (the causal *reference*, ``rbpf_ref``): the particles also know what the generator says about
the flight's start (the first leg lasts ``max(U(first leg), first_leg_min_s)`` from ``t = 0``; the flight has
``U(n_legs)`` legs), as the look times of a random episode count from it. Without it (``rbpf``, the deployed
tracker) a track starts on a leg of unknown age (its stationary distribution) with unlimited legs ahead.

Randomness: a counter-based stream per row (:func:`radar_env.sim.draws._u01`) keyed by the caller (the runner hashes
the row's looks), counter ``(look, particle, draw)``: the same looks give the same numbers in any batch.
The kernel works over rows in parallel (``prange``), each row's particles in one thread.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields

import numba
import numpy as np

from ..common.units import DEG, G0_M_S2, KNOT_M_S
from ..common.validate import check_number
from ..sim.draws import _u01
from ..sim.looks import padded_looks, range_rate_inputs
from ..sim.scenario import RandomScenarioConfig
from . import imm_cv_ct, kernels
from .imm_cv_ct import _add_cv_noise
from .kernels import _gain_update_in_frame_inlined, _logsumexp, _pd_floor, _r_frame, _symmetrize

__all__ = ["RBPFSpec", "DEFAULT_RBPF", "RBPF_PARAMS", "rbpf_filter", "prior_vector"]

# regimes
STRAIGHT, TURN, SPEED, BROAD = 0, 1, 2, 3

_DRAWS_PER_PARTICLE_LOOK = 64    # counters reserved per (look, particle): regime moves and their draws
_MAX_MOVES_PER_LOOK = 6          # regime changes one particle may make between two looks (more: it stays)
_LOG_2PI = math.log(2.0 * math.pi)
_RESAMPLE_STREAM = np.uint64(0x5DEECE66D2545F49)   # xor on the row key: the resampling draws' own stream

RBPF_PARAMS = (
    # name, default, low, high, doc
    ("n_particles", 4096, 16, 1_000_000, "particles per track"),
    ("q_floor_g", 0.005, 0.0, 10.0, "process-noise floor on every regime (white acceleration std, g)"),
    ("sigma_turn_rate0_deg_s", 0.3, 0.0, 20.0, "spread of a new turn's rate around its drawn value (deg/s)"),
    ("sigma_turn_rate_walk_deg_s15", 0.02, 0.0, 10.0, "random walk of the turn rate in a turn (deg/s/sqrt(s))"),
    ("sigma_accel0_g", 0.02, 0.0, 5.0, "spread of a speed change's acceleration around its drawn value (g)"),
    ("sigma_accel_walk_g_s05", 0.002, 0.0, 5.0, "random walk of the acceleration in a speed change (g/sqrt(s))"),
    ("broad_rate_per_s", 1e-3, 0.0, 1.0, "rate at which a particle enters the broad regime (1/s)"),
    ("broad_q_g", 3.0, 0.0, 100.0, "white-acceleration std of the broad regime (g)"),
    ("broad_min_s", 5.0, 0.0, 3600.0, "shortest stay in the broad regime (s)"),
    ("broad_max_s", 60.0, 0.0, 3600.0, "longest stay in the broad regime (s)"),
    ("resample_ess", 0.5, 0.0, 1.0, "resample when the effective sample size falls below this fraction of N"),
    ("rdot_noise_scale", 1.0, 0.1, 100.0, "radial_velocity only: the range-rate noise std used, over the radar's"),
    ("onset_boost", 8.0, 1.0, 100.0, "importance proposal: a leg's end is proposed this many times as often as "
                                     "the prior says, the weights corrected"),
)
_RANGES = {p[0]: (p[2], p[3]) for p in RBPF_PARAMS}


@dataclass(frozen=True)
class RBPFSpec:
    """The particle filter's settings (:data:`RBPF_PARAMS` gives each one's range and meaning) and its prior.

    Attributes: the names of :data:`RBPF_PARAMS`; ``prior``: the :class:`RandomScenarioConfig` whose laws the
    regimes follow (default: the ``random`` suite's); ``flight_start_known``: the particles know the look times
    count from the flight's start (the causal reference; see the module docstring); ``radial_velocity``: each
    particle's filter also updates on the plot's radial velocity (:func:`radar_env.filters.kernels._rdot_update`,
    after the position), its noise std ``rdot_noise_scale`` x the radar's.
    Every value is checked when built: ``ValueError`` naming the field and its range."""

    n_particles: int = 4096
    q_floor_g: float = 0.005
    sigma_turn_rate0_deg_s: float = 0.3
    sigma_turn_rate_walk_deg_s15: float = 0.02
    sigma_accel0_g: float = 0.02
    sigma_accel_walk_g_s05: float = 0.002
    broad_rate_per_s: float = 1e-3
    broad_q_g: float = 3.0
    broad_min_s: float = 5.0
    broad_max_s: float = 60.0
    resample_ess: float = 0.5
    onset_boost: float = 8.0
    rdot_noise_scale: float = 1.0
    radial_velocity: bool = False
    prior: RandomScenarioConfig = RandomScenarioConfig()
    flight_start_known: bool = False

    def __post_init__(self):
        for f in fields(self):
            if f.name in _RANGES:
                lo, hi = _RANGES[f.name]
                v = check_number(f"RBPFSpec.{f.name}", getattr(self, f.name), lo, hi,
                                 integer=f.name == "n_particles")
                object.__setattr__(self, f.name, v)
        if self.broad_min_s > self.broad_max_s:
            raise ValueError(f"RBPFSpec: broad_min_s ({self.broad_min_s}) must be <= broad_max_s ({self.broad_max_s})")
        if not isinstance(self.prior, RandomScenarioConfig):
            raise ValueError(f"RBPFSpec.prior must be a RandomScenarioConfig, got {type(self.prior).__name__}")
        for name in ("flight_start_known", "radial_velocity"):
            if not isinstance(getattr(self, name), bool):
                raise ValueError(f"RBPFSpec.{name} must be a bool, got {getattr(self, name)!r}")


DEFAULT_RBPF = RBPFSpec()

# index of each value in the kernel's parameter vector (prior_vector)
(_P_LEG_LO, _P_LEG_HI, _P_FIRST_LO, _P_FIRST_HI, _P_FIRST_MIN, _P_LEGS_LO, _P_LEGS_HI, _P_PTURN, _P_PSPEED,
 _P_TURN_G_LO, _P_TURN_G_HI, _P_WMAX, _P_DH_LO, _P_DH_HI, _P_ACC_LO, _P_ACC_HI, _P_V_LO, _P_V_HI,
 _P_QFLOOR, _P_SW0, _P_SWW, _P_SA0, _P_SAW, _P_BRATE, _P_BQ, _P_BMIN, _P_BMAX, _P_ESS, _P_START, _P_BOOST, _P_RDOT, _P_RDOT_SCALE) = range(32)


def prior_vector(spec: RBPFSpec = DEFAULT_RBPF) -> np.ndarray:
    """The kernel's parameter vector: the prior's laws in SI units, then the filter's settings."""
    c = spec.prior
    first = c.first_leg_range_s
    v = [c.leg_duration_s[0], c.leg_duration_s[1], first[0], first[1], c.first_leg_min_s, c.n_legs[0], c.n_legs[1],
         c.turn_probability, c.speed_change_probability, c.turn_accel_g[0] * G0_M_S2, c.turn_accel_g[1] * G0_M_S2,
         c.max_turn_rate_deg_s * DEG, c.turn_heading_change_deg[0] * DEG, c.turn_heading_change_deg[1] * DEG,
         c.speed_change_accel_g[0] * G0_M_S2, c.speed_change_accel_g[1] * G0_M_S2, c.speed_kt[0] * KNOT_M_S,
         c.speed_kt[1] * KNOT_M_S, spec.q_floor_g * G0_M_S2, spec.sigma_turn_rate0_deg_s * DEG,
         spec.sigma_turn_rate_walk_deg_s15 * DEG, spec.sigma_accel0_g * G0_M_S2, spec.sigma_accel_walk_g_s05 * G0_M_S2,
         spec.broad_rate_per_s, spec.broad_q_g * G0_M_S2, spec.broad_min_s, spec.broad_max_s, spec.resample_ess,
         1.0 if spec.flight_start_known else 0.0, spec.onset_boost, 1.0 if spec.radial_velocity else 0.0,
         spec.rdot_noise_scale]
    return np.asarray(v, dtype=np.float64)


# Every helper called per particle is compiled without numba's reference counting (``_nrt=False``: they only read
# and write elements of the arrays they are given, never allocate or keep one). With it, each array argument of
# each call cost an atomic increment and decrement (NRT_incref / NRT_decref) per particle and look: about a third of
# the filter's time. The shared filter helpers are compiled again here the same way, from the same Python functions
# (the same arithmetic; not cached on their own: they live in the cached kernel's code).
def _leaf(f):
    return numba.njit(_nrt=False)(f.py_func)


_ct_predict, _rdot_update, _abat = (_leaf(imm_cv_ct._ct_predict), _leaf(kernels._rdot_update),
                                    _leaf(imm_cv_ct._abat))


@numba.njit(cache=True, _nrt=False)
def _moments(w, xs, Ps, n, x_out, P_out):
    """:func:`radar_env.filters.imm_cv_ct._moments` of the particles' first ``n = 4`` states (the only ``n`` the
    filter asks for): the same sums in the same order (over the particles, for each entry), each entry's sum held in
    a register instead of in ``P_out`` between particles."""
    m0 = m1 = m2 = m3 = 0.0
    for i in range(w.shape[0]):
        wi = w[i]
        m0 += wi * xs[i, 0]
        m1 += wi * xs[i, 1]
        m2 += wi * xs[i, 2]
        m3 += wi * xs[i, 3]
    a00 = a01 = a02 = a03 = a10 = a11 = a12 = a13 = 0.0
    a20 = a21 = a22 = a23 = a30 = a31 = a32 = a33 = 0.0
    for i in range(w.shape[0]):
        wi = w[i]
        d0, d1, d2, d3 = xs[i, 0] - m0, xs[i, 1] - m1, xs[i, 2] - m2, xs[i, 3] - m3
        a00 += wi * (Ps[i, 0, 0] + d0 * d0)
        a01 += wi * (Ps[i, 0, 1] + d0 * d1)
        a02 += wi * (Ps[i, 0, 2] + d0 * d2)
        a03 += wi * (Ps[i, 0, 3] + d0 * d3)
        a10 += wi * (Ps[i, 1, 0] + d1 * d0)
        a11 += wi * (Ps[i, 1, 1] + d1 * d1)
        a12 += wi * (Ps[i, 1, 2] + d1 * d2)
        a13 += wi * (Ps[i, 1, 3] + d1 * d3)
        a20 += wi * (Ps[i, 2, 0] + d2 * d0)
        a21 += wi * (Ps[i, 2, 1] + d2 * d1)
        a22 += wi * (Ps[i, 2, 2] + d2 * d2)
        a23 += wi * (Ps[i, 2, 3] + d2 * d3)
        a30 += wi * (Ps[i, 3, 0] + d3 * d0)
        a31 += wi * (Ps[i, 3, 1] + d3 * d1)
        a32 += wi * (Ps[i, 3, 2] + d3 * d2)
        a33 += wi * (Ps[i, 3, 3] + d3 * d3)
    x_out[:] = 0.0
    x_out[0], x_out[1], x_out[2], x_out[3] = m0, m1, m2, m3
    P_out[:, :] = 0.0
    P_out[0, 0], P_out[0, 1], P_out[0, 2], P_out[0, 3] = a00, a01, a02, a03
    P_out[1, 0], P_out[1, 1], P_out[1, 2], P_out[1, 3] = a10, a11, a12, a13
    P_out[2, 0], P_out[2, 1], P_out[2, 2], P_out[2, 3] = a20, a21, a22, a23
    P_out[3, 0], P_out[3, 1], P_out[3, 2], P_out[3, 3] = a30, a31, a32, a33
    _symmetrize(P_out)


# ------------------------------------------------------------------------------------------------ motion models
@numba.njit(cache=True, _nrt=False)
def _accel_predict(x, dt, out, J):
    """A speed change: acceleration ``eta = x[4]`` along the velocity, the heading fixed (exact motion), and its
    Jacobian."""
    vx, vy, a = x[2], x[3], x[4]
    s = max(math.hypot(vx, vy), 1.0)
    ux, uy = vx / s, vy / s
    h2 = 0.5 * dt * dt
    out[0] = x[0] + vx * dt + a * h2 * ux
    out[1] = x[1] + vy * dt + a * h2 * uy
    out[2] = vx + a * dt * ux
    out[3] = vy + a * dt * uy
    out[4] = a
    # d u / d v = (I - u u^T) / s
    pxx, pxy, pyy = (1.0 - ux * ux) / s, -ux * uy / s, (1.0 - uy * uy) / s
    J[:, :] = 0.0
    J[0, 0] = J[1, 1] = J[4, 4] = 1.0
    J[0, 2], J[0, 3] = dt + a * h2 * pxx, a * h2 * pxy
    J[1, 2], J[1, 3] = a * h2 * pxy, dt + a * h2 * pyy
    J[2, 2], J[2, 3] = 1.0 + a * dt * pxx, a * dt * pxy
    J[3, 2], J[3, 3] = a * dt * pxy, 1.0 + a * dt * pyy
    J[0, 4], J[1, 4] = h2 * ux, h2 * uy
    J[2, 4], J[3, 4] = dt * ux, dt * uy


@numba.njit(cache=True, _nrt=False)
def _propagate(kind, x, P, h, pv, xo, J, tmp, Po):
    """Propagate one particle's filter ``(x, P)`` in place over ``h`` seconds of regime ``kind``: the regime's
    motion and Jacobian, the noise floor on every regime, the broad regime's noise, ``eta``'s random walk."""
    if h <= 0.0:
        return
    if kind == TURN or kind == SPEED:
        if kind == TURN:
            _ct_predict(x, h, xo, J)
        else:
            _accel_predict(x, h, xo, J)
        _abat(J, P, tmp, Po)
        for r in range(5):
            x[r] = xo[r]
            for c in range(5):
                P[r, c] = Po[r, c]
    else:     # constant velocity (eta's row and column are 0): F P F^T in place, F = [[I, h I], [0, I]]
        x[0] += h * x[2]
        x[1] += h * x[3]
        for c in range(5):
            P[0, c] += h * P[2, c]
            P[1, c] += h * P[3, c]
        for r in range(5):
            P[r, 0] += h * P[r, 2]
            P[r, 1] += h * P[r, 3]
    _add_cv_noise(P, h, pv[_P_QFLOOR])
    if kind == BROAD:
        _add_cv_noise(P, h, pv[_P_BQ])
    elif kind == TURN:
        P[4, 4] += pv[_P_SWW] * pv[_P_SWW] * h
    elif kind == SPEED:
        P[4, 4] += pv[_P_SAW] * pv[_P_SAW] * h
    _symmetrize(P)


@numba.njit(cache=True, _nrt=False)
def _plot_update(x, P, n, z0, z1, frame, xo, Po):
    """The chain's Kalman update (:func:`radar_env.filters.kernels._gain_update`) of the first ``n`` states (4 where
    ``eta``'s row and column are 0) with the position plot, in place; returns the plot's log-likelihood. ``frame``:
    the plot's R in its principal axes (:func:`radar_env.filters.kernels._r_frame`), the same for every particle."""
    nis, d = _gain_update_in_frame_inlined(x, P, n, z0 - x[0], z1 - x[1], frame[0], frame[1], frame[2], frame[3],
                                           xo, Po)
    for r in range(n):
        x[r] = xo[r]
        for c in range(n):
            P[r, c] = Po[r, c]
    return -0.5 * (nis + 2.0 * _LOG_2PI + math.log(d))


@numba.njit(cache=True)
def _end_within(tau, dlo, dhi, h, u, boost):
    """When, within the next ``h`` s, a segment of duration ``U(dlo, dhi)`` that has lasted ``tau`` ends, drawn with
    the uniform ``u`` from its conditional law with the end's probability ``p`` proposed as
    ``1 - (1 - p)^boost`` (``boost`` times as likely while ``p`` is small, below 1 while ``p`` is);
    -1 if it does not end within ``h``. Returns ``(when, log of the prior over the proposal's probability)``."""
    if math.isinf(dhi):
        return -1.0, 0.0
    if tau >= dhi:
        return 0.0, 0.0
    lo = max(tau, dlo)
    if tau + h <= lo:
        return -1.0, 0.0
    span = dhi - lo
    if span <= 1e-12:                      # a known end (a degenerate law)
        return lo - tau, 0.0
    hi = min(tau + h, dhi)
    p = (hi - lo) / span
    pb = 1.0 - (1.0 - p) ** boost     # ~ boost p while p is small, below 1 while p is: not ending keeps its support
    if u >= pb:
        return -1.0, (1.0 - boost) * math.log1p(-p)
    return lo + (u / pb) * (hi - lo) - tau, math.log(p / pb)


@numba.njit(cache=True, _nrt=False)
def _set_eta(x, P, value, var):
    x[4] = value
    P[4, :] = 0.0
    P[:, 4] = 0.0
    P[4, 4] = var


@numba.njit(cache=True, _nrt=False)
def _start_turn(x, P, pv, key, c, seg):
    """A new coordinated turn: rate ``min(U(turn_accel) / speed, w_max)``, either way, spread ``sigma``; duration
    ``U(heading change) / rate``. ``seg``: (kind, dlo, dhi) written in place."""
    s = max(math.hypot(x[2], x[3]), 1.0)
    g = pv[_P_TURN_G_LO] + (pv[_P_TURN_G_HI] - pv[_P_TURN_G_LO]) * _u01(key, c)
    w = min(g / s, pv[_P_WMAX])
    sign = 1.0 if _u01(key, c + 1) < 0.5 else -1.0
    sd = pv[_P_SW0]
    _set_eta(x, P, sign * w + sd * _normal2(key, c + 2), sd * sd)
    seg[0], seg[1], seg[2] = TURN, pv[_P_DH_LO] / w, pv[_P_DH_HI] / w


@numba.njit(cache=True)
def _normal2(key, c):
    """A standard normal from counters ``c``, ``c + 1``."""
    u1 = 1.0 - _u01(key, c)
    return math.sqrt(-2.0 * math.log(u1)) * math.cos(2.0 * math.pi * _u01(key, c + 1))


@numba.njit(cache=True, _nrt=False)
def _start_leg(x, P, legs_left, seg):
    """A new straight leg (the last one, with no end, when no leg ends are left)."""
    _set_eta(x, P, 0.0, 0.0)
    seg[0] = STRAIGHT
    if legs_left == 0:
        seg[1] = seg[2] = np.inf


@numba.njit(cache=True, _nrt=False)
def _next_segment(kind, pending_turn, legs_left, x, P, pv, key, c, seg):
    """The segment after one of ``kind`` ended; writes ``seg`` = (kind, dlo, dhi) and returns
    ``(pending_turn, legs_left)``."""
    seg[1], seg[2] = pv[_P_LEG_LO], pv[_P_LEG_HI]
    if kind == STRAIGHT:
        if legs_left > 0:
            legs_left -= 1
        turn = _u01(key, c) < pv[_P_PTURN]
        if _u01(key, c + 1) < pv[_P_PSPEED]:
            s = math.hypot(x[2], x[3])
            v_lo, v_hi = pv[_P_V_LO], pv[_P_V_HI]
            p_up = min(max((v_hi - s) / (v_hi - v_lo), 0.0), 1.0)
            up = _u01(key, c + 2) < p_up
            room = (v_hi - s) if up else (s - v_lo)
            if room > 1e-6:
                a = pv[_P_ACC_LO] + (pv[_P_ACC_HI] - pv[_P_ACC_LO]) * _u01(key, c + 3)
                sd = pv[_P_SA0]
                _set_eta(x, P, (a if up else -a) + sd * _normal2(key, c + 4), sd * sd)
                seg[0], seg[1], seg[2] = SPEED, 0.0, room / a
                return turn, legs_left
        if turn:
            _start_turn(x, P, pv, key, c + 6, seg)
        else:                                  # neither: the legs join
            _start_leg(x, P, legs_left, seg)
        return False, legs_left
    if kind == SPEED and pending_turn:
        _start_turn(x, P, pv, key, c + 6, seg)
        return False, legs_left
    _start_leg(x, P, legs_left, seg)           # after a turn, a speed change without a turn, the broad regime
    return False, legs_left


@numba.njit(cache=True)
def _init_particle(t0, x4, P4, pv, key, c, x, P, seg):
    """A particle at the track start: a straight leg; with the flight's start known, the first leg's law from
    ``t = 0`` given it lasted ``t0`` and ``U(n_legs)`` legs; else a leg of stationary (unknown) age and unlimited
    legs. Returns ``(tau, legs_left)``."""
    x[:4] = x4
    x[4] = 0.0
    P[:, :] = 0.0
    P[:4, :4] = P4
    lo, hi = pv[_P_LEG_LO], pv[_P_LEG_HI]
    seg[0], seg[1], seg[2] = STRAIGHT, lo, hi
    u = _u01(key, c)
    if pv[_P_START] > 0.0:
        n_legs = int(pv[_P_LEGS_LO] + math.floor(_u01(key, c + 1) * (pv[_P_LEGS_HI] - pv[_P_LEGS_LO] + 1.0)))
        legs_left = min(n_legs, int(pv[_P_LEGS_HI])) - 1
        if legs_left == 0:
            seg[1] = seg[2] = np.inf
            return t0, 0
        f_lo, f_hi, f_min = pv[_P_FIRST_LO], pv[_P_FIRST_HI], pv[_P_FIRST_MIN]
        if t0 < f_min:     # D = max(U(f_lo, f_hi), f_min): the point mass at f_min, else uniform above it
            p_min = min(max((f_min - f_lo) / (f_hi - f_lo), 0.0), 1.0)
            d = f_min if u < p_min else max(f_lo, f_min) + (f_hi - max(f_lo, f_min)) * _u01(key, c + 2)
        else:
            a = max(t0, f_lo)
            d = a + max(f_hi - a, 0.0) * u
        seg[1] = seg[2] = d
        return t0, legs_left
    # stationary age of a renewal leg U(lo, hi): density proportional to its survival function
    m = u * (lo + 0.5 * (hi - lo))
    if m < lo:
        return m, -1
    L = hi - lo
    return lo + L - math.sqrt(max(L * L - 2.0 * L * (m - lo), 0.0)), -1


# A view such as ``xs[i]`` costs an atomic reference-count increment and decrement (numba's NRT): per particle and
# look they took about half of the filter's time (perf: NRT_incref / NRT_decref). The particle is copied into scratch
# arrays and back instead, by index: the same values, the same arithmetic.
@numba.njit(cache=True, _nrt=False)
def _load(xs, Ps, i, x, P):
    for r in range(5):
        x[r] = xs[i, r]
        for c in range(5):
            P[r, c] = Ps[i, r, c]


@numba.njit(cache=True, _nrt=False)
def _store(x, P, xs, Ps, i):
    for r in range(5):
        xs[i, r] = x[r]
        for c in range(5):
            Ps[i, r, c] = P[r, c]


@numba.njit(cache=True, _nrt=False)
def _copy_particle(xs, Ps, j, xs2, Ps2, i):
    for r in range(5):
        xs2[i, r] = xs[j, r]
        for c in range(5):
            Ps2[i, r, c] = Ps[j, r, c]


@numba.njit(cache=True)
def _init_row(t0, x4, P4, pv, key, k0, N, xs, Ps, kind, tau, dlo, dhi, legs, pend, logw):
    """Every particle at the track start ``(x4, P4)`` at look ``k0`` (time ``t0``), in place
    (:func:`_init_particle`, counters of look ``k0``), equal weights."""
    seg = np.empty(3)
    D = _DRAWS_PER_PARTICLE_LOOK
    for i in range(N):
        tau[i], legs[i] = _init_particle(t0, x4, P4, pv, key, (k0 * N + i) * D, xs[i], Ps[i], seg)
        kind[i], dlo[i], dhi[i] = int(seg[0]), seg[1], seg[2]
        pend[i] = False
        logw[i] = -math.log(N)


@numba.njit(cache=True)
def _predict_look(k, dt, key, pv, N, xs, Ps, kind, tau, dlo, dhi, legs, pend, logw):
    """One look's prediction, in place: each particle's regime moves over ``dt`` (the broad regime's entry, the
    segments' ends with their draws, counters of look ``k``) and its filter's propagation through them; the
    proposal's weight corrections join ``logw`` (not normalised)."""
    xo, J, tmp, Po, seg = np.empty(5), np.empty((5, 5)), np.empty((5, 5)), np.empty((5, 5)), np.empty(3)
    x, P = np.empty(5), np.empty((5, 5))     # the particle being filtered (see _load)
    D = _DRAWS_PER_PARTICLE_LOOK
    p_broad = 1.0 - math.exp(-pv[_P_BRATE] * dt)
    for i in range(N):
        c = (k * N + i) * D
        _load(xs, Ps, i, x, P)
        if kind[i] != BROAD and _u01(key, c) < p_broad:    # off the prior: the broad regime from this look
            _set_eta(x, P, 0.0, 0.0)
            kind[i], tau[i], dlo[i], dhi[i], pend[i] = BROAD, 0.0, pv[_P_BMIN], pv[_P_BMAX], False
        h = dt
        for move in range(_MAX_MOVES_PER_LOOK + 1):
            cm = c + 2 + 10 * move
            s_end = -1.0
            if move < _MAX_MOVES_PER_LOOK:
                s_end, lr = _end_within(tau[i], dlo[i], dhi[i], h, _u01(key, cm),
                                        pv[_P_BOOST] if kind[i] == STRAIGHT else 1.0)
                logw[i] += lr
            if s_end < 0.0:
                _propagate(kind[i], x, P, h, pv, xo, J, tmp, Po)
                tau[i] += h
                break
            _propagate(kind[i], x, P, s_end, pv, xo, J, tmp, Po)
            h -= s_end
            pend[i], legs[i] = _next_segment(kind[i], pend[i], legs[i], x, P, pv, key, cm + 1, seg)
            kind[i], tau[i], dlo[i], dhi[i] = int(seg[0]), 0.0, seg[1], seg[2]
        _store(x, P, xs, Ps, i)


@numba.njit(cache=True)
def _update_look(k, det, z0, z1, R00, R01, R11, rdot, sx, sy, rdot_var, key, pv, N, xs, Ps, kind, tau, dlo, dhi,
                 legs, pend, logw, xs2, Ps2, kind2, tau2, dlo2, dhi2, legs2, pend2, w, xc, Pc):
    """One look's update after :func:`_predict_look`: with a plot (``det``), each particle's Kalman update on it
    (and on its radial velocity with ``pv[_P_RDOT]``; ``rdot_var`` not finite: position only), its likelihood into
    ``logw``; then the weights normalised, the combination (``xc``, ``Pc``: 5 states, the first 4 reported), and
    systematic resampling (draw of look ``k``) when the ESS is below ``pv[_P_ESS] N``: the resampled particles in the
    second buffers (``xs2`` ...), ``logw`` reset. Returns ``(maneuver probability, mean turn rate, ESS, resampled)``;
    the caller swaps the buffers when ``resampled``."""
    xo, Po = np.empty(5), np.empty((5, 5))
    x, P = np.empty(5), np.empty((5, 5))
    if det:      # R's frame once per look, not per particle (three transcendentals per particle-look)
        frame = _r_frame(R00, R01, R11)
        use_rdot = pv[_P_RDOT] > 0.0
        for i in range(N):
            _load(xs, Ps, i, x, P)
            n = 4 if kind[i] == STRAIGHT or kind[i] == BROAD else 5
            logw[i] += _plot_update(x, P, n, z0, z1, frame, xo, Po)
            if use_rdot:
                logw[i] += _rdot_update(x, P, n, rdot, sx, sy, rdot_var, xo, Po)
                for r in range(n):
                    x[r] = xo[r]
                    for c in range(n):
                        P[r, c] = Po[r, c]
            _store(x, P, xs, Ps, i)
    lse = _logsumexp(logw, N)
    s2, pman, om = 0.0, 0.0, 0.0
    for i in range(N):
        logw[i] -= lse
        w[i] = math.exp(logw[i])
        s2 += w[i] * w[i]
        if kind[i] != STRAIGHT:
            pman += w[i]
        if kind[i] == TURN:
            om += w[i] * xs[i, 4]
    _moments(w, xs, Ps, 4, xc, Pc)
    _pd_floor(Pc, np.int64(4), Pc)      # the mixture can round below positive definite (floored only then)
    resampled = 1.0 / s2 < pv[_P_ESS] * N
    if resampled:                 # systematic resampling
        u = _u01(key ^ _RESAMPLE_STREAM, k) / N
        j, cum = 0, w[0]
        for i in range(N):
            while cum < u and j < N - 1:
                j += 1
                cum += w[j]
            _copy_particle(xs, Ps, j, xs2, Ps2, i)
            kind2[i], tau2[i] = kind[j], tau[j]
            dlo2[i], dhi2[i], legs2[i], pend2[i] = dlo[j], dhi[j], legs[j], pend[j]
            u += 1.0 / N
        logw[:] = -math.log(N)
    return pman, om, 1.0 / s2, resampled


@numba.njit(cache=True)
def _row(t, z, R, det, rdot, site, rdot_var, n_looks, k_start, x4, P4, key, pv, N, out_x, out_P, out_pman, out_w,
         out_ess):
    """One track's looks ``k_start .. n_looks - 1`` with ``N`` particles: :func:`_init_row`, then per look
    :func:`_predict_look` and :func:`_update_look` (the Stone Soup components, :mod:`baselines.stonesoup_rbpf`, call
    the same three)."""
    xs, Ps = np.empty((N, 5)), np.empty((N, 5, 5))
    kind, tau, dlo, dhi = np.empty(N, np.int64), np.empty(N), np.empty(N), np.empty(N)
    legs, pend, logw = np.empty(N, np.int64), np.zeros(N, np.bool_), np.empty(N)
    xs2, Ps2 = np.empty((N, 5)), np.empty((N, 5, 5))
    kind2, tau2, dlo2, dhi2 = np.empty(N, np.int64), np.empty(N), np.empty(N), np.empty(N)
    legs2, pend2 = np.empty(N, np.int64), np.zeros(N, np.bool_)
    w = np.empty(N)
    xc, Pc = np.empty(5), np.empty((5, 5))
    k0 = k_start - 1
    t_prev = t[k0]
    _init_row(t_prev, x4, P4, pv, key, k0, N, xs, Ps, kind, tau, dlo, dhi, legs, pend, logw)
    for k in range(k_start, n_looks):
        dt = t[k] - t_prev
        t_prev = t[k]
        _predict_look(k, dt, key, pv, N, xs, Ps, kind, tau, dlo, dhi, legs, pend, logw)
        pman, om, ess, resampled = _update_look(
            k, det[k], z[k, 0], z[k, 1], R[k, 0, 0], 0.5 * (R[k, 0, 1] + R[k, 1, 0]), R[k, 1, 1], rdot[k], site[k, 0],
            site[k, 1], rdot_var[k], key, pv, N, xs, Ps, kind, tau, dlo, dhi, legs, pend, logw, xs2, Ps2, kind2, tau2,
            dlo2, dhi2, legs2, pend2, w, xc, Pc)
        out_x[k] = xc[:4]
        out_P[k] = Pc[:4, :4]
        out_pman[k], out_w[k], out_ess[k] = pman, om, ess
        if resampled:
            xs, xs2, Ps, Ps2, kind, kind2, tau, tau2 = xs2, xs, Ps2, Ps, kind2, kind, tau2, tau
            dlo, dlo2, dhi, dhi2, legs, legs2, pend, pend2 = dlo2, dlo, dhi2, dhi, legs2, legs, pend2, pend


@numba.njit(cache=True, parallel=True)
def _kernel(t, z, R, det, rdot, site, rdot_var, n_looks, k_start, x4, P4, keys, pv, N, out_x, out_P, out_pman, out_w,
            out_ess):
    for b in numba.prange(t.shape[0]):
        _row(t[b], z[b], R[b], det[b], rdot[b], site[b], rdot_var[b], n_looks[b], k_start[b], x4[b], P4[b], keys[b], pv, N, out_x[b], out_P[b],
             out_pman[b], out_w[b], out_ess[b])


def rbpf_filter(t_s, z_m, R_m2, detected, n_looks, k_start, x0, P0, keys, spec: RBPFSpec = DEFAULT_RBPF,
                radial_velocity_m_s=None, site_xy_m=None, radial_velocity_std_m_s=None):
    """Run the particle filter on B padded look sequences from a given start (no track start of its own).

    Args:
        t_s (B, K), z_m (B, K, 2), R_m2 (B, K, 2, 2), detected (B, K): the looks (NaN allowed where missed).
        n_looks (B,), k_start (B,) >= 1: looks per row and the first look filtered (``k_start - 1`` is the start).
        x0 (B, 4), P0 (B, 4, 4): the start estimate (every particle's filter begins there).
        keys (B,) uint64: each row's random stream.
        spec: the settings and prior (:class:`RBPFSpec`).
        radial_velocity_m_s (B, K), site_xy_m (B, K, 2), radial_velocity_std_m_s (B, K): the measured radial
            velocity, the site that looked and its noise std; needed with ``spec.radial_velocity`` (a look whose
            radial velocity or std is not finite, or whose std is not positive, updates on its position only).
    Returns ``(x (B, K, 4), P (B, K, 4, 4), maneuver_probability (B, K), turn_rate_rad_s (B, K), ess (B, K))``,
    NaN outside the filtered looks."""
    t, z, R, det, n, ks = padded_looks(t_s, z_m, R_m2, detected, n_looks, k_start)
    B, K = t.shape
    x0 = np.ascontiguousarray(x0, dtype=np.float64).reshape(B, 4)
    P0 = np.ascontiguousarray(P0, dtype=np.float64).reshape(B, 4, 4)
    keys = np.ascontiguousarray(keys, dtype=np.uint64).reshape(B)
    if spec.radial_velocity and (radial_velocity_m_s is None or site_xy_m is None or radial_velocity_std_m_s is None):
        raise ValueError("rbpf_filter: spec.radial_velocity needs radial_velocity_m_s, site_xy_m and "
                         "radial_velocity_std_m_s")
    rdot, var, site = range_rate_inputs((B, K), *((radial_velocity_m_s, site_xy_m, radial_velocity_std_m_s)
                                                  if spec.radial_velocity else ()), noise_scale=spec.rdot_noise_scale)
    out = (np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan), np.full((B, K), np.nan),
           np.full((B, K), np.nan), np.full((B, K), np.nan))
    _kernel(t, z, R, det, np.ascontiguousarray(rdot), site, np.ascontiguousarray(var), n, ks, x0, P0, keys,
            prior_vector(spec), int(spec.n_particles), *out)
    return out
