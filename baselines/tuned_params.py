"""Where the tuned baseline parameters live (``baselines/tuned.json``, written by ``python -m baselines.tuning``),
and the tracker factories that turn a parameter dict into a tracker's specification.

A parameter dict is what ``tuned.json`` stores per tracker (e.g. ``{"q_low_g": ..., "q_high_g": ...,
"p_stay_low": ..., "p_stay_high": ...}`` for ``imm2``); the tuner builds trackers from candidate dicts through the
same factories, so what was tuned is what runs.
"""

from __future__ import annotations

import json
from pathlib import Path

from radar_env.units import G0_M_S2

from . import trackers as T

__all__ = ["TUNED_PATH", "tuned_parameters", "imm2_spec_from_params", "kf_q_m_s2_from_params"]

TUNED_PATH = Path(__file__).with_name("tuned.json")


def tuned_parameters():
    """The tuned parameters (dict) from ``baselines/tuned.json``; ``ValueError`` if the file is missing."""
    if not TUNED_PATH.is_file():
        raise ValueError(f"{TUNED_PATH} is missing; run `python -m baselines.tuning` to create it")
    return json.loads(TUNED_PATH.read_text())


def _get(params, key, who):
    try:
        return float(params[key])
    except KeyError:
        raise ValueError(f"{who}: parameter {key!r} missing from {sorted(params)}") from None


def kf_q_m_s2_from_params(params):
    """The constant-q KF's q (m/s^2) from ``{"q_g": ...}``."""
    return _get(params, "q_g", "kf") * G0_M_S2


def imm2_spec_from_params(params):
    """The 2-mode CV IMM (:class:`baselines.trackers.IMMSpec`) from ``{"q_low_g", "q_high_g", "p_stay_low",
    "p_stay_high"}``: mode noises in g, per-look stay probabilities; starts at mode probabilities (0.9, 0.1)."""
    ql, qh = _get(params, "q_low_g", "imm2"), _get(params, "q_high_g", "imm2")
    sl, sh = _get(params, "p_stay_low", "imm2"), _get(params, "p_stay_high", "imm2")
    return T.IMMSpec(q_m_s2=(ql * G0_M_S2, qh * G0_M_S2), turn_rate_rad_s=(0.0, 0.0),
                     Pi=((sl, 1 - sl), (1 - sh, sh)), mu0=(0.9, 0.1), maneuver_modes=(1,))
