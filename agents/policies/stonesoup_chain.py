"""What the Stone Soup components of the learned trackers share (:mod:`agents.policies.stonesoup_learned`, the
learned IMM, and :mod:`agents.policies.stonesoup_qpolicy`, the q-policies; here so that those two do not import
each other): the feature chain a track carries (a 1-row :class:`radar_env.filters.tracking.Tracker` fed plots as
they come, in our look fields), and the steps of a look that do not depend on the tracker: the context a prediction
starts from (:func:`prior_context`), a start from a Stone Soup Gaussian (:func:`gaussian_start`) and the context
after an update (:func:`context_after`); the plot-aware gate (:class:`PlotAwareHypothesiser`, the look's prediction
made given each detection, :func:`plot_look`)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from baselines import stonesoup_components as _ss
from radar_env.filters.tracking import StepOutput
from radar_env.sim.looks import LOOK_COLUMNS, W_LOOK

from stonesoup.base import Property
from stonesoup.hypothesiser.distance import DistanceHypothesiser
from stonesoup.types.detection import MissedDetection
from stonesoup.types.state import State, StateMutableSequence


def _row_of(out: StepOutput, b) -> StepOutput:
    """Row ``b`` of a StepOutput (copies, shape (1, ...))."""
    def take(v):
        return None if v is None else np.array(v[b:b + 1])
    return out._replace(**{f: take(getattr(out, f)) for f in out._fields if f != "features"},
                        features={k: np.array(v[b:b + 1]) for k, v in out.features.items()})


def _look_row(look) -> np.ndarray:
    """Our look fields (dict) as a packed look row (W_LOOK,); truth unknown (NaN)."""
    row = np.full(W_LOOK, np.nan)
    for f, (c, tail) in LOOK_COLUMNS.items():
        w = int(np.prod(tail)) if tail else 1
        if f in look:
            row[c:c + w] = np.asarray(look[f], dtype=np.float64).reshape(w)
    row[LOOK_COLUMNS["maneuvering"][0]] = 0.0
    return row


def _missed_look(ctx, t_s, detection=None) -> dict:
    """Our look fields of a missed look at ``t_s``: the site and stds of ``detection``'s (a MissedDetection's)
    polar model if it has one, else the last detection's (``ctx.radar``; any context with one)."""
    sx, sy, rs, bs, rds = ctx.radar
    model = getattr(detection, "measurement_model", None)
    if model is not None:
        noise = np.asarray(model.covar(), dtype=np.float64)
        site = np.asarray(model.translation_offset, dtype=np.float64).reshape(-1)
        sx, sy, bs, rs = float(site[0]), float(site[1]), math.sqrt(noise[0, 0]), math.sqrt(noise[1, 1])
        rds = math.sqrt(noise[2, 2]) if noise.shape[0] == 3 else rds
    return {"t_s": t_s, "detected": False, "z_m": np.zeros(2), "R_m2": np.eye(2), "site_xy_m": np.array([sx, sy]),
            "range_m": math.nan, "bearing_rad": math.nan, "radial_velocity_m_s": math.nan,
            "range_noise_std_m": rs, "bearing_noise_std_rad": bs, "radial_velocity_noise_std_m_s": rds}


def _radar_of(look: dict) -> tuple:
    """``(site x, site y, range std, bearing std, range-rate std)`` of our look fields (a context's ``radar``)."""
    return tuple(float(v) for v in (*look["site_xy_m"], look["range_noise_std_m"], look["bearing_noise_std_rad"],
                                    look["radial_velocity_noise_std_m_s"]))


def _episode_radar(e, k) -> tuple:
    """The ``radar`` tuple (:func:`_radar_of`) of look ``k`` of episode ``e``."""
    return tuple(float(v) for v in (*e.site_xy_m[k], e.range_noise_std_m[k], e.bearing_noise_std_rad[k],
                                    e.radial_velocity_noise_std_m_s[k]))


class _Radar(NamedTuple):
    radar: tuple


def _fresh_chain(track_start, x4, P4, t_s, radar):
    """A 1-row feature chain of ``track_start`` at the posterior ``x4, P4`` (our order) at ``t_s`` with an empty
    history, and its first output (1 row): a missed look at dt 0 with the warm-up q (the site and stds ``radar``),
    so that a track started from a Stone Soup Gaussian has a chain output to read its first observation from."""
    chain = track_start.tracker(1)
    chain.x[0], chain.P[0], chain.t_last[0] = x4, P4, t_s
    chain.bank.reset(x=np.asarray(x4)[None], t_s=np.array([t_s]))
    chain.feed([0], _look_row(_missed_look(_Radar(radar), t_s))[None])
    return chain, _row_of(chain.step(track_start.warmup_q_m_s2), 0)


def prior_context(prior, timestamp, state_type, prediction_type, start, what, starts):
    """``(prior state, context)``: the context a learned tracker's look starts from, for ``predict(prior,
    timestamp)``: a prediction kept for a missed look (``prediction_type``) gives its missed-look context, a
    ``state_type`` its context, a track its last state's, and an initiator's Gaussian update with its detection the
    context of the state ``start(prior)`` makes. ``what`` names the tracker, ``starts`` its track-start function,
    in the one-line errors."""
    if isinstance(prior, StateMutableSequence) and not isinstance(prior, State):
        prior = prior.state
    if isinstance(prior, prediction_type):
        ctx = prior.missed_context
        if ctx is None:
            raise ValueError(f"prior is a {prediction_type.__name__} made given a detection (predict(..., "
                             "measurement=...)): it cannot be kept for a missed look; keep the missed "
                             "hypothesis' prediction (made without one)")
    elif isinstance(prior, state_type):
        ctx = prior.context
    elif getattr(getattr(prior, "hypothesis", None), "measurement", None) is not None:
        ctx = start(prior).context
    else:
        raise ValueError(f"prior must be a {state_type.__name__} (start one with {starts} or "
                         f"{state_type.__name__}.from_gaussian) or an initiator's Gaussian update with its "
                         f"detection, got {type(prior).__name__}")
    if timestamp is None:
        raise ValueError(f"timestamp must be a datetime ({what}'s chain needs times)")
    return prior, ctx


def gaussian_start(state, detection, what):
    """``(x4, P4, t_s, radar)`` of a track started from a Stone Soup Gaussian ``state`` (our order, seconds, the
    site and noise stds of ``detection``, default ``state.hypothesis.measurement``, an initiator's); one-line
    errors naming the argument (``what`` names the tracker)."""
    if state.timestamp is None:
        raise ValueError(f"state.timestamp must be a datetime ({what}'s chain needs times)")
    if detection is None:
        detection = getattr(getattr(state, "hypothesis", None), "measurement", None)
    if detection is None or getattr(detection, "measurement_model", None) is None:
        raise ValueError("detection must be given (a polar detection: the site and noise stds) when state has "
                         "no hypothesis.measurement")
    x4, P4 = _ss.ours_from_state(state)
    return x4, P4, _ss.seconds(state.timestamp), _radar_of(_ss.look_from_detection(detection))


def plot_look(detection, t_s, measurement_model=None, range_rate_needed=None, what="hypothesis.measurement",
              when=None) -> dict:
    """Our look fields of ``detection`` at a look at ``t_s`` (its own measurement model, else
    ``measurement_model``): one-line errors naming ``what`` if it has no range rate and ``range_rate_needed`` (why
    the tracker needs it) is given, or if its time is not ``t_s`` (``when``: that time as a datetime)."""
    look = _ss.look_from_detection(detection, measurement_model)
    if range_rate_needed and not math.isfinite(look["radial_velocity_m_s"]):
        raise ValueError(f"{what} must carry a range rate (CartesianToBearingRangeRate2D): {range_rate_needed}")
    if look["t_s"] != t_s:
        raise ValueError(f"{what}.timestamp {detection.timestamp} differs from the prediction's {when}")
    return look


def given_plot(measurement) -> bool:
    """Whether ``predict(..., measurement=...)`` was given a detection (not None, not a ``MissedDetection``)."""
    return measurement is not None and not isinstance(measurement, MissedDetection)


class PlotAwareHypothesiser(DistanceHypothesiser):
    """Stone Soup's :class:`~stonesoup.hypothesiser.distance.DistanceHypothesiser` with
    ``predict_with_measurements`` on (its own hook: the predictor is called with ``measurement=detection`` for each
    detection), for the learned trackers' predictors, whose look's parameters depend on the look's plot: each
    (track, detection) pair is scored with the prediction the network makes *given that detection* (the look's
    parameters chosen with that plot as the preview, then the prediction and ``predict_measurement`` with them),
    and its hypothesis carries that prediction (and the look's context after that plot, which the updater takes
    as it is: the update is the single-target run's). The missed-detection hypothesis keeps the prediction made
    without a detection (the missed look's parameters). The associator is unchanged."""

    predict_with_measurements: bool = Property(
        default=True, doc="Pass each detection to the predictor (the plot-aware gate); False: the missed-look gate "
                          "of DistanceHypothesiser")

    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)
        d = self.missed_distance
        if isinstance(d, bool) or not isinstance(d, (int, float, np.number)) or math.isnan(d) or d < 0:
            raise ValueError(f"PlotAwareHypothesiser.missed_distance must be a number >= 0 (inf allowed), got {d!r}")
        for name, method in (("predictor", "predict"), ("updater", "update")):
            if not callable(getattr(getattr(self, name), method, None)):
                raise ValueError(f"PlotAwareHypothesiser.{name} must be a Stone Soup {name} (e.g. "
                                 f"LearnedIMM{name.capitalize()}), got {type(getattr(self, name)).__name__}")


def context_after(hypothesis, measurement_model, run, range_rate_needed=None):
    """The context after the look of ``hypothesis`` (its prediction carries the context before it): with a
    detection, ``run(context, look)`` on the detection's look (``measurement_model``: the updater's, for a
    detection without one); a ``MissedDetection`` with a polar model, ``run`` on a missed look at its site and
    stds; without one, the prediction's missed-look context. ``range_rate_needed``: why the tracker needs the
    plot's range rate (then a detection without it is refused), or None."""
    pred = hypothesis.prediction
    ctx, t = pred.context, _ss.seconds(pred.timestamp)
    if hypothesis:
        if getattr(pred, "plot", None) is not None and pred.plot is hypothesis.measurement:
            return pred.plot_context        # the look given this plot, run by the predictor (plot-aware gate)
        return run(ctx, plot_look(hypothesis.measurement, t, measurement_model, range_rate_needed,
                                  "hypothesis.measurement", pred.timestamp))
    if getattr(hypothesis.measurement, "measurement_model", None) is not None:
        return run(ctx, _missed_look(ctx, t, hypothesis.measurement))
    return pred.missed_context
