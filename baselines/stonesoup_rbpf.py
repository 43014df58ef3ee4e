r"""Stone Soup components for ``rbpf`` (and ``rbpf_ref``, ``rbpf_rdot``), the Rao-Blackwellised particle filter over
the random flights' regimes (:mod:`radar_env.filters.rbpf`): a predictor, an updater and the state types, the
track's state carrying the particles.

These wrap the compiled filter, not a second copy of it: the batched kernel's row (:func:`radar_env.filters.rbpf.
_row`, what :func:`baselines.rbpf.run_rbpf` runs) is the start of the particles (:func:`~radar_env.filters.rbpf.
_init_row`) and, per look, the prediction half (:func:`~radar_env.filters.rbpf._predict_look`: each particle's regime
moves over ``dt`` with their counter-based draws and its Kalman prediction through them) and the update half
(:func:`~radar_env.filters.rbpf._update_look`: each particle's Kalman update on the plot, the weights, the
combination, systematic resampling when the effective sample size is low). :class:`RBPFPredictor` calls the first,
:class:`RBPFUpdater` the second; one predict and one update equal one look of ``run_rbpf``
(tests/test_stonesoup_rbpf.py checks every look of whole episodes).

The state (:class:`RBPFState`) carries the particles (:class:`RBPFParticles`: each one's 5-state filter
``[x, y, vx, vy, eta]`` in our order, its regime, the time spent in it, its duration's support, the legs left, a
pending turn, its log weight), the row's random-stream key and the look counter: the draws are counter-based
(:func:`radar_env.sim.draws._u01`, counter ``(look, particle, draw)``), so the same key and looks give the runner's
numbers. ``state_vector`` / ``covar`` are the particles' combined Gaussian in Stone Soup's order ``[x, vx, y, vy]``
(what hypothesisers, gaters and metrics read).

Conventions (state order, polar detections, time, gating) are those of :mod:`baselines.stonesoup_components`; the
range-rate filter (``rbpf_rdot``: ``RBPFPredictor(spec=RBPF_RDOT)``) updates on a
``CartesianToBearingRangeRate2D`` detection's range rate (its noise std times ``spec.rdot_noise_scale``, as the
runner), position only for a detection without one.

Missed looks: the runner still runs the update half at a missed look (the weights normalised, resampling). Given a
prediction a tracker kept for a missed look, :class:`RBPFPredictor` first runs that missed update, so the track
continues the runner's exactly; :class:`RBPFUpdater` with a ``MissedDetection`` hypothesis runs it too.

Track start: :func:`rbpf_track_starts` gives our evaluation's (the common track start, the row key of
:func:`baselines.rbpf.episode_key`); :meth:`RBPFState.from_gaussian` starts from a Stone Soup Gaussian (an
initiator's) with a key hashed from it.

Cost: the filter's own (``n_particles`` particles per track and look) plus a copy of the particles at each prediction
and update (a state is never modified in place): with the default 4096, a predict and an update take about 2 ms
together on one core (measured).
"""

from __future__ import annotations

import hashlib
import math
from typing import NamedTuple

import numpy as np

from baselines import stonesoup_components as _ss
from baselines.rbpf import DEFAULT_RBPF, RBPFSpec, episode_key
from radar_env.filters.imm_cv_ct import _moments
from radar_env.filters.kernels import _logsumexp
from radar_env.filters.rbpf import _init_row, _predict_look, _update_look, prior_vector

from stonesoup.base import Property
from stonesoup.models.measurement.base import MeasurementModel
from stonesoup.models.transition.base import TransitionModel
from stonesoup.predictor.base import Predictor
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.prediction import Prediction
from stonesoup.types.state import GaussianState, State, StateMutableSequence
from stonesoup.types.update import Update
from stonesoup.updater.kalman import ExtendedKalmanUpdater

__all__ = ["RBPFParticles", "RBPFState", "RBPFStatePrediction", "RBPFStateUpdate", "RBPFPredictor", "RBPFUpdater",
           "rbpf_track_starts", "rbpf_pair"]

_SS4 = _ss.SS_FROM_OURS


class RBPFParticles(NamedTuple):
    """The particles of one track (our order; never modified once in a state: each step makes new arrays)."""

    x: np.ndarray               # (N, 5) each particle's filter mean [x, y, vx, vy, eta]
    P: np.ndarray               # (N, 5, 5)
    kind: np.ndarray            # (N,) int64 regime (radar_env.filters.rbpf STRAIGHT, TURN, SPEED, BROAD)
    tau: np.ndarray             # (N,) time spent in it (s)
    dlo: np.ndarray             # (N,) its duration's support (s)
    dhi: np.ndarray             # (N,)
    legs: np.ndarray            # (N,) int64 leg ends left (-1: unlimited)
    pend: np.ndarray            # (N,) bool: a turn follows the speed change
    logw: np.ndarray            # (N,) log weights (normalised after an update)

    def copy(self) -> "RBPFParticles":
        return RBPFParticles(*(np.array(a) for a in self))

    @classmethod
    def empty(cls, n) -> "RBPFParticles":
        return cls(np.empty((n, 5)), np.empty((n, 5, 5)), np.empty(n, np.int64), np.empty(n), np.empty(n),
                   np.empty(n), np.empty(n, np.int64), np.zeros(n, np.bool_), np.empty(n))


def _combined(p: RBPFParticles):
    """``(x (4,), P (4, 4), w (N,))``: the particles' moment-matched Gaussian (our order) with normalised weights."""
    w = np.exp(p.logw - _logsumexp(p.logw, p.logw.shape[0]))
    xc, Pc = np.empty(5), np.empty((5, 5))
    _moments(w, p.x, p.P, 4, xc, Pc)
    return xc[:4], Pc[:4, :4], w


# ------------------------------------------------------------------------------------------------ state types
class RBPFState(GaussianState):
    """An ``rbpf`` posterior as a Stone Soup Gaussian: ``state_vector (4, 1)``, ``covar (4, 4)`` the particles'
    combination (Stone Soup's order ``[x, vx, y, vy]``); the particles, the random stream and the look counter
    ride along."""

    particles: RBPFParticles = Property(default=None, doc="the particles (RBPFParticles, our order)")
    key: int = Property(default=0, doc="the track's random-stream key (uint64; the runner's episode_key)")
    look: int = Property(default=0, doc="the look counter of this state (the next prediction draws with look + 1)")
    spec: RBPFSpec = Property(default=None, doc="the filter's settings and prior (None: rbpf's, DEFAULT_RBPF)")
    maneuver_probability: float = Property(default=math.nan, doc="weight of particles off a straight leg (after "
                                                                  "an update; NaN otherwise)")
    turn_rate_rad_s: float = Property(default=math.nan, doc="mean turn rate, straight particles counting 0 (after an "
                                                            "update)")
    ess: float = Property(default=math.nan, doc="effective sample size before resampling (after an update)")

    @property
    def spec_or_default(self) -> RBPFSpec:
        return self.spec if self.spec is not None else DEFAULT_RBPF

    @classmethod
    def from_gaussian(cls, state, spec: RBPFSpec | None = None, key=None, look=0):
        """Every particle's filter at ``state``'s mean and covariance (4-state, Stone Soup's order; ``eta`` 0), on a
        straight leg as the runner starts them (:func:`radar_env.filters.rbpf._init_row`); ``key`` (default: a hash
        of the state's mean, covariance and time) and ``look`` the counter of this start."""
        spec = spec if spec is not None else DEFAULT_RBPF
        x4, P4 = _ss.ours_from_state(state)
        t0 = _ss.seconds(state.timestamp) if state.timestamp is not None else 0.0
        if key is None:
            h = hashlib.blake2b(digest_size=8)
            for a in (x4, P4, np.array([t0])):
                h.update(np.ascontiguousarray(a, dtype=np.float64).tobytes())
            key = int.from_bytes(h.digest(), "little")
        return _start(cls, spec, x4, P4, t0, int(key), int(look), state.timestamp)


class RBPFStatePrediction(Prediction, RBPFState):
    """An ``rbpf`` prediction: the particles after the look's regime moves and Kalman predictions (weights not yet
    normalised), their combination."""


class RBPFStateUpdate(Update, RBPFState):
    """An ``rbpf`` posterior after an update (with the hypothesis used)."""


def _start(cls, spec, x4, P4, t0, key, look, timestamp):
    N = int(spec.n_particles)
    p = RBPFParticles.empty(N)
    _init_row(float(t0), np.ascontiguousarray(x4, dtype=np.float64), np.ascontiguousarray(P4, dtype=np.float64),
              prior_vector(spec), np.uint64(key), int(look), N, *p)
    return cls(StateVector(np.asarray(x4)[_SS4]), CovarianceMatrix(np.asarray(P4)[np.ix_(_SS4, _SS4)]),
               timestamp=timestamp, particles=p, key=key, look=look, spec=spec)


def rbpf_track_starts(episodes, spec: RBPFSpec = DEFAULT_RBPF, cfg=None, start=None):
    """Our evaluation's track start of ``rbpf`` on ``episodes`` (:func:`baselines.rbpf.run_rbpf`'s: the common track
    start, the key :func:`baselines.rbpf.episode_key`): ``(states [RBPFState], k0 (B,))`` with ``k0`` each episode's
    last warm-up look (the filter's first look is ``k0 + 1``); ``start``: a
    :func:`baselines.imm_cv_ct_runner.common_start` result to reuse."""
    from .imm_cv_ct_runner import common_start
    episodes = list(episodes)
    _, k0, x4, P4 = start if start is not None else common_start(episodes, cfg)
    states = [_start(RBPFState, spec, x4[b], P4[b], float(e.t_s[int(k0[b])]), int(episode_key(e)), int(k0[b]),
                     _ss.stamp(e.t_s[int(k0[b])])) for b, e in enumerate(episodes)]
    return states, np.asarray(k0, dtype=np.int64)


# ------------------------------------------------------------------------------------------------ the two halves
def _update_half(state, spec, look=None):
    """The update half (:func:`radar_env.filters.rbpf._update_look`) on a copy of ``state``'s particles;
    ``look``: ``None`` for a missed look, else ``(z, R, range_rate or None)`` (:func:`baselines.
    stonesoup_components.plot_from_detection`). Returns ``(particles, x4, P4, pman, omega, ess)``."""
    p = state.particles.copy()
    N = p.x.shape[0]
    q = RBPFParticles.empty(N)
    xc, Pc = np.empty(5), np.empty((5, 5))
    rdot, sx, sy, var = 0.0, 0.0, 0.0, math.inf
    if look is None:
        det, z, R = False, np.zeros(2), np.zeros((2, 2))
    else:
        det, (z, R, rr) = True, look
        if spec.radial_velocity and rr is not None:
            sd = math.sqrt(rr[1]) * float(spec.rdot_noise_scale)    # range_rate_inputs' variance
            if math.isfinite(rr[0]) and math.isfinite(sd) and sd > 0.0:
                rdot, var, sx, sy = float(rr[0]), sd * sd, float(rr[2]), float(rr[3])
    pman, om, ess, resampled = _update_look(
        int(state.look), det, float(z[0]), float(z[1]), float(R[0, 0]), 0.5 * (float(R[0, 1]) + float(R[1, 0])),
        float(R[1, 1]), rdot, sx, sy, var, np.uint64(state.key), prior_vector(spec), N, *p, *q[:-1], np.empty(N),
        xc, Pc)
    if resampled:
        p = RBPFParticles(*q[:-1], p.logw)
    return p, xc[:4].copy(), Pc[:4, :4].copy(), float(pman), float(om), float(ess)


def _missed_update(pred: "RBPFStatePrediction") -> RBPFState:
    """The runner's missed look on a kept prediction: an :class:`RBPFState` after the update half without a plot."""
    spec = pred.spec_or_default
    p, x4, P4, pman, om, ess = _update_half(pred, spec)
    return RBPFState(StateVector(x4[_SS4]), CovarianceMatrix(P4[np.ix_(_SS4, _SS4)]), timestamp=pred.timestamp,
                     particles=p, key=pred.key, look=pred.look, spec=spec, maneuver_probability=pman,
                     turn_rate_rad_s=om, ess=ess)


# ------------------------------------------------------------------------------------------------ predictor, updater
class RBPFPredictor(Predictor):
    """Stone Soup predictor of ``rbpf``: each particle's regime moves and Kalman prediction over ``dt`` (the
    kernel's prediction half, look counter + 1). ``predict(prior, timestamp)`` takes an :class:`RBPFState` (an
    update or a start), a prediction a tracker kept for a missed look (its missed update first, as the runner), a
    track (its last state), or a plain 4-state ``GaussianState`` (a new track: :meth:`RBPFState.from_gaussian`)."""

    transition_model: TransitionModel = Property(
        default=None, doc="Not used (the particles' regimes are the transition model); Stone Soup's interface")
    spec: RBPFSpec = Property(default=None, doc="the filter's settings (None: rbpf's, DEFAULT_RBPF; RBPF_REF, "
                                                "RBPF_RDOT of baselines.rbpf for the others) for tracks it starts")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.spec is None:
            self.spec = DEFAULT_RBPF
        elif not isinstance(self.spec, RBPFSpec):
            raise ValueError(f"RBPFPredictor.spec must be an RBPFSpec, got {type(self.spec).__name__}")

    def predict(self, prior, timestamp=None, **kwargs) -> RBPFStatePrediction:
        """Predict ``prior`` to ``timestamp`` (a ``datetime``; ``None`` with a prior without one: dt = 0)."""
        if isinstance(prior, StateMutableSequence) and not isinstance(prior, State):
            prior = prior.state
        if isinstance(prior, RBPFStatePrediction):
            prior = _missed_update(prior)
        elif not isinstance(prior, RBPFState):
            prior = RBPFState.from_gaussian(prior, self.spec)
        if prior.spec is not None and prior.spec != self.spec:
            raise ValueError("prior.spec differs from RBPFPredictor.spec: the state was made with other settings")
        dt = _ss.prediction_dt(prior.timestamp, timestamp, "the particle filter")
        spec = prior.spec_or_default
        p = prior.particles.copy()
        look = int(prior.look) + 1
        _predict_look(look, float(dt), np.uint64(prior.key), prior_vector(spec), p.x.shape[0], *p)
        x4, P4, _ = _combined(p)
        return Prediction.from_state(
            prior, state_vector=StateVector(x4[_SS4]), covar=CovarianceMatrix(P4[np.ix_(_SS4, _SS4)]),
            timestamp=timestamp if timestamp is not None else prior.timestamp, particles=p, key=prior.key,
            look=look, spec=spec, maneuver_probability=math.nan, turn_rate_rad_s=math.nan, ess=math.nan,
            prior=prior, transition_model=None, target_type=RBPFStatePrediction)


class RBPFUpdater(ExtendedKalmanUpdater):
    """Stone Soup updater of ``rbpf``: each particle's update with the converted plot (and its range rate with
    ``spec.radial_velocity``), the weights, the combination and resampling (the kernel's update half), on an
    :class:`RBPFStatePrediction`; a ``MissedDetection``: the missed look. :meth:`predict_measurement` is the
    extended Kalman updater's on the combined Gaussian (for gating)."""

    measurement_model: MeasurementModel = Property(
        default=None, doc="used for detections that carry no measurement model: a CartesianToBearingRange[Rate2D] "
                          "or LinearGaussian (plot_from_detection)")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        _ss.check_measurement_model("RBPFUpdater", self.measurement_model)

    def update(self, hypothesis, **kwargs) -> RBPFStateUpdate:
        pred = hypothesis.prediction
        if not isinstance(pred, RBPFStatePrediction):
            raise ValueError(f"hypothesis.prediction must be an RBPFStatePrediction (from RBPFPredictor), got "
                             f"{type(pred).__name__}")
        spec = pred.spec_or_default
        if hypothesis:
            look = _ss._measurement(hypothesis.measurement, self.measurement_model)
            when = hypothesis.measurement.timestamp
        else:
            look, when = None, pred.timestamp
        p, x4, P4, pman, om, ess = _update_half(pred, spec, look)
        return Update.from_state(
            pred, state_vector=StateVector(x4[_SS4]), covar=CovarianceMatrix(P4[np.ix_(_SS4, _SS4)]),
            timestamp=when, particles=p, key=pred.key, look=pred.look, spec=spec, maneuver_probability=pman,
            turn_rate_rad_s=om, ess=ess, hypothesis=hypothesis, target_type=RBPFStateUpdate)


def rbpf_pair(spec: RBPFSpec | None = None):
    """A fresh ``(RBPFPredictor, RBPFUpdater)`` of ``spec`` (default ``rbpf``'s)."""
    return RBPFPredictor(spec=spec), RBPFUpdater()
