"""Comparison trackers by stable name: ``run_tracker(name, episodes) -> TrackRun``.

Names (the evaluation's ``--trackers``): ``imm2`` (tuned 2-mode IMM), ``imm2_bizup``, ``imm3_ct``, ``kf_tuned``,
``kf_low`` (0.03 g), ``kf_high`` (2 g), ``kf_blair``, ``cmin``, ``ckf``, ``reinit``, ``kim_lee``, ``alpha_beta``,
``alpha_beta_adaptive``, ``adrian1``, ``adrian2``, ``konle``, ``clairvoyant``, ``oracle_q``, ``hindsight_q``,
``hindsight_q_turn`` (the hindsight bounds, :mod:`baselines.hindsight`: seconds per episode, so in no default list).
``policy`` (a learned policy) is resolved by the evaluation, which owns the model loading.

Tuned values (``kf_tuned``'s q, ``imm2``'s mode noises and transition probabilities) are read from
``baselines/tuned.json``, written by ``python -m baselines.tuning`` on training seeds only.
"""

from __future__ import annotations

import numpy as np

from radar_env.env import EnvConfig
from radar_env.observation import ObservationLayout
from radar_env.units import G0_M_S2

from . import trackers as T
from .policies import make_policy
from .tuned_params import TUNED_PATH, tuned_parameters

__all__ = ["TRACKER_NAMES", "DESIGN_ENVELOPES", "run_tracker", "tuned_parameters", "tuned_imm2_spec", "TUNED_PATH"]

def tuned_imm2_spec():
    p = tuned_parameters()["imm2"]
    stay_low, stay_high = p["p_stay_low"], p["p_stay_high"]
    return T.IMMSpec(q_m_s2=(p["q_low_g"] * G0_M_S2, p["q_high_g"] * G0_M_S2), turn_rate_rad_s=(0.0, 0.0),
                     Pi=((stay_low, 1 - stay_low), (1 - stay_high, stay_high)), mu0=(0.9, 0.1),
                     maneuver_modes=(1,))


def _layout(cfg):
    lv = np.asarray(cfg.q_levels_g) * G0_M_S2
    return ObservationLayout(cfg.features, lv[0], lv[-1]), lv


def _policy_run(name):
    """A reference policy (:func:`baselines.policies.make_policy`) run through the tracking chain."""
    def run(episodes, cfg):
        layout, lv = _layout(cfg)
        pol = make_policy(name, layout, "continuous", lv)
        return T.run_q_policy(episodes, pol.q_m_s2, name=name, cfg=cfg, declare=getattr(pol, "declared", None))
    return run


def _hindsight():
    from . import hindsight   # imports numba; only when a hindsight bound is asked for
    return hindsight


_RUNNERS = {
    "imm2": lambda eps, cfg: T.run_imm(eps, tuned_imm2_spec(), "imm2", cfg),
    "imm2_bizup": lambda eps, cfg: T.run_imm(eps, T.IMM2_BIZUP, "imm2_bizup", cfg),
    "imm3_ct": lambda eps, cfg: T.run_imm(eps, T.IMM3_CT, "imm3_ct", cfg),
    "kf_tuned": _policy_run("kf_tuned"),
    "kf_low": _policy_run("kf_low"),
    "kf_high": _policy_run("kf_high"),
    "kf_blair": _policy_run("kf_blair"),
    "cmin": _policy_run("cmin"),
    "ckf": _policy_run("ckf"),
    "kim_lee": _policy_run("kim_lee"),
    "reinit": lambda eps, cfg: T.run_reinit(eps, cfg=cfg),
    "adrian1": lambda eps, cfg: T.run_turn_rate_kf(eps, 1, cfg=cfg),
    "adrian2": lambda eps, cfg: T.run_turn_rate_kf(eps, 2, cfg=cfg),
    "alpha_beta": lambda eps, cfg: T.run_alpha_beta_tracker(eps, False, cfg=cfg),
    "alpha_beta_adaptive": lambda eps, cfg: T.run_alpha_beta_tracker(eps, True, cfg=cfg),
    "konle": lambda eps, cfg: T.run_konle_tracker(eps, cfg=cfg),
    "clairvoyant": lambda eps, cfg: T.run_clairvoyant(eps, cfg=cfg),
    "oracle_q": lambda eps, cfg: T.run_oracle_q(eps, cfg=cfg),
    "hindsight_q": lambda eps, cfg: _hindsight().run_hindsight_q(eps, cfg=cfg),
    "hindsight_q_turn": lambda eps, cfg: _hindsight().run_hindsight_q_turn(eps, cfg=cfg),
}

TRACKER_NAMES = ("policy",) + tuple(_RUNNERS)

DESIGN_ENVELOPES = {
    "alpha_beta": "Kalata gains assume a constant scan period; with irregular or two-site looks each gap gets the "
                  "steady-state gain of its own period (baselines/alpha_beta.py)",
    "alpha_beta_adaptive": "as alpha_beta, and the 12-look fudge-factor window assumes one scan period "
                           "(baselines/alpha_beta.py)",
    "konle": "the differential EKF assumes plot noise small against the chord v*dt between plots; far outside it "
             "(e.g. 1 deg at 250 km, 0.5 s) it is stable but poor (baselines/konle.py)",
}
"""Trackers used outside the conditions their papers designed them for on some suites: the evaluation tables
print these notes beside them, so a poor number is read as what it is."""


def run_tracker(name, episodes, cfg: EnvConfig | None = None):
    """Run comparison tracker ``name`` on ``episodes`` (list of :class:`radar_env.episode.Episode`)."""
    if name not in _RUNNERS:
        raise ValueError(f"unknown tracker {name!r}; valid: {list(TRACKER_NAMES)}")
    return _RUNNERS[name](list(episodes), cfg or EnvConfig())
