"""Observation features: names, physical units, scaling to the Box, and decoding back to physical units.

Every observation entry is one feature of the tracking chain's output (never the truth), scaled to [-1, 1] or
[0, 1] and clipped there. :class:`ObservationLayout` builds the vector for a chosen list of names and decodes an
observation back to physical units (the classical reference policies read their features this way, so a rule
sees exactly what an agent sees, clipping included).

=====================  =========  =======================================================  ========  ==========
name                   unit       meaning                                                  scaling   obs range
=====================  =========  =======================================================  ========  ==========
``nu_along``           sigma      innovation along the predicted track, normalised         x / 5     [-1, 1]
``nu_cross``           sigma      innovation across the track (+ = right of track)         x / 5     [-1, 1]
``nis``                1          normalised innovation squared (chi^2, 2 dof)             log10(1+x)/3  [0, 1]
``c_min_g``            g          Bizup's minimum centripetal acceleration                 x / 8     [0, 1]
``turn_rate_alg1_deg_s``  deg/s   Adrian algorithm 1 (plot headings n apart, + = right)    x / 20    [-1, 1]
``turn_rate_alg2_deg_s``  deg/s   Adrian algorithm 2 (filtered headings n apart)           x / 20    [-1, 1]
``fma_innovation_km``  km         fading-memory average of abs(innovation) (Bizup's CKF)   x / 20    [0, 1]
``kim_lee_q_g``        g          sqrt(max(phi, 0)), Kim & Lee's sliding-window q          x / 8     [0, 1]
``speed_m_s``          m/s        estimated speed                                          x / 400   [0, 1]
``range_km``           km         estimated range from the site of the last look           x / 200   [0, 1]
``dt_s``               s          time since the previous look                             x / 20    [0, 1]
``pos_std_ratio``      1          filter position std / measurement std (per axis RMS)     x / 3     [0, 1]
``q_prev_g``           g          process-noise level used for the last prediction         log-map   [-1, 1]
``detected``           1          1 if the last look gave a plot                           x         [0, 1]
``nu_along_fm``        sigma      fading-memory mean of nu_along (weight 0.2 per plot)     x / 3     [-1, 1]
``nu_cross_fm``        sigma      fading-memory mean of nu_cross                           x / 3     [-1, 1]
``nis_fm``             1          fading-memory mean of the NIS (Bar-Shalom, alpha 0.8)    log10(1+x)/3  [0, 1]
``next_nu_along``      sigma      next plot's innovation along track, q = 0 prediction     x / 10    [-1, 1]
``next_nu_cross``      sigma      next plot's innovation across track (+ right)            x / 10    [-1, 1]
``next_nis``           1          next plot's NIS against the q = 0 prediction             log10(1+x)/3  [0, 1]
``next_q_fit_g``       g          q explaining the next plot's innovation (Kim & Lee, N=1)  log-map   [-1, 1]
``next_c_min_g``       g          Bizup's c_min from the next plot                         x / 8     [0, 1]
``next_los_accel_g``   g          (rdot of the next plot - rdot of F x) / dt               x / 4     [-1, 1]
``next_rdot_nu``       sigma      next plot's radial-velocity innovation, q = 0 prediction  x / 10    [-1, 1]
``next_dt_s``          s          time to the next look                                    x / 20    [0, 1]
``next_meas_std_m``    m          per-axis RMS noise of the next plot                      log10(1+x)/3  [0, 1]
``next_detected``      1          1 if the next look gives a plot                          x         [0, 1]
=====================  =========  =======================================================  ========  ==========

The ``next_*`` entries preview the plot that the chosen q will be used for
(:func:`radar_env.tracking.preview_next_plot`): the q-free predicted mean makes its innovation known before q is
chosen, so a policy, like an IMM, can weigh the plot itself. ``DEFAULT_FEATURES`` has all 27;
``PAST_FEATURES`` the first 17 (no preview: q for a look chosen from the looks before it).

``q_prev_g`` and ``next_q_fit_g`` use the action map: ``2 (log10 q - log10 q_min) / (log10 q_max - log10 q_min) - 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .units import G0_M_S2
from .validate import check_known_keys

__all__ = ["FEATURE_SPECS", "DEFAULT_FEATURES", "PAST_FEATURES", "DEFAULT_Q_LEVELS_G", "ObservationLayout",
           "FrameStack", "measurement_sigma_m"]

DEFAULT_Q_LEVELS_G = tuple(float(0.03 * (2.0 / 0.03) ** (j / 6.0)) for j in range(-4, 9))
"""13 levels, g: ``0.03 * (2/0.03)^(j/6)``, j = -4..8, i.e. a ratio of ~2.01 between neighbours, exactly 0.03 g
(j = 0) and 2 g (j = 6), from 0.00182 g to 8.11 g. The env's default action levels; their first and last bound
the continuous action and the ``q_prev_g`` / ``next_q_fit_g`` map."""


@dataclass(frozen=True)
class FeatureSpec:
    name: str
    unit: str
    low: float
    high: float
    kind: str      # "linear": obs = phys / scale; "log10p": obs = log10(1 + phys) / scale; "logq": action map
    scale: float
    description: str


FEATURE_SPECS = {s.name: s for s in [
    FeatureSpec("nu_along", "sigma", -1, 1, "linear", 5.0, "normalised along-track innovation"),
    FeatureSpec("nu_cross", "sigma", -1, 1, "linear", 5.0, "normalised cross-track innovation (+ right)"),
    FeatureSpec("nis", "1", 0, 1, "log10p", 3.0, "normalised innovation squared"),
    FeatureSpec("c_min_g", "g", 0, 1, "linear", 8.0, "Bizup c_min"),
    FeatureSpec("turn_rate_alg1_deg_s", "deg/s", -1, 1, "linear", 20.0, "Adrian algorithm 1 turn rate"),
    FeatureSpec("turn_rate_alg2_deg_s", "deg/s", -1, 1, "linear", 20.0, "Adrian algorithm 2 turn rate"),
    FeatureSpec("fma_innovation_km", "km", 0, 1, "linear", 20.0, "fading-memory average of |innovation|"),
    FeatureSpec("kim_lee_q_g", "g", 0, 1, "linear", 8.0, "Kim & Lee sliding-window q"),
    FeatureSpec("speed_m_s", "m/s", 0, 1, "linear", 400.0, "estimated speed"),
    FeatureSpec("range_km", "km", 0, 1, "linear", 200.0, "estimated range"),
    FeatureSpec("dt_s", "s", 0, 1, "linear", 20.0, "time since the previous look"),
    FeatureSpec("pos_std_ratio", "1", 0, 1, "linear", 3.0, "filter position std / measurement std"),
    FeatureSpec("q_prev_g", "g", -1, 1, "logq", 1.0, "q used for the last prediction"),
    FeatureSpec("detected", "1", 0, 1, "linear", 1.0, "last look detected"),
    FeatureSpec("nu_along_fm", "sigma", -1, 1, "linear", 3.0, "fading-memory mean of nu_along"),
    FeatureSpec("nu_cross_fm", "sigma", -1, 1, "linear", 3.0, "fading-memory mean of nu_cross"),
    FeatureSpec("nis_fm", "1", 0, 1, "log10p", 3.0, "fading-memory mean of the NIS"),
    FeatureSpec("next_nu_along", "sigma", -1, 1, "linear", 10.0, "next plot's along-track innovation (q = 0)"),
    FeatureSpec("next_nu_cross", "sigma", -1, 1, "linear", 10.0, "next plot's cross-track innovation (q = 0)"),
    FeatureSpec("next_nis", "1", 0, 1, "log10p", 3.0, "next plot's NIS (q = 0)"),
    FeatureSpec("next_q_fit_g", "g", -1, 1, "logq", 1.0, "q explaining the next plot's innovation"),
    FeatureSpec("next_c_min_g", "g", 0, 1, "linear", 8.0, "Bizup c_min from the next plot"),
    FeatureSpec("next_los_accel_g", "g", -1, 1, "linear", 4.0, "line-of-sight acceleration from the next plot's "
                "radial velocity"),
    FeatureSpec("next_rdot_nu", "sigma", -1, 1, "linear", 10.0, "next plot's radial-velocity innovation (q = 0)"),
    FeatureSpec("next_dt_s", "s", 0, 1, "linear", 20.0, "time to the next look"),
    FeatureSpec("next_meas_std_m", "m", 0, 1, "log10p", 3.0, "per-axis RMS noise of the next plot"),
    FeatureSpec("next_detected", "1", 0, 1, "linear", 1.0, "next look detected"),
]}

DEFAULT_FEATURES = tuple(FEATURE_SPECS)

_FROM_FEATURES = {  # observation name -> (StepOutput.features key, divisor to the observation's unit)
    "nu_along": ("nu_along", 1.0), "nu_cross": ("nu_cross", 1.0), "nis": ("nis", 1.0),
    "nu_along_fm": ("nu_along_fm", 1.0), "nu_cross_fm": ("nu_cross_fm", 1.0), "nis_fm": ("nis_fm", 1.0),
    "c_min_g": ("c_min_m_s2", G0_M_S2), "fma_innovation_km": ("fma_innovation_m", 1e3),
    "speed_m_s": ("speed_m_s", 1.0), "range_km": ("range_m", 1e3),
    "next_nu_along": ("next_nu_along", 1.0), "next_nu_cross": ("next_nu_cross", 1.0), "next_nis": ("next_nis", 1.0),
    "next_q_fit_g": ("next_q_fit_m_s2", G0_M_S2), "next_c_min_g": ("next_c_min_m_s2", G0_M_S2),
    "next_los_accel_g": ("next_los_accel_m_s2", G0_M_S2), "next_dt_s": ("next_dt_s", 1.0),
    "next_rdot_nu": ("next_rdot_nu", 1.0),
    "next_meas_std_m": ("next_meas_std_m", 1.0), "next_detected": ("next_detected", 1.0),
}
_DEGREES_FROM = {"turn_rate_alg1_deg_s": "turn_rate_alg1_rad_s", "turn_rate_alg2_deg_s": "turn_rate_alg2_rad_s"}
PAST_FEATURES = tuple(n for n in FEATURE_SPECS if not n.startswith("next_"))


def measurement_sigma_m(range_m, range_noise_std_m, bearing_noise_std_rad):
    """Per-axis RMS measurement noise of a converted plot, ``sqrt((sr^2 + (r sb)^2) / 2)`` (m)."""
    return np.sqrt(0.5 * (range_noise_std_m ** 2 + (range_m * bearing_noise_std_rad) ** 2))


class ObservationLayout:
    """Encode tracking-chain outputs into an observation vector and decode it back.

    Args:
        names: feature names (subset of ``FEATURE_SPECS``, no repeats).
        q_min_m_s2, q_max_m_s2: the action range, for ``q_prev_g``.
    """

    def __init__(self, names=DEFAULT_FEATURES, q_min_m_s2=0.003 * G0_M_S2, q_max_m_s2=8 * G0_M_S2):
        names = tuple(names)
        if not names:
            raise ValueError(f"features must name at least one of {list(FEATURE_SPECS)}")
        check_known_keys("", names, FEATURE_SPECS, noun="feature")
        if len(set(names)) != len(names):
            raise ValueError(f"features contains repeats: {list(names)}")
        self.names = names
        self.specs = [FEATURE_SPECS[n] for n in names]
        self.low = np.array([s.low for s in self.specs], dtype=np.float32)
        self.high = np.array([s.high for s in self.specs], dtype=np.float32)
        self._lq0, self._lq1 = np.log10(q_min_m_s2 / G0_M_S2), np.log10(q_max_m_s2 / G0_M_S2)
        self._index = {n: i for i, n in enumerate(names)}
        self._scale = np.array([s.scale for s in self.specs])
        self._log10p = np.array([s.kind == "log10p" for s in self.specs])
        self._logq = np.array([s.kind == "logq" for s in self.specs])
        # encode's plan, made once: the columns that are a feature over a divisor (one stack and one division for
        # all of them), the entries of the two non-linear scalings, and the other columns by name
        self._columns = [(_FROM_FEATURES[n][0] if n in _FROM_FEATURES else None, n) for n in names]
        self._divisor_col = np.array([_FROM_FEATURES[n][1] if n in _FROM_FEATURES else 1.0 for n in names])[:, None]
        self._log10p_idx, self._logq_idx = np.flatnonzero(self._log10p), np.flatnonzero(self._logq)
        self._scale_col = self._scale[:, None]
        self._log10p_scale_col = self._scale[self._log10p_idx][:, None]
        self._low_col, self._high_col = self.low.astype(np.float64)[:, None], self.high.astype(np.float64)[:, None]

    def __contains__(self, name):
        return name in self._index

    def physical(self, out, q_prev_m_s2):
        """Physical values (n, F) from a :class:`radar_env.tracking.StepOutput`."""
        f = out.features
        n = out.dt_s.shape[0]
        phys = np.empty((n, len(self.names)))
        for i, name in enumerate(self.names):
            if name in _FROM_FEATURES:
                key, divisor = _FROM_FEATURES[name]
                phys[:, i] = f[key] / divisor
            elif name in _DEGREES_FROM:
                phys[:, i] = np.degrees(f[_DEGREES_FROM[name]])
            elif name == "kim_lee_q_g":
                phys[:, i] = np.sqrt(np.maximum(f["kim_lee_phi_m2_s4"], 0.0)) / G0_M_S2
            elif name == "dt_s":
                phys[:, i] = out.dt_s
            elif name == "pos_std_ratio":
                sig = measurement_sigma_m(f["range_m"], out.range_noise_std_m, out.bearing_noise_std_rad)
                phys[:, i] = np.sqrt(0.5 * (out.P[:, 0, 0] + out.P[:, 1, 1])) / sig
            elif name == "q_prev_g":
                phys[:, i] = np.asarray(q_prev_m_s2, dtype=np.float64) / G0_M_S2
            else:  # "detected"
                phys[:, i] = out.detected
        return phys

    def encode_physical(self, phys):
        """(n, F) physical values -> (n, F) float32 observation, clipped to the Box."""
        phys = np.asarray(phys, dtype=np.float64)
        F = len(self.names)
        return self._encode_rows(phys.reshape(-1, F).T).reshape(phys.shape)

    def _encode_rows(self, pt):
        """(F, n) physical values, one row per feature -> (n, F) float32 observation (C order). Rows, so each
        scaling touches a few contiguous rows; the same element-wise operations as the scaling table, bit for bit."""
        obs = pt / self._scale_col
        i = self._log10p_idx
        if i.size:
            obs[i] = np.log10(1.0 + np.maximum(pt[i], 0.0)) / self._log10p_scale_col
        i = self._logq_idx
        if i.size:
            lq = np.log10(np.maximum(pt[i], 1e-12))
            obs[i] = 2.0 * (lq - self._lq0) / (self._lq1 - self._lq0) - 1.0
        np.copyto(obs, 0.0, where=np.isnan(obs))
        np.minimum(np.maximum(obs, self._low_col, out=obs), self._high_col, out=obs)   # np.clip, NaN gone
        return obs.T.astype(np.float32, order="C")

    def encode(self, out, q_prev_m_s2):
        """The (n, F) float32 observation of a :class:`radar_env.tracking.StepOutput`: ``encode_physical(
        physical(out, q_prev_m_s2))``, bit for bit, in a few vectorised calls (the env's per-step path)."""
        f = out.features
        cols = [f[key] if key is not None else self._special(name, out, q_prev_m_s2) for key, name in self._columns]
        return self._encode_rows(np.concatenate(cols).reshape(len(cols), -1) / self._divisor_col)

    def _special(self, name, out, q_prev_m_s2):
        """A column of :meth:`physical` that is not a feature over a divisor."""
        f = out.features
        if name in _DEGREES_FROM:
            return np.degrees(f[_DEGREES_FROM[name]])
        if name == "kim_lee_q_g":
            return np.sqrt(np.maximum(f["kim_lee_phi_m2_s4"], 0.0)) / G0_M_S2
        if name == "dt_s":
            return out.dt_s
        if name == "pos_std_ratio":
            sig = measurement_sigma_m(f["range_m"], out.range_noise_std_m, out.bearing_noise_std_rad)
            return np.sqrt(0.5 * (out.P[:, 0, 0] + out.P[:, 1, 1])) / sig
        if name == "q_prev_g":
            q = np.asarray(q_prev_m_s2, dtype=np.float64) / G0_M_S2
            return q if q.shape == out.dt_s.shape else np.full(out.dt_s.shape, q)
        return out.detected   # "detected"

    def decode(self, obs, name):
        """Physical value of feature ``name`` from observations ``obs`` (..., F) (clipped values stay clipped)."""
        if name not in self._index:
            raise ValueError(f"feature {name!r} is not in this observation; it has {list(self.names)}")
        s = self.specs[self._index[name]]
        v = np.asarray(obs, dtype=np.float64)[..., self._index[name]]
        if s.kind == "linear":
            return v * s.scale
        if s.kind == "log10p":
            return 10.0 ** (v * s.scale) - 1.0
        return 10.0 ** (self._lq0 + (v + 1.0) * 0.5 * (self._lq1 - self._lq0))


class FrameStack:
    """The last ``k`` observations of every row, newest first, as one ``(n, k * F)`` float32 vector (the env's
    ``frame_stack`` argument). At a row's first look the older frames repeat it (a zero frame would read as "every
    feature zero", a real observation). The newest frame comes first, so ``ObservationLayout.decode`` reads the
    current look's features from a stacked observation unchanged.

    Args:
        n_rows: rows (tracks); k: frames kept (>= 1); n_features: F, entries of one frame.
    """

    def __init__(self, n_rows, k, n_features):
        self.k, self.F = int(k), int(n_features)
        self.buf = np.zeros((int(n_rows), self.k, self.F), dtype=np.float32)

    def reset(self, rows, obs):
        """Rows ``rows`` start a new episode with observation ``obs`` (len(rows), F); returns their stacks."""
        self.buf[rows] = np.asarray(obs, dtype=np.float32)[:, None, :]
        return self.buf[rows].reshape(-1, self.k * self.F).copy()

    def push(self, rows, obs):
        """Rows ``rows`` move one look on with observation ``obs``; returns their stacks (len(rows), k F)."""
        b = self.buf[rows]          # a copy for an index array, a view for a slice
        b[:, 1:] = b[:, :-1].copy()
        b[:, 0] = obs
        self.buf[rows] = b
        return b.reshape(b.shape[0], self.k * self.F).copy()   # the caller's array never changes under it

    @staticmethod
    def bounds(layout, k):
        """The Box bounds of ``k`` stacked frames of ``layout``."""
        return np.tile(layout.low, int(k)), np.tile(layout.high, int(k))

