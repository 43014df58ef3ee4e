r"""Classical maneuver detectors as optional observation features of the default env (``tracker="cv"``): two
IMMs run beside the env's CV chain on the same looks, their parameters fixed at the tuned values, and three of
their outputs become features (none is in ``DEFAULT_FEATURES``; name them in ``features`` to use them):

=====================  =======  ===========================================================================
name                   unit     meaning
=====================  =======  ===========================================================================
``imm_ct_prob``        1        imm_cv_ct's CT-mode probability after the look (its maneuver detector)
``imm_omega_deg_s``    deg/s    imm_cv_ct's combined turn-rate estimate (+ = clockwise = right turn)
``imm2_high_prob``     1        imm2's high-noise-mode probability after the look
=====================  =======  ===========================================================================

The IMMs are :mod:`radar_env.filters.imm_cv_ct`'s filter (``_look``, the arithmetic of the ``imm_cv_ct`` tracker) with
the parameters of ``radar_env/data/imm_cv_ct_env.json`` and, for imm2 (two CV modes, mode probabilities starting
at (0.9, 0.1)), those of ``radar_env/data/detector_imm2.json``: copies of ``baselines/tuned.json``'s ``imm_cv_ct``
and ``imm2`` (radar_env reads nothing of baselines; tests/test_detectors.py fails when they drift). Both start
at the chain's track start (every mode at the warm-up estimate, as the baselines start them), so the features
equal what the ``imm_cv_ct`` and ``imm2`` trackers compute on the same episode (tested against both, imm2 against
the independent 4-state IMM of :func:`radar_env.filters.kalman.imm_filter`). At the track start (before any look of the
IMMs) the features are their initial values: the CT probability ``(1 - mu0_cv) / 2``, turn rate 0, imm2's 0.1.

Per step the env calls :func:`k_detectors_step` before its chain's look (it reads the look the chain is about to
process) and hands the three values to its observation kernel (:func:`radar_env.envs.env_kernels.k_env`'s ``ext``); the
baselines' lockstep (``baselines.trackers.run_q_policy``) runs the same :class:`DetectorBank`, so a policy trained
with these features sees the same numbers in evaluation. Cost: two IMM looks (5 modes of a 5-state EKF) per row
and step, beside the chain's one CV look.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from numba import njit

from . import env_kernels as _ek
from ..filters import kernels as _k
from ..filters.imm_cv_ct import _look, _no_range_rate, _work, imm_cv_ct_spec_from_params, kernel_parameters
from .imm_env import imm_env_defaults, k_imm_start
from .observation import DETECTOR_FEATURES
from ..common.units import DEG, G0_M_S2

__all__ = ["DETECTOR_FEATURES", "DETECTOR_IMM2_PATH", "detector_imm2_parameters", "DetectorBank"]


DETECTOR_IMM2_PATH = Path(__file__).parents[1] / "data" / "detector_imm2.json"

_IMM2_MU0 = (0.9, 0.1)     # baselines.trackers.imm2_spec_from_params's start


def detector_imm2_parameters():
    """imm2's tuned parameters ``{"q_low_g", "q_high_g", "p_stay_low", "p_stay_high"}`` (the data file's)."""
    return dict(json.loads(DETECTOR_IMM2_PATH.read_text())["imm2_parameters"])


def _imm2_arrays():
    p = detector_imm2_parameters()
    sl, sh = p["p_stay_low"], p["p_stay_high"]
    Pi = np.array([[sl, 1.0 - sl], [1.0 - sh, sh]])
    return (np.array([False, False]), np.array([p["q_low_g"], p["q_high_g"]]) * G0_M_S2, np.log(Pi),
            np.log(np.array(_IMM2_MU0)))


class DetectorBank:
    """The two detector IMMs of ``n`` rows (module docstring). Works on a :class:`radar_env.filters.tracking.Tracker`'s
    look arrays (``st``, ``looks``, ``it``), so the env and the baselines' lockstep share it.

    Args:
        n: rows.
    Attributes: ``initial`` (3,) the values at a track start; ``values`` (n, 3) the last values of every row.
    """

    def __init__(self, n):
        spec = imm_cv_ct_spec_from_params(imm_env_defaults()["imm_parameters"])
        is_ct, _, _, log_mu0 = spec.mode_arrays()
        q, sw2, log_Pi = kernel_parameters(spec)
        sig_w0 = spec.sigma_omega0_deg_s * DEG
        self._a = (np.ascontiguousarray(is_ct), q[0, 0].copy(), float(sw2[0, 0]), log_Pi[0, 0].copy(),
                   np.ascontiguousarray(log_mu0))
        self._b = _imm2_arrays()
        self._consts = (sig_w0 * sig_w0, spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2)
        M = is_ct.shape[0]
        self.xa, self.Pa, self.lma = np.zeros((n, M, 5)), np.zeros((n, M, 5, 5)), np.zeros((n, M))
        self.xb, self.Pb, self.lmb = np.zeros((n, 2, 5)), np.zeros((n, 2, 5, 5)), np.zeros((n, 2))
        self.initial = np.array([math.exp(log_mu0[1]), 0.0, _IMM2_MU0[1]])
        self.values = np.tile(self.initial, (n, 1))

    def start(self, rows, st):
        """Start ``rows``' IMMs at the chain's state ``st`` (the track start, after the warm-up looks); their
        values become :attr:`initial`."""
        rows = np.ascontiguousarray(rows, dtype=np.int64)
        sig_w0_2 = self._consts[0]
        k_imm_start(rows, st, self._a[0], sig_w0_2, sig_w0_2, self._a[4], self.xa, self.Pa, self.lma)
        k_imm_start(rows, st, self._b[0], sig_w0_2, sig_w0_2, self._b[3], self.xb, self.Pb, self.lmb)
        self.values[rows] = self.initial

    def step(self, looks, it, rows=None, act=None, ep=None):
        """Both IMMs of ``rows`` (all if None) take the look their chain processes next (``it[r, I_K]``); returns
        the status ``ST_*`` (nothing changed unless ST_OK): with ``act``/``ep`` the env's actions are checked first
        (as its step kernel checks them), so a refused step leaves the IMMs where they were."""
        if rows is None:
            rows = np.arange(self.values.shape[0], dtype=np.int64)
        if act is None:
            act, ep = np.zeros(0), np.zeros(0)
        return k_detectors_step(np.ascontiguousarray(rows, dtype=np.int64), act, ep, looks, it, *self._a,
                                *self._b, *self._consts, self.xa, self.Pa, self.lma, self.xb, self.Pb, self.lmb,
                                self.values)


@njit(cache=True)
def k_detectors_step(rows, act, ep, looks, it, is_ct_a, q_a, sw2_a, log_Pi_a, log_mu0_a, is_ct_b, q_b, log_Pi_b,
                     log_mu0_b, sig_w0_2, omega_max, accel_max, xa, Pa, lma, xb, Pb, lmb, values):
    """:meth:`DetectorBank.step` (one call for all rows): ``values[r] = (mu_ct, omega deg/s, mu_high)``."""
    if act.shape[0] > 0:
        s = _ek._check_actions(act, ep)
        if s != _ek.ST_OK:
            return s
    for i in range(rows.shape[0]):
        r = rows[i]
        if it[r, _k.I_K] >= it[r, _k.I_N]:
            return _ek.ST_ENDED
    work_a, work_b = _work(is_ct_a.shape[0]), _work(2)
    rr = _no_range_rate()       # the detectors' IMMs update on position plots
    x, P = np.empty(4), np.empty((4, 4))
    mu_a, mu_b = np.empty(is_ct_a.shape[0]), np.empty(2)
    for i in range(rows.shape[0]):
        r = rows[i]
        k = it[r, _k.I_K]
        lk = looks[r, k]
        dt = lk[_k.L_T] - looks[r, k - 1, _k.L_T]
        z = lk[_k.L_Z:_k.L_Z + 2]
        R = lk[_k.L_R:_k.L_R + 4].reshape((2, 2))
        det = lk[_k.L_DET] != 0.0
        _, om, _ = _look(dt, z, R, det, rr, is_ct_a, q_a, sw2_a, log_Pi_a, sig_w0_2, omega_max, accel_max, xa[r], Pa[r],
                         lma[r], work_a, x, P, mu_a)
        _look(dt, z, R, det, rr, is_ct_b, q_b, 0.0, log_Pi_b, sig_w0_2, omega_max, accel_max, xb[r], Pb[r], lmb[r],
              work_b, x, P, mu_b)
        values[r, 0] = mu_a[1]
        values[r, 1] = om / DEG
        values[r, 2] = mu_b[1]
    return _ek.ST_OK
