r"""Track applications from seed 002: closest approach / conflict warning, intercept course, intercept simulation,
and a two-aircraft encounter generator.

All functions are pure numpy, float64, batch axis first. Vector arguments have a trailing axis of length 2
(``[x, y]`` or ``[vx, vy]``, x east, y north, metres and m/s) and broadcast against each other, so a single
pair of ``(2,)`` vectors works as well as ``(B, 2)`` batches; the outputs then have the broadcast batch shape
(``()`` for a single pair). Headings are clockwise from north, ``heading = atan2(vx, vy)``. The only
randomness is in :func:`two_aircraft_encounter`, drawn from the ``numpy.random.Generator`` passed in.

Relative motion
---------------
For two constant-velocity objects with relative position :math:`\Delta p = p_2 - p_1` and relative velocity
:math:`\Delta v = v_2 - v_1`, the squared separation is the quadratic

.. math:: |\Delta p + \Delta v\,t|^2 = |\Delta v|^2 t^2 + 2(\Delta p\cdot\Delta v)\,t + |\Delta p|^2 .

Seed 002 (eqs 40-45) expands this as
:math:`t^2(\Delta v_x + \Delta v_y) + t(2\Delta v_y + 2\Delta v_x) + \Delta x^2 + \Delta y^2 - 1`, which drops the
squares of the velocity terms and the position factor of the linear term; it is not the separation and can even
have a negative leading coefficient. The correct coefficients are
:math:`a = \Delta v_x^2 + \Delta v_y^2`, :math:`b = 2(\Delta x\,\Delta v_x + \Delta y\,\Delta v_y)`,
:math:`c = \Delta x^2 + \Delta y^2 - d^2`; they are used below.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radar_env.common.units import DEG, KNOT_M_S, NM_M

__all__ = [
    "ClosestApproach",
    "ConflictWarning",
    "InterceptCourse",
    "InterceptResult",
    "Encounter",
    "closest_approach",
    "conflict_warning",
    "intercept_course",
    "simulate_intercept",
    "two_aircraft_encounter",
]


def _vec(a):
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 0 or a.shape[-1] != 2:
        raise ValueError(f"expected a trailing axis of length 2, got shape {a.shape}")
    return a


def _out(a):
    """Return a 0-d result as a numpy scalar, anything else unchanged."""
    return a[()] if isinstance(a, np.ndarray) and a.ndim == 0 else a


def _dot(a, b):
    return a[..., 0] * b[..., 0] + a[..., 1] * b[..., 1]


class ClosestApproach(NamedTuple):
    t_cpa_s: np.ndarray
    """Time of closest approach from now, clamped to ``>= 0`` (batch shape)."""
    d_cpa_m: np.ndarray
    """Separation at ``t_cpa_s`` (batch shape)."""


def _cpa(dp, dv):
    dv2 = _dot(dv, dv)
    pv = _dot(dp, dv)
    moving = dv2 > 0.0
    t = np.where(moving, -pv / np.where(moving, dv2, 1.0), 0.0)
    t = np.maximum(t, 0.0)
    rel = dp + dv * t[..., None]
    return t, np.hypot(rel[..., 0], rel[..., 1])


def closest_approach(p1_m, v1_m_s, p2_m, v2_m_s) -> ClosestApproach:
    r"""Time and distance of the closest approach of two constant-velocity objects.

    Minimising :math:`|\Delta p + \Delta v\,t|^2` (module docstring) gives

    .. math:: t^* = -\frac{\Delta p\cdot\Delta v}{|\Delta v|^2}, \qquad t_{cpa} = \max(t^*, 0),
              \qquad d_{cpa} = |\Delta p + \Delta v\,t_{cpa}| .

    Diverging pairs (:math:`t^* < 0`) get ``t_cpa = 0`` and the current distance. Equal velocities
    (:math:`\Delta v = 0`, the separation never changes) get ``t_cpa = 0`` with no division, NaN or warning.

    Parameters
    ----------
    p1_m, v1_m_s, p2_m, v2_m_s : array_like, shape (..., 2)
        Positions (m) and velocities (m/s), broadcast together.

    Returns
    -------
    ClosestApproach
        ``(t_cpa_s, d_cpa_m)`` with the broadcast batch shape.
    """
    p1, v1, p2, v2 = (_vec(a) for a in (p1_m, v1_m_s, p2_m, v2_m_s))
    t, d = _cpa(p2 - p1, v2 - v1)
    return ClosestApproach(_out(t), _out(d))


class ConflictWarning(NamedTuple):
    warning: np.ndarray
    """True when the minimum separation over ``[0, lookahead_s]`` is below ``threshold_m``."""
    t_cpa_s: np.ndarray
    """Unrestricted closest-approach time (>= 0), as :func:`closest_approach`."""
    d_cpa_m: np.ndarray
    """Separation at ``t_cpa_s``."""
    d_min_window_m: np.ndarray
    """Minimum separation inside the look-ahead window, i.e. at ``min(t_cpa_s, lookahead_s)``."""
    t_entry_s: np.ndarray
    """First time ``>= 0`` at which the separation drops below ``threshold_m`` (0 if already inside, ``inf`` if
    never; not limited to the window)."""


def conflict_warning(p1_m, v1_m_s, p2_m, v2_m_s, threshold_m, lookahead_s) -> ConflictWarning:
    r"""Predicted loss of separation within a look-ahead window (seed 002 eqs 30-45, corrected).

    The separation is convex in time, so its minimum over :math:`[0, T_{la}]` is at
    :math:`\min(t_{cpa}, T_{la})`; ``warning = d_min_window < threshold_m`` (strict, as the paper's eq 31).

    The entry time solves the corrected quadratic of eq 41,
    :math:`|\Delta v|^2 t^2 + 2(\Delta p\cdot\Delta v)t + |\Delta p|^2 - d_{th}^2 = 0`, taking the smaller root
    (computed in the cancellation-free form :math:`t = c / (-h + \sqrt{h^2 - a c})` with
    :math:`h = \Delta p\cdot\Delta v`). The paper's discriminant test ignores the direction of time (a pair that
    passed within the threshold in the past also has two real roots) and the look-ahead; here both are handled.
    The paper's 12-mile range gate (eq 30) is left to the caller.

    Parameters
    ----------
    p1_m, v1_m_s, p2_m, v2_m_s : array_like, shape (..., 2)
    threshold_m : float or array_like, broadcast to the batch shape
        Separation minimum (the paper uses 1 mile).
    lookahead_s : float or array_like, >= 0
        Length of the prediction window.

    Returns
    -------
    ConflictWarning
        ``(warning, t_cpa_s, d_cpa_m, d_min_window_m, t_entry_s)``.
    """
    p1, v1, p2, v2 = (_vec(a) for a in (p1_m, v1_m_s, p2_m, v2_m_s))
    dp, dv = p2 - p1, v2 - v1
    t_cpa, d_cpa = _cpa(dp, dv)
    thr = np.asarray(threshold_m, dtype=np.float64)
    la = np.asarray(lookahead_s, dtype=np.float64)
    if np.any(la < 0):
        raise ValueError("lookahead_s must be >= 0")
    t_w = np.minimum(t_cpa, la)
    rel = dp + dv * t_w[..., None]
    d_win = np.hypot(rel[..., 0], rel[..., 1])
    warning = d_win < thr

    a = _dot(dv, dv)
    h = _dot(dp, dv)
    c = _dot(dp, dp) - thr**2
    disc = h * h - a * c
    inside = c < 0.0
    approaching = (h < 0.0) & (disc > 0.0)
    den = np.sqrt(np.maximum(disc, 0.0)) - h
    t_entry = np.where(approaching, c / np.where(approaching, den, 1.0), np.inf)
    t_entry = np.where(inside, 0.0, t_entry)
    return ConflictWarning(_out(warning), _out(t_cpa), _out(d_cpa), _out(d_win), _out(t_entry))


class InterceptCourse(NamedTuple):
    heading_rad: np.ndarray
    """Course to fly, clockwise from north in (-pi, pi]. Pure-pursuit bearing to the target when infeasible."""
    time_to_intercept_s: np.ndarray
    """Earliest intercept time from now; ``np.inf`` when infeasible (never NaN)."""
    feasible: np.ndarray
    """Whether a constant-heading intercept exists."""


def intercept_course(interceptor_pos_m, interceptor_speed_m_s, target_pos_m, target_vel_m_s) -> InterceptCourse:
    r"""Earliest constant-heading intercept of a constant-velocity target.

    With :math:`\Delta p = p_T - p_I`, target velocity :math:`v_T` and interceptor speed :math:`s`, the
    interceptor meets the target at the smallest :math:`t > 0` with :math:`|\Delta p + v_T t| = s\,t`:

    .. math:: a t^2 + 2 h t + c = 0,\quad a = |v_T|^2 - s^2,\ h = \Delta p\cdot v_T,\ c = |\Delta p|^2 .

    * :math:`h < 0` (target closing on the interceptor's position) and :math:`h^2 - ac \ge 0`:
      :math:`t = c / (\sqrt{h^2 - ac} - h)` (smaller positive root, any sign of :math:`a`, no cancellation).
    * :math:`h \ge 0` and :math:`a < 0` (interceptor faster): :math:`t = (h + \sqrt{h^2 - ac}) / (-a)`.
    * otherwise (target at least as fast and opening, or faster and passing too far): infeasible.
      An exactly tangent case (:math:`h^2 = ac`, target faster) counts as feasible; rounding can tip it either way.

    The heading is that of the aim point :math:`\Delta p + v_T t`: ``atan2(aim_x, aim_y)``. When infeasible,
    ``feasible = False``, ``time_to_intercept_s = inf`` and the heading points at the target's current position
    (pure pursuit), so a caller can fly it unconditionally. A target already at the interceptor's position gives
    ``t = 0``, feasible, heading 0 (north) by the ``atan2(0, 0)`` convention.

    Comparison with seed 002 eqs 23-29. The paper solves the triangle interceptor-target-intercept point with the
    law of sines, :math:`\sin\tau = (v_T/v_I)\sin\beta` (eq 24 as printed misplaces the parenthesis:
    :math:`\sin^{-1}(A/B)\sin\beta`), and sets :math:`\alpha = \gamma - \tau` with
    :math:`\gamma = \cos^{-1}((y_T - y_I)/D)` (eq 28). Differences:

    * :math:`\cos^{-1}` returns :math:`[0, \pi]`, so eq 28 loses the sign of :math:`x_T - x_I`; it is right only for
      targets east of the interceptor. We use ``atan2``.
    * The sign of :math:`\tau` (lead to the left or right of the line of sight) depends on which side the target
      velocity points; eq 29 always subtracts. The aim-point form needs no case analysis.
    * No feasibility test: :math:`(v_T/v_I)\sin\beta > 1` makes the arcsin undefined, and for :math:`v_T > v_I`
      the law of sines has two solutions (the arcsin picks one, not necessarily the earliest). The quadratic gives
      feasibility and the earliest time explicitly, and also the time to go, which the paper does not compute.

    Where the paper's construction is valid (interceptor faster, target east, lead taken on the correct side) the
    two headings agree.

    Parameters
    ----------
    interceptor_pos_m : array_like, shape (..., 2)
    interceptor_speed_m_s : float or array_like (batch shape), > 0
    target_pos_m, target_vel_m_s : array_like, shape (..., 2)

    Returns
    -------
    InterceptCourse
        ``(heading_rad, time_to_intercept_s, feasible)`` with the broadcast batch shape.
    """
    pi_, pt, vt = (_vec(a) for a in (interceptor_pos_m, target_pos_m, target_vel_m_s))
    s = np.asarray(interceptor_speed_m_s, dtype=np.float64)
    if np.any(s <= 0):
        raise ValueError("interceptor_speed_m_s must be > 0")
    heading, t, feasible = _intercept(pt - pi_, vt, s)
    return InterceptCourse(_out(heading), _out(t), _out(feasible))


def _intercept(dp, vt, s, a=None):
    if a is None:       # a given: the caller computed it for many looks at once
        a = _dot(vt, vt) - s**2
    h = _dot(dp, vt)
    c = _dot(dp, dp)
    disc = h * h - a * c
    sq = np.sqrt(np.maximum(disc, 0.0))
    closing = (h < 0.0) & (disc >= 0.0)
    faster_opening = (h >= 0.0) & (a < 0.0)
    at_target = c == 0.0
    feasible = closing | faster_opening | at_target
    den1 = np.where(closing, sq - h, 1.0)
    den2 = np.where(faster_opening, -a, 1.0)
    t = np.where(closing, c / den1, np.where(faster_opening, (h + sq) / den2, np.inf))
    t = np.where(at_target, 0.0, t)
    t_aim = np.where(feasible, t, 0.0)
    aim = dp + vt * t_aim[..., None]
    heading = np.arctan2(aim[..., 0], aim[..., 1])
    return heading, t, feasible


class InterceptResult(NamedTuple):
    miss_distance_m: np.ndarray
    """Minimum true interceptor-target distance over the simulated interval, shape (B,) (or () unbatched)."""
    capture_time_s: np.ndarray
    """First time (absolute, same clock as ``times_s``) the distance is <= ``capture_radius_m``; ``inf`` if never."""
    interceptor_xy_m: np.ndarray
    """Interceptor positions at the scan times, shape (B, K, 2) (or (K, 2))."""
    feasible: np.ndarray
    """Whether the course computed at each scan was a feasible intercept, shape (B, K-1) (or (K-1,))."""


def simulate_intercept(target_truth_xy, track_estimates, times_s, interceptor_start_m, interceptor_speed_m_s,
                       capture_radius_m, n_looks=None) -> InterceptResult:
    r"""Fly an interceptor against a tracked target, re-aiming at every scan.

    At scan :math:`k` the course is :func:`intercept_course` from the interceptor's position to the track estimate
    ``track_estimates[..., k, :]`` (``[x, y, vx, vy]``); it is held (straight, constant speed) until scan
    :math:`k+1`. When no intercept is feasible the interceptor flies pure pursuit toward the estimated position.
    The true target moves linearly between consecutive truth samples, so within each interval the relative motion
    is linear and the minimum distance and the capture (entry) time are exact (closest approach on the interval,
    clamped to its length; entry from the corrected quadratic of :func:`conflict_warning`). The interceptor keeps
    flying after capture; the miss distance is the minimum over ``[times_s[0], times_s[-1]]``.

    Parameters
    ----------
    target_truth_xy : array_like, shape (K, 2) or (B, K, 2)
        True target positions at ``times_s``.
    track_estimates : array_like, shape (K, 4) or (B, K, 4)
        Track states ``[x, y, vx, vy]`` available at each scan (the estimate used to aim at scan k).
    times_s : array_like, shape (K,) or (B, K), strictly increasing (per row; rows may have their own scan times)
    interceptor_start_m : array_like, shape (2,) or (B, 2)
        Interceptor position at ``times_s[0]``.
    interceptor_speed_m_s : float or array_like (B,)
    capture_radius_m : float or array_like (B,)
    n_looks : array_like of int (B,), optional
        Looks of each row that count (``2 <= n_looks <= K``; default all K): rows of different lengths padded to
        one K are flown together, each stopping at its own last look (miss, capture and the interceptor frozen
        there; ``feasible`` False beyond). Padded looks need strictly increasing times too.

    Returns
    -------
    InterceptResult
    """
    truth = np.asarray(target_truth_xy, dtype=np.float64)
    est = np.asarray(track_estimates, dtype=np.float64)
    t = np.asarray(times_s, dtype=np.float64)
    unbatched = truth.ndim == 2 and est.ndim == 2 and t.ndim == 1
    if truth.ndim == 2:
        truth = truth[None]
    if est.ndim == 2:
        est = est[None]
    if t.ndim not in (1, 2):
        raise ValueError(f"times_s must be (K,) or (B, K), got shape {t.shape}")
    B = max(truth.shape[0], est.shape[0], t.shape[0] if t.ndim == 2 else 1)
    K = t.shape[-1]
    if truth.shape[-2:] != (K, 2) or est.shape[-2:] != (K, 4):
        raise ValueError("target_truth_xy must be (..., K, 2) and track_estimates (..., K, 4) with K = len(times_s)")
    if K < 2 or np.any(np.diff(t, axis=-1) <= 0):
        raise ValueError("times_s needs K >= 2 strictly increasing entries")
    t = np.broadcast_to(t, (B, K))   # one scan clock per row (the same clock when times_s is (K,))
    truth = np.broadcast_to(truth, (B, K, 2))
    est = np.broadcast_to(est, (B, K, 4))
    pos = np.broadcast_to(_vec(interceptor_start_m), (B, 2)).copy()
    s = np.broadcast_to(np.asarray(interceptor_speed_m_s, dtype=np.float64), (B,))
    r_cap = np.broadcast_to(np.asarray(capture_radius_m, dtype=np.float64), (B,))
    if np.any(s <= 0):
        raise ValueError("interceptor_speed_m_s must be > 0")
    n_ok = np.full(B, K) if n_looks is None else np.broadcast_to(np.asarray(n_looks), (B,))
    if n_ok.dtype.kind not in "iu" or np.any(n_ok < 2) or np.any(n_ok > K):
        raise ValueError(f"n_looks must be integers in [2, {K}] (K = len(times_s)), got {n_looks!r}")

    track = np.empty((B, K, 2))
    track[:, 0] = pos
    feas = np.empty((B, K - 1), dtype=bool)
    d0 = truth[:, 0] - pos
    miss = np.hypot(d0[:, 0], d0[:, 1])
    capture = np.where(miss <= r_cap, t[:, 0], np.inf)
    # what does not depend on the interceptor's path, for every interval at once (the same element-wise arithmetic)
    dt_all = t[:, 1:] - t[:, :-1]
    on_all = np.arange(1, K) < n_ok[:, None]   # rows still flying (a padded row stops at its last look)
    v_t_all = (truth[:, 1:] - truth[:, :-1]) / dt_all[..., None]
    a_int_all = _dot(est[..., 2:], est[..., 2:]) - s[:, None] ** 2     # _intercept's a
    r_cap2 = r_cap ** 2
    for k in range(K - 1):
        dt, on, v_t = dt_all[:, k], on_all[:, k], v_t_all[:, k]
        heading, _, feas_k = _intercept(est[:, k, :2] - pos, est[:, k, 2:], s, a_int_all[:, k])
        feas[:, k] = feas_k & on
        v_i = s[:, None] * np.stack([np.sin(heading), np.cos(heading)], -1)
        dp = truth[:, k] - pos
        dv = v_t - v_i
        # minimum distance on [0, dt]
        a = _dot(dv, dv)
        h = _dot(dp, dv)
        tc = np.minimum(np.maximum(np.where(a > 0.0, -h / np.where(a > 0.0, a, 1.0), 0.0), 0.0), dt)   # _cpa's t
        rel = dp + dv * tc[:, None]
        miss = np.where(on, np.minimum(miss, np.hypot(rel[:, 0], rel[:, 1])), miss)
        # first entry into the capture circle on [0, dt]
        c = _dot(dp, dp) - r_cap2
        disc = h * h - a * c
        ok = (h < 0.0) & (disc >= 0.0)
        te = np.where(ok, c / np.where(ok, np.sqrt(np.maximum(disc, 0.0)) - h, 1.0), np.inf)
        te = np.where(c <= 0.0, 0.0, te)
        new = on & np.isinf(capture) & (te <= dt)
        capture = np.where(new, t[:, k] + te, capture)
        pos = np.where(on[:, None], pos + v_i * dt[:, None], pos)
        track[:, k + 1] = pos
    if unbatched:
        return InterceptResult(miss[0][()], capture[0][()], track[0], feas[0])
    return InterceptResult(miss, capture, track, feas)


class Encounter(NamedTuple):
    state1: np.ndarray
    """Initial state ``[x, y, vx, vy]`` of aircraft 1, shape (n, 4)."""
    state2: np.ndarray
    """Initial state of aircraft 2, shape (n, 4)."""
    d_cpa_m: np.ndarray
    """Prescribed closest-approach distance, shape (n,)."""
    t_cpa_s: np.ndarray
    """Prescribed time of closest approach from the initial states, shape (n,)."""
    crossing_angle_rad: np.ndarray
    """Heading of aircraft 2 minus heading of aircraft 1, in (-pi, pi], shape (n,)."""


def two_aircraft_encounter(rng: np.random.Generator, conflict: bool, n: int = 1, *,
                           t_cpa_s=300.0,
                           speed_range_m_s=(100.0 * KNOT_M_S, 600.0 * KNOT_M_S),
                           crossing_angle_range_rad=(15.0 * DEG, 180.0 * DEG),
                           conflict_cpa_max_m=1.0 * NM_M,
                           safe_cpa_range_m=(5.0 * NM_M, 10.0 * NM_M),
                           cpa_point_m=(0.0, 0.0)) -> Encounter:
    r"""Initial states of two straight-flying aircraft with a prescribed closest approach.

    Draws (all from ``rng``): speeds ``U(speed_range_m_s)`` for each aircraft, heading of aircraft 1
    ``U(-pi, pi)``, crossing angle magnitude ``U(crossing_angle_range_rad)`` with a random sign, the CPA distance
    ``U(0, conflict_cpa_max_m)`` if ``conflict`` else ``U(safe_cpa_range_m)``, and the side of the miss.
    Construction: aircraft 1 is at ``cpa_point_m`` at time ``t_cpa_s``; aircraft 2 is then at
    ``cpa_point_m + d n``, with :math:`n` a unit vector perpendicular to the relative velocity
    :math:`\Delta v = v_2 - v_1` (the CPA condition :math:`\Delta p(t_{cpa})\cdot\Delta v = 0`). Both are propagated
    back by ``t_cpa_s``. The crossing angle lower bound > 0 keeps :math:`|\Delta v| > 0`, so the CPA is unique.

    Parameters
    ----------
    rng : numpy.random.Generator
    conflict : bool
        Conflict (CPA below ``conflict_cpa_max_m``, default 1 NM) or safe pass (CPA in ``safe_cpa_range_m``,
        default 5-10 NM).
    n : int
        Number of encounters.
    t_cpa_s : float, default 300 s
        Time from the initial states to the closest approach (> 0).
    speed_range_m_s : (float, float), default 100-600 kt
    crossing_angle_range_rad : (float, float), default 15-180 deg
        Range of the absolute heading difference.
    cpa_point_m : (float, float), default origin
        Position of aircraft 1 at the closest approach.

    Returns
    -------
    Encounter
    """
    if not isinstance(rng, np.random.Generator):
        raise TypeError("rng must be a numpy.random.Generator")
    lo_c, hi_c = crossing_angle_range_rad
    if not (0.0 < lo_c <= hi_c <= np.pi):
        raise ValueError("crossing_angle_range_rad must satisfy 0 < lo <= hi <= pi")
    if t_cpa_s <= 0:
        raise ValueError("t_cpa_s must be > 0")
    s1 = rng.uniform(*speed_range_m_s, n)
    s2 = rng.uniform(*speed_range_m_s, n)
    h1 = rng.uniform(-np.pi, np.pi, n)
    cross = rng.uniform(lo_c, hi_c, n) * rng.choice([-1.0, 1.0], n)
    if conflict:
        d = rng.uniform(0.0, conflict_cpa_max_m, n)
    else:
        d = rng.uniform(*safe_cpa_range_m, n)
    side = rng.choice([-1.0, 1.0], n)
    h2 = h1 + cross
    v1 = s1[:, None] * np.stack([np.sin(h1), np.cos(h1)], -1)
    v2 = s2[:, None] * np.stack([np.sin(h2), np.cos(h2)], -1)
    dv = v2 - v1
    nrm = np.stack([-dv[:, 1], dv[:, 0]], -1) / np.hypot(dv[:, 0], dv[:, 1])[:, None]
    c = np.asarray(cpa_point_m, dtype=np.float64)
    p1 = c - v1 * t_cpa_s
    p2 = c + (side * d)[:, None] * nrm - v2 * t_cpa_s
    wrapped = np.angle(np.exp(1j * cross))
    return Encounter(np.concatenate([p1, v1], -1), np.concatenate([p2, v2], -1), d,
                     np.full(n, float(t_cpa_s)), wrapped)
