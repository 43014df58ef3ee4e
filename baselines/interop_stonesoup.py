"""Worked example of a user tracker: a Stone Soup Kalman filter in the comparison.

``radar-track evaluate --tracker-module baselines.interop_stonesoup --trackers stonesoup_kf,kf_tuned`` (or
``python -m agents.cli evaluate ...``) runs it beside the built-ins. Importing this module registers
``stonesoup_kf`` (:func:`baselines.registry.register_tracker`); it needs Stone Soup, an optional dependency
(``pip install -e '.[test]'`` or ``pip install stonesoup``).

The filter is Stone Soup's: ``KalmanPredictor`` with a ``CombinedLinearGaussianTransitionModel`` of two 1-D
constant-velocity models, ``KalmanUpdater`` with a ``LinearGaussian`` measurement model whose noise is each plot's
converted covariance ``R_m2``, on our converted plots ``z_m``, from the common track start
(:class:`baselines.user_trackers.TrackStart`), at ``kf_tuned``'s q (``baselines/tuned.json``). Two adaptations,
both needed for it to be the same filter as our ``kf_tuned``:

* Stone Soup's ``ConstantVelocity`` uses the continuous white-noise acceleration covariance
  ``q_c [[dt^3/3, dt^2/2], [dt^2/2, dt]]``; our chain uses the piecewise-constant (discrete) white acceleration
  ``q^2 [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` (:func:`radar_env.filters.kalman.process_noise`). :class:`_DiscreteCV`
  subclasses ``ConstantVelocity`` with that covariance (``noise_diff_coeff = q^2``); its transition matrix is
  Stone Soup's.
* Stone Soup's state order is ``[x, vx, y, vy]``, ours ``[x, y, vx, vy]``: the adapter permutes.

Timestamps are ``datetime`` values, exact to 1 microsecond: look times are rounded to that. With these, its
estimates equal ``kf_tuned``'s to ~1e-9 relative (tests/test_user_tracker.py checks the RMSE to 1e-6).
"""

from __future__ import annotations

import datetime as _dt
import importlib.util

import numpy as np


from .registry import register_tracker
from .user_trackers import Looks, TrackStart

__all__ = ["StoneSoupKF", "NAME"]

NAME = "stonesoup_kf"
_EPOCH = _dt.datetime(2000, 1, 1)
_PERM = [0, 2, 1, 3]      # ours [x, y, vx, vy] <-> Stone Soup's [x, vx, y, vy] (its own inverse)

if importlib.util.find_spec("stonesoup") is None:
    raise ImportError("baselines.interop_stonesoup needs Stone Soup: pip install -e '.[test]' (or pip install "
                      "stonesoup)")

_SS = {}


def _stonesoup():
    """Stone Soup's classes, imported on first use (the module import is already checked above)."""
    if not _SS:
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.models.transition.linear import CombinedLinearGaussianTransitionModel, ConstantVelocity
        from stonesoup.predictor.kalman import KalmanPredictor
        from stonesoup.types.array import CovarianceMatrix
        from stonesoup.types.detection import Detection
        from stonesoup.types.hypothesis import SingleHypothesis
        from stonesoup.types.state import GaussianState
        from stonesoup.updater.kalman import KalmanUpdater

        class _DiscreteCV(ConstantVelocity):
            """Stone Soup's 1-D constant velocity with the piecewise-constant white-acceleration covariance
            ``noise_diff_coeff * [[dt^4/4, dt^3/2], [dt^3/2, dt^2]]`` (``noise_diff_coeff = q^2``)."""

            def covar(self, time_interval, **kwargs):
                dt = time_interval.total_seconds()
                return CovarianceMatrix(self.noise_diff_coeff * np.array([[dt ** 4 / 4, dt ** 3 / 2],
                                                                          [dt ** 3 / 2, dt ** 2]]))

        _SS.update(LinearGaussian=LinearGaussian, Combined=CombinedLinearGaussianTransitionModel, CV=_DiscreteCV,
                   Predictor=KalmanPredictor, Detection=Detection, Hypothesis=SingleHypothesis,
                   GaussianState=GaussianState, Updater=KalmanUpdater)
    return _SS


def _stamp(t_s):
    return _EPOCH + _dt.timedelta(seconds=float(t_s))


class StoneSoupKF:
    """A :class:`baselines.user_trackers.UserTracker`: Stone Soup's CV Kalman filter at constant ``q_m_s2``
    (default: ``kf_tuned``'s q, read from ``baselines/tuned.json`` when it runs)."""

    def __init__(self, q_m_s2=None):
        if q_m_s2 is not None and not (np.isfinite(q_m_s2) and q_m_s2 >= 0):
            raise ValueError(f"StoneSoupKF: q_m_s2 must be a finite number >= 0 (m/s^2), got {q_m_s2!r}")
        self.q_m_s2 = q_m_s2

    def _q(self):
        if self.q_m_s2 is not None:
            return float(self.q_m_s2)
        from .tuned_params import kf_q_m_s2_from_params, tuned_parameters
        return kf_q_m_s2_from_params(tuned_parameters()["kf"])

    def __call__(self, looks: Looks, start: TrackStart):
        ss = _stonesoup()
        q2 = self._q() ** 2
        transition = ss["Combined"]([ss["CV"](q2), ss["CV"](q2)])
        predictor, updater = ss["Predictor"](transition), ss["Updater"](measurement_model=None)
        K = looks.t_s.shape[0]
        x, P = np.full((K, 4), np.nan), np.full((K, 4, 4), np.nan)
        state = ss["GaussianState"](start.x[_PERM].reshape(4, 1), start.P[np.ix_(_PERM, _PERM)], _stamp(start.t_s))
        for k in range(start.index, K):
            when = _stamp(looks.t_s[k])
            prior = predictor.predict(state, timestamp=when)
            if looks.detected[k]:
                model = ss["LinearGaussian"](ndim_state=4, mapping=(0, 2), noise_covar=looks.R_m2[k])
                det = ss["Detection"](looks.z_m[k].reshape(2, 1), timestamp=when, measurement_model=model)
                state = updater.update(ss["Hypothesis"](prior, det))
            else:
                state = prior
            x[k] = np.asarray(state.state_vector, dtype=np.float64).ravel()[_PERM]
            P[k] = np.asarray(state.covar, dtype=np.float64)[np.ix_(_PERM, _PERM)]
        return x, P


register_tracker(NAME, StoneSoupKF())
