"""Truth trajectories (scenarios) in the 2-D plane: exact piecewise kinematics and user trajectories.

Conventions (docs/architecture.md): metres, seconds, radians; x east, y north; state ``[x, y, vx, vy]``;
heading clockwise from north; turn rate positive = clockwise = right turn.

A scenario answers, for any array of times ``t_s`` inside ``[0, duration_s]``:

* ``states_at(t_s) -> (K, 4)`` true state,
* ``accelerations_at(t_s) -> (K, 2)`` true acceleration (m/s^2),
* ``turn_rates_at(t_s) -> (K,)`` heading rate (rad/s),
* ``maneuvering_at(t_s) -> (K,)`` bool, True while the aircraft turns or changes speed.

Two kinds:

* :class:`SegmentScenario`: straight legs, coordinated turns (constant speed and turn rate) and longitudinal
  accelerations (constant heading). Each segment is integrated in closed form from the state at its start:

  - turn (``omega``, including 0 = straight), with ``theta = omega * tau``::

        vx(tau) =  vx cos(theta) + vy sin(theta)        x(tau) = x + vx sin(theta)/omega + vy (1 - cos(theta))/omega
        vy(tau) = -vx sin(theta) + vy cos(theta)        y(tau) = y - vx (1 - cos(theta))/omega + vy sin(theta)/omega

    which is ``motion.transition_ct(tau, omega) @ state`` (used here, so the truth and the CT filter share one
    formula);
  - longitudinal acceleration ``a`` along the unit velocity ``u``: ``v = u (s + a tau)``,
    ``p = p0 + u (s tau + a tau^2 / 2)``.

  No Euler steps anywhere: the state at any time is exact to rounding.
* :class:`TrajectoryScenario`: a user trajectory given as samples ``t_s, x_m, y_m, vx_m_s, vy_m_s`` (arrays or a
  CSV file), interpolated by a cubic Hermite spline that matches both positions and velocities at the samples;
  acceleration is the spline's second derivative.

:func:`random_scenario` draws a whole scenario (and a radar site position for it) from a seeded generator.
"""

from __future__ import annotations

import csv
import io
import math
from dataclasses import dataclass, field, fields
from pathlib import Path

import numpy as np

from ..common.units import DEG, G0_M_S2, KNOT_M_S
from ..common.validate import check_known_keys, check_number, check_pair
from .motion import transition_ct

__all__ = [
    "Segment",
    "SegmentScenario",
    "ScenarioBuilder",
    "TrajectoryScenario",
    "RandomScenarioConfig",
    "random_scenario",
    "place_radar_site",
    "MIN_SPEED_M_S",
]

MIN_SPEED_M_S = 10.0
"""Lowest speed a scenario may reach (m/s); headings and turn rates are undefined near zero speed."""


# ---------------------------------------------------------------------------------------------------- segments
@dataclass(frozen=True)
class Segment:
    """One piece of a piecewise trajectory.

    Args:
        duration_s: length of the segment, > 0.
        turn_rate_rad_s: heading rate during the segment (positive = right turn); 0 for straight or accelerating.
        accel_m_s2: longitudinal acceleration (speed change rate); must be 0 when ``turn_rate_rad_s`` != 0.
    """

    duration_s: float
    turn_rate_rad_s: float = 0.0
    accel_m_s2: float = 0.0

    def __post_init__(self):
        check_number("Segment.duration_s", self.duration_s, 0.0, math.inf, lo_open=True)
        check_number("Segment.turn_rate_rad_s", self.turn_rate_rad_s, -math.pi, math.pi)
        check_number("Segment.accel_m_s2", self.accel_m_s2, -100 * G0_M_S2, 100 * G0_M_S2)
        if self.turn_rate_rad_s != 0.0 and self.accel_m_s2 != 0.0:
            raise ValueError("Segment: a segment is a coordinated turn (turn_rate_rad_s != 0) or a speed change "
                             "(accel_m_s2 != 0), not both; split it into two segments")


class SegmentScenario:
    """Piecewise truth: straight legs, coordinated turns and speed changes, integrated exactly.

    Args:
        initial_state: ``[x_m, y_m, vx_m_s, vy_m_s]`` at ``t = 0``; speed >= ``MIN_SPEED_M_S``.
        segments: sequence of :class:`Segment`, flown in order from ``t = 0``.
        name: label used in tables and plots.
        maneuver_threshold_m_s2: ``maneuvering_at`` is True where the true acceleration exceeds this (m/s^2).
    """

    def __init__(self, initial_state, segments, name="segments", maneuver_threshold_m_s2=0.05 * G0_M_S2):
        x0 = np.asarray(initial_state, dtype=np.float64).reshape(-1)
        if x0.shape != (4,) or not np.all(np.isfinite(x0)):
            raise ValueError(f"initial_state must be 4 finite numbers [x_m, y_m, vx_m_s, vy_m_s], got {initial_state!r}")
        segs = tuple(segments)
        if not segs:
            raise ValueError("segments must contain at least one Segment")
        for s in segs:
            if not isinstance(s, Segment):
                raise ValueError(f"segments must contain Segment objects, got {type(s).__name__}")
        self.name = str(name)
        self.maneuver_threshold_m_s2 = float(maneuver_threshold_m_s2)
        self.segments = segs
        n = len(segs)
        self._t0 = np.zeros(n)
        self._x0 = np.zeros((n, 4))
        self._w = np.array([s.turn_rate_rad_s for s in segs])
        self._a = np.array([s.accel_m_s2 for s in segs])
        t, x = 0.0, x0.copy()
        for i, s in enumerate(segs):
            speed = math.hypot(x[2], x[3])
            if speed < MIN_SPEED_M_S - 1e-9:
                raise ValueError(f"segment {i}: speed {speed:.3f} m/s at its start is below MIN_SPEED_M_S = "
                                 f"{MIN_SPEED_M_S} m/s")
            self._t0[i], self._x0[i] = t, x
            end_speed = speed + s.accel_m_s2 * s.duration_s
            if end_speed < MIN_SPEED_M_S - 1e-9:
                raise ValueError(f"segment {i}: accel_m_s2={s.accel_m_s2} for {s.duration_s} s would bring the "
                                 f"speed to {end_speed:.3f} m/s, below MIN_SPEED_M_S = {MIN_SPEED_M_S} m/s")
            x = self._propagate(np.array([i]), np.array([s.duration_s]))[0]
            t += s.duration_s
        self.duration_s = t
        self.final_state = x

    # -------------------------------------------------------------------------------------------- evaluation
    def _propagate(self, idx, tau):
        """State at ``tau`` seconds into segments ``idx`` (arrays of equal shape (K,)) -> (K, 4)."""
        x0 = self._x0[idx]
        w, a = self._w[idx], self._a[idx]
        out = np.einsum("kij,kj->ki", transition_ct(tau, w), x0)
        acc = a != 0.0
        if np.any(acc):
            v = x0[acc, 2:]
            s = np.hypot(v[:, 0], v[:, 1])
            u = v / s[:, None]
            ta = tau[acc]
            out[acc, :2] = x0[acc, :2] + u * (s * ta + 0.5 * a[acc] * ta * ta)[:, None]
            out[acc, 2:] = u * (s + a[acc] * ta)[:, None]
        return out

    def _locate(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        tol = 1e-9 * max(1.0, self.duration_s)
        if t.size and (not np.all(np.isfinite(t)) or t.min() < -tol or t.max() > self.duration_s + tol):
            raise ValueError(f"times must lie in [0, duration_s = {self.duration_s}] s, got range "
                             f"[{t.min()}, {t.max()}]")
        t = np.clip(t, 0.0, self.duration_s)
        idx = np.clip(np.searchsorted(self._t0, t, side="right") - 1, 0, len(self.segments) - 1)
        return t, idx, t - self._t0[idx]

    def states_at(self, t_s):
        """True states ``[x, y, vx, vy]`` at times ``t_s`` (K,) -> (K, 4)."""
        _, idx, tau = self._locate(t_s)
        return self._propagate(idx, tau)

    def accelerations_at(self, t_s):
        """True accelerations (m/s^2) -> (K, 2): ``omega * (vy, -vx)`` in turns, ``a * u`` in speed changes."""
        _, idx, tau = self._locate(t_s)
        x = self._propagate(idx, tau)
        w, a = self._w[idx], self._a[idx]
        s = np.hypot(x[:, 2], x[:, 3])
        ax = w * x[:, 3] + a * x[:, 2] / s
        ay = -w * x[:, 2] + a * x[:, 3] / s
        return np.stack([ax, ay], axis=-1)

    def turn_rates_at(self, t_s):
        """True heading rate (rad/s, positive = right turn) -> (K,)."""
        _, idx, _ = self._locate(t_s)
        return self._w[idx].copy()

    def maneuvering_at(self, t_s):
        """True where the aircraft turns or changes speed with acceleration above the threshold -> (K,) bool."""
        acc = self.accelerations_at(t_s)
        return np.hypot(acc[:, 0], acc[:, 1]) > self.maneuver_threshold_m_s2

    def __repr__(self):
        return f"SegmentScenario(name={self.name!r}, segments={len(self.segments)}, duration_s={self.duration_s:g})"


class ScenarioBuilder:
    """Fluent construction of a :class:`SegmentScenario` in user units.

    Example::

        sc = (ScenarioBuilder(position_m=(0, 0), speed_kt=350, heading_deg=90)
              .straight(290).turn(90, accel_g=2).straight(280).turn(-90, rate_deg_s=3).straight(100)
              .build("two_turns"))

    ``turn(heading_change_deg, ...)``: positive = right (clockwise), negative = left; give exactly one of
    ``rate_deg_s`` (magnitude of the turn rate) or ``accel_g`` (lateral acceleration at the current speed).
    ``change_speed(to_speed_m_s, accel_m_s2)``: straight-line speed change at ``|accel_m_s2|``.
    """

    def __init__(self, position_m=(0.0, 0.0), speed_m_s=None, heading_deg=0.0, *, speed_kt=None):
        if (speed_m_s is None) == (speed_kt is None):
            raise ValueError("ScenarioBuilder: give exactly one of speed_m_s or speed_kt")
        speed = float(speed_m_s) if speed_m_s is not None else float(speed_kt) * KNOT_M_S
        check_number("speed_m_s", speed, MIN_SPEED_M_S, 3000.0)
        h = check_number("heading_deg", heading_deg) * DEG
        px, py = (float(v) for v in position_m)
        self.initial_state = np.array([px, py, speed * math.sin(h), speed * math.cos(h)])
        self._speed = speed
        self.segments: list[Segment] = []

    def straight(self, duration_s):
        self.segments.append(Segment(duration_s))
        return self

    def turn(self, heading_change_deg, *, rate_deg_s=None, accel_g=None):
        dh = check_number("heading_change_deg", heading_change_deg, -3600.0, 3600.0) * DEG
        if dh == 0.0:
            raise ValueError("heading_change_deg must be non-zero")
        if (rate_deg_s is None) == (accel_g is None):
            raise ValueError("turn: give exactly one of rate_deg_s or accel_g")
        if rate_deg_s is not None:
            w = check_number("rate_deg_s", rate_deg_s, 0.0, 180.0, lo_open=True) * DEG
        else:
            w = check_number("accel_g", accel_g, 0.0, 100.0, lo_open=True) * G0_M_S2 / self._speed
        self.segments.append(Segment(abs(dh) / w, turn_rate_rad_s=math.copysign(w, dh)))
        return self

    def change_speed(self, to_speed_m_s, accel_m_s2):
        to = check_number("to_speed_m_s", to_speed_m_s, MIN_SPEED_M_S, 3000.0)
        a = check_number("accel_m_s2", abs(accel_m_s2), 0.0, 100 * G0_M_S2, lo_open=True)
        if to == self._speed:
            return self
        self.segments.append(Segment(abs(to - self._speed) / a, accel_m_s2=math.copysign(a, to - self._speed)))
        self._speed = to
        return self

    def build(self, name="segments"):
        return SegmentScenario(self.initial_state, self.segments, name=name)


# ---------------------------------------------------------------------------------------------------- user data
TRAJECTORY_COLUMNS = ("t_s", "x_m", "y_m", "vx_m_s", "vy_m_s")
"""Columns of a trajectory CSV (any order; extra columns are ignored)."""

TRAJECTORY_MAX_COORDINATE_M = 1e7
"""Largest ``|x_m|``, ``|y_m|`` of a trajectory sample: 10,000 km, beyond any radar's local east/north frame
(larger values are usually millimetres, centimetres or geocentric coordinates)."""

TRAJECTORY_MAX_SPEED_M_S = 3000.0
"""Highest speed of a trajectory, at the samples and on the spline between them (Mach ~9; the same bound as
:class:`ScenarioBuilder`)."""

TRAJECTORY_MAX_ACCEL_G = 20.0
"""Velocity-consistency tolerance: the peak acceleration (g) of the Hermite spline through the samples.

The spline is the path the simulator flies, so velocity columns that disagree with the positions' time derivative
show up as the acceleration needed to honour both. Aircraft do not exceed ~12 g; the Hermite cubic overshoots the
real peak a little (a 9 g turn sampled every 5 s needs 11.3 g, every 10 s 12.3 g), so 20 g refuses only data that
no aircraft flies: e.g. velocities off by 50 m/s at 1 s spacing (200-300 m/s^2), positions with 50 m noise at
1 s spacing, or a wrong sign of a velocity column."""

TRAJECTORY_MAX_DURATION_S = 1e5
"""Longest trajectory (27.8 h, longer than any flight)."""

_MS_RATIO = (300.0, 3000.0)  # velocity columns / positions' rate on this order: milliseconds (or kilometres)
TRAJECTORY_RATE_RATIO = (0.8, 1.25)
"""Accepted range of the median over the intervals of |mean of the velocity columns| / |positions' rate|:
velocity columns in another unit (knots: 1.94x, km/h: 3.6x) or scaled are refused even where the 20 g bound on
the spline, which widens with the spacing, would pass them."""
TRAJECTORY_MIN_RATE_COS = 0.98
"""Accepted median over the intervals of the cosine between the velocity columns' mean and the positions' rate
(11.5 deg): swapped (off the diagonal) or sign-flipped velocity columns are refused. A steady turn keeps this near 1 (the chord is
parallel to the mean of its end velocities)."""


def _num(x):
    return repr(float(x))


def _check_trajectory(t, p, v, prefix, where):
    """Refuse implausible samples (see :class:`TrajectoryScenario`). Messages start with ``prefix`` and name sample
    ``i`` as ``where(i)``. ``t`` (N,), ``p`` and ``v`` (N, 2): finite, N >= 2.

    Returns the Hermite splines ``(sx, sy)`` on ``t - t[0]``."""
    n = t.size
    dt = np.diff(t)
    bad = np.flatnonzero(~(dt > 0))
    if bad.size:
        i = int(bad[0]) + 1
        raise ValueError(f"{prefix}{where(i)}: t_s = {_num(t[i])} does not follow t_s = {_num(t[i - 1])} "
                         f"({where(i - 1)}); t_s must be strictly increasing (no duplicate time stamps)")
    with np.errstate(over="ignore", invalid="ignore"):
        tr = t - t[0]
        dt = np.diff(tr)
    if not (math.isfinite(tr[-1]) and tr[-1] <= TRAJECTORY_MAX_DURATION_S and np.all(dt > 0)):
        raise ValueError(f"{prefix}{where(n - 1)}: the trajectory lasts {_num(tr[-1])} s from t_s = {_num(t[0])}; "
                         f"at most {TRAJECTORY_MAX_DURATION_S:g} s ({TRAJECTORY_MAX_DURATION_S / 3600:.1f} h) is "
                         "accepted (t_s must be seconds)")
    far = np.abs(p) > TRAJECTORY_MAX_COORDINATE_M
    if far.any():
        i, j = (int(k) for k in np.argwhere(far)[0])
        raise ValueError(f"{prefix}{where(i)}: {('x_m', 'y_m')[j]} = {_num(p[i, j])} is beyond "
                         f"+-{TRAJECTORY_MAX_COORDINATE_M:g} m (coordinates are metres east/north in a local frame; "
                         "millimetres or geocentric coordinates?)")
    speed = np.hypot(v[:, 0], v[:, 1])
    out = ~((speed >= MIN_SPEED_M_S) & (speed <= TRAJECTORY_MAX_SPEED_M_S))
    if out.any():
        i = int(np.flatnonzero(out)[0])
        raise ValueError(f"{prefix}{where(i)}: speed {speed[i]:.6g} m/s (from vx_m_s, vy_m_s) is outside "
                         f"[{MIN_SPEED_M_S:g}, {TRAJECTORY_MAX_SPEED_M_S:g}] m/s")
    h = dt[:, None]
    d = np.diff(p, axis=0) / h                    # mean velocity over each interval, from the positions
    vm = 0.5 * (v[:-1] + v[1:])                   # mean of the velocity columns at its ends
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = np.hypot(vm[:, 0], vm[:, 1]) / np.hypot(d[:, 0], d[:, 1])
    med = float(np.median(ratio))
    if _MS_RATIO[0] <= med <= _MS_RATIO[1]:
        i = int(np.flatnonzero((ratio >= _MS_RATIO[0]) & (ratio <= _MS_RATIO[1]))[0]) + 1
        spacing = float(np.median(dt))
        what = ("time stamps look like milliseconds" if spacing >= 20.0 else
                "time stamps in milliseconds or positions in kilometres?")
        raise ValueError(f"{prefix}{where(i)}: {what} (median spacing {spacing:.6g} s, velocity columns {med:.0f}x "
                         "the positions' rate); t_s must be seconds and x_m, y_m metres")
    # The Hermite cubic's acceleration is linear on each interval, so its peak is at an end.
    a0 = (6.0 * d - 4.0 * v[:-1] - 2.0 * v[1:]) / h
    a1 = (-6.0 * d + 2.0 * v[:-1] + 4.0 * v[1:]) / h
    a0n, a1n = np.hypot(a0[:, 0], a0[:, 1]), np.hypot(a1[:, 0], a1[:, 1])
    peak = np.maximum(a0n, a1n)
    out = ~(peak <= TRAJECTORY_MAX_ACCEL_G * G0_M_S2)
    if out.any():
        k = int(np.flatnonzero(out)[0])
        i = k if a0n[k] >= a1n[k] else k + 1
        raise ValueError(
            f"{prefix}{where(i)}: velocity columns inconsistent with the positions' time derivative between t_s = "
            f"{_num(t[k])} ({where(k)}) and {_num(t[k + 1])} ({where(k + 1)}): the positions give "
            f"({d[k, 0]:.6g}, {d[k, 1]:.6g}) m/s, the velocity columns ({v[k, 0]:.6g}, {v[k, 1]:.6g}) and "
            f"({v[k + 1, 0]:.6g}, {v[k + 1, 1]:.6g}) m/s; honouring both needs {peak[k] / G0_M_S2:.3g} g, the "
            f"tolerance is {TRAJECTORY_MAX_ACCEL_G:g} g (smooth noisy data first, e.g. radar_env.sim.adsb.smooth_segment)")
    # Speed between samples: |v| is Lipschitz in t with constant peak, so a 16-step grid bounds it to within
    # peak * h / 32; only intervals near a limit are solved exactly (roots of d|v|^2/ds, v quadratic in s).
    s = np.linspace(0.0, 1.0, 17)
    vg = v[:-1, None] + (a0 * h)[:, None] * s[:, None] + (0.5 * (a1 - a0) * h)[:, None] * (s * s)[:, None]
    sg = np.hypot(vg[..., 0], vg[..., 1])
    slack = peak * dt / 32.0
    near = (sg.min(axis=1) - slack < MIN_SPEED_M_S) | (sg.max(axis=1) + slack > TRAJECTORY_MAX_SPEED_M_S)
    for k in np.flatnonzero(near):
        A, B, C = v[k], a0[k] * dt[k], 0.5 * (a1[k] - a0[k]) * dt[k]
        c = [4 * C @ C, 6 * B @ C, 2 * (B @ B + 2 * A @ C), 2 * A @ B]
        r = np.roots(c) if np.any(c) else np.array([])
        r = r.real[(np.abs(r.imag) <= 1e-9) & (r.real > 0.0) & (r.real < 1.0)]
        for sk in r:
            sp = float(np.hypot(*(A + B * sk + C * sk * sk)))
            if not MIN_SPEED_M_S <= sp <= TRAJECTORY_MAX_SPEED_M_S:
                raise ValueError(
                    f"{prefix}{where(int(k))}: between t_s = {_num(t[k])} and {_num(t[k + 1])} ({where(int(k) + 1)}) "
                    f"the spline through the samples reaches a speed of {sp:.6g} m/s, outside [{MIN_SPEED_M_S:g}, "
                    f"{TRAJECTORY_MAX_SPEED_M_S:g}] m/s: velocity columns inconsistent with the positions, or "
                    "samples too far apart for the motion")
    # Median checks over the intervals that move (a unit or column mix-up affects every interval; one bad sample
    # is the 20 g check's job), after the specific checks above so that they give their clearer messages first.
    moving = np.hypot(d[:, 0], d[:, 1]) >= 0.5 * MIN_SPEED_M_S
    with np.errstate(divide="ignore", invalid="ignore"):
        cos = np.einsum("ij,ij->i", vm, d) / (np.hypot(vm[:, 0], vm[:, 1]) * np.hypot(d[:, 0], d[:, 1]))
    med = float(np.median(ratio[moving])) if moving.any() else 1.0
    med_cos = float(np.median(cos[moving])) if moving.any() else 1.0
    if not TRAJECTORY_RATE_RATIO[0] <= med <= TRAJECTORY_RATE_RATIO[1] or med_cos < TRAJECTORY_MIN_RATE_COS:
        bad = moving & ~((ratio >= TRAJECTORY_RATE_RATIO[0]) & (ratio <= TRAJECTORY_RATE_RATIO[1])
                         & (cos >= TRAJECTORY_MIN_RATE_COS))
        i = int(np.flatnonzero(bad)[0]) + 1 if bad.any() else 1
        raise ValueError(
            f"{prefix}{where(i)}: velocity columns inconsistent with the positions' time derivative over the whole "
            f"trajectory: their speed is {med:.3g}x the positions' rate (median over the intervals; accepted "
            f"{TRAJECTORY_RATE_RATIO[0]:g}-{TRAJECTORY_RATE_RATIO[1]:g}x) and their direction agrees with it by a "
            f"median cosine of {med_cos:.3g} (accepted >= {TRAJECTORY_MIN_RATE_COS:g}); vx_m_s, vy_m_s must be m/s "
            "east/north (knots are 1.94x, km/h 3.6x)")
    from scipy.interpolate import CubicHermiteSpline   # here: a second of imports only trajectory suites need
    return CubicHermiteSpline(tr, p[:, 0], v[:, 0]), CubicHermiteSpline(tr, p[:, 1], v[:, 1])


def _read_utf8(path):
    """The text of ``path``, decoded as UTF-8 (a leading byte-order mark is dropped); ``ValueError`` naming the file
    (and the line of the first undecodable byte) otherwise."""
    return decode_utf8(path.read_bytes(), path)


def decode_utf8(raw, path):
    """``raw`` (the bytes of file ``path``) decoded as UTF-8 (a leading byte-order mark is dropped); ``ValueError``
    naming the file and the line of the first undecodable byte otherwise."""
    if raw[:2] in (b"\xff\xfe", b"\xfe\xff"):
        raise ValueError(f"{path}: line 1: UTF-16 text (byte-order mark 0x{raw[:2].hex()}); save the file as UTF-8")
    try:
        return raw.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        line = raw[: e.start].count(b"\n") + 1
        raise ValueError(f"{path}: line {line}: not UTF-8 text (byte 0x{raw[e.start]:02x} at offset {e.start}: "
                         f"{e.reason}); save the file as UTF-8") from None


class TrajectoryScenario:
    """A user trajectory: samples of position and velocity, interpolated by a cubic Hermite spline.

    Args:
        t_s, x_m, y_m, vx_m_s, vy_m_s: 1-D arrays of equal length >= 2, finite, ``t_s`` strictly increasing.
            Times are shifted so that the scenario starts at 0.
        name: label.
        maneuver_threshold_m_s2: acceleration above which ``maneuvering_at`` is True.

    The spline reproduces the given positions and velocities at the samples; between them it is the unique
    cubic matching both, so the velocity is continuous and the acceleration piecewise linear.

    Implausible samples raise ``ValueError`` naming the sample (``row i``, 0-based; ``from_csv``: the file and
    line) and the reason:

    * a duration above ``TRAJECTORY_MAX_DURATION_S`` (1e5 s);
    * ``|x_m|`` or ``|y_m|`` above ``TRAJECTORY_MAX_COORDINATE_M`` (1e7 m);
    * a speed outside [``MIN_SPEED_M_S``, ``TRAJECTORY_MAX_SPEED_M_S``] = [10, 3000] m/s, at a sample or on the
      spline between samples (checked at 16 points per interval);
    * velocity columns on the order of 1000x the positions' rate (median over the intervals between 300x and
      3000x): time stamps in milliseconds (or positions in kilometres);
    * velocity columns inconsistent with the positions' time derivative: the spline's acceleration, which is
      linear on each interval and thus peaks at its ends, ``|6 d - 4 v_i - 2 v_{i+1}| / h`` and
      ``|6 d - 2 v_i - 4 v_{i+1}| / h`` (``d`` the mean velocity from the positions, ``h`` the spacing), must not
      exceed ``TRAJECTORY_MAX_ACCEL_G`` = 20 g. E.g. at 1 s spacing a velocity column off by 40 m/s is refused,
      at 10 s by 400 m/s. Over the whole trajectory, the median over the intervals of the velocity columns' mean
      speed / the positions' rate must lie in ``TRAJECTORY_RATE_RATIO`` (0.8-1.25) and the median cosine of the
      angle between them be at least ``TRAJECTORY_MIN_RATE_COS`` (0.98, 11.5 deg): velocity columns in knots or km/h, scaled,
      swapped or at right angles to the motion are refused however long the spacing.
    """

    def __init__(self, t_s, x_m, y_m, vx_m_s, vy_m_s, name="trajectory", maneuver_threshold_m_s2=0.05 * G0_M_S2):
        cols = {"t_s": t_s, "x_m": x_m, "y_m": y_m, "vx_m_s": vx_m_s, "vy_m_s": vy_m_s}
        arr = {}
        for k, v in cols.items():
            a = np.asarray(v, dtype=np.float64).reshape(-1)
            if not np.all(np.isfinite(a)):
                raise ValueError(f"trajectory column {k} has non-finite values at rows "
                                 f"{np.flatnonzero(~np.isfinite(a))[:5].tolist()}")
            arr[k] = a
        n = arr["t_s"].size
        if n < 2:
            raise ValueError(f"a trajectory needs at least 2 samples, got {n}")
        for k, a in arr.items():
            if a.size != n:
                raise ValueError(f"trajectory column {k} has {a.size} values, t_s has {n}")
        self._init(arr, name, "trajectory ", lambda i: f"row {i}", maneuver_threshold_m_s2)

    def _init(self, arr, name, prefix, where, maneuver_threshold_m_s2=0.05 * G0_M_S2):
        t = arr["t_s"]
        p = np.column_stack([arr["x_m"], arr["y_m"]])
        v = np.column_stack([arr["vx_m_s"], arr["vy_m_s"]])
        self._sx, self._sy = _check_trajectory(t, p, v, prefix, where)
        self.name = str(name)
        self.maneuver_threshold_m_s2 = float(maneuver_threshold_m_s2)
        self.t_samples_s = self._sx.x.copy()
        self.duration_s = float(self.t_samples_s[-1])
        self.final_state = self.states_at(np.array([self.duration_s]))[0]

    @classmethod
    def from_csv(cls, path, name=None, **kwargs):
        """Read a UTF-8 CSV (a byte-order mark is allowed) with header ``t_s,x_m,y_m,vx_m_s,vy_m_s`` (any order,
        extra columns ignored, blank lines skipped); seconds, metres east/north, m/s.

        Raises ``ValueError`` naming the file and line (header = line 1) for: a missing file, text that is not
        UTF-8, an empty file, a missing or repeated column, a cell that is not a finite number, fewer than 2 data
        rows, and every implausible sample listed in :class:`TrajectoryScenario`."""
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"trajectory file {str(path)!r} does not exist")
        text = _read_utf8(path)
        need = TRAJECTORY_COLUMNS
        reader = csv.reader(io.StringIO(text, newline=""))
        rows, lines = [], []
        try:
            try:
                header = [h.strip() for h in next(reader)]
            except StopIteration:
                raise ValueError(f"{path}: line 1: empty file; expected header {','.join(need)}") from None
            missing = [c for c in need if c not in header]
            if missing:
                raise ValueError(f"{path}: line 1: missing column(s) {missing}; expected header {','.join(need)}")
            twice = [c for c in need if header.count(c) > 1]
            if twice:
                raise ValueError(f"{path}: line 1: column(s) {twice} appear more than once")
            pos = [header.index(c) for c in need]
            for row in reader:
                line_no = reader.line_num
                if not row or all(not c.strip() for c in row):
                    continue
                vals = []
                for c, j in zip(need, pos):
                    cell = row[j] if j < len(row) else "<missing>"
                    try:
                        x = float(cell)
                    except ValueError:
                        raise ValueError(f"{path}: line {line_no}, column {c!r}: cannot read {cell!r} as a "
                                         "number") from None
                    if not math.isfinite(x):
                        raise ValueError(f"{path}: line {line_no}, column {c!r}: {cell.strip()!r} is not a finite "
                                         "number")
                    vals.append(x)
                rows.append(vals)
                lines.append(line_no)
        except csv.Error as e:
            raise ValueError(f"{path}: line {reader.line_num}: not a readable CSV ({e})") from None
        if len(rows) < 2:
            raise ValueError(f"{path}: line {reader.line_num}: needs at least 2 data rows, got {len(rows)}")
        a = np.array(rows)
        self = cls.__new__(cls)
        self._init(dict(zip(need, a.T)), name or path.stem, f"{path}: ", lambda i: f"line {lines[i]}", **kwargs)
        return self

    def _check(self, t_s):
        t = np.atleast_1d(np.asarray(t_s, dtype=np.float64))
        tol = 1e-9 * max(1.0, self.duration_s)
        if t.size and (not np.all(np.isfinite(t)) or t.min() < -tol or t.max() > self.duration_s + tol):
            raise ValueError(f"times must lie in [0, duration_s = {self.duration_s}] s")
        return np.clip(t, 0.0, self.duration_s)

    def states_at(self, t_s):
        t = self._check(t_s)
        return np.stack([self._sx(t), self._sy(t), self._sx(t, 1), self._sy(t, 1)], axis=-1)

    def accelerations_at(self, t_s):
        t = self._check(t_s)
        return np.stack([self._sx(t, 2), self._sy(t, 2)], axis=-1)

    def turn_rates_at(self, t_s):
        """Heading rate ``(vy ax - vx ay) / speed^2`` (rad/s, positive = right turn)."""
        t = self._check(t_s)
        vx, vy, ax, ay = self._sx(t, 1), self._sy(t, 1), self._sx(t, 2), self._sy(t, 2)
        return (vy * ax - vx * ay) / np.maximum(vx * vx + vy * vy, MIN_SPEED_M_S ** 2)

    def maneuvering_at(self, t_s):
        acc = self.accelerations_at(t_s)
        return np.hypot(acc[:, 0], acc[:, 1]) > self.maneuver_threshold_m_s2

    def __repr__(self):
        return f"TrajectoryScenario(name={self.name!r}, samples={self.t_samples_s.size}, duration_s={self.duration_s:g})"


# ---------------------------------------------------------------------------------------------------- random
def _range_field(lo, hi):
    return field(default=(lo, hi))


@dataclass(frozen=True)
class RandomScenarioConfig:
    """Parameters of :func:`random_scenario` (every range is ``(low, high)``, drawn uniformly).

    Attributes:
        speed_kt: initial speed, knots. Default (100, 600).
        n_legs: number of straight legs, integers inclusive. Default (3, 6); legs are joined by maneuvers.
        leg_duration_s: straight-leg length. Default (30, 300).
        first_leg_min_s: the first leg lasts at least this long, so that the track start (two hits and 12 warm-up
            looks, 70 s at T = 5 s) happens on a straight leg as in Bizup's comparison. Default 90; 0 lets a maneuver
            begin during the track start.
        first_leg_s: the first leg's length range (then at least ``first_leg_min_s``), or None (default): drawn
            from ``leg_duration_s`` like the other legs. E.g. ``(1, 40)`` with ``first_leg_min_s=0``: the first
            maneuver begins during the track start (the ``start_maneuver`` family).
        turn_probability: probability that a maneuver includes a turn (after its speed change, if any). Default 1;
            with ``speed_change_probability=1`` and 0 every maneuver is a pure speed change. A maneuver with
            neither is no maneuver (its legs join).
        turn_accel_g: lateral acceleration of a turn, g. Default (0.5, 7).
        max_turn_rate_deg_s: turn rate cap (a 7 g turn at 100 kt would be 77 deg/s); turns above it are flown at
            the cap. Default 20.
        turn_heading_change_deg: magnitude of a turn's heading change. Default (10, 270); direction 50/50.
        speed_change_probability: probability that a maneuver also includes a speed change (before the turn).
            Default 0.2.
        speed_change_accel_g: longitudinal acceleration of a speed change, g. Default (0.1, 0.5).
        range_km: allowed range from the radar over the whole flight, km. Default (10, 150).
        site_candidates: number of candidate radar positions tried; the one that keeps the flight in range the
            longest is chosen and the scenario is cut at its first exit. Default 64.
        min_duration_s: a draw whose in-range part is shorter than this is redrawn. Default 120.
        max_duration_s: the flight is cut after this long (s). Default 1e6 (no cut); e.g. 190 s gives tracks of
            under 40 looks at T = 5 s (the ``short_tracks`` family). (The env also
            redraws an episode with fewer looks than its track start needs, e.g. a short flight seen by a slow
            radar: :func:`radar_env.envs.env.draw_setup_and_episode`.)

    Every value is checked when the config is built: a range must be a ``(low, high)`` pair of real numbers (a
    list is accepted and stored as a tuple), a scalar a real number; strings, ``None``, booleans and complex
    numbers raise ``ValueError`` naming the key.
        random_radar_probability: scenario ``random_radars`` only: the probability that the radar is drawn by
            :func:`radar_env.sim.catalog.random_radar`; otherwise it is the ATC radar of ``random``. Default 1.
    """

    speed_kt: tuple = _range_field(100.0, 600.0)
    n_legs: tuple = _range_field(3, 6)
    leg_duration_s: tuple = _range_field(30.0, 300.0)
    first_leg_min_s: float = 90.0
    first_leg_s: object = None
    turn_probability: float = 1.0
    turn_accel_g: tuple = _range_field(0.5, 7.0)
    max_turn_rate_deg_s: float = 20.0
    turn_heading_change_deg: tuple = _range_field(10.0, 270.0)
    speed_change_probability: float = 0.2
    speed_change_accel_g: tuple = _range_field(0.1, 0.5)
    range_km: tuple = _range_field(10.0, 150.0)
    site_candidates: int = 64
    min_duration_s: float = 120.0
    max_duration_s: float = 1e6
    random_radar_probability: float = 1.0

    _PAIRS = {
        "speed_kt": (20.0, 3000.0), "n_legs": (1, 50), "leg_duration_s": (1.0, 3600.0),
        "turn_accel_g": (0.01, 20.0), "turn_heading_change_deg": (1.0, 720.0),
        "speed_change_accel_g": (0.001, 5.0), "range_km": (0.1, 1000.0),
    }
    _SCALARS = {  # name: (low, high, low open, integer)
        "max_turn_rate_deg_s": (0.0, 180.0, True, False), "speed_change_probability": (0.0, 1.0, False, False),
        "site_candidates": (1, 100000, False, True), "min_duration_s": (1.0, 1e5, False, False),
        "first_leg_min_s": (0.0, 1e5, False, False), "random_radar_probability": (0.0, 1.0, False, False),
        "turn_probability": (0.0, 1.0, False, False), "max_duration_s": (1.0, 1e6, False, False),
    }

    def __post_init__(self):
        # the checked values are stored (pairs as tuples, floats, ints): a list or numpy scalar given here then
        # draws exactly what the equal plain value draws
        for name, (lo, hi) in self._PAIRS.items():
            v = check_pair(f"RandomScenarioConfig.{name}", getattr(self, name), lo, hi, integer=name == "n_legs")
            object.__setattr__(self, name, v)
        for name, (lo, hi, lo_open, integer) in self._SCALARS.items():
            v = check_number(f"RandomScenarioConfig.{name}", getattr(self, name), lo, hi, lo_open=lo_open,
                             integer=integer)
            object.__setattr__(self, name, v)
        if self.first_leg_s is not None:
            v = check_pair("RandomScenarioConfig.first_leg_s", self.first_leg_s, 1.0, 3600.0)
            object.__setattr__(self, "first_leg_s", v)
        if self.max_duration_s < self.min_duration_s:
            raise ValueError(f"RandomScenarioConfig.max_duration_s must be >= min_duration_s ({self.min_duration_s} "
                             f"s), got {self.max_duration_s!r}")

    @property
    def first_leg_range_s(self):
        """``(low, high)`` of the first leg's draw (``first_leg_s`` or ``leg_duration_s``)."""
        return self.leg_duration_s if self.first_leg_s is None else self.first_leg_s

    @classmethod
    def from_dict(cls, d):
        """Build from a dict, rejecting unknown keys with a ``ValueError`` that lists the valid ones."""
        if not isinstance(d, dict):
            raise ValueError(f"random_config must be a dict or RandomScenarioConfig, got {type(d).__name__}")
        check_known_keys("RandomScenarioConfig", d, [f.name for f in fields(cls)])
        return cls(**d)


def _draw_segments(rng, cfg, speed):
    """Legs and maneuvers in a fixed draw order (one uniform per quantity)."""
    segs = []
    n_legs = int(rng.integers(int(cfg.n_legs[0]), int(cfg.n_legs[1]) + 1))
    lo_v, hi_v = (v * KNOT_M_S for v in cfg.speed_kt)
    for i in range(n_legs):
        leg = rng.uniform(*(cfg.first_leg_range_s if i == 0 else cfg.leg_duration_s))
        segs.append(Segment(max(leg, cfg.first_leg_min_s) if i == 0 else leg))
        if i == n_legs - 1:
            break
        change = rng.uniform() < cfg.speed_change_probability
        new_speed = rng.uniform(lo_v, hi_v)
        accel = rng.uniform(*cfg.speed_change_accel_g) * G0_M_S2
        g = rng.uniform(*cfg.turn_accel_g)
        dh = rng.uniform(*cfg.turn_heading_change_deg) * DEG * (1.0 if rng.uniform() < 0.5 else -1.0)
        # the turn's own draw only when turns can be skipped: the default configuration keeps its stream
        turn = cfg.turn_probability >= 1.0 or rng.uniform() < cfg.turn_probability
        if change and abs(new_speed - speed) > 1e-6:
            segs.append(Segment(abs(new_speed - speed) / accel, accel_m_s2=math.copysign(accel, new_speed - speed)))
            speed = new_speed
        if turn:
            w = min(g * G0_M_S2 / speed, cfg.max_turn_rate_deg_s * DEG)
            segs.append(Segment(abs(dh) / w, turn_rate_rad_s=math.copysign(w, dh)))
    return segs


_PLACEMENT_BLOCK = 2048
"""Grid points per block in :func:`place_radar_site`."""


RADAR_PLACEMENT_RANGE_M = (10e3, 150e3)
"""Default range annulus (m) of :func:`place_radar_site`: where the ATC radar for a trajectory is put."""


def place_radar_site(rng, scenario, range_m=RADAR_PLACEMENT_RANGE_M, n_candidates=64, grid_dt_s=2.0):
    """Choose a radar position for ``scenario`` so that the flight stays within ``range_m`` for as long as possible.

    ``n_candidates`` positions are drawn around the track's start (distance uniform in ``range_m``, direction
    uniform); the one whose annulus contains the flight longest from ``t = 0`` wins (ties: first drawn).
    Returns ``(site_xy_m (2,), in_range_until_s)``; ``in_range_until_s`` is the time of the first exit (or the
    scenario's duration)."""
    lo, hi = range_m
    dur = scenario.duration_s
    n_grid = int(math.ceil((dur + 1e-9) / grid_dt_s))           # np.arange(0, dur + 1e-9, grid_dt_s).size
    extra = (n_grid - 1) * grid_dt_s < dur                      # the grid stops short: the duration is added
    K = n_grid + int(extra)

    def grid(k0, k1):   # grid points k0..k1-1 (k * grid_dt_s, as np.arange gives them, then the duration)
        t = np.arange(k0, min(k1, n_grid), dtype=np.float64) * grid_dt_s
        return np.append(t, dur) if extra and k1 >= K else t

    d = rng.uniform(lo, hi, size=n_candidates)
    a = rng.uniform(0.0, 2 * np.pi, size=n_candidates)
    sites = scenario.states_at(grid(0, 1))[0, :2] + np.stack([d * np.sin(a), d * np.cos(a)], axis=-1)
    # The grid in blocks, stopping once every candidate has seen the flight leave its annulus: the same first
    # exits as the whole (C, K) grid at once, without its memory on very long flights (slow turns, long legs).
    first_out = np.full(n_candidates, K)
    for k0 in range(0, K, _PLACEMENT_BLOCK):
        p = scenario.states_at(grid(k0, k0 + _PLACEMENT_BLOCK))[:, :2]
        r = np.hypot(p[None, :, 0] - sites[:, None, 0], p[None, :, 1] - sites[:, None, 1])  # (C, block)
        out = (r < lo) | (r > hi)
        new = (first_out == K) & out.any(axis=1)
        first_out[new] = k0 + out[new].argmax(axis=1)
        if np.all(first_out < K):
            break
    best = int(np.argmax(first_out))
    j = max(int(first_out[best]) - 1, 0)        # last grid point still in range
    until = dur if first_out[best] == K else float(grid(j, j + 1)[0])
    return sites[best], until


def random_scenario(rng, config=None, max_tries=50, name="random"):
    """Draw a random scenario and a radar site for it.

    Fixed draw order: initial speed, heading, segments (see :class:`RandomScenarioConfig`), then the radar site.
    A flight that leaves the radar's range annulus is cut at its first exit; if less than
    ``config.min_duration_s`` remains, the whole draw is repeated (at most ``max_tries`` times, all from ``rng``).

    Returns:
        (scenario, site_xy_m): a :class:`SegmentScenario` starting at the origin and the radar position (2,).
    """
    cfg = config or RandomScenarioConfig()
    rng = np.random.default_rng(rng) if not isinstance(rng, np.random.Generator) else rng
    for _ in range(max_tries):
        speed = rng.uniform(*cfg.speed_kt) * KNOT_M_S
        heading = rng.uniform(0.0, 2 * np.pi)
        segs = _draw_segments(rng, cfg, speed)
        x0 = np.array([0.0, 0.0, speed * math.sin(heading), speed * math.cos(heading)])
        sc = SegmentScenario(x0, segs, name=name)
        site, until = place_radar_site(rng, sc, tuple(v * 1e3 for v in cfg.range_km), int(cfg.site_candidates))
        until = min(until, cfg.max_duration_s)
        if until >= cfg.min_duration_s:
            if until < sc.duration_s:
                sc = _truncate(sc, until)
            return sc, site
    raise ValueError(f"random_scenario: no draw stayed in range_km={cfg.range_km} for min_duration_s="
                     f"{cfg.min_duration_s} s in {max_tries} tries; widen range_km, lower min_duration_s or slow the "
                     "flights (speed_kt)")


def _truncate(sc, t_end):
    """The same flight cut at ``t_end`` (s)."""
    segs = []
    for s, t0 in zip(sc.segments, sc._t0):
        if t0 >= t_end:
            break
        segs.append(Segment(min(s.duration_s, t_end - t0), s.turn_rate_rad_s, s.accel_m_s2))
    return SegmentScenario(sc._x0[0], segs, name=sc.name, maneuver_threshold_m_s2=sc.maneuver_threshold_m_s2)
