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
``imm_ct_prob``        1          imm_cv_ct's CT-mode probability (opt-in detector)        x         [0, 1]
``imm_omega_deg_s``    deg/s      imm_cv_ct's turn-rate estimate, + = right (opt-in)       x / 20    [-1, 1]
``imm2_high_prob``     1          imm2's high-noise-mode probability (opt-in detector)     x         [0, 1]
=====================  =========  =======================================================  ========  ==========

The ``next_*`` entries preview the plot that the chosen q will be used for
(:func:`radar_env.filters.tracking.preview_next_plot`): the q-free predicted mean makes its innovation known before q is
chosen, so a policy, like an IMM, can weigh the plot itself. ``DEFAULT_FEATURES`` has the first 27;
``PAST_FEATURES`` the first 17 (no preview: q for a look chosen from the looks before it).

The last three, ``DETECTOR_FEATURES``, are classical maneuver detectors: the tuned ``imm_cv_ct`` and ``imm2``
IMMs run beside the chain on the same looks (:mod:`radar_env.envs.detectors`). They are in no default list (the
bundled policies' observations stay as they were); name them in ``features`` to add them. Only the env with
``tracker="cv"`` computes them (the IMM env has its own detectors), and :meth:`ObservationLayout.encode` takes
their values as ``detectors``.

``q_prev_g`` and ``next_q_fit_g`` use the action map: ``2 (log10 q - log10 q_min) / (log10 q_max - log10 q_min) - 1``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from . import env_kernels as _ek
from ..filters import kernels as _k
from ..common.units import G0_M_S2
from ..common.validate import check_known_keys

__all__ = ["FEATURE_SPECS", "DEFAULT_FEATURES", "PAST_FEATURES", "DETECTOR_FEATURES", "DEFAULT_Q_LEVELS_G",
           "ObservationLayout", "FrameStack", "measurement_sigma_m"]

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
    FeatureSpec("imm_ct_prob", "1", 0, 1, "linear", 1.0, "imm_cv_ct's CT-mode probability"),
    FeatureSpec("imm_omega_deg_s", "deg/s", -1, 1, "linear", 20.0, "imm_cv_ct's turn-rate estimate"),
    FeatureSpec("imm2_high_prob", "1", 0, 1, "linear", 1.0, "imm2's high-noise-mode probability"),
]}

DETECTOR_FEATURES = ("imm_ct_prob", "imm_omega_deg_s", "imm2_high_prob")
"""The detector features (:mod:`radar_env.envs.detectors`), in the order of its value columns."""
DEFAULT_FEATURES = tuple(n for n in FEATURE_SPECS if n not in DETECTOR_FEATURES)

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
_SPECIAL_SOURCES = {  # observation name -> (env_kernels.SP_* special, the feature it reads or None)
    "turn_rate_alg1_deg_s": (_ek.SP_DEGREES, "turn_rate_alg1_rad_s"),
    "turn_rate_alg2_deg_s": (_ek.SP_DEGREES, "turn_rate_alg2_rad_s"),
    "kim_lee_q_g": (_ek.SP_KIM_LEE_Q, "kim_lee_phi_m2_s4"), "dt_s": (_ek.SP_DT, None),
    "pos_std_ratio": (_ek.SP_POS_STD, "range_m"), "q_prev_g": (_ek.SP_Q_PREV, None),
    "detected": (_ek.SP_DETECTED, None),
}
_FEATURE_COLUMN = {k: i for i, k in enumerate(_k.BANK_FLOAT_KEYS + _k.PREVIEW_KEYS)}
_FEATURE_COLUMN.update({k: _k.W_FEAT + c for c, k in enumerate(DETECTOR_FEATURES)})   # the env kernel's ext
PAST_FEATURES = tuple(n for n in DEFAULT_FEATURES if not n.startswith("next_"))


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
        self._lq0, self._lq1 = float(np.log10(q_min_m_s2 / G0_M_S2)), float(np.log10(q_max_m_s2 / G0_M_S2))
        self._index = {n: i for i, n in enumerate(names)}
        # the compiled encoding's plan (radar_env.envs.env_kernels: one row per entry); ``_sources`` names the feature
        # each entry reads (None: dt, q_prev, detected), ``env_plan`` reads the chain's feature row directly
        self._sources, rows = [], []
        for n, s in zip(names, self.specs):
            kind = {"linear": _ek.KIND_LINEAR, "log10p": _ek.KIND_LOG10P, "logq": _ek.KIND_LOGQ}[s.kind]
            if n in _FROM_FEATURES:
                key, divisor = _FROM_FEATURES[n]
                special = _ek.SP_COLUMN
            elif n in DETECTOR_FEATURES:
                key, divisor, special = n, 1.0, _ek.SP_COLUMN
            else:
                key, divisor = _SPECIAL_SOURCES[n][1], 1.0
                special = _SPECIAL_SOURCES[n][0]
            self._sources.append(key)
            rows.append([special, 0.0, divisor, kind, s.scale, s.low, s.high])
        self._plan = np.array(rows, dtype=np.float64).reshape(len(names), _ek.W_PLAN)
        self._plan[:, _ek.PL_COL] = np.arange(len(names))
        self.env_plan = self._plan.copy()
        self.env_plan[:, _ek.PL_COL] = [_FEATURE_COLUMN.get(k, 0) for k in self._sources]

    def __contains__(self, name):
        return name in self._index

    @property
    def uses_detectors(self):
        """True if an entry is a :data:`DETECTOR_FEATURES` (the caller then runs :mod:`radar_env.envs.detectors`)."""
        return any(n in DETECTOR_FEATURES for n in self.names)

    def _inputs(self, out, q_prev_m_s2, detectors=None):
        """The compiled encoding's inputs from a StepOutput: the features each entry reads (n, F) and the step's
        dt, position variances, site sigmas, detection flags and previous q (n,)."""
        f = out.features
        n = out.dt_s.shape[0]
        src = np.zeros((n, len(self.names)))
        if self.uses_detectors and (detectors is None or np.shape(detectors) != (n, len(DETECTOR_FEATURES))):
            raise ValueError(f"detectors must be the ({n}, {len(DETECTOR_FEATURES)}) values of "
                             f"radar_env.envs.detectors.DetectorBank ({', '.join(DETECTOR_FEATURES)}) for this layout's "
                             f"detector features, got {None if detectors is None else np.shape(detectors)}")
        for j, key in enumerate(self._sources):
            if key in DETECTOR_FEATURES:
                src[:, j] = detectors[:, DETECTOR_FEATURES.index(key)]
            elif key is not None:
                src[:, j] = f[key]
        c = _k.c_array
        q = np.asarray(q_prev_m_s2, dtype=np.float64)
        return (src, c(out.dt_s, np.float64), c(out.P[:, 0, 0], np.float64), c(out.P[:, 1, 1], np.float64),
                c(out.range_noise_std_m, np.float64), c(out.bearing_noise_std_rad, np.float64),
                c(out.detected, np.bool_), c(q if q.shape == (n,) else np.broadcast_to(q, (n,)), np.float64))

    def physical(self, out, q_prev_m_s2, detectors=None):
        """Physical values (n, F) from a :class:`radar_env.filters.tracking.StepOutput` (and the detectors' (n, 3) values,
        needed if :attr:`uses_detectors`)."""
        inp = self._inputs(out, q_prev_m_s2, detectors)
        phys = np.empty(inp[0].shape)
        _ek.k_physical(self._plan, *inp, phys)
        return phys

    def encode_physical(self, phys):
        """(..., F) physical values -> (..., F) float32 observation, clipped to the Box."""
        phys = np.asarray(phys, dtype=np.float64)
        F = len(self.names)
        flat = _k.c_array(phys.reshape(-1, F), np.float64)
        obs = np.empty(flat.shape, dtype=np.float32)
        _ek.k_scale(self._plan, self._lq0, self._lq1, flat, obs)
        return obs.reshape(phys.shape)

    def encode(self, out, q_prev_m_s2, detectors=None):
        """The (n, F) float32 observation of a :class:`radar_env.filters.tracking.StepOutput`: ``encode_physical(
        physical(out, q_prev_m_s2, detectors))`` in one compiled pass (the env's step runs the same code,
        :mod:`radar_env.envs.env_kernels`)."""
        inp = self._inputs(out, q_prev_m_s2, detectors)
        obs = np.empty(inp[0].shape, dtype=np.float32)
        _ek.k_encode(self._plan, self._lq0, self._lq1, *inp, obs)
        return obs

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

