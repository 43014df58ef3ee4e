r"""RadarTrack-v0 with ``tracker="imm_cv_ct"``: the agent sets the CV / CT-EKF IMM's per-look parameters (no
Gymnasium needed). This module: the arguments, the action map, the detectors' observation and the compiled step;
the batched core that runs them beside the env's chain is :mod:`radar_env.envs.imm_core`.

The filter is :mod:`radar_env.filters.imm_cv_ct`'s IMM (a CV mode, a CT-EKF mode with the turn rate in its state, a
high-noise CV mode); the action is its per-look parameter vector (:func:`radar_env.filters.imm_cv_ct.look_parameter_names`:
``q_cv_g``, ``q_ct_g``, ``sigma_omega_deg_s15``, ``p_stay_cv``, ``p_stay_ct``, ``q_high_g``, ``p_stay_high``). Per
step of a row (look ``k``), as ``agents.policies.learned_imm.LearnedIMM.run`` runs it::

    action a (n_par,) -> parameters p_k (IMMActionMap) -> IMM look k with p_k (radar_env.filters.imm_cv_ct._look)
        -> estimate, covariance, mode probabilities mu, turn rate omega and its std
    the env's CV chain at the constant q feature_q_g (radar_env.filters.kernels, the env's own step) -> the features
    observation = [the env's features after look k (incl. the preview of plot k+1), detectors(mu, omega, std)]
    reward and track loss = the env's terms (radar_env.envs.env_kernels._reward_terms) on the IMM's estimate

Action map (:class:`IMMActionMap`), per parameter with range ``[lo, hi]`` (:data:`radar_env.filters.imm_cv_ct.IMM_CV_CT_PARAMS`)
and base value ``v0`` (the a = 0 point: ``imm_cv_ct``'s tuned value): piecewise linear in ``s = log p`` (noises) or
``s = logit p`` (stay probabilities), ``s(-1) = s(lo)``, ``s(0) = s(v0)``, ``s(+1) = s(hi)``, computed as
``p = v0 exp(d)`` (log) or ``p = v0 e^d / ((1 - v0) + v0 e^d)`` (logit) with ``d = s(a) - s(v0)``, so a = 0 gives
``v0`` exactly; then clipped to ``[lo, hi]`` (only rounding reaches beyond). A discrete action ``i`` in
``[0, L-1]`` is ``a = (2 i - (L - 1)) / (L - 1)`` (L odd: the middle level is ``v0``).

The defaults (``radar_env/data/imm_cv_ct_env.json``): ``imm_cv_ct``'s tuned parameters and ``kf``'s tuned q
(``baselines/tuned.json``; copied, so that radar_env reads nothing of baselines; tests/test_env_imm.py checks the
copy), so the zero action is the ``imm_cv_ct`` tracker bit for bit in its arithmetic (tested to 1e-9).
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
from numba import njit

from . import env_kernels as _ek
from ..filters import kernels as _k
from ..filters.imm_cv_ct import (IMM_CT_BANK_PARAMS, IMM_CV_CT_PARAMS, _init_modes, _look_predict, _look_range_rate,
                                 _look_update, _work, imm_cv_ct_spec_from_params, look_parameter_names,
                                 look_parameter_vector)
from ..common.units import DEG, G0_M_S2
from ..common.validate import check_number

__all__ = ["IMM_ENV_DEFAULTS_PATH", "DEFAULT_IMM_ACTION_LEVELS", "imm_env_defaults", "imm_spec", "feature_q_m_s2",
           "imm_action_map", "IMMActionMap", "detector_bounds", "detector_observation", "check_imm_config"]

IMM_ENV_DEFAULTS_PATH = Path(__file__).parents[1] / "data" / "imm_cv_ct_env.json"
DEFAULT_IMM_ACTION_LEVELS = 5
"""Levels per parameter of ``action_type="discrete"`` (``imm_action_levels``)."""



def detector_bounds(n_modes):
    """``(low, high)`` float32 of the detector entries: mode probabilities in [0, 1], turn rate / 20 deg/s in
    [-1, 1] (the IMM bounds it at 20 deg/s), log10(its std in deg/s) / 3 in [-1, 1] (1e-3 to 1e3 deg/s)."""
    return (np.array([0.0] * n_modes + [-1.0, -1.0], dtype=np.float32),
            np.array([1.0] * n_modes + [1.0, 1.0], dtype=np.float32))


def detector_observation(detectors):
    """The observation's detector entries: :func:`radar_env.filters.imm_cv_ct.detector_inputs` ``(n, M + 2)`` clipped to
    :func:`detector_bounds`, float32."""
    lo, hi = detector_bounds(detectors.shape[1] - 2)
    return np.clip(detectors, lo, hi).astype(np.float32)

M_LOG, M_BASE, M_NEG, M_POS, M_LO, M_HI = range(6)
W_MAP = 6


def imm_env_defaults():
    """``{"imm_parameters": {name: value}, "feature_q_g": q}`` of ``radar_env/data/imm_cv_ct_env.json``."""
    d = json.loads(IMM_ENV_DEFAULTS_PATH.read_text())
    return {"imm_parameters": dict(d["imm_parameters"]), "feature_q_g": float(d["feature_q_g"])}


def imm_spec(cfg):
    """The :class:`radar_env.filters.imm_cv_ct.IMMCVCTSpec` of an env config: the defaults' parameters, updated by
    ``cfg.imm_parameters``."""
    return imm_cv_ct_spec_from_params({**imm_env_defaults()["imm_parameters"], **dict(cfg.imm_parameters or {})})


def feature_q_m_s2(cfg):
    """The q (m/s^2) of the feature chain: ``cfg.feature_q_g`` or the default's."""
    q = imm_env_defaults()["feature_q_g"] if cfg.feature_q_g is None else cfg.feature_q_g
    return float(q) * G0_M_S2


def mode_parameter_columns(spec):
    """``(q_of, stay_of)`` (M,) int64: the column of :func:`radar_env.filters.imm_cv_ct.look_parameter_names` that
    gives each mode's q and stay probability (the CV mode's, every CT mode's, the high-noise mode's), as
    ``kernel_parameters`` builds them."""
    names = look_parameter_names(spec)
    i = {n: j for j, n in enumerate(names)}
    kinds = ["cv"] + ["ct"] * spec.n_ct + (["high"] if spec.q_high_g is not None else [])
    return (np.array([i[f"q_{m}_g"] for m in kinds], dtype=np.int64),
            np.array([i[f"p_stay_{m}"] for m in kinds], dtype=np.int64))


def imm_action_map(cfg, spec=None):
    """The :class:`IMMActionMap` of an env config (``spec``: its :func:`imm_spec`, if already built)."""
    return IMMActionMap(spec or imm_spec(cfg), cfg.action_type == "discrete",
                        cfg.imm_action_levels or DEFAULT_IMM_ACTION_LEVELS)


def check_imm_config(cfg, p="RadarTrack-v0: "):
    """The refusals of ``tracker="imm_cv_ct"`` (``ValueError`` naming the argument)."""
    from .observation import DETECTOR_FEATURES
    det = [f for f in cfg.features if f in DETECTOR_FEATURES]
    if det:
        raise ValueError(f"{p}features {det} apply only with tracker='cv' (with tracker='imm_cv_ct' the "
                         f"observation has the IMM's own detectors after the features)")
    if cfg.frame_stack != 1:
        raise ValueError(f"{p}frame_stack must be 1 with tracker='imm_cv_ct' (its observation appends the IMM's "
                         f"detectors to one feature vector), got {cfg.frame_stack!r}")
    if cfg.imm_action_levels is not None:
        L = check_number(p + "imm_action_levels", cfg.imm_action_levels, 3, 101, integer=True)
        if L % 2 != 1:
            raise ValueError(f"{p}imm_action_levels must be odd (the middle level is imm_cv_ct's tuned value), "
                             f"got {L}")
        if cfg.action_type != "discrete":
            raise ValueError(f"{p}imm_action_levels applies only with action_type='discrete', got "
                             f"action_type={cfg.action_type!r}")
    if cfg.imm_parameters is not None:
        if not isinstance(cfg.imm_parameters, dict):
            raise ValueError(f"{p}imm_parameters must be a dict of {[n for n, *_ in IMM_CT_BANK_PARAMS]}, got "
                             f"{type(cfg.imm_parameters).__name__}")
        try:
            imm_spec(cfg)
        except ValueError as e:
            raise ValueError(f"{p}imm_parameters: {e}") from None
    if cfg.feature_q_g is not None:
        check_number(p + "feature_q_g", cfg.feature_q_g, 1e-6, 100.0)


# ---------------------------------------------------------------------------------------------------- action map
class IMMActionMap:
    """Actions -> the IMM's per-look parameters (module docstring).

    Args:
        spec: the IMM's spec (its :func:`radar_env.filters.imm_cv_ct.look_parameter_vector` is the a = 0 point).
        discrete: actions are level indices (else values in [-1, 1]); levels: levels per parameter (odd).
    Attributes: ``names`` (the parameters), ``n_par``, ``lo``, ``hi``, ``base`` (n_par,), ``table``
    (n_par, W_MAP) the kernel's map.
    """

    def __init__(self, spec, discrete=False, levels=DEFAULT_IMM_ACTION_LEVELS):
        self.names = look_parameter_names(spec)
        self.n_par = len(self.names)
        self.discrete, self.levels = bool(discrete), int(levels)
        info = {n: (lo, hi, log) for n, _, lo, hi, log in IMM_CV_CT_PARAMS}
        self.lo = np.array([info[n][0] for n in self.names], dtype=np.float64)
        self.hi = np.array([info[n][1] for n in self.names], dtype=np.float64)
        self.base = look_parameter_vector(spec)
        log = np.array([info[n][2] for n in self.names])
        s = lambda v: np.where(log, np.log(v), np.log(v) - np.log1p(-np.where(log, 0.0, v)))   # noqa: E731
        s0 = s(self.base)
        self.table = np.zeros((self.n_par, W_MAP))
        self.table[:, M_LOG] = log
        self.table[:, M_BASE] = self.base
        self.table[:, M_NEG] = s0 - s(self.lo)
        self.table[:, M_POS] = s(self.hi) - s0
        self.table[:, M_LO], self.table[:, M_HI] = self.lo, self.hi

    def parameters(self, actions):
        """``actions (n, n_par)`` (checked) -> the parameters ``(n, n_par)`` in their units (g, deg/s^1.5,
        probabilities); ``ValueError`` for an action outside the action space."""
        a = np.ascontiguousarray(np.asarray(actions, dtype=np.float64).reshape(-1, self.n_par))
        out = np.empty_like(a)
        if k_map(a, self.discrete, self.levels, self.table, out) != _ek.ST_OK:
            raise ValueError(f"actions must be {self._what()}, got {actions!r}")
        return out

    def _what(self):
        return (f"{self.n_par} integers in [0, {self.levels - 1}] per row" if self.discrete
                else f"{self.n_par} finite values in [-1, 1] per row")


@njit(cache=True)
def _check_actions(act, discrete, levels):
    """ST_ACTION_SHAPE for a continuous action not in [-1, 1] (as the default env, 1e-6 of slack, then clipped)
    or a non-integer discrete one, ST_ACTION_RANGE for a level out of range."""
    for i in range(act.shape[0]):
        for j in range(act.shape[1]):
            a = act[i, j]
            if discrete:
                if not (math.isfinite(a) and a == math.floor(a)):
                    return _ek.ST_ACTION_SHAPE
                if not (a >= 0.0 and a < levels):
                    return _ek.ST_ACTION_RANGE
            elif not abs(a) <= 1.0 + 1e-6:
                return _ek.ST_ACTION_SHAPE
    return _ek.ST_OK


@njit(cache=True)
def _map_value(a, discrete, levels, row):
    """One parameter of one action (module docstring's map)."""
    if discrete:
        a = (2.0 * a - (levels - 1)) / (levels - 1)
    if a < -1.0:
        a = -1.0
    elif a > 1.0:
        a = 1.0
    d = a * (row[M_POS] if a >= 0.0 else row[M_NEG])
    v0 = row[M_BASE]
    e = math.exp(d)
    p = v0 * e if row[M_LOG] != 0.0 else v0 * e / ((1.0 - v0) + v0 * e)
    return min(max(p, row[M_LO]), row[M_HI])


@njit(cache=True)
def k_map(act, discrete, levels, table, out):
    """:meth:`IMMActionMap.parameters` (returns a status ``ST_*``)."""
    s = _check_actions(act, discrete, levels)
    if s == _ek.ST_OK:
        for i in range(act.shape[0]):
            for j in range(act.shape[1]):
                out[i, j] = _map_value(act[i, j], discrete, levels, table[j])
    return s


@njit(cache=True)
def k_imm_start(rows, st, is_ct, sig_w0_2, p_w0, log_mu0, xm, Pm, log_mu):
    """Start the IMM of ``rows`` at the chain's warm-up estimate (as ``baselines.imm_cv_ct_runner.run_imm_cv_ct``): turn
    rate 0 with variance ``p_w0`` in the CT mode, every mode at that state (a CV mode with its augmentation)."""
    x5 = np.zeros(5)
    P5 = np.zeros((5, 5))
    for j in range(rows.shape[0]):
        r = rows[j]
        for a in range(4):
            x5[a] = st[r, _k.S_X + a]
            for b in range(4):
                P5[a, b] = st[r, _k.S_P + 4 * a + b]
        P5[4, 4] = p_w0
        _init_modes(x5, P5, is_ct, sig_w0_2, log_mu0, xm[r], Pm[r], log_mu[r])


@njit(cache=True)
def k_imm_step(act, discrete, levels, table, is_ct, q_of, stay_of, entry_w, sig_w0_2, omega_max, accel_max, rdot_scale,
               looks, it, xm, Pm, log_mu, par, x, P, mu, om, om_var):
    """The IMM's next look of every row (the look the chain processes next, ``it[r, I_K]``) with the parameters of
    action ``act[r]``: ``par (n, n_par)``, the combined ``x (n, 4)``, ``P (n, 4, 4)``, ``mu (n, M)``, turn rate
    ``om`` and its variance ``om_var``; the modes ``xm, Pm, log_mu`` in place. Mode ``a`` takes its q from
    ``par[:, q_of[a]]`` and its stay probability from ``par[:, stay_of[a]]`` (:func:`mode_parameter_columns`: a bank's
    CT modes share theirs), ``entry_w (M,)`` the modes' entry turn rates. The per-look arrays are those of
    ``radar_env.filters.imm_cv_ct.kernel_parameters`` (same operations). ``rdot_scale`` > 0: the modes also update
    on the look's radial velocity, its noise std the radar's times ``rdot_scale`` (0: position only). Returns a
    status ``ST_*`` (nothing changed unless
    ST_OK)."""
    s = _check_actions(act, discrete, levels)
    if s != _ek.ST_OK:
        return s
    n = act.shape[0]
    for r in range(n):
        if it[r, _k.I_K] >= it[r, _k.I_N]:
            return _ek.ST_ENDED
    M = is_ct.shape[0]
    work = _work(M)
    rr = np.empty(4)
    q = np.empty(M)
    stay = np.empty(M)
    log_Pi = np.empty((M, M))
    for r in range(n):
        for j in range(act.shape[1]):
            par[r, j] = _map_value(act[r, j], discrete, levels, table[j])
        for a in range(M):
            q[a], stay[a] = par[r, q_of[a]] * G0_M_S2, par[r, stay_of[a]]
        sw = par[r, 2] * DEG
        for a in range(M):
            off = math.log((1.0 - stay[a]) / (M - 1))
            for b in range(M):
                log_Pi[a, b] = off
            log_Pi[a, a] = math.log(stay[a])
        k = it[r, _k.I_K]
        lk = looks[r, k]
        R = lk[_k.L_R:_k.L_R + 4].reshape((2, 2))
        _look_range_rate(lk, rdot_scale, rr)
        # imm_cv_ct._look's two halves called directly: one level of compiled calls less to link and optimise
        _look_predict(lk[_k.L_T] - looks[r, k - 1, _k.L_T], is_ct, q, sw * sw, log_Pi, sig_w0_2, omega_max,
                      accel_max, xm[r], Pm[r], log_mu[r], work, entry_w)
        _, om[r], om_var[r] = _look_update(lk[_k.L_Z:_k.L_Z + 2], R, lk[_k.L_DET] != 0.0, rr, is_ct, omega_max,
                                           accel_max, xm[r], Pm[r], log_mu[r], work, x[r], P[r], mu[r])
    return _ek.ST_OK


@njit(cache=True)
def k_imm_emit(ep, looks, it, elapsed_before, x, P, fo, fs, bo):
    """After the chain's step: the info's estimate and covariance, the reward's position and track-loss terms and
    the end flags of every row from the IMM's ``x, P`` (the default env's terms and rules, core's step kernel:
    terminated = lost, truncated = last look without loss or ``EP_MAX_STEPS`` steps)."""
    max_steps = int(ep[_ek.EP_MAX_STEPS])
    for r in range(x.shape[0]):
        lk = looks[r, it[r, _k.I_K] - 1]
        for a in range(4):
            fo[r, _ek.FO_X + a] = x[r, a]
            for b in range(4):
                fo[r, _ek.FO_P + 4 * a + b] = P[r, a, b]
        pos, tl, lost = _ek._reward_terms(x[r, 0], x[r, 1], lk, float(it[r, _k.I_N] - it[r, _k.I_K]), True, ep)
        fs[_ek.FS_POS, r] = pos
        fs[_ek.FS_LOST, r] = tl
        fs[_ek.FS_REWARD, r] = pos + tl
        trunc = it[r, _k.I_K] >= it[r, _k.I_N] and not lost
        if max_steps > 0 and elapsed_before[r] + 1 >= max_steps:
            trunc = True
        bo[_ek.BO_LOST, r] = lost
        bo[_ek.BO_TRUNC, r] = trunc
        bo[_ek.BO_DONE, r] = lost or trunc
