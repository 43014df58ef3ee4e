r"""Stone Soup components for the learned q-policies (``policy_bp``, ``policy_bp_rdot``: a GRU choosing the CV
Kalman filter's process noise q each look, :mod:`agents.policies.recurrent`; ``policy``: the PPO q-policy, a
feed-forward network on four stacked observations, run through its numpy export
:mod:`agents.policies.numpy_policy`): a predictor, an updater and the state types, the track's state carrying the
GRU state (or the stacked frames) and the feature chain.

One look of a q-policy as the evaluation runs it (:func:`baselines.trackers.run_q_policy`) is, from the context
after the previous look (GRU state ``h``, the chain -- a 1-row :class:`radar_env.filters.tracking.Tracker`, the CV
Kalman filter and its features -- its last step's output and that step's q):

1. the observation after the previous look, with the preview of this look's plot
   (:func:`radar_env.filters.tracking.preview_next_plot`, what the chain's step computes when it knows the next
   look), encoded as the env does (:class:`radar_env.envs.observation.ObservationLayout`);
2. the GRU: this look's q (:meth:`agents.policies.recurrent.RecurrentQPolicy.act` and ``q_of_actions``, clipped
   as the runner clips); a stable-baselines3 q-policy (``policy``): its ``choose_q``
   (:func:`agents.policies.loading.model_choose_q`, deterministic actions through the env's action map) on the
   observation stacked with the previous looks' (``frame_stack`` frames newest first, the first look's repeated,
   as :class:`radar_env.envs.observation.FrameStack` stacks them; the frames ride in the context);
3. the chain's step with that q on the plot (:meth:`Tracker.feed`, :meth:`Tracker.step`): the estimate.

Nothing of the chain or the network is written again here: these are the functions the runner calls, and the
pieces of :mod:`agents.policies.stonesoup_learned` (the learned IMM's components, whose look is split the same
way). tests/test_stonesoup_qpolicy.py checks every look of whole episodes against the evaluation's run (estimate
to 1e-6 relative, q to 1e-9).

Stone Soup splits a look into a prediction (before any detection is associated, for gating) and an update. The
q-policy chooses the look's q *after* seeing the look's plot (its preview features), so its prediction depends on
the plot. As for the learned IMM:

* :class:`QPolicyPredictor` predicts with the q the network chooses for a *missed* look (the preview of "no
  plot"): the exact look if the track gets no detection (its missed-look posterior rides along in the prediction,
  so a tracker that keeps the prediction, as Stone Soup's do, continues the runner's track exactly), and the
  Gaussian that hypothesisers gate with (the Kalman prediction with that q; :class:`QPolicyUpdater`'s inherited
  extended-Kalman ``predict_measurement``);
* :class:`QPolicyUpdater` redoes the look with the associated detection (q from the plot's preview, then the
  chain's step): the estimate is the runner's; with a plain ``DistanceHypothesiser`` the gate was that of the
  missed-look q;
* given a detection (``predict(..., measurement=detection)``, :class:`agents.policies.stonesoup_chain.
  PlotAwareHypothesiser`), the predictor runs the look with the q chosen with that plot and returns its Kalman
  prediction, carrying the look's context, which the updater takes for a hypothesis with that detection.

Measurements: polar detections (conventions of :mod:`baselines.stonesoup_components`). The bundled q-policies'
inputs include the plots' range rate (``c_min_g``, ``next_c_min_g``, ``next_los_accel_g``, ``next_rdot_nu``:
:data:`RANGE_RATE_FEATURES`) -- ``policy_bp`` too, whose filter updates on position only -- so they take
``CartesianToBearingRangeRate2D`` detections and refuse a plot without range rate; a q-policy whose inputs read
none of these takes ``CartesianToBearingRange`` detections. Missed looks: the site and noise stds of a
``MissedDetection``'s measurement model if it has one, else the last detection's (they enter the features).

Track start: :func:`q_track_starts` gives our evaluation's (two-hit start and warm-up on an episode's first plots);
:meth:`QPolicyState.from_gaussian` starts from a Stone Soup initiator's Gaussian with an empty feature history
(not what the network was trained with; the first looks' features differ from our start's).
"""

from __future__ import annotations

import copy
from typing import NamedTuple

import numpy as np

from baselines import stonesoup_components as _ss
from baselines.trackers import observation_layout
from radar_env.common.units import G0_M_S2
from radar_env.envs.observation import DETECTOR_FEATURES, ObservationLayout
from radar_env.filters.tracking import StepOutput, Tracker, preview_next_plot

from stonesoup.base import Property
from stonesoup.models.transition.base import TransitionModel
from stonesoup.predictor.base import Predictor
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.prediction import Prediction
from stonesoup.types.state import GaussianState
from stonesoup.types.update import Update
from stonesoup.updater.kalman import ExtendedKalmanUpdater

from agents.policies.recurrent import RecurrentQPolicy
from agents.policies.stonesoup_chain import (_episode_radar, _fresh_chain, _look_row, _missed_look, _radar_of,
                                             _row_of, context_after, gaussian_start, given_plot, plot_look,
                                             prior_context)

__all__ = ["RANGE_RATE_FEATURES", "QPolicy", "load_q_policy", "QPolicyContext", "QPolicyState",
           "QPolicyStatePrediction", "QPolicyStateUpdate", "QPolicyPredictor", "QPolicyUpdater", "q_track_starts",
           "q_policy_pair"]

_SS4 = _ss.SS_FROM_OURS
RANGE_RATE_FEATURES = frozenset({"c_min_g", "next_c_min_g", "next_los_accel_g", "next_rdot_nu"})
"""Observation entries computed from the plots' range rate (NaN without it; tests/test_stonesoup_qpolicy.py checks
that no other entry of the full observation depends on it)."""
_MAX_Q_M_S2 = 100 * G0_M_S2     # run_q_policy's clip of the chosen q


class QPolicy(NamedTuple):
    """A loaded q-policy as these components run it."""

    name: str                   # its tracker name (a bundled name or the folder's label)
    policy: object              # the network: a RecurrentQPolicy, or an SB3 q-policy's choose_q (obs -> q m/s^2)
    env_config: object          # the EnvConfig it was trained with (features, q levels, track start)
    layout: ObservationLayout   # its observation (the runner's, observation_layout(env_config))

    @property
    def recurrent(self) -> bool:
        """A GRU q-policy (a state ``h``); else a stable-baselines3 one (stateless, stacked frames)."""
        return isinstance(self.policy, RecurrentQPolicy)

    def initial_h(self) -> np.ndarray:
        """The network's state at a track start (the GRU's; an empty array for a stateless policy)."""
        return self.policy.initial_state(1)[0] if self.recurrent else np.zeros(0)

    @property
    def needs_range_rate(self) -> bool:
        """Whether its inputs read the plots' range rate (:data:`RANGE_RATE_FEATURES`)."""
        return any(n in RANGE_RATE_FEATURES for n in self.layout.names)


def load_q_policy(name_or_folder="policy_bp") -> QPolicy:
    """A q-policy by bundled name (``policy_bp``, ``policy_bp_rdot``, ``policy``) or folder
    (:func:`agents.policies.learned.load_learned` with a q-policy kind: ``gru_q_policy``, or a stable-baselines3
    one, ``ppo_q_policy`` ..., through its numpy export; a learned IMM is refused there). ``ValueError`` naming the
    field for an env config these components cannot run: a recurrent policy with stacked frames (``frame_stack``)
    or the IMM detector features."""
    from agents.policies.learned import load_learned
    from agents.policies.layout import Q_POLICY_KINDS
    lt = load_learned(name_or_folder, kinds=Q_POLICY_KINDS)
    cfg = lt.env_config
    layout = observation_layout(cfg)[0]
    if lt.kind == "gru_q_policy" and int(cfg.frame_stack) != 1:
        raise ValueError(f"{lt.folder}: env_config frame_stack must be 1 for a recurrent Stone Soup q-policy, got "
                         f"{cfg.frame_stack}")
    if getattr(lt.policy, "turn_aware", False):
        raise ValueError(f"{lt.folder}: a turn-aware q-policy (model 'cv_turn') sets the prediction's turn rate; "
                         "the Stone Soup q-policy components run q-policies only")
    if layout.uses_detectors:
        raise ValueError(f"{lt.folder}: env_config features include IMM detector features "
                         f"({[n for n in layout.names if n in DETECTOR_FEATURES]}); the Stone Soup q-policy does "
                         "not run the detectors")
    return QPolicy(lt.name, lt.policy, cfg, layout)


def _as_q_policy(policy) -> QPolicy:
    """``policy`` if it is a :class:`QPolicy`, else :func:`load_q_policy` of it (a bundled name or folder)."""
    return policy if isinstance(policy, QPolicy) else load_q_policy(policy)


class QPolicyContext(NamedTuple):
    """Everything one look of the q-policy needs from the previous one (our state order; never modified: each look
    makes a new one)."""

    model: QPolicy              # the policy (network, observation layout, chain parameters)
    t_s: float                  # time of the previous look (s since stonesoup_components.EPOCH)
    x: np.ndarray               # (4,) the chain's posterior [x, y, vx, vy]
    P: np.ndarray               # (4, 4)
    h: np.ndarray               # (H,) GRU state
    chain: Tracker              # 1-row chain after the previous look
    chain_out: StepOutput       # its last step's output (1 row)
    q_m_s2: float               # the q of that step (the observation's q_prev; the q the policy chose there)
    radar: tuple                # (site x, site y, range std, bearing std, range-rate std) of the last detection
    frames: np.ndarray = None   # (frame_stack, F) float32: the stacked observation used at that look, newest first
                                # (None at a track start and for a policy without stacking)


def _run_look(ctx: QPolicyContext, look: dict) -> QPolicyContext:
    """One look of the q-policy (module docstring) from ``ctx`` with our look fields ``look``: the new context."""
    m = ctx.model
    if not look["t_s"] - ctx.t_s >= 0.0:
        raise ValueError(f"the look's time {look['t_s']} s is before the track's last look {ctx.t_s} s: the "
                         "q-policy goes forward only")
    prev = preview_next_plot(ctx.chain.x, ctx.chain.P, ctx.chain.t_last,
                             {k: np.asarray(v)[None] for k, v in look.items()})
    obs = m.layout.encode(ctx.chain_out._replace(features={**ctx.chain_out.features, **prev}),
                          np.array([ctx.q_m_s2]))
    frames, k = None, int(m.env_config.frame_stack)
    if k > 1:       # as FrameStack: newest first, the first look's observation repeated (float32)
        new = np.asarray(obs, dtype=np.float32)
        frames = np.repeat(new, k, 0) if ctx.frames is None else np.concatenate([new, ctx.frames[:-1]])
        obs = frames.reshape(1, -1)
    if m.recurrent:
        a, h = m.policy.act(obs, ctx.h[None])
        q, h = m.policy.q_of_actions(a), h[0]
    else:
        q, h = m.policy(obs), ctx.h
    q = float(np.clip(np.asarray(q, dtype=np.float64).reshape(1), 0.0, _MAX_Q_M_S2)[0])
    chain = copy.deepcopy(ctx.chain)
    chain.feed([0], _look_row(look)[None])
    out = _row_of(chain.step(q), 0)
    return QPolicyContext(m, float(look["t_s"]), out.x[0].copy(), out.P[0].copy(), h, chain, out, q,
                          _radar_of(look), frames)


# ------------------------------------------------------------------------------------------------ state types
class QPolicyState(GaussianState):
    """A q-policy posterior: the chain's Gaussian (Stone Soup's order ``[x, vx, y, vy]``) and the
    :class:`QPolicyContext` the next look starts from (the GRU state, the chain)."""

    context: QPolicyContext = Property(default=None, doc="the q-policy's context after this look")

    @property
    def q_m_s2(self) -> float:
        """The process noise q (m/s^2) the policy chose for this look (the warm-up q at a track start)."""
        return self.context.q_m_s2

    @classmethod
    def from_gaussian(cls, state, policy="policy_bp", detection=None):
        """A track started from a Stone Soup Gaussian ``state`` (4-state, a timestamp; e.g. an initiator's):
        ``h = 0``, a fresh chain at the state (empty history; its first output that of a missed look at dt 0).

        Parameters
        ----------
        state : GaussianState
            The start (Stone Soup's order).
        policy : QPolicy or str
            The q-policy (or a bundled name or folder, :func:`load_q_policy`).
        detection : Detection, optional
            A polar detection giving the site and noise stds (default ``state.hypothesis.measurement``, an
            initiator's).
        """
        model = _as_q_policy(policy)
        x4, P4, t, radar = gaussian_start(state, detection, "the q-policy")
        ts = model.env_config.track_start
        chain, out = _fresh_chain(ts, x4, P4, t, radar)
        ctx = QPolicyContext(model, t, x4, P4, model.initial_h(), chain, out, ts.warmup_q_m_s2, radar)
        return _state_from(cls, ctx, state.timestamp)


class QPolicyStatePrediction(Prediction, QPolicyState):
    """The q-policy's prediction with the q for a missed look (module docstring), or, made given a detection
    (``predict(..., measurement=detection)``, the plot-aware gate), with the q chosen with that plot; ``context``
    is the context before the look, ``missed_context`` the one after it if the look is missed (None for a
    prediction made given a detection), ``plot`` that detection and ``plot_context`` the context after the look
    with it (what the updater takes for a hypothesis with that detection)."""

    missed_context: QPolicyContext = Property(default=None, doc="the context after this look if it is missed")
    plot: object = Property(default=None, doc="the detection this prediction was made given (None: a missed look)")
    plot_context: QPolicyContext = Property(default=None, doc="the context after the look with ``plot``")


class QPolicyStateUpdate(Update, QPolicyState):
    """A q-policy posterior after an update (with the hypothesis used)."""


def _state_from(cls, ctx: QPolicyContext, timestamp, **kw):
    """A ``cls`` state of the posterior in ``ctx`` (Stone Soup's order)."""
    return cls(StateVector(ctx.x[_SS4]), CovarianceMatrix(ctx.P[np.ix_(_SS4, _SS4)]), timestamp=timestamp,
               context=ctx, **kw)


def q_track_starts(episodes, policy="policy_bp"):
    """Our evaluation's track start of a q-policy on ``episodes`` (the runner's: two-hit start and warm-up of the
    policy's chain, ``h = 0``).

    Returns
    -------
    states : list of QPolicyState
        One per episode, at its last warm-up look.
    k0 : ndarray (B,)
        Each episode's last warm-up look (the policy's first look is ``k0 + 1``).
    """
    model = _as_q_policy(policy)
    episodes = list(episodes)
    ts = model.env_config.track_start
    tr = ts.tracker(len(episodes))
    out = tr.load(np.arange(len(episodes)), episodes)
    k0 = np.asarray(out.look_index, dtype=np.int64)
    states = []
    for b, e in enumerate(episodes):
        k = int(k0[b])
        ctx = QPolicyContext(model, float(e.t_s[k]), tr.x[b].copy(), tr.P[b].copy(), model.initial_h(),
                             tr.detached(b), _row_of(out, b), ts.warmup_q_m_s2, _episode_radar(e, k))
        states.append(_state_from(QPolicyState, ctx, _ss.stamp(e.t_s[k])))
    return states, k0


# ------------------------------------------------------------------------------------------------ predictor, updater
class QPolicyPredictor(Predictor):
    """Stone Soup predictor of a q-policy: the look with the q the network chooses for a missed look (module
    docstring). ``predict(prior, timestamp)`` takes a :class:`QPolicyState` (an update, a start, or a prediction a
    tracker kept for a missed look: its missed-look posterior), a track, or an initiator's 4-state Gaussian update
    (started with :meth:`QPolicyState.from_gaussian` from its detection)."""

    transition_model: TransitionModel = Property(
        default=None, doc="Not used (the chain's CV model with the chosen q is the transition); Stone Soup's "
                          "interface")
    policy: QPolicy = Property(default=None, doc="the q-policy for tracks it starts (None: the bundled policy_bp); "
                                                 "a QPolicyState carries its own")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.policy is not None and not isinstance(self.policy, QPolicy):
            raise ValueError(f"QPolicyPredictor.policy must be a QPolicy (load_q_policy(name or folder)) or None (the "
                             f"bundled policy_bp), got {self.policy!r}"[:300])

    def _start(self, update):
        if self.policy is None:         # loaded once, when the first track starts from a Gaussian
            self.policy = load_q_policy("policy_bp")
        return QPolicyState.from_gaussian(update, self.policy)

    def predict(self, prior, timestamp=None, measurement=None, **kwargs) -> QPolicyStatePrediction:
        """The look's Kalman prediction with the q for a missed look, or, given a detection ``measurement``
        (Stone Soup's ``predict_with_measurements`` hook, :class:`~agents.policies.stonesoup_chain.
        PlotAwareHypothesiser`), with the q the network chooses with that plot as the preview (the detection needs
        its measurement model)."""
        prior, ctx = prior_context(prior, timestamp, QPolicyState, QPolicyStatePrediction, self._start,
                                   "the q-policy", "q_track_starts")
        t = _ss.seconds(timestamp)
        if given_plot(measurement):
            if measurement.measurement_model is None:
                raise ValueError("measurement must carry its measurement_model (polar) for the plot-aware "
                                 "prediction")
            m = ctx.model
            why = (f"{m.name}'s inputs include {sorted(RANGE_RATE_FEATURES & set(m.layout.names))}"
                   if m.needs_range_rate else None)
            after = _run_look(ctx, plot_look(measurement, t, None, why, "measurement", timestamp))
            kw = dict(missed_context=None, plot=measurement, plot_context=after)
        else:
            after = _run_look(ctx, _missed_look(ctx, t))
            kw = dict(missed_context=after)
        out = after.chain_out      # the look's Kalman prediction, made with the q chosen for it
        return Prediction.from_state(
            prior, state_vector=StateVector(out.x_prior[0][_SS4]),
            covar=CovarianceMatrix(out.P_prior[0][np.ix_(_SS4, _SS4)]), timestamp=timestamp, context=ctx,
            transition_model=None, target_type=QPolicyStatePrediction, **kw)


class QPolicyUpdater(ExtendedKalmanUpdater):
    """Stone Soup updater of a q-policy: the whole look with the associated detection (polar; with range rate if
    the policy reads it, :data:`RANGE_RATE_FEATURES`); a ``MissedDetection``: the missed look (with its measurement
    model's site and stds if it has one). ``predict_measurement``: the extended Kalman updater's on the
    prediction's Gaussian."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        _ss.check_measurement_model("QPolicyUpdater", self.measurement_model)

    def update(self, hypothesis, **kwargs) -> QPolicyStateUpdate:
        pred = hypothesis.prediction
        if not isinstance(pred, QPolicyStatePrediction):
            raise ValueError(f"hypothesis.prediction must be a QPolicyStatePrediction (from QPolicyPredictor), got "
                             f"{type(pred).__name__}")
        m = pred.context.model
        why = (f"{m.name}'s inputs include {sorted(RANGE_RATE_FEATURES & set(m.layout.names))}"
               if m.needs_range_rate else None)
        after = context_after(hypothesis, self.measurement_model, _run_look, why)
        return Update.from_state(
            pred, state_vector=StateVector(after.x[_SS4]), covar=CovarianceMatrix(after.P[np.ix_(_SS4, _SS4)]),
            timestamp=pred.timestamp, context=after, hypothesis=hypothesis, target_type=QPolicyStateUpdate)


def q_policy_pair(policy="policy_bp"):
    """A fresh ``(QPolicyPredictor, QPolicyUpdater)`` of ``policy`` (a :class:`QPolicy`, or a bundled name or
    folder: :func:`load_q_policy`)."""
    return QPolicyPredictor(policy=_as_q_policy(policy)), QPolicyUpdater()
