"""Comparison trackers by stable name: ``run_tracker(name, episodes) -> TrackRun``.

Names (the evaluation's ``--trackers``): ``imm2`` (tuned 2-mode IMM), ``imm2_bizup``, ``imm3_ct``, ``kf_tuned``,
``kf_low`` (0.03 g), ``kf_high`` (2 g), ``kf_blair``, ``cmin``, ``ckf``, ``reinit``, ``kim_lee``, ``alpha_beta``,
``alpha_beta_adaptive``, ``adrian1``, ``adrian2``, ``konle``, ``clairvoyant``, ``oracle_q``, ``imm2_grid`` (``imm2``
as tuned by the earlier grid search), ``imm_cv_ct`` (the mixed-order CV / CT-EKF IMM, :mod:`baselines.imm_cv_ct_runner`),
``imm_ct_bank`` (the same IMM over a bank of six CT modes entered at three tuned turn rates, right and left),
``kf_tuned_rdot``, ``imm2_rdot``, ``imm_cv_ct_rdot``, ``imm_ct_bank_rdot`` (the same four also updating on each
plot's radial velocity, tuned on their own: :func:`radar_env.filters.kernels._rdot_update`),
``rbpf`` (the particle filter over the random flights' regimes, :mod:`baselines.rbpf`) and ``rbpf_ref`` (the same
knowing the flight's start: the causal reference on ``random``), ``rbpf_rdot`` (``rbpf`` also updating on the radial
velocity),
``hindsight_q``, ``hindsight_q_turn`` (the hindsight bounds, :mod:`baselines.hindsight`: seconds per episode, so
in no default list). ``policy`` (a learned policy), ``policy_bp`` (the bundled policy trained by backpropagation)
``policy_imm_bp`` and ``policy_imm_ppo`` (the bundled learned IMMs, by backpropagation and by PPO), ``policy_bp_rdot``
and ``policy_imm_bp_rdot`` (``policy_bp``'s and ``policy_imm_bp``'s recipes on the range-rate filter),
``policy_imm_bp_prior`` and ``policy_bp_prior`` (``policy_imm_bp``'s recipe and a wider ``policy_bp`` trained on the
random suites' own flights) and ``policy_window`` (``policy_bp_prior`` with a learned window correction of its
reported position) are resolved by the evaluation, which owns the model loading (:data:`POLICY_TRACKERS`). User
trackers are added by :func:`register_tracker` (:mod:`baselines.user_trackers`); :func:`tracker_names` lists all.

Tuned values (``kf_tuned``'s q, ``imm2``'s mode noises and transition probabilities) are read from
``baselines/tuned.json``, written by ``python -m baselines.tuning`` on training seeds only.
"""

from __future__ import annotations

import re

import numpy as np

from . import trackers as T
from .imm_cv_ct_runner import run_imm_cv_ct, tuned_imm_cv_ct_spec
from .policies import make_policy
from .rbpf import RBPF_RDOT, RBPF_REF, run_rbpf
from .trackers import imm2_spec_from_params
from .tuned_params import TUNED_PATH, kf_q_m_s2_from_params, tuned_parameters
from .user_trackers import batch_runner, per_episode_runner

__all__ = ["TRACKER_NAMES", "BOUND_TRACKERS", "RANGE_RATE_TRACKERS", "POLICY_TRACKERS", "DESIGN_ENVELOPES",
           "run_tracker", "tuned_parameters", "tuned_imm2_spec", "TUNED_PATH",
           "register_tracker", "tracker_names"]


def tuned_imm2_spec(key="imm2"):
    """The tuned 2-mode IMM (``key`` ``"imm2"``, ``"imm2_rdot"``, or ``"imm2_grid"``: the earlier grid search's) from
    tuned.json."""
    return imm2_spec_from_params(tuned_parameters()[key])


def _kf_rdot(episodes, cfg):
    """``kf_tuned_rdot``: the constant-q KF also updating on the radial velocity, at its own tuned q."""
    q = kf_q_m_s2_from_params(tuned_parameters()["kf_rdot"])
    return T.run_q_policy(episodes, lambda o: np.full(o.shape[0], q), "kf_tuned_rdot",
                          T._with_range_rate(cfg, True), features=())


def _policy_run(name):
    """A reference policy (:func:`baselines.policies.make_policy`) run through the tracking chain, observing only
    the features its rule reads (the same values as in the full observation)."""
    def run(episodes, cfg):
        layout, lv = T.observation_layout(cfg)
        reads = make_policy(name, layout, "continuous", lv).reads     # checked against the full observation
        pol = make_policy(name, T.observation_layout(cfg, reads)[0] if reads else layout, "continuous", lv)
        return T.run_q_policy(episodes, pol.q_m_s2, name=name, cfg=cfg, declare=getattr(pol, "declared", None),
                              features=reads)
    return run


def _hindsight():
    from . import hindsight   # imports numba; only when a hindsight bound is asked for
    return hindsight


_RUNNERS = {
    "imm2": lambda eps, cfg: T.run_imm(eps, tuned_imm2_spec(), "imm2", cfg),
    "imm2_grid": lambda eps, cfg: T.run_imm(eps, tuned_imm2_spec("imm2_grid"), "imm2_grid", cfg),
    "imm2_bizup": lambda eps, cfg: T.run_imm(eps, T.IMM2_BIZUP, "imm2_bizup", cfg),
    "imm3_ct": lambda eps, cfg: T.run_imm(eps, T.IMM3_CT, "imm3_ct", cfg),
    "imm_cv_ct": lambda eps, cfg: run_imm_cv_ct(eps, tuned_imm_cv_ct_spec(), "imm_cv_ct", cfg),
    "imm_ct_bank": lambda eps, cfg: run_imm_cv_ct(eps, tuned_imm_cv_ct_spec("imm_ct_bank"), "imm_ct_bank", cfg),
    "kf_tuned_rdot": _kf_rdot,
    "imm2_rdot": lambda eps, cfg: T.run_imm(eps, tuned_imm2_spec("imm2_rdot"), "imm2_rdot", cfg,
                                            radial_velocity=True),
    "imm_cv_ct_rdot": lambda eps, cfg: run_imm_cv_ct(eps, tuned_imm_cv_ct_spec("imm_cv_ct_rdot"), "imm_cv_ct_rdot",
                                                     cfg, radial_velocity=True),
    "imm_ct_bank_rdot": lambda eps, cfg: run_imm_cv_ct(eps, tuned_imm_cv_ct_spec("imm_ct_bank_rdot"),
                                                       "imm_ct_bank_rdot", cfg, radial_velocity=True),
    "rbpf": lambda eps, cfg: run_rbpf(eps, name="rbpf", cfg=cfg),
    "rbpf_ref": lambda eps, cfg: run_rbpf(eps, RBPF_REF, name="rbpf_ref", cfg=cfg),
    "rbpf_rdot": lambda eps, cfg: run_rbpf(eps, RBPF_RDOT, name="rbpf_rdot", cfg=cfg),
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

POLICY_TRACKERS = ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo", "policy_bp_rdot", "policy_imm_bp_rdot",
                   "policy_imm_bp_prior", "policy_bp_prior", "policy_window")
"""Tracker names of learned policies, each run by the evaluation from its file: a q-policy through
:func:`baselines.trackers.run_q_policy`, a learned IMM or a window correction by its own ``run``."""

TRACKER_NAMES = POLICY_TRACKERS + tuple(_RUNNERS)
"""The built-in tracker names (user trackers: :func:`tracker_names`)."""

_USER = set()
_NAME_RE = re.compile(r"[A-Za-z][A-Za-z0-9_\-]{0,63}")


def register_tracker(name, fn, overwrite=False, batch=False):
    """Put a user tracker into the comparison under ``name`` (see :mod:`baselines.user_trackers`).

    Args:
        name: 1-64 characters, a letter then letters, digits, ``_`` or ``-`` (no commas: ``--trackers`` splits on
            them); not a built-in tracker's name.
        fn: a per-episode :class:`baselines.user_trackers.UserTracker` ``fn(looks, start) -> (x, P)``, or with
            ``batch=True`` a batch tracker ``fn(episodes, cfg) -> TrackRun``.
        overwrite: replace a user tracker registered earlier under ``name`` (a built-in is never replaced).
    Raises ``ValueError`` for a bad name, a name taken (built-in, or user without ``overwrite``), a non-callable."""
    if not isinstance(name, str) or not _NAME_RE.fullmatch(name):
        raise ValueError(f"register_tracker: name must be 1-64 characters, a letter then letters, digits, '_' or "
                         f"'-', got {name!r}")
    if name in TRACKER_NAMES:
        raise ValueError(f"register_tracker: {name!r} is a built-in tracker's name; choose another "
                         f"(built-ins: {list(TRACKER_NAMES)})")
    for flag, v in (("overwrite", overwrite), ("batch", batch)):
        if not isinstance(v, (bool, np.bool_)):       # "no" is truthy: it would replace, or run as a batch tracker
            raise ValueError(f"register_tracker: {flag} must be True or False, got {v!r}")
    if name in _USER and not overwrite:
        raise ValueError(f"register_tracker: a user tracker named {name!r} is already registered; pass "
                         "overwrite=True to replace it")
    if not callable(fn):
        raise ValueError(f"register_tracker: fn must be callable, got {type(fn).__name__}")
    _RUNNERS[name] = batch_runner(name, fn) if batch else per_episode_runner(name, fn)
    _USER.add(name)


def tracker_names():
    """Every tracker name :func:`run_tracker` and ``--trackers`` accept: the built-ins, then user trackers."""
    return POLICY_TRACKERS + tuple(_RUNNERS)

RANGE_RATE_TRACKERS = ("kf_tuned_rdot", "imm2_rdot", "imm_cv_ct_rdot", "imm_ct_bank_rdot", "rbpf_rdot")
"""The classical trackers that also update on each plot's radial velocity (a learned tracker does when its env
config has ``radial_velocity``)."""

BOUND_TRACKERS = ("clairvoyant", "oracle_q", "hindsight_q", "hindsight_q_turn")
"""Trackers that see the truth (its acceleration, or the whole episode): reference bounds, not causal trackers. A
bound worse than a real tracker on a suite is flagged by the evaluation (it bounds nothing there: e.g. the known
input of ``clairvoyant`` is no help when the track is lost on a radar far outside the filter's assumptions)."""

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


def run_tracker(name, episodes, cfg=None):
    """Run comparison tracker ``name`` on ``episodes`` (list of :class:`radar_env.sim.episode.Episode`). ``cfg``: the
    track start and observation (an env config or a :class:`radar_env.filters.tracking.TrackStart`; default the env's
    defaults), see :mod:`baselines.trackers`."""
    if not isinstance(name, str) or name not in _RUNNERS:
        raise ValueError(f"unknown tracker {name!r}; valid: {list(tracker_names())}")
    from radar_env.sim.episode import Episode
    given = episodes
    try:
        episodes = list(episodes)
    except TypeError:
        episodes = None
    if not episodes or not all(isinstance(e, Episode) for e in episodes):
        raise ValueError(f"run_tracker: episodes must be a non-empty list of radar_env.sim.episode.Episode (e.g. "
                         f"agents.evaluation.suites.draw_suite(...)), got {type(given).__name__}"
                         + ("" if not episodes else f" of {sorted({type(e).__name__ for e in episodes})}"))
    return _RUNNERS[name](episodes, cfg)
