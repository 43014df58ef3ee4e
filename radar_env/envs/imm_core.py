"""The batched core of RadarTrack-v0 with ``tracker="imm_cv_ct"`` (:class:`_IMMCore`, no Gymnasium needed) and
:func:`make_core`, the core of a configuration; the IMM env itself: :mod:`radar_env.envs.imm_env`."""

from __future__ import annotations

import math

import numpy as np

from . import env_kernels as _ek
from .core import _NO_ROWS, _Core
from .config import EnvConfig
from ..common.parallel import run as _run_rows
from ..filters.imm_cv_ct import detector_inputs, detector_names, initial_detectors
from .imm_env import (detector_bounds, detector_observation, feature_q_m_s2, imm_action_map, imm_spec, k_imm_emit,
                      k_imm_start, k_imm_step, mode_parameter_columns)
from ..common.units import DEG, G0_M_S2

__all__ = ["make_core"]


def make_core(n, cfg: EnvConfig, autoreset=False, max_episode_steps=None):
    """The batched core of ``cfg``'s tracker: :class:`radar_env.envs.core._Core` (``tracker="cv"``) or
    :class:`_IMMCore` (``tracker="imm_cv_ct"``)."""
    cls = _IMMCore if cfg.tracker == "imm_cv_ct" else _Core
    return cls(n, cfg, autoreset, max_episode_steps)


# ---------------------------------------------------------------------------------------------------- batched core
class _IMMCore(_Core):
    """:class:`radar_env.envs.core._Core` whose filter is the IMM: the same rows, draws, autoreset, feature chain and
    reward code, with the IMM's look before the chain's and its estimate in the info, reward and end flags.

    Attributes: ``spec`` (the IMM's), ``action_map`` (:class:`IMMActionMap`), ``feature_q_m_s2``, ``n_features``
    (the env's features; the detectors follow them in the observation)."""

    def __init__(self, n, cfg, autoreset=False, max_episode_steps=None):
        super().__init__(n, cfg, autoreset, max_episode_steps)
        self.spec = spec = imm_spec(cfg)
        self.action_map = imm_action_map(cfg, spec)
        self.action_shape = (self.action_map.n_par,)
        self.feature_q_m_s2 = feature_q_m_s2(cfg)
        # the chain's parameters: every step at level 0 = feature q, never lost (the IMM's estimate decides)
        ep = self.ep.copy()
        ep[_ek.EP_ACT_CONT], ep[_ek.EP_GATE] = 0.0, math.inf
        ep[int(ep[_ek.EP_LEVELS])] = self.feature_q_m_s2
        self._ep_chain, self._level0 = ep, np.zeros(n)
        M = spec.n_modes
        self.n_features = self.obs_width
        self.detector_names = detector_names(spec)
        self.obs_width += len(self.detector_names)
        is_ct, _, _, log_mu0 = spec.mode_arrays()
        self._is_ct, self._log_mu0 = np.ascontiguousarray(is_ct), np.ascontiguousarray(log_mu0)
        self._q_of, self._stay_of = mode_parameter_columns(spec)
        self._entry_w = spec.entry_rates()
        sig_w0 = spec.sigma_omega0_deg_s * DEG
        self._sig_w0_2, self._p_w0 = sig_w0 * sig_w0, (spec.sigma_omega0_deg_s * DEG) ** 2
        self._bounds = spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2
        self.xm, self.Pm, self.log_mu = np.zeros((n, M, 5)), np.zeros((n, M, 5, 5)), np.zeros((n, M))
        self._det0 = detector_observation(initial_detectors(spec, 1))[0]
        self._scratch = (np.empty((n, self.action_map.n_par)), np.empty((n, 4)), np.empty((n, 4, 4)), np.empty((n, M)),
                         np.empty(n), np.empty(n), np.empty(n, dtype=np.int64))

    def observation_bounds(self):
        lo, hi = super().observation_bounds()
        dlo, dhi = detector_bounds(self.spec.n_modes)
        return np.concatenate([lo, dlo]), np.concatenate([hi, dhi])

    def _kernel_args(self):
        return (self._ep_chain,) + super()._kernel_args()[1:]

    def _actions(self, action):
        a = np.asarray(action)
        if a.dtype.kind not in "iuf":
            raise ValueError(f"action must be {'integer' if self.action_map.discrete else 'real'} number(s), got "
                             f"{action!r} (dtype {a.dtype})")
        if a.shape != (self.n, self.action_map.n_par):
            self._refuse(_ek.ST_ACTION_SHAPE, action)
        return np.ascontiguousarray(a, dtype=np.float64)

    def _refuse(self, status, action):
        if status == _ek.ST_ENDED:
            super()._refuse(status, action)
        m = self.action_map
        raise ValueError(f"action must be {self.n} row(s) of {m._what()[:-len(' per row')]} (the IMM's "
                         f"{', '.join(m.names)}), got {action!r}")

    def action_to_parameters(self, action):
        """Validated actions -> the IMM's parameters ``(n, n_par)`` (:class:`IMMActionMap`)."""
        return self.action_map.parameters(self._actions(action))

    def _start(self, rows, blocks, scenario=None, prepared=False):
        super()._start(rows, blocks, scenario, prepared)
        k_imm_start(rows, self.tracker._st, self._is_ct, self._sig_w0_2, self._p_w0, self._log_mu0, self.xm, self.Pm,
                    self.log_mu)
        blocks[0][rows, self.n_features:] = self._det0

    def _advance(self, a, action, blocks):
        obs, fo, fs, bo = blocks
        m, tr = self.action_map, self.tracker
        par, x, P, mu, om, om_var, elapsed = self._scratch   # the IMM's look, copied into the blocks below
        status = k_imm_step(a, m.discrete, m.levels, m.table, self._is_ct, self._q_of, self._stay_of, self._entry_w,
                            self._sig_w0_2, *self._bounds,
                            1.0 if tr.radial_velocity else 0.0, tr._looks, tr._it, self.xm, self.Pm, self.log_mu, par, x, P, mu, om, om_var)
        if status != _ek.ST_OK:
            self._refuse(status, action)
        elapsed[:] = self.elapsed
        status = _run_rows(self.num_threads, self.n, _ek.k_env, _NO_ROWS, self._level0, *self._kernel_args(), *blocks)
        if status != _ek.ST_OK:
            raise RuntimeError("the feature chain refused a step the IMM took")   # a bug: the same rows and looks
        k_imm_emit(self.ep, tr._looks, tr._it, elapsed, x, P, fo, fs, bo)
        obs[:, self.n_features:] = detector_observation(detector_inputs(mu, om, np.sqrt(om_var)))
