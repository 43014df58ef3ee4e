"""Where the tuned baseline parameters live (``baselines/tuned.json``, written by ``python -m baselines.tuning``).

A parameter dict is what ``tuned.json`` stores per tracker (e.g. ``{"q_low_g": ..., "q_high_g": ...,
"p_stay_low": ..., "p_stay_high": ...}`` for ``imm2``); the tuner builds trackers from candidate dicts through the
same factories, so what was tuned is what runs.
"""

from __future__ import annotations

import json
from pathlib import Path

from radar_env.common.units import G0_M_S2

__all__ = ["TUNED_PATH", "tuned_parameters", "param", "kf_q_m_s2_from_params"]

TUNED_PATH = Path(__file__).with_name("tuned.json")


def tuned_parameters():
    """The tuned parameters (dict) from ``baselines/tuned.json``; ``ValueError`` if the file is missing."""
    if not TUNED_PATH.is_file():
        raise ValueError(f"{TUNED_PATH} is missing; run `python -m baselines.tuning` to create it")
    return json.loads(TUNED_PATH.read_text())


def param(params, key, who):
    """``float(params[key])``; a ``ValueError`` naming the tracker ``who`` and the keys present if it is missing."""
    try:
        return float(params[key])
    except KeyError:
        raise ValueError(f"{who}: parameter {key!r} missing from {sorted(params)}") from None


def kf_q_m_s2_from_params(params):
    """The constant-q KF's q (m/s^2) from ``{"q_g": ...}``."""
    return param(params, "q_g", "kf") * G0_M_S2
