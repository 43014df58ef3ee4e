"""The feature chain of a learned tracker as a Stone Soup track carries it: a 1-row
:class:`radar_env.filters.tracking.Tracker` fed plots as they come, in our look fields (the helpers that
:mod:`agents.policies.stonesoup_learned` and :mod:`agents.policies.stonesoup_qpolicy` share; no Stone Soup import,
so those two modules do not import each other)."""

from __future__ import annotations

import math
from typing import NamedTuple

import numpy as np

from radar_env.filters.tracking import StepOutput
from radar_env.sim.looks import LOOK_COLUMNS, W_LOOK


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
