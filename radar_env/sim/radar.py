"""Radar sites: measurement geometry, polar noise, converted plots and their covariance.

Conventions (docs/architecture.md): bearing clockwise from north, ``bearing = atan2(x - sx, y - sy)``; radial
velocity ``(dx vx + dy vy) / range``, positive receding.

A plot is made in polar coordinates and converted for the Cartesian Kalman filter:

    range_meas   = range + range_bias_m + N(0, range_noise_std_m^2)
    bearing_meas = bearing + bearing_bias_rad + N(0, bearing_noise_std_rad^2)
    rdot_meas    = radial velocity + N(0, radial_velocity_noise_std_m_s^2)
    z            = site + range_meas * (sin(bearing_meas), cos(bearing_meas))

and the converted covariance (seed 002 eqs 16-19, rewritten for bearing measured from north; the paper's
``theta`` is measured from the x axis, which swaps sin and cos), evaluated at the *measured* range and bearing:

    Rxx = sr^2 sin^2 b + r^2 sb^2 cos^2 b
    Ryy = sr^2 cos^2 b + r^2 sb^2 sin^2 b
    Rxy = (sr^2 - r^2 sb^2) sin b cos b

This is the first-order (linearised) covariance; at the bearing noises used here (<= 0.1 deg) the bias of the
plain conversion, ``r (1 - exp(-sb^2/2))``, is below 0.2 m at 150 km and is not corrected. A registration bias
is unknown to the tracker and therefore not in R.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from ..common.units import DEG, FT_M, KNOT_M_S, NM_M
from ..common.validate import check_known_keys, check_number, is_real_number

__all__ = [
    "RadarSite",
    "Radar",
    "atc_radar",
    "bizup_radar",
    "polar_from_cartesian",
    "cartesian_from_polar",
    "converted_covariance",
    "scan_schedule",
]


def polar_from_cartesian(states, site_xy_m):
    """Range (m), bearing (rad, clockwise from north, in (-pi, pi]) and radial velocity (m/s, + receding).

    Args:
        states: (K, 4) ``[x, y, vx, vy]``.
        site_xy_m: (2,) or (K, 2) radar positions.
    Returns:
        (range_m, bearing_rad, radial_velocity_m_s), each (K,).
    """
    s = np.asarray(states, dtype=np.float64)
    site = np.broadcast_to(np.asarray(site_xy_m, dtype=np.float64), s[..., :2].shape)
    dx, dy = s[..., 0] - site[..., 0], s[..., 1] - site[..., 1]
    r = np.hypot(dx, dy)
    b = np.arctan2(dx, dy)
    rdot = (dx * s[..., 2] + dy * s[..., 3]) / np.where(r > 0, r, 1.0)
    return r, b, rdot


def cartesian_from_polar(range_m, bearing_rad, site_xy_m):
    """Converted plot position (K, 2): ``site + r (sin b, cos b)``."""
    r = np.asarray(range_m, dtype=np.float64)
    b = np.asarray(bearing_rad, dtype=np.float64)
    site = np.asarray(site_xy_m, dtype=np.float64)
    return site + np.stack([r * np.sin(b), r * np.cos(b)], axis=-1)


def converted_covariance(range_m, bearing_rad, range_noise_std_m, bearing_noise_std_rad):
    """Covariance (K, 2, 2) in m^2 of the converted plot (module docstring, seed 002 eqs 16-19)."""
    r = np.asarray(range_m, dtype=np.float64)
    b = np.asarray(bearing_rad, dtype=np.float64)
    sr2 = np.asarray(range_noise_std_m, dtype=np.float64) ** 2
    cb2 = (r * np.asarray(bearing_noise_std_rad, dtype=np.float64)) ** 2
    s, c = np.sin(b), np.cos(b)
    R = np.empty(np.broadcast(r, b, sr2, cb2).shape + (2, 2))
    R[..., 0, 0] = sr2 * s * s + cb2 * c * c
    R[..., 1, 1] = sr2 * c * c + cb2 * s * s
    R[..., 0, 1] = R[..., 1, 0] = (sr2 - cb2) * s * c
    return R


def _check(name, v, lo, hi, lo_open=False):
    return check_number(name, v, lo, hi, lo_open=lo_open)


@dataclass(frozen=True)
class RadarSite:
    """One radar.

    Attributes:
        position_m: (x, y) of the site, m.
        scan_period_s: time between looks at the target, s, in (0, 3600].
        range_noise_std_m: range noise standard deviation, m, in (0, 1e5].
        bearing_noise_std_rad: bearing noise standard deviation, rad, in (0, 0.5].
        radial_velocity_noise_std_m_s: radial-velocity noise standard deviation, m/s, in (0, 1e3].
        detection_probability: probability that a scan yields a plot, in (0, 1].
        range_bias_m: constant registration bias added to every range, m (unknown to the tracker).
        bearing_bias_rad: constant azimuth registration bias, rad (unknown to the tracker).
        first_scan_s: time of the site's first look after the scenario starts, s, in [0, scan_period_s).
        name: label.
    """

    position_m: tuple = (0.0, 0.0)
    scan_period_s: float = 5.0
    range_noise_std_m: float = 0.04 * NM_M
    bearing_noise_std_rad: float = 0.07 * DEG
    radial_velocity_noise_std_m_s: float = 2.0 * KNOT_M_S
    detection_probability: float = 1.0
    range_bias_m: float = 0.0
    bearing_bias_rad: float = 0.0
    first_scan_s: float = 0.0
    name: str = "radar"

    def __post_init__(self):
        pos = self.position_m
        flat = list(np.asarray(pos, dtype=object).reshape(-1)) if np.ndim(pos) == 1 else [pos]
        if len(flat) != 2 or not all(is_real_number(v) and math.isfinite(float(v)) for v in flat):
            raise ValueError(f"RadarSite.position_m must be 2 finite numbers (x, y) in m, got {self.position_m!r}")
        object.__setattr__(self, "position_m", tuple(float(v) for v in flat))
        if not isinstance(self.name, str):
            raise ValueError(f"RadarSite.name must be a str, got {self.name!r}")
        # stored as floats: a numpy scalar or int given here must not change the arithmetic downstream
        for name, lo, hi, lo_open in (("scan_period_s", 0.0, 3600.0, True), ("range_noise_std_m", 0.0, 1e5, True),
                                      ("bearing_noise_std_rad", 0.0, 0.5, True),
                                      ("radial_velocity_noise_std_m_s", 0.0, 1e3, True),
                                      ("detection_probability", 0.0, 1.0, True), ("range_bias_m", -1e4, 1e4, False),
                                      ("bearing_bias_rad", -0.1, 0.1, False)):
            object.__setattr__(self, name, _check(f"RadarSite.{name}", getattr(self, name), lo, hi, lo_open))
        object.__setattr__(self, "first_scan_s", _check("RadarSite.first_scan_s", self.first_scan_s, 0.0,
                                                        self.scan_period_s))
        if self.first_scan_s == self.scan_period_s:
            raise ValueError(f"RadarSite.first_scan_s must be in [0, scan_period_s={self.scan_period_s}), "
                             f"got {self.first_scan_s!r}")

    def replace(self, **changes):
        """A copy with some attributes changed (validated); unknown names raise ``ValueError``."""
        check_known_keys("RadarSite", changes, [f.name for f in fields(self)], noun="attribute")
        d = {f.name: getattr(self, f.name) for f in fields(self)}
        d.update(changes)
        return RadarSite(**d)


@dataclass(frozen=True)
class Radar:
    """A set of radar sites observing one target. Several sites give irregular update times.

    Attributes:
        sites: tuple of :class:`RadarSite` (at least one).
    """

    sites: tuple = field(default_factory=lambda: (RadarSite(),))

    def __post_init__(self):
        s = self.sites
        s = (s,) if isinstance(s, RadarSite) else tuple(s) if isinstance(s, (tuple, list)) else None
        if not s or not all(isinstance(x, RadarSite) for x in s):
            raise ValueError(f"Radar.sites must be a RadarSite or a non-empty tuple/list of RadarSite, got "
                             f"{self.sites!r}")
        object.__setattr__(self, "sites", s)

    @property
    def site_positions_m(self):
        """(n_sites, 2) site positions."""
        return np.array([s.position_m for s in self.sites])

    def moved_to(self, position_m):
        """The same radar with its first site at ``position_m`` and the others moved by the same offset."""
        off = np.asarray(position_m, dtype=np.float64) - self.site_positions_m[0]
        return Radar(tuple(s.replace(position_m=tuple(np.asarray(s.position_m) + off)) for s in self.sites))


MAX_LOOKS = 10_000_000
"""Most looks of one episode (all sites; 1 s looks for 115 days): the episode's per-look arrays (tens of float64 per
look, about 2 GB at this bound) must fit in memory; a schedule beyond it is refused before anything is allocated
(and the tracker refuses a batch whose look arrays exceed half the machine's memory)."""


def scan_schedule(radar, duration_s):
    """Times and site indices of all looks in ``[0, duration_s]``, sorted by time (ties: lower site first).

    Returns ``(t_s (K,), site_index (K,) int)``."""
    ts, idx = [], []
    counts = [int(math.floor((duration_s - s.first_scan_s) / s.scan_period_s + 1e-9)) + 1 for s in radar.sites]
    if sum(max(n, 0) for n in counts) > MAX_LOOKS:      # checked before any allocation (tens of arrays per look)
        worst = int(np.argmax(counts))
        raise ValueError(f"RadarSite.scan_period_s: {sum(max(n, 0) for n in counts):,} looks in a {duration_s:g} s "
                         f"flight (site {worst}: scan_period_s={radar.sites[worst].scan_period_s:g}) exceed "
                         f"{MAX_LOOKS:,} looks per episode, more than the episode arrays can hold in memory; give a "
                         "longer scan_period_s or a shorter flight")
    for i, s in enumerate(radar.sites):
        n = counts[i]
        if n <= 0:
            continue
        t = s.first_scan_s + s.scan_period_s * np.arange(n)
        ts.append(t)
        idx.append(np.full(n, i))
    t = np.concatenate(ts)
    site = np.concatenate(idx)
    order = np.lexsort((site, t))
    return t[order], site[order]


def atc_radar(position_m=(0.0, 0.0), **overrides):
    """Adrian's ATC radar (seed 003): T = 5 s, range noise 0.04 NM, azimuth noise 0.07 deg.

    Adrian's radar measures no radial velocity; so that Bizup's c_min feature is defined on every scenario, this
    preset adds Bizup's 2 kt radial-velocity noise (override ``radial_velocity_noise_std_m_s`` to change it)."""
    base = dict(position_m=position_m, scan_period_s=5.0, range_noise_std_m=0.04 * NM_M,
                bearing_noise_std_rad=0.07 * DEG, radial_velocity_noise_std_m_s=2.0 * KNOT_M_S, name="atc")
    base.update(overrides)
    return Radar((RadarSite(**base),))


def bizup_radar(position_m=(0.0, 0.0), bearing_noise_deg=0.1, **overrides):
    """Bizup's radar (seed 000): T = 10 s, range noise 100 ft, radial-velocity noise 2 kt, bearing noise a
    parameter. The paper prints "0.1 radian"; 0.1 deg is the reading that fits the rest of the paper (seed map)
    and is the default here."""
    base = dict(position_m=position_m, scan_period_s=10.0, range_noise_std_m=100.0 * FT_M,
                bearing_noise_std_rad=float(bearing_noise_deg) * DEG,
                radial_velocity_noise_std_m_s=2.0 * KNOT_M_S, name="bizup")
    base.update(overrides)
    return Radar((RadarSite(**base),))
