r"""Stone Soup components for ``imm_cv_ct``, the tuned CV / CT-EKF IMM: a predictor, an updater and the state types
they exchange, so the IMM runs inside Stone Soup's trackers, hypothesisers, associators and metrics.

Stone Soup (1.9) has no Gaussian IMM in its release. These components wrap ours, not a second copy of it: the
predictor runs the prediction half of the compiled per-look kernel (mixing and mode-matched prediction,
:func:`radar_env.filters.imm_cv_ct.predict_modes`), the updater the update half
(:func:`radar_env.filters.imm_cv_ct.update_modes`); one predict and one update equal one look of
:func:`baselines.imm_cv_ct_runner.run_imm_cv_ct` (tests/test_stonesoup_components.py checks every look of whole
episodes).

Conventions (Stone Soup's on the outside, ours inside):

* State order. Stone Soup's ``[x, vx, y, vy]`` (m, m/s) for the combined mean and covariance
  (``state_vector``, ``covar``: what gaters, associators and metrics read); the modes' 5-state means and
  covariances in the same order plus the turn rate, ``[x, vx, y, vy, omega]`` (omega in rad/s, positive =
  clockwise = right turn, our convention). Ours is ``[x, y, vx, vy(, omega)]``: the components permute (exactly).
* Measurements. A :class:`~stonesoup.types.detection.Detection` with Stone Soup's polar
  :class:`~stonesoup.models.measurement.nonlinear.CartesianToBearingRange` (``mapping=(0, 2)``, the site as
  ``translation_offset``, no rotation, noise ``diag(sigma_bearing^2, sigma_range^2)``), or a Cartesian
  :class:`~stonesoup.models.measurement.linear.LinearGaussian` with ``mapping=(0, 2)``. Stone Soup's bearing is
  ``atan2(y - sy, x - sx)``, counter-clockwise from the x axis (east); ours (:mod:`radar_env.sim.radar`) is
  ``atan2(x - sx, y - sy)``, clockwise from north: ``ours = pi/2 - stone_soup``. A polar plot is converted inside
  the updater exactly as our episodes convert theirs (:func:`radar_env.sim.radar.cartesian_from_polar`,
  :func:`radar_env.sim.radar.converted_covariance` at the measured range and bearing), then the IMM's update.
* Range rate. A detection ``[bearing, range, range rate]`` with
  :class:`~stonesoup.models.measurement.nonlinear.CartesianToBearingRangeRate2D` (the 2-D one: Stone Soup's
  ``CartesianToBearingRangeRate`` needs a 6-state ``[x, vx, y, vy, z, vz]``; ``mapping=(0, 2)``,
  ``velocity_mapping=(1, 3)``, a stationary site: ``velocity`` zero, noise ``diag(sb^2, sr^2, srdot^2)``): its
  range rate ``(p - site) . v / |p - site|`` is ours (positive receding, the same sign). The plot converts as
  above, then every mode updates on the range rate after its position and that likelihood joins the mode's: the
  range-rate IMM, ``imm_cv_ct_rdot`` (``IMMCVCTPredictor(spec=tuned_imm_cv_ct_spec("imm_cv_ct_rdot"))``; equal to
  ``run_imm_cv_ct(..., radial_velocity=True)``, tested), and so the bank of CT modes with range rate,
  ``imm_ct_bank_rdot`` (its spec likewise; tested).
* Gating. :meth:`IMMCVCTUpdater.predict_measurement` is Stone Soup's extended-Kalman one on the combined Gaussian
  (the IMM's moment-matched prediction): a hypothesiser gates in the detection's own (polar) space with the
  linearised innovation covariance. The update itself uses the converted plot, as our chain does; the two
  innovations agree to first order.
* Time. Stone Soup passes ``datetime`` timestamps; ``dt = (timestamp - prior.timestamp).total_seconds()``,
  ``dt = 0`` allowed (the IMM still mixes, as our kernel does at a look with dt 0), a negative ``dt`` rejected.
  :func:`stamp` turns our seconds into datetimes (1 microsecond resolution).
* Missed looks. Stone Soup's trackers keep the prediction when a track gets no detection; that is what
  ``run_imm_cv_ct`` does too up to rounding. The updater also accepts a
  :class:`~stonesoup.types.detection.MissedDetection` hypothesis and then runs the kernel's missed-look branch
  (posterior = prediction, mode probabilities renormalised): bit for bit the runner's.

Needs Stone Soup (``pip install -e ".[stonesoup]"``); importing this module without it raises an ``ImportError``
saying so. Example: docs/stonesoup.md.
"""

from __future__ import annotations

import datetime as _dt
import math

import numpy as np

try:
    import stonesoup  # noqa: F401
except ImportError as _err:
    raise ImportError('baselines.stonesoup_components needs Stone Soup: pip install -e ".[stonesoup]" (or pip install '
                      '"stonesoup>=1.2")') from _err

from stonesoup.base import Property  # noqa: E402
from stonesoup.models.measurement.base import MeasurementModel  # noqa: E402
from stonesoup.models.transition.base import TransitionModel  # noqa: E402
from stonesoup.models.measurement.linear import LinearGaussian  # noqa: E402
from stonesoup.models.measurement.nonlinear import (  # noqa: E402
    CartesianToBearingRange, CartesianToBearingRangeRate, CartesianToBearingRangeRate2D)
from stonesoup.predictor.base import Predictor  # noqa: E402
from stonesoup.types.angle import Bearing  # noqa: E402
from stonesoup.types.array import CovarianceMatrix, StateVector  # noqa: E402
from stonesoup.types.detection import Detection  # noqa: E402
from stonesoup.types.prediction import Prediction  # noqa: E402
from stonesoup.types.state import GaussianState, State, StateMutableSequence  # noqa: E402
from stonesoup.types.update import Update  # noqa: E402
from stonesoup.updater.kalman import ExtendedKalmanUpdater  # noqa: E402

from radar_env.filters.imm_cv_ct import IMMCVCTSpec, initial_modes, predict_modes, update_modes  # noqa: E402
from radar_env.sim.radar import cartesian_from_polar, converted_covariance  # noqa: E402

__all__ = ["IMMCVCTState", "IMMCVCTStatePrediction", "IMMCVCTStateUpdate", "IMMCVCTPredictor", "IMMCVCTUpdater",
           "plot_from_detection", "range_rate_from_detection", "polar_detection", "detections_from_episode",
           "look_from_detection", "gaussian_state", "ours_from_state", "stamp", "seconds", "prediction_dt", "EPOCH",
           "SS_FROM_OURS", "check_measurement_model"]

EPOCH = _dt.datetime(2000, 1, 1)
"""The datetime of our ``t_s = 0`` (:func:`stamp`)."""

SS_FROM_OURS = np.array([0, 2, 1, 3])
"""Index from our ``[x, y, vx, vy]`` to Stone Soup's ``[x, vx, y, vy]`` (the permutation is its own inverse)."""
_P5 = np.array([0, 2, 1, 3, 4])         # the same with the turn rate last in both


def stamp(t_s) -> _dt.datetime:
    """Our time ``t_s`` (seconds) as a Stone Soup timestamp: :data:`EPOCH` + ``t_s``, rounded to 1 microsecond."""
    t = float(t_s)
    if not math.isfinite(t):
        raise ValueError(f"t_s must be a finite number of seconds, got {t_s!r}")
    return EPOCH + _dt.timedelta(seconds=t)


def seconds(timestamp) -> float:
    """A Stone Soup timestamp as our time (seconds since :data:`EPOCH`), the inverse of :func:`stamp`."""
    if not isinstance(timestamp, _dt.datetime):
        raise ValueError(f"timestamp must be a datetime, got {timestamp!r}")
    return (timestamp - EPOCH).total_seconds()


def prediction_dt(prior_timestamp, timestamp, what) -> float:
    """The seconds a prediction spans, ``timestamp - prior_timestamp`` (0 if both are None); ``ValueError`` if only one
    is a datetime or the step goes back in time (``what`` names the filter that predicts forward only)."""
    if timestamp is None or prior_timestamp is None:
        if timestamp is not None or prior_timestamp is not None:
            raise ValueError(f"timestamp ({timestamp}) and prior.timestamp ({prior_timestamp}) must both be "
                             "datetimes, or both None (dt = 0)")
        return 0.0
    dt = (timestamp - prior_timestamp).total_seconds()
    if dt < 0:
        raise ValueError(f"timestamp {timestamp} is before prior.timestamp {prior_timestamp}: {what} predicts "
                         "forward only")
    return dt


def _tuned_spec():
    from .imm_cv_ct_runner import tuned_imm_cv_ct_spec
    return tuned_imm_cv_ct_spec()


# ------------------------------------------------------------------------------------------------ state types
class IMMCVCTState(GaussianState):
    """An ``imm_cv_ct`` posterior as a Stone Soup Gaussian: ``state_vector (4, 1)`` and ``covar (4, 4)`` are the
    moment-matched combination of the modes (Stone Soup's order ``[x, vx, y, vy]``), what hypothesisers, gaters and
    metrics see; the modes ride along.

    Build one from a plain :class:`~stonesoup.types.state.GaussianState` with :meth:`from_gaussian` (as the
    runner starts its modes) or let :class:`IMMCVCTPredictor` do it on the first prediction."""

    mode_state_vectors: np.ndarray = Property(
        default=None, doc="(M, 5) the modes' means, order [x, vx, y, vy, omega] (m, m/s, rad/s; omega > 0 clockwise)")
    mode_covars: np.ndarray = Property(default=None, doc="(M, 5, 5) the modes' covariances, the same order")
    log_mode_probabilities: np.ndarray = Property(
        default=None, doc="(M,) log mode probabilities, modes CV, CT[, high-noise CV] (carried as logs, as the "
                          "kernel does)")
    spec: IMMCVCTSpec = Property(default=None, doc="the IMM's parameters (None: the tuned imm_cv_ct's)")

    @property
    def mode_probabilities(self) -> np.ndarray:
        """(M,) mode probabilities, ``exp(log_mode_probabilities)``."""
        return np.exp(np.asarray(self.log_mode_probabilities, dtype=np.float64))

    @property
    def maneuver_probability(self) -> float:
        """``1 - mu_cv``: the probability of the CT and high-noise modes (the runner's ``maneuver_probability``)."""
        return 1.0 - float(self.mode_probabilities[0])

    @property
    def turn_rate_rad_s(self) -> float:
        """The combined turn rate ``sum_j mu_j omega_j`` over the CT modes (a CV mode's turn rate is 0)."""
        is_ct = self.spec_or_tuned.mode_arrays()[0]
        return float(np.sum(self.mode_probabilities[is_ct] * np.asarray(self.mode_state_vectors)[is_ct, 4]))

    @property
    def spec_or_tuned(self) -> IMMCVCTSpec:
        return self.spec if self.spec is not None else _tuned_spec()

    @classmethod
    def from_gaussian(cls, state: GaussianState, spec: IMMCVCTSpec | None = None):
        """Every mode at ``state``'s mean and covariance (4-state, Stone Soup's order), turn rate 0 with variance
        ``sigma_omega0^2``, mode probabilities ``mu0``: how :func:`baselines.imm_cv_ct_runner.run_imm_cv_ct` starts
        from the common track start."""
        spec = spec if spec is not None else _tuned_spec()
        x, P = _gaussian_ours(state, "state")
        xm, Pm, log_mu = initial_modes(spec, x, P)
        return cls(StateVector(state.state_vector), CovarianceMatrix(state.covar), timestamp=state.timestamp,
                   mode_state_vectors=xm[:, _P5], mode_covars=Pm[:, _P5][:, :, _P5], log_mode_probabilities=log_mu,
                   spec=spec)


class IMMCVCTStatePrediction(Prediction, IMMCVCTState):
    """An ``imm_cv_ct`` prediction: the predicted modes, their combination and the predicted mode probabilities
    (the mixing normalisers ``c_j``)."""


class IMMCVCTStateUpdate(Update, IMMCVCTState):
    """An ``imm_cv_ct`` posterior after an update (with the hypothesis used)."""


def _gaussian_ours(state, name):
    """``(x (4,), P (4, 4))`` in our order from a 4-state Gaussian in Stone Soup's."""
    x = np.asarray(state.state_vector, dtype=np.float64).reshape(-1)
    P = np.asarray(getattr(state, "covar", None), dtype=np.float64)
    if x.shape != (4,) or P.shape != (4, 4):
        raise ValueError(f"{name} must be a 4-state Gaussian [x, vx, y, vy] (state_vector (4, 1), covar (4, 4)); "
                         f"got {x.shape} and {P.shape}")
    return x[SS_FROM_OURS], P[np.ix_(SS_FROM_OURS, SS_FROM_OURS)]


def gaussian_state(x, P, t_s) -> GaussianState:
    """A Stone Soup :class:`~stonesoup.types.state.GaussianState` from our ``x (4,) [x, y, vx, vy]``, ``P (4, 4)``
    at our time ``t_s`` (seconds)."""
    x = np.asarray(x, dtype=np.float64).reshape(-1)
    P = np.asarray(P, dtype=np.float64)
    if x.shape != (4,) or P.shape != (4, 4):
        raise ValueError(f"x must be (4,) and P (4, 4) ([x, y, vx, vy]); got {x.shape}, {P.shape}")
    return GaussianState(StateVector(x[SS_FROM_OURS]), CovarianceMatrix(P[np.ix_(SS_FROM_OURS, SS_FROM_OURS)]),
                         timestamp=stamp(t_s))


def ours_from_state(state) -> tuple[np.ndarray, np.ndarray]:
    """``(x (4,), P (4, 4))`` in our order ``[x, y, vx, vy]`` from a Stone Soup 4-state Gaussian."""
    return _gaussian_ours(state, "state")


# ------------------------------------------------------------------------------------------------ measurements
def plot_from_detection(detection, measurement_model=None) -> tuple[np.ndarray, np.ndarray]:
    """The Cartesian plot ``z (2,)`` (m) and its covariance ``R (2, 2)`` (m^2) our chain filters, from a Stone Soup
    detection.

    ``CartesianToBearingRange`` (``[bearing, range]``, Stone Soup's bearing counter-clockwise from east) or
    ``CartesianToBearingRangeRate2D`` (``[bearing, range, range rate]``): converted as our episodes convert plots
    (:func:`radar_env.sim.radar.cartesian_from_polar`, :func:`radar_env.sim.radar.converted_covariance` at the
    measured values, our bearing ``pi/2 -`` Stone Soup's). ``LinearGaussian`` with ``mapping=(0, 2)``: the
    detection is already the plot, its noise ``R``.

    Args:
        detection: a :class:`~stonesoup.types.detection.Detection`.
        measurement_model: used when the detection carries none.
    Raises:
        ValueError: a model other than those, a mapping other than ``(0, 2)`` (x and y of ``[x, vx, y, vy]``),
            a rotated or non-diagonal polar model, a moving sensor, a non-finite measurement.
    """
    return _measurement(detection, measurement_model)[:2]


def range_rate_from_detection(detection, measurement_model=None):
    """The range-rate input of the IMM's update (:func:`radar_env.filters.imm_cv_ct.update_modes`'s
    ``range_rate``): ``(range rate (m/s, positive receding), its variance (m^2/s^2), site x, site y (m))`` of a
    ``CartesianToBearingRangeRate2D`` detection; None for a detection without range rate. Raises as
    :func:`plot_from_detection`."""
    return _measurement(detection, measurement_model)[2]


def look_from_detection(detection, measurement_model=None) -> dict:
    """A polar detection as our look fields (:data:`radar_env.sim.looks.LOOK_COLUMNS` names): ``t_s`` (seconds,
    :func:`seconds`), ``detected`` True, ``z_m``, ``R_m2`` (:func:`plot_from_detection`), ``site_xy_m``,
    ``range_m``, ``bearing_rad`` (ours: clockwise from north), ``radial_velocity_m_s``, the noise stds
    ``range_noise_std_m``, ``bearing_noise_std_rad``, ``radial_velocity_noise_std_m_s`` (the range-rate ones NaN
    for a ``CartesianToBearingRange``). ``ValueError`` for a ``LinearGaussian`` (no polar values) and as
    :func:`plot_from_detection`."""
    model = detection.measurement_model if detection.measurement_model is not None else measurement_model
    z, R, rr = _measurement(detection, measurement_model)
    if not isinstance(model, (CartesianToBearingRange, CartesianToBearingRangeRate2D)):
        raise ValueError(f"measurement_model must be polar (CartesianToBearingRange[Rate2D]) for a look with range "
                         f"and bearing, got {type(model).__name__}")
    y = np.asarray(detection.state_vector, dtype=np.float64).reshape(-1)
    noise = np.asarray(model.covar(), dtype=np.float64)
    site = np.asarray(model.translation_offset, dtype=np.float64).reshape(-1)[:2].copy()
    return {"t_s": seconds(detection.timestamp), "detected": True, "z_m": z, "R_m2": R, "site_xy_m": site,
            "range_m": float(y[1]), "bearing_rad": 0.5 * math.pi - float(y[0]),
            "radial_velocity_m_s": math.nan if rr is None else rr[0],
            "range_noise_std_m": math.sqrt(noise[1, 1]), "bearing_noise_std_rad": math.sqrt(noise[0, 0]),
            "radial_velocity_noise_std_m_s": math.nan if rr is None else math.sqrt(rr[1])}


def _measurement(detection, measurement_model):
    """``(z (2,), R (2, 2), range_rate or None)`` of a detection (:func:`plot_from_detection`)."""
    model = detection.measurement_model if detection.measurement_model is not None else measurement_model
    if model is None:
        raise ValueError("detection has no measurement_model and none was given (measurement_model)")
    if isinstance(model, CartesianToBearingRangeRate):
        raise ValueError("measurement_model CartesianToBearingRangeRate is Stone Soup's 3-D model (a 6-state "
                         "[x, vx, y, vy, z, vz]); for the 4-state [x, vx, y, vy] use CartesianToBearingRangeRate2D")
    if tuple(int(i) for i in model.mapping) != (0, 2):
        raise ValueError(f"measurement_model.mapping must be (0, 2) (x and y of [x, vx, y, vy]), got "
                         f"{tuple(model.mapping)}")
    with_rdot = isinstance(model, CartesianToBearingRangeRate2D)
    n_meas = 3 if with_rdot else 2
    y = np.asarray(detection.state_vector, dtype=np.float64).reshape(-1)
    noise = np.asarray(model.covar(), dtype=np.float64)
    if y.shape != (n_meas,) or not np.isfinite(y).all():
        raise ValueError(f"detection.state_vector must be {n_meas} finite numbers for a {type(model).__name__}, "
                         f"got {y.tolist()}")
    if isinstance(model, (CartesianToBearingRange, CartesianToBearingRangeRate2D)):
        name = type(model).__name__
        if np.any(np.asarray(model.rotation_offset, dtype=np.float64) != 0.0):
            raise ValueError(f"{name}.rotation_offset must be zero (a bearing measured from east), "
                             f"got {np.asarray(model.rotation_offset).ravel().tolist()}")
        if np.any(noise != np.diag(np.diag(noise))):
            raise ValueError(f"{name}.noise_covar must be diagonal (independent bearing, range[ and range-rate] "
                             f"noise, as our converted covariance assumes), got {noise.tolist()}")
        site = np.asarray(model.translation_offset, dtype=np.float64).reshape(-1)[:2]
        bearing = 0.5 * math.pi - y[0]         # Stone Soup's (from east, counter-clockwise) -> ours (from north, cw)
        z = cartesian_from_polar(y[1], bearing, site)
        R = converted_covariance(y[1], bearing, math.sqrt(noise[1, 1]), math.sqrt(noise[0, 0]))
        if not with_rdot:
            return z, R, None
        if tuple(int(i) for i in model.velocity_mapping) != (1, 3):
            raise ValueError(f"{name}.velocity_mapping must be (1, 3) (vx and vy of [x, vx, y, vy]), got "
                             f"{tuple(model.velocity_mapping)}")
        if np.any(np.asarray(model.velocity, dtype=np.float64) != 0.0):
            raise ValueError(f"{name}.velocity must be zero (a stationary site, as our range-rate update assumes), "
                             f"got {np.asarray(model.velocity).ravel().tolist()}")
        return z, R, (float(y[2]), float(noise[2, 2]), float(site[0]), float(site[1]))
    if isinstance(model, LinearGaussian):
        return y, noise, None
    raise ValueError(f"measurement_model must be a CartesianToBearingRange, CartesianToBearingRangeRate2D or "
                     f"LinearGaussian, got {type(model).__name__}")


def polar_detection(range_m, bearing_rad, site_xy_m, range_noise_std_m, bearing_noise_std_rad, t_s,
                    ndim_state=4, radial_velocity_m_s=None, radial_velocity_noise_std_m_s=None) -> Detection:
    """One of our polar plots (bearing ours: clockwise from north) as a Stone Soup ``Detection`` with a
    ``CartesianToBearingRange`` model (Stone Soup's bearing ``pi/2 - ours``, the site as ``translation_offset``);
    with ``radial_velocity_m_s`` (and its noise std) a ``[bearing, range, range rate]`` detection with a
    ``CartesianToBearingRangeRate2D`` model (same sign: positive receding). ``ValueError`` naming the argument for
    a range < 0, a noise std <= 0, or a value that is not a finite number."""
    from radar_env.common.validate import check_number
    try:
        site = np.asarray(site_xy_m, dtype=np.float64).reshape(2)
    except (TypeError, ValueError):
        site = None
    if site is None or not np.all(np.isfinite(site)):
        raise ValueError(f"polar_detection: site_xy_m must be two finite numbers (m), got {site_xy_m!r}")
    site = StateVector(site)
    range_m = check_number("polar_detection: range_m", range_m, 0.0)
    bearing_rad = check_number("polar_detection: bearing_rad", bearing_rad)
    t_s = check_number("polar_detection: t_s", t_s)
    y = [Bearing(0.5 * math.pi - bearing_rad), range_m]
    var = [check_number("polar_detection: bearing_noise_std_rad", bearing_noise_std_rad, 0.0, lo_open=True) ** 2,
           check_number("polar_detection: range_noise_std_m", range_noise_std_m, 0.0, lo_open=True) ** 2]
    if radial_velocity_m_s is None:
        model = CartesianToBearingRange(ndim_state=ndim_state, mapping=(0, 2),
                                        noise_covar=CovarianceMatrix(np.diag(var)), translation_offset=site)
    else:
        if radial_velocity_noise_std_m_s is None:
            raise ValueError("radial_velocity_noise_std_m_s must be given with radial_velocity_m_s")
        y.append(check_number("polar_detection: radial_velocity_m_s", radial_velocity_m_s))
        var.append(check_number("polar_detection: radial_velocity_noise_std_m_s", radial_velocity_noise_std_m_s, 0.0,
                                lo_open=True) ** 2)
        model = CartesianToBearingRangeRate2D(ndim_state=ndim_state, mapping=(0, 2), velocity_mapping=(1, 3),
                                              noise_covar=CovarianceMatrix(np.diag(var)), translation_offset=site)
    return Detection(StateVector(y), timestamp=stamp(t_s), measurement_model=model)


def detections_from_episode(episode, radial_velocity=False):
    """Our episode's plots as Stone Soup detections, one per look: ``[Detection or None]`` (None where missed);
    ``radial_velocity``: with range rate (:func:`polar_detection`) where the look has a finite one with a positive
    noise std (else position only, as our range-rate chain treats such a look)."""
    out = []
    for k in range(episode.n_looks):
        if not episode.detected[k]:
            out.append(None)
            continue
        rd = sd = None
        if radial_velocity:
            rd, sd = float(episode.radial_velocity_m_s[k]), float(episode.radial_velocity_noise_std_m_s[k])
            if not (math.isfinite(rd) and math.isfinite(sd) and sd > 0.0):
                rd = sd = None
        out.append(polar_detection(episode.range_m[k], episode.bearing_rad[k], episode.site_xy_m[k],
                                   episode.range_noise_std_m[k], episode.bearing_noise_std_rad[k], episode.t_s[k],
                                   radial_velocity_m_s=rd, radial_velocity_noise_std_m_s=sd))
    return out


# ------------------------------------------------------------------------------------------------ predictor, updater
def _modes_ours(state):
    xs = np.asarray(state.mode_state_vectors, dtype=np.float64)
    Ps = np.asarray(state.mode_covars, dtype=np.float64)
    return xs[:, _P5], Ps[:, _P5][:, :, _P5]


class IMMCVCTPredictor(Predictor):
    """Stone Soup predictor of ``imm_cv_ct``: mixing and mode-matched prediction (the kernel's first half).

    ``predict(prior, timestamp)`` takes an :class:`IMMCVCTState` (a previous prediction or update) or a plain
    4-state ``GaussianState`` (a new track: started as :meth:`IMMCVCTState.from_gaussian`), returns an
    :class:`IMMCVCTStatePrediction`."""

    transition_model: TransitionModel = Property(
        default=None, doc="Not used (the IMM's modes are its transition model); kept for Stone Soup's Predictor "
                          "interface")
    spec: IMMCVCTSpec = Property(default=None, doc="the IMM's parameters (None: the tuned imm_cv_ct's, "
                                                   "baselines.imm_cv_ct_runner.tuned_imm_cv_ct_spec)")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.spec is None:
            self.spec = _tuned_spec()
        elif not isinstance(self.spec, IMMCVCTSpec):
            raise ValueError(f"IMMCVCTPredictor.spec must be an IMMCVCTSpec, got {type(self.spec).__name__}")

    def predict(self, prior, timestamp=None, **kwargs) -> IMMCVCTStatePrediction:
        """Predict ``prior`` (a state or a track: its last state) to ``timestamp`` (a ``datetime``; ``None`` with a
        prior without one: dt = 0)."""
        if isinstance(prior, StateMutableSequence) and not isinstance(prior, State):
            prior = prior.state     # a Track (Stone Soup's hypothesisers pass the track): its last state
        if not isinstance(prior, IMMCVCTState):
            prior = IMMCVCTState.from_gaussian(prior, self.spec)
        elif prior.spec is not None and prior.spec != self.spec:
            raise ValueError("prior.spec differs from IMMCVCTPredictor.spec: the state was made with other IMM "
                             "parameters")
        dt = prediction_dt(prior.timestamp, timestamp, "the IMM")
        xm, Pm = _modes_ours(prior)
        p = predict_modes(self.spec, xm, Pm, prior.log_mode_probabilities, dt)
        return Prediction.from_state(
            prior, state_vector=StateVector(p.x[SS_FROM_OURS]),
            covar=CovarianceMatrix(p.P[np.ix_(SS_FROM_OURS, SS_FROM_OURS)]),
            timestamp=timestamp if timestamp is not None else prior.timestamp,
            mode_state_vectors=p.x_modes[:, _P5], mode_covars=p.P_modes[:, _P5][:, :, _P5],
            log_mode_probabilities=p.log_c, spec=self.spec, prior=prior, transition_model=None,
            target_type=IMMCVCTStatePrediction)


def check_measurement_model(owner, model):
    """``ValueError`` naming ``owner``'s ``measurement_model`` unless it is None or a Stone Soup measurement model
    (checked when an updater is built: a wrong value would fail only at its first detection)."""
    if model is not None and not isinstance(model, MeasurementModel):
        raise ValueError(f"{owner}.measurement_model must be a Stone Soup MeasurementModel (e.g. "
                         f"CartesianToBearingRangeRate2D) or None, got {type(model).__name__}")


class IMMCVCTUpdater(ExtendedKalmanUpdater):
    """Stone Soup updater of ``imm_cv_ct``: the mode-matched updates with the converted plot (and its range rate,
    for a ``CartesianToBearingRangeRate2D`` detection), the mode probabilities and the combination (the kernel's
    second half), on an :class:`IMMCVCTStatePrediction`.

    :meth:`predict_measurement` is the extended Kalman updater's on the combined Gaussian (for gating and
    association, in the detection's space). The IMM parameters come with the prediction (its ``spec``)."""

    measurement_model: MeasurementModel = Property(
        default=None, doc="used for detections that carry no measurement model: a CartesianToBearingRange[Rate2D] "
                          "or LinearGaussian (plot_from_detection)")
    use_range_rate: bool = Property(
        default=True, doc="update on a detection's range rate when it has one (False: its position only, the "
                          "position-only imm_cv_ct on range-rate detections)")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        check_measurement_model("IMMCVCTUpdater", self.measurement_model)
        if not isinstance(self.use_range_rate, (bool, np.bool_)):     # "no" would be truthy: a range-rate update
            raise ValueError(f"IMMCVCTUpdater.use_range_rate must be True or False, got {self.use_range_rate!r}")

    def update(self, hypothesis, **kwargs) -> IMMCVCTStateUpdate:
        """Update ``hypothesis.prediction`` with ``hypothesis.measurement`` (a ``MissedDetection``: the kernel's
        missed look)."""
        pred = hypothesis.prediction
        if not isinstance(pred, IMMCVCTStatePrediction):
            raise ValueError(f"hypothesis.prediction must be an IMMCVCTStatePrediction (from IMMCVCTPredictor), got "
                             f"{type(pred).__name__}")
        spec = pred.spec_or_tuned
        xm, Pm = _modes_ours(pred)
        if hypothesis:
            z, R, rr = _measurement(hypothesis.measurement, self.measurement_model)
            u = update_modes(spec, xm, Pm, pred.log_mode_probabilities, z, R,
                             range_rate=rr if self.use_range_rate else None)
            when = hypothesis.measurement.timestamp
        else:
            u = update_modes(spec, xm, Pm, pred.log_mode_probabilities)
            when = pred.timestamp
        return Update.from_state(
            pred, state_vector=StateVector(u.x[SS_FROM_OURS]),
            covar=CovarianceMatrix(u.P[np.ix_(SS_FROM_OURS, SS_FROM_OURS)]),
            timestamp=when, mode_state_vectors=u.x_modes[:, _P5], mode_covars=u.P_modes[:, _P5][:, :, _P5],
            log_mode_probabilities=u.log_mu, spec=spec, hypothesis=hypothesis, target_type=IMMCVCTStateUpdate)
