r"""Stone Soup components for the learned IMMs (``policy_imm_bp``, :mod:`agents.policies.learned_imm`, and
``policy_imm_ppo``, the stable-baselines3 one, :class:`SB3IMMModel`): a predictor, an updater and the state types,
the track's state carrying the network's recurrent state and the feature chain.

One look of the learned IMM (:func:`baselines.imm_cv_ct_runner.run_imm_lockstep`) is, from the context after the
previous look (IMM modes, GRU state ``h``, the IMM's detectors, the feature chain -- a 1-row
:class:`radar_env.filters.tracking.Tracker` at the checkpoint's constant q -- and its last step's output):

1. the observation after the previous look, with the preview of this look's plot
   (:func:`radar_env.filters.tracking.preview_next_plot`, what the chain's step computes when it knows the next
   look), encoded as the env does;
2. the GRU and its head: this look's IMM parameters (:meth:`agents.policies.learned_imm.LearnedIMM.offsets`,
   :class:`~agents.policies.learned_imm.ParamMap`); for ``policy_imm_ppo`` the feed-forward network's
   deterministic action on the observation and the clipped detectors, through the env's action map
   (:func:`agents.policies.loading.model_run_imm`'s ``choose``; :meth:`SB3IMMModel.parameters`);
3. the IMM's look with them (:func:`radar_env.filters.imm_cv_ct.predict_modes` with ``params``, then
   :func:`~radar_env.filters.imm_cv_ct.update_modes`) and its detectors;
4. the feature chain's step on the plot (:meth:`Tracker.feed`, :meth:`Tracker.step`).

Nothing of the chain or the network is written again here: these are the functions the runner calls.
tests/test_stonesoup_learned.py checks every look of whole episodes against ``LearnedIMM.run`` and
``policy_imm_ppo``'s run (:class:`agents.policies.loading.SB3LearnedIMM`) (1e-6 relative).

Stone Soup splits a look into a prediction (before any detection is associated, for gating) and an update. The
learned IMM sets the look's parameters *after* seeing the look's plot (the preview, as an IMM weighs its modes with
the plot), so its prediction depends on the plot. Here:

* :class:`LearnedIMMPredictor` predicts with the parameters the network chooses for a *missed* look (the preview
  of "no plot"): the exact look if the track gets no detection (its missed-look posterior rides along in the
  prediction, so a tracker that keeps the prediction, as Stone Soup's do, continues the runner's track exactly),
  and the Gaussian that hypothesisers gate with (in the detection's space, :meth:`LearnedIMMUpdater`'s inherited
  extended-Kalman ``predict_measurement``);
* :class:`LearnedIMMUpdater` redoes the whole look with the associated detection (parameters from the plot's
  preview, mixing, prediction, update): the estimate is the runner's; with a plain ``DistanceHypothesiser`` the
  gate was that of the missed-look parameters (the same mixing, a different process noise);
* given a detection (``predict(..., measurement=detection)``, Stone Soup's ``predict_with_measurements`` hook,
  :class:`agents.policies.stonesoup_chain.PlotAwareHypothesiser`), the predictor runs the look with the
  parameters chosen with that plot and returns that prediction, carrying the look's context after the plot,
  which the updater takes as it is for a hypothesis with that detection: the plot-aware gate.

Measurements: polar detections with range rate (:class:`~stonesoup.models.measurement.nonlinear.
CartesianToBearingRangeRate2D`, conventions of :mod:`baselines.stonesoup_components`): ``policy_imm_bp``'s inputs
include the plots' range rate (c_min, line-of-sight acceleration, range-rate innovation); a plot without it is
refused. Missed looks: the site and noise stds of a ``MissedDetection``'s measurement model if it has one, else
the last detection's (they enter the features: range, position-variance ratio).

Missed looks in a gated tracker: ``LearnedIMMPredictor(missed_parameters="tuned")`` (``learned_pair(model,
"tuned")``) predicts a missed look with the IMM spec's tuned constants instead of the network's choice (the GRU
still steps): in training a miss is a random non-detection, in a gated tracker often a plot gated out at a maneuver,
and the network's tight coast then loses the target (docs/stonesoup.md, "Why the learned IMM lost targets in the
example"). The default (``"network"``) is the runner's look, exact against the evaluation.

Track start: :func:`track_starts` gives our evaluation's (two-hit start and warm-up on an episode's first plots,
as the runner); :meth:`LearnedIMMState.from_gaussian` starts from a Stone Soup initiator's Gaussian with an empty
feature history (not what the network was trained with; the first looks' features differ from our start's).
"""

from __future__ import annotations

import copy
import math
from pathlib import Path
from typing import NamedTuple

import numpy as np

from baselines import stonesoup_components as _ss
from radar_env.filters.imm_cv_ct import (detector_inputs, initial_detectors, initial_modes, predict_modes,
                                         update_modes)
from radar_env.filters.tracking import StepOutput, Tracker, preview_next_plot

from stonesoup.base import Property
from stonesoup.models.transition.base import TransitionModel
from stonesoup.predictor.base import Predictor
from stonesoup.types.array import CovarianceMatrix, StateVector
from stonesoup.types.prediction import Prediction
from stonesoup.types.update import Update
from stonesoup.updater.kalman import ExtendedKalmanUpdater

from agents.policies.learned_imm import LearnedIMM, load_learned_imm, BUNDLED_LEARNED_IMM
# the chain helpers it shares with stonesoup_qpolicy
from agents.policies.stonesoup_chain import (_episode_radar, _fresh_chain, _look_row, _missed_look,  # noqa: F401
                                             _radar_of, _row_of, PlotAwareHypothesiser, context_after,
                                             gaussian_start, given_plot, plot_look, prior_context)

__all__ = ["LearnedIMMContext", "LearnedIMMState", "LearnedIMMStatePrediction", "LearnedIMMStateUpdate",
           "LearnedIMMPredictor", "LearnedIMMUpdater", "track_starts", "bundled_learned_imm", "learned_pair",
           "SB3IMMModel", "load_imm_model"]

_P5 = np.array([0, 2, 1, 3, 4])
_SS4 = _ss.SS_FROM_OURS


def bundled_learned_imm() -> LearnedIMM:
    """The bundled ``policy_imm_bp`` checkpoint (:data:`agents.policies.learned_imm.BUNDLED_LEARNED_IMM`)."""
    return load_learned_imm(BUNDLED_LEARNED_IMM)


class SB3IMMModel:
    """A stable-baselines3 learned IMM (``policy_imm_ppo``: a model trained on ``RadarTrack-v0`` with
    ``tracker="imm_cv_ct"``, :class:`agents.policies.loading.SB3LearnedIMM`) with what these components read of a
    :class:`~agents.policies.learned_imm.LearnedIMM`: ``spec``, ``cfg``, ``layout``, ``feature_q_m_s2``, ``arch``
    (no recurrent state: ``hidden_size`` 0), and :meth:`parameters`, the runner's choice
    (:func:`agents.policies.loading.model_run_imm`)."""

    def __init__(self, sb3, name="policy_imm_ppo"):
        from radar_env.envs.imm_env import feature_q_m_s2, imm_action_map, imm_spec
        from baselines.trackers import observation_layout
        self.name, self.sb3, self.cfg = name, sb3, sb3.cfg
        self.spec = imm_spec(self.cfg)
        self.amap = imm_action_map(self.cfg, self.spec)
        self.feature_q_m_s2 = feature_q_m_s2(self.cfg)
        self.layout = observation_layout(self.cfg)[0]
        self.arch = {"hidden_size": 0}

    def parameters(self, obs, detectors):
        """This look's IMM parameters ``(n_par,)`` from the observation ``obs (1, F)`` and the detectors
        ``(M + 2,)``: the model's deterministic action through the env's action map, as the runner chooses."""
        from radar_env.envs.imm_env import detector_observation
        act, _ = self.sb3.model.predict(np.concatenate([obs, detector_observation(detectors[None])], 1),
                                        deterministic=True)
        return self.amap.parameters(np.asarray(act).reshape(1, self.amap.n_par))[0]

    def run(self, episodes, name=None):
        """The evaluation's run (:meth:`agents.policies.loading.SB3LearnedIMM.run`)."""
        return self.sb3.run(episodes, name or self.name)


def load_imm_model(name_or_folder="policy_imm_bp"):
    """A learned IMM by bundled name (``policy_imm_bp``, ``policy_imm_bp_rdot``, ``policy_imm_bp_prior``,
    ``policy_imm_ppo``) or folder (:func:`agents.policies.learned.load_learned` with a learned-IMM kind): a
    :class:`~agents.policies.learned_imm.LearnedIMM`, or an :class:`SB3IMMModel` for a stable-baselines3 one (its
    numpy export; nothing unpickled)."""
    from agents.policies.learned import IMM_KINDS, load_learned
    lt = load_learned(name_or_folder, kinds=IMM_KINDS)
    return lt.policy if isinstance(lt.policy, LearnedIMM) else SB3IMMModel(lt.policy, lt.name)


def _look_parameters(m, obs, detectors, h):
    """``(params (n_par,), h)``: this look's IMM parameters chosen by ``m`` (a LearnedIMM: the GRU and its head;
    an :class:`SB3IMMModel`: its action, no state)."""
    if isinstance(m, LearnedIMM):
        delta, h = m.offsets(np.concatenate([obs.astype(np.float64), detectors[None]], 1), h[None])
        return m.pmap.physical(delta)[0], h[0]
    return m.parameters(obs, detectors), h


class LearnedIMMContext(NamedTuple):
    """Everything one look of the learned IMM needs from the previous one (our state order; never modified: each
    look makes a new one)."""

    model: LearnedIMM           # the checkpoint (network, IMM spec, observation layout, chain parameters; or an
                                # SB3IMMModel)
    t_s: float                  # time of the previous look (s since stonesoup_components.EPOCH)
    x: np.ndarray               # (4,) the IMM's combined posterior [x, y, vx, vy]
    P: np.ndarray               # (4, 4)
    x_modes: np.ndarray         # (M, 5) IMM posterior modes [x, y, vx, vy, omega]
    P_modes: np.ndarray         # (M, 5, 5)
    log_mu: np.ndarray          # (M,)
    h: np.ndarray               # (H,) GRU state
    detectors: np.ndarray       # (M + 2,) the IMM's detectors after the previous look
    chain: Tracker              # 1-row feature chain after the previous look
    chain_out: StepOutput       # its last step's output (1 row)
    q_prev_m_s2: float          # the q of that step (the observation's q_prev)
    radar: tuple                # (site x, site y, range std, bearing std, range-rate std) of the last detection
    missed_parameters: str = "network"  # a missed look's IMM parameters: the network's ("network", the runner's)
                                        # or the spec's tuned constants ("tuned"; the GRU still steps)


def _run_look(ctx: LearnedIMMContext, look: dict):
    """One look of the learned IMM (module docstring) from ``ctx`` with our look fields ``look``: ``(the IMM's
    prediction (ModePrediction), its update (ModeUpdate), the new context)``."""
    m = ctx.model
    dt = look["t_s"] - ctx.t_s
    if not dt >= 0.0:
        raise ValueError(f"the look's time {look['t_s']} s is before the track's last look {ctx.t_s} s: the learned "
                         "IMM goes forward only")
    det = bool(look["detected"])
    nxt = {k: np.asarray(v)[None] for k, v in look.items()}
    prev = preview_next_plot(ctx.chain.x, ctx.chain.P, ctx.chain.t_last, nxt)
    out = ctx.chain_out._replace(features={**ctx.chain_out.features, **prev})
    obs = m.layout.encode(out, np.array([ctx.q_prev_m_s2]))
    params, h = _look_parameters(m, obs, ctx.detectors, ctx.h)
    if not det and ctx.missed_parameters == "tuned":
        params = None        # the spec's constant (tuned) parameters; the GRU state still steps as the runner's
    pred = predict_modes(m.spec, ctx.x_modes, ctx.P_modes, ctx.log_mu, dt, params)
    rr = None
    if det and m.cfg.track_start.radial_velocity:
        rr = (look["radial_velocity_m_s"], look["radial_velocity_noise_std_m_s"] ** 2, *look["site_xy_m"])
    up = update_modes(m.spec, pred.x_modes, pred.P_modes, pred.log_c, look["z_m"] if det else None,
                      look["R_m2"] if det else None, range_rate=rr)
    detectors = detector_inputs(up.mu[None], np.array([up.omega_rad_s]), np.array([math.sqrt(up.omega_var)]))[0]
    chain = copy.deepcopy(ctx.chain)
    chain.feed([0], _look_row(look)[None])
    chain_out = _row_of(chain.step(m.feature_q_m_s2), 0)
    new = LearnedIMMContext(m, float(look["t_s"]), up.x, up.P, up.x_modes, up.P_modes, up.log_mu, h, detectors,
                            chain, chain_out, m.feature_q_m_s2, _radar_of(look), ctx.missed_parameters)
    return pred, up, new


# ------------------------------------------------------------------------------------------------ state types
class LearnedIMMState(_ss.IMMCVCTState):
    """A learned-IMM posterior: the IMM's combined Gaussian and modes as :class:`baselines.stonesoup_components.
    IMMCVCTState` (Stone Soup's order), and the :class:`LearnedIMMContext` the next look starts from (the GRU
    state, the detectors, the feature chain)."""

    context: LearnedIMMContext = Property(default=None, doc="the learned IMM's context after this look")

    @classmethod
    def from_gaussian(cls, state, model: LearnedIMM | None = None, detection=None):
        """A track started from a Stone Soup Gaussian ``state`` (4-state, a timestamp; e.g. an initiator's): the
        IMM's modes as :meth:`IMMCVCTState.from_gaussian`, ``h = 0``, the start detectors, a fresh feature chain
        at the state (empty history; its first output that of a missed look at dt 0). ``detection``: a polar
        detection giving the site and noise stds (default ``state.hypothesis.measurement``, an initiator's)."""
        model = model if model is not None else bundled_learned_imm()
        x4, P4, t, radar = gaussian_start(state, detection, "the learned IMM")
        chain, out = _fresh_chain(model.cfg.track_start, x4, P4, t, radar)
        start = LearnedIMMContext(model, t, x4, P4, *initial_modes(model.spec, x4, P4),
                                  np.zeros(model.arch["hidden_size"]), initial_detectors(model.spec, 1)[0], chain, out,
                                  model.cfg.track_start.warmup_q_m_s2, radar)
        return _state_from(cls, start, state.timestamp)


class LearnedIMMStatePrediction(Prediction, LearnedIMMState):
    """The learned IMM's prediction with the parameters for a missed look (module docstring), or, made given a
    detection (``predict(..., measurement=detection)``, the plot-aware gate), with the parameters chosen with that
    plot; ``context`` is the context before the look, ``missed_context`` the one after it if the look is missed
    (None for a prediction made given a detection), ``plot`` that detection and ``plot_context`` the context after
    the look with it (what the updater takes for a hypothesis with that detection)."""

    missed_context: LearnedIMMContext = Property(default=None, doc="the context after this look if it is missed")
    plot: object = Property(default=None, doc="the detection this prediction was made given (None: a missed look)")
    plot_context: LearnedIMMContext = Property(default=None, doc="the context after the look with ``plot``")


class LearnedIMMStateUpdate(Update, LearnedIMMState):
    """A learned-IMM posterior after an update (with the hypothesis used)."""


def _state_from(cls, ctx: LearnedIMMContext, timestamp, **kw):
    """A ``cls`` state of the posterior in ``ctx`` (Stone Soup's order)."""
    return cls(StateVector(ctx.x[_SS4]), CovarianceMatrix(ctx.P[np.ix_(_SS4, _SS4)]), timestamp=timestamp,
               mode_state_vectors=ctx.x_modes[:, _P5], mode_covars=ctx.P_modes[:, _P5][:, :, _P5],
               log_mode_probabilities=ctx.log_mu, spec=ctx.model.spec, context=ctx, **kw)


def track_starts(episodes, model: LearnedIMM | None = None):
    """Our evaluation's track start of the learned IMM on ``episodes`` (the runner's: two-hit start and warm-up of
    the checkpoint's chain, every IMM mode at the warm-up estimate): ``(states [LearnedIMMState], k0 (B,))`` with
    ``k0`` each episode's last warm-up look (the learned IMM's first look is ``k0 + 1``)."""
    model = model if model is not None else bundled_learned_imm()
    episodes = list(episodes)
    B = len(episodes)
    tr = model.cfg.track_start.tracker(B)
    out = tr.load(np.arange(B), episodes)
    k0 = np.asarray(out.look_index, dtype=np.int64)
    states = []
    for b, e in enumerate(episodes):
        xm, Pm, log_mu = initial_modes(model.spec, tr.x[b], tr.P[b])     # as run_imm_lockstep's _start_state
        k = int(k0[b])
        ctx = LearnedIMMContext(model, float(e.t_s[k]), tr.x[b].copy(), tr.P[b].copy(), xm, Pm, log_mu,
                                np.zeros(model.arch["hidden_size"]), initial_detectors(model.spec, 1)[0],
                                tr.detached(b), _row_of(out, b), model.cfg.track_start.warmup_q_m_s2,
                                _episode_radar(e, k))
        states.append(_state_from(LearnedIMMState, ctx, _ss.stamp(e.t_s[k])))
    return states, k0


# ------------------------------------------------------------------------------------------------ predictor, updater
class LearnedIMMPredictor(Predictor):
    """Stone Soup predictor of the learned IMM: the look with the network's parameters for a missed look (module
    docstring). ``predict(prior, timestamp)`` takes a :class:`LearnedIMMState` (an update, a start, or a
    prediction a tracker kept for a missed look: its missed-look posterior), a track, or an initiator's 4-state
    Gaussian update (started with :meth:`LearnedIMMState.from_gaussian` from its detection)."""

    transition_model: TransitionModel = Property(
        default=None, doc="Not used (the learned IMM's modes are its transition model); Stone Soup's interface")
    model: LearnedIMM = Property(default=None, doc="the checkpoint for tracks it starts (None: the bundled "
                                                    "policy_imm_bp); a LearnedIMMState carries its own")
    missed_parameters: str = Property(
        default="network", doc="a missed look's IMM parameters: 'network' (the network's choice, the runner's: exact "
                               "against the evaluation) or 'tuned' (the IMM spec's constant, tuned parameters, the "
                               "GRU state still stepping; for gated trackers, where a missed look is often a plot "
                               "gated out at a maneuver, which the network never saw in training)")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        if self.missed_parameters not in ("network", "tuned"):
            raise ValueError(f"missed_parameters must be 'network' or 'tuned', got {self.missed_parameters!r}")
        if self.model is not None and not isinstance(self.model, (LearnedIMM, SB3IMMModel)):
            raise ValueError(f"LearnedIMMPredictor.model must be a learned IMM (load_imm_model(name or folder)) or "
                             f"None (the bundled policy_imm_bp), got {type(self.model).__name__}")

    def _start(self, update):
        if self.model is None:          # loaded once, when the first track starts from a Gaussian
            self.model = bundled_learned_imm()
        return LearnedIMMState.from_gaussian(update, self.model)

    def predict(self, prior, timestamp=None, measurement=None, **kwargs) -> LearnedIMMStatePrediction:
        """The look's prediction with the parameters for a missed look, or, given a detection ``measurement``
        (Stone Soup's ``predict_with_measurements`` hook, :class:`PlotAwareHypothesiser`), with the parameters
        the network chooses with that plot as the preview (the detection needs its measurement model, with range
        rate)."""
        prior, ctx = prior_context(prior, timestamp, LearnedIMMState, LearnedIMMStatePrediction, self._start,
                                   "the learned IMM", "track_starts")
        t = _ss.seconds(timestamp)
        if ctx.missed_parameters != self.missed_parameters:     # this predictor's choice for the looks it runs
            ctx = ctx._replace(missed_parameters=self.missed_parameters)
        if given_plot(measurement):
            if measurement.measurement_model is None:
                raise ValueError("measurement must carry its measurement_model (polar, with range rate) for the "
                                 "plot-aware prediction")
            look = plot_look(measurement, t, None, "the learned IMM's inputs include it", "measurement", timestamp)
            pred, up, after = _run_look(ctx, look)
            kw = dict(missed_context=None, plot=measurement, plot_context=after)
        else:
            pred, up, after = _run_look(ctx, _missed_look(ctx, t))
            kw = dict(missed_context=after)
        return Prediction.from_state(
            prior, state_vector=StateVector(pred.x[_SS4]), covar=CovarianceMatrix(pred.P[np.ix_(_SS4, _SS4)]),
            timestamp=timestamp, mode_state_vectors=pred.x_modes[:, _P5], mode_covars=pred.P_modes[:, _P5][:, :, _P5],
            log_mode_probabilities=pred.log_c, spec=ctx.model.spec, context=ctx, transition_model=None,
            target_type=LearnedIMMStatePrediction, **kw)


class LearnedIMMUpdater(ExtendedKalmanUpdater):
    """Stone Soup updater of the learned IMM: the whole look with the associated detection (a polar detection with
    range rate); a ``MissedDetection``: the missed look (with its measurement model's site and stds if it has
    one). ``predict_measurement``: the extended Kalman updater's on the prediction's combined Gaussian."""

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        _ss.check_measurement_model("LearnedIMMUpdater", self.measurement_model)

    def update(self, hypothesis, **kwargs) -> LearnedIMMStateUpdate:
        pred = hypothesis.prediction
        if not isinstance(pred, LearnedIMMStatePrediction):
            raise ValueError(f"hypothesis.prediction must be a LearnedIMMStatePrediction (from LearnedIMMPredictor), "
                             f"got {type(pred).__name__}")
        after = context_after(hypothesis, self.measurement_model, lambda ctx, look: _run_look(ctx, look)[2],
                              "the learned IMM's inputs include it")
        return Update.from_state(
            pred, state_vector=StateVector(after.x[_SS4]), covar=CovarianceMatrix(after.P[np.ix_(_SS4, _SS4)]),
            timestamp=pred.timestamp, mode_state_vectors=after.x_modes[:, _P5],
            mode_covars=after.P_modes[:, _P5][:, :, _P5], log_mode_probabilities=after.log_mu, spec=after.model.spec,
            context=after, hypothesis=hypothesis, target_type=LearnedIMMStateUpdate)


# ------------------------------------------------------------------------------------------------ the example
FIGURE = Path(__file__).resolve().parents[2] / "docs" / "figures" / "stonesoup_multitarget_learned.png"
GATES = ["plot"]
"""The learned trackers' gates the example runs by default: ``"plot"`` (:class:`PlotAwareHypothesiser`),
``"missed"`` (``DistanceHypothesiser`` on the missed-look prediction); ``--gate-plot`` / ``--gate-missed`` choose,
both given: both run (columns suffixed with the gate)."""


def learned_pair(model: LearnedIMM | None = None, missed_parameters="network"):
    """A fresh ``(LearnedIMMPredictor, LearnedIMMUpdater)`` of ``model`` (default the bundled ``policy_imm_bp``);
    ``missed_parameters``: :attr:`LearnedIMMPredictor.missed_parameters`."""
    return (LearnedIMMPredictor(model=model if model is not None else bundled_learned_imm(),
                                missed_parameters=missed_parameters), LearnedIMMUpdater())


def main(argv=None):
    """``python -m agents.policies.stonesoup_learned``: :mod:`baselines.stonesoup_example` with range rate, the
    learned IMM (``policy_imm_bp``) and the learned q-policy (``policy_bp``, :mod:`agents.policies.stonesoup_qpolicy`)
    added, gated with :class:`PlotAwareHypothesiser` (:data:`GATES`); the same options, plus ``--gate-plot`` and
    ``--gate-missed`` (the plain ``DistanceHypothesiser`` on the missed-look prediction; both given: both run, the
    columns named with the gate). The learned IMM runs twice: with the network's parameters on missed looks (the
    evaluation's learned IMM) and with the tuned constants there (``(tuned coast)``,
    ``learned_pair(model, "tuned")``)."""
    from baselines import stonesoup_example
    from agents.policies.stonesoup_qpolicy import load_q_policy, q_policy_pair
    argv = list(argv if argv is not None else __import__("sys").argv[1:])
    if "--range-rate" not in argv:
        argv.append("--range-rate")        # the learned trackers read the range rate
    gates = {"plot": ("plot-aware", PlotAwareHypothesiser), "missed": ("missed-look", None)}
    chosen = []
    for g in ("plot", "missed"):
        if f"--gate-{g}" in argv:
            argv.remove(f"--gate-{g}")
            chosen.append(g)
    chosen = chosen or GATES
    model, q_policy = bundled_learned_imm(), load_q_policy("policy_bp")
    extra = {}
    for g in chosen:
        suffix = "" if len(chosen) == 1 else f" ({gates[g][0]} gate)"
        hyp = gates[g][1]
        extra[f"policy_imm_bp{suffix}"] = lambda hyp=hyp: (*learned_pair(model), *([hyp] if hyp else []))
        extra[f"policy_imm_bp (tuned coast){suffix}"] = lambda hyp=hyp: (*learned_pair(model, "tuned"),
                                                                        *([hyp] if hyp else []))
        extra[f"policy_bp{suffix}"] = lambda hyp=hyp: (*q_policy_pair(q_policy), *([hyp] if hyp else []))
    return stonesoup_example.main(argv, extra=extra, prog="python -m agents.policies.stonesoup_learned",
                                  figure_path=FIGURE)


if __name__ == "__main__":
    main()
