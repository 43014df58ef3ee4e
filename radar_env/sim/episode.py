"""An episode is data: the truth and every plot of one run, drawn once from one seeded generator.

``draw_episode(scenario, radar, rng)`` evaluates the truth at the radar's look times and draws, in this fixed
order, (1) one uniform per look for detection, (2) one standard normal triple per look for range, bearing and
radial-velocity noise. Every look consumes its draws whether or not it is detected, so changing the detection
probability does not change the noise of the other looks (common random numbers across configurations).

Stepping an episode is then pure arithmetic, the evaluation replays the same plots through every tracker, and the
same seed gives the same episode bit for bit.

``stack_episodes`` pads episodes of different lengths into an :class:`EpisodeBatch` with a leading batch axis
for the batched trackers and the native vector env.
"""

from __future__ import annotations

from dataclasses import dataclass, fields, make_dataclass

import numpy as np

from .radar import Radar, cartesian_from_polar, converted_covariance, polar_from_cartesian, scan_schedule

__all__ = ["Episode", "EpisodeBatch", "draw_episode", "stack_episodes", "stack_fields"]


@dataclass(frozen=True)
class Episode:
    """All looks of one run, in time order (K looks). Arrays are float64 unless noted.

    Attributes:
        name: scenario name.
        t_s: (K,) look times.
        site_index: (K,) int, which radar site looked.
        site_xy_m: (K, 2) position of that site.
        truth: (K, 4) true ``[x, y, vx, vy]``.
        truth_accel_m_s2: (K, 2) true acceleration.
        truth_turn_rate_rad_s: (K,) true heading rate.
        maneuvering: (K,) bool, truth is turning or changing speed.
        detected: (K,) bool, the look produced a plot.
        range_m, bearing_rad, radial_velocity_m_s: (K,) measured polar values (NaN where missed).
        z_m: (K, 2) converted plot position (NaN where missed).
        R_m2: (K, 2, 2) converted covariance at the measured range and bearing (NaN where missed).
        range_noise_std_m, bearing_noise_std_rad, radial_velocity_noise_std_m_s: (K,) sigmas of the site.
    """

    name: str
    t_s: np.ndarray
    site_index: np.ndarray
    site_xy_m: np.ndarray
    truth: np.ndarray
    truth_accel_m_s2: np.ndarray
    truth_turn_rate_rad_s: np.ndarray
    maneuvering: np.ndarray
    detected: np.ndarray
    range_m: np.ndarray
    bearing_rad: np.ndarray
    radial_velocity_m_s: np.ndarray
    z_m: np.ndarray
    R_m2: np.ndarray
    range_noise_std_m: np.ndarray
    bearing_noise_std_rad: np.ndarray
    radial_velocity_noise_std_m_s: np.ndarray

    @property
    def n_looks(self):
        return int(self.t_s.shape[0])


_ARRAY_FIELDS = [f.name for f in fields(Episode) if f.name != "name"]


def draw_episode(scenario, radar: Radar, rng: np.random.Generator, name=None) -> Episode:
    """Draw one episode of ``scenario`` observed by ``radar`` (see module docstring for the draw order)."""
    if not isinstance(rng, np.random.Generator):
        raise ValueError(f"rng must be a numpy.random.Generator, got {type(rng).__name__}")
    t, site_idx = scan_schedule(radar, scenario.duration_s)
    K = t.size
    if K < 2:
        raise ValueError(f"scenario {scenario.name!r} ({scenario.duration_s} s) gives only {K} look(s); "
                         "at least 2 are needed")
    sites = radar.sites
    pos = radar.site_positions_m[site_idx]
    col = lambda attr: np.array([getattr(s, attr) for s in sites], dtype=np.float64)[site_idx]  # noqa: E731
    sr, sb, sv = col("range_noise_std_m"), col("bearing_noise_std_rad"), col("radial_velocity_noise_std_m_s")
    pd, rb, bb = col("detection_probability"), col("range_bias_m"), col("bearing_bias_rad")

    truth = scenario.states_at(t)
    r, b, rdot = polar_from_cartesian(truth, pos)
    u = rng.uniform(size=K)                  # (1) detections
    e = rng.standard_normal(size=(K, 3))     # (2) range, bearing, radial-velocity noise
    det = u < pd
    r_m = r + rb + sr * e[:, 0]
    b_m = b + bb + sb * e[:, 1]
    b_m = np.pi - np.mod(np.pi - b_m, 2 * np.pi)  # wrap to (-pi, pi]
    v_m = rdot + sv * e[:, 2]
    # A negative measured range cannot happen at the ranges we simulate (>> sigma); clamp for safety.
    r_m = np.maximum(r_m, 0.0)
    z = cartesian_from_polar(r_m, b_m, pos)
    R = converted_covariance(r_m, b_m, sr, sb)
    nan = ~det
    r_m[nan] = b_m[nan] = v_m[nan] = np.nan
    z[nan] = np.nan
    R[nan] = np.nan
    return Episode(
        name=name or scenario.name, t_s=t, site_index=site_idx, site_xy_m=pos, truth=truth,
        truth_accel_m_s2=scenario.accelerations_at(t), truth_turn_rate_rad_s=scenario.turn_rates_at(t),
        maneuvering=scenario.maneuvering_at(t), detected=det, range_m=r_m, bearing_rad=b_m,
        radial_velocity_m_s=v_m, z_m=z, R_m2=R, range_noise_std_m=sr, bearing_noise_std_rad=sb,
        radial_velocity_noise_std_m_s=sv,
    )


class _EpisodeBatchMethods:
    @property
    def batch_size(self):
        return int(self.valid.shape[0])

    def episode(self, i) -> Episode:
        """Row ``i`` as an unpadded :class:`Episode`."""
        k = int(self.n_looks[i])
        return Episode(name=self.names[i], **{f: getattr(self, f)[i, :k] for f in _ARRAY_FIELDS})


# The fields are Episode's arrays (declared once, above) with a leading batch axis, plus names, valid, n_looks.
EpisodeBatch = make_dataclass(
    "EpisodeBatch",
    [("names", tuple), ("valid", np.ndarray), ("n_looks", np.ndarray)] + [(f, np.ndarray) for f in _ARRAY_FIELDS],
    bases=(_EpisodeBatchMethods,), frozen=True)
EpisodeBatch.__module__ = __name__
EpisodeBatch.__doc__ = """B episodes padded to the longest (K_max looks): every :class:`Episode` array with a leading
batch axis (``t_s (B, K_max)``, ``z_m (B, K_max, 2)`` ...), plus ``names`` (B,), ``valid (B, K_max)`` (False on
padding) and ``n_looks (B,)``. Padding repeats the last look's time and truth and is marked not detected, so a
tracker stepping through it only predicts with dt = 0."""


def stack_episodes(episodes) -> EpisodeBatch:
    """Pad and stack episodes (see :class:`EpisodeBatch`)."""
    eps = list(episodes)
    if not eps:
        raise ValueError("stack_episodes needs at least one episode")
    n = np.array([e.n_looks for e in eps])
    K = int(n.max())
    out = stack_fields(eps, _ARRAY_FIELDS)
    valid = np.arange(K)[None, :] < n[:, None]
    return EpisodeBatch(names=tuple(e.name for e in eps), valid=valid, n_looks=n, **out)


def stack_fields(episodes, names):
    """``{name: (B, K, ...) array}`` of the episodes' fields ``names`` padded to the longest as
    :func:`stack_episodes` pads them (the last look repeated; no detection, no maneuver, NaN plots and measurements
    in the padding): for a reader of a few fields, without stacking the others."""
    eps = list(episodes)
    if not eps:
        raise ValueError("stack_fields needs at least one episode")
    K = max(e.n_looks for e in eps)
    out = {}
    for f in names:
        rows = []
        for e in eps:
            a = getattr(e, f)
            pad = K - a.shape[0]
            if pad:
                a = np.concatenate([a, np.repeat(a[-1:], pad, axis=0)])
                if f == "detected" or f == "maneuvering":
                    a[-pad:] = False
                elif f in ("range_m", "bearing_rad", "radial_velocity_m_s", "z_m", "R_m2"):
                    a[-pad:] = np.nan
            rows.append(a)
        out[f] = np.stack(rows)
    return out
