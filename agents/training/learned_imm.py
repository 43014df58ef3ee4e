r"""The learned IMM's torch model, trained by backpropagation: ``radar-track train --method backprop --tracker
imm_cv_ct``.

:class:`LearnedIMMModel` is the network of :mod:`agents.policies.learned_imm` in torch (a GRU over the env's
observation and the IMM's own detectors, whose offsets set imm_cv_ct's per-look parameters) and the differentiable
IMM they drive (:mod:`radar_env.filters.torch_imm`, built from the one torch chain's blocks). One look of it is one
function, :func:`look_step`; hyperparameter ``chain`` (default ``compiled``) runs it under ``torch.compile`` (inductor:
the look's few hundred small tensor operations and their backward fused into C++ loops, the same arithmetic to
rounding), ``torch`` runs it eagerly (the reference). It implements the backprop
trainer's model interface (:class:`agents.training.backprop.ChainModel`), so that trainer runs it: the rows' flights,
the lockstep numba :class:`radar_env.filters.tracking.Tracker` (stepped at kf_tuned's constant q: the env's observation,
as ``RadarTrack-v0`` computes it), chunks of truncated backpropagation of the pooled position MSE through the IMM
into the network, validation on training-range seeds and the best checkpoint, the run folder. Its hyperparameters:
``agents/training/hyperparams/backprop_imm_cv_ct.toml``. A checkpoint is the learned IMM's own format
(:func:`agents.policies.learned_imm.save_learned_imm`), run by the numpy inference; the validation scores that
inference (:meth:`agents.training.selection.SelectionSuites.score_runs`).
"""

from __future__ import annotations

import functools
import shutil

import numpy as np
import torch

from baselines.imm_cv_ct_runner import IMM_CV_CT_PARAMS, look_parameter_names, tuned_imm_cv_ct_spec
from radar_env.filters import torch_chain as tc
from radar_env.filters import torch_imm as ti
from radar_env.common.units import DEG, G0_M_S2

from agents.policies.learned_imm import (LearnedIMM, ParamMap, detector_inputs, detector_names, initial_detectors,
                                         save_learned_imm, weight_shapes)
from agents.training.backprop import CHAINS, DTYPE, ChainModel, gru_weights

__all__ = ["LearnedIMMModel", "look_step", "compiler_available"]


def look_step(model, obs, det, h, state, dt, G, z, R, mask, rr):
    """One look of the learned IMM for every row: the GRU reads the observation ``obs (B, F)`` and the IMM's
    detectors ``det (B, M + 2)`` of the look before, its offsets set the look's IMM parameters, the IMM filters the
    look (``dt (B,)``, ``G``, ``z``, ``R``, ``mask``, ``rr``: column ``j`` of a
    :class:`radar_env.filters.torch_chain.ChainLooks`). Returns ``(h', state', record, det', delta)``: the new GRU
    and IMM states, the :class:`radar_env.filters.torch_imm.IMMRecord`, the next detectors (detached: inputs, not a
    path for the gradient) and the offsets ``delta (B, n_par)``. Tensors and the model only: what ``torch.compile``
    traces (:attr:`LearnedIMMModel.chain`)."""
    delta, h = model.offsets(obs, det, h)
    q, sig_w2, log_Pi = model.imm_parameters(delta)
    state, rec = ti.look(state, dt, G, z, R, mask, q, sig_w2, log_Pi, model.consts, rr=rr)
    mu = torch.exp(rec.modes.log_mu[model._inverse]).T
    det = detector_inputs(mu, rec.omega, torch.sqrt(rec.omega_var), torch).detach()
    return h, state, rec, det, delta


@functools.cache
def _compiled():
    """:func:`look_step` under ``torch.compile`` (one wrapper for the process). One graph per input shape (rows,
    GRU width, features, range rate), compiled in about a minute and kept by inductor on disk
    (``/tmp/torchinductor_$USER``), so a later process with the same shapes loads it in seconds; ``fullgraph``: a
    break in the graph is an error, not a silent fall-back to Python."""
    return torch.compile(look_step, dynamic=False, fullgraph=True)


def _cxx():
    """The C++ compiler inductor calls (its ``cpp.cxx`` setting: ``$CXX`` at torch's import, else ``g++``)."""
    from torch._inductor import config
    cxx = config.cpp.cxx
    return cxx[-1] if isinstance(cxx, (tuple, list)) else cxx


def compiler_available():
    """Whether the C++ compiler ``torch.compile``'s inductor calls (:func:`_cxx`) is on this machine."""
    return shutil.which(_cxx()) is not None


# ===================================================================================================== the model
class LearnedIMMModel(ChainModel):
    """The learned IMM in torch (the trainer's :class:`agents.training.backprop.ChainModel` interface).

    Args:
        obs_size: entries of the env's observation. hidden_size: GRU width. head: widths of tanh layers between the
            GRU and the output layer (may be empty).
        spec: the ``IMMCVCTSpec`` whose per-look parameters the network offsets (the tuned ``imm_cv_ct``).
        feature_q_m_s2: the constant q the lockstep numba Tracker (the observation's chain) is stepped with.
        chain: ``compiled`` (:func:`look_step` under ``torch.compile`` when a gradient is taken; needs a C++
            compiler) or ``torch`` (eager). The same gradient to rounding (tests/test_learned_imm.py).
    """

    kind = "imm_cv_ct"

    def __init__(self, obs_size, hidden_size, head, spec, feature_q_m_s2, chain="compiled"):
        super().__init__()
        if chain not in CHAINS:
            raise ValueError(f"chain must be one of {list(CHAINS)}, got {chain!r}")
        if chain == "compiled" and not compiler_available():
            raise ValueError(f"--hp chain: 'compiled' (torch.compile of the learned IMM's look) needs a C++ compiler, "
                             f"and {_cxx()!r} was not found: install g++ (or set CXX), or train with --hp chain=torch "
                             "(eager, about half the speed)")
        self.chain = chain
        self.spec = spec
        self.names = look_parameter_names(spec)
        self.base = {n: getattr(spec, n) for n, *_ in IMM_CV_CT_PARAMS if getattr(spec, n) is not None}
        self.base.update({f"ct_rate_{k + 1}_deg_s": r for k, r in enumerate(spec.ct_rates_deg_s)})   # a bank
        self.pmap = ParamMap(self.base, self.names)
        self._pmap_t = self.pmap.tensors(torch)
        self.consts = ti.IMMConstants(**spec.filter_constants())
        self._inverse = torch.argsort(self.consts.order)
        self.obs_size, self.hidden_size, self.head_sizes = int(obs_size), int(hidden_size), [int(n) for n in head]
        self.n_det = len(detector_names(spec))
        self.gru = torch.nn.GRUCell(self.obs_size + self.n_det, self.hidden_size, dtype=DTYPE)
        layers, prev = [], self.hidden_size
        for n in self.head_sizes:
            layers.append(torch.nn.Linear(prev, n, dtype=DTYPE))
            prev = n
        self.head = torch.nn.ModuleList(layers)
        self.out = torch.nn.Linear(prev, len(self.names), dtype=DTYPE)
        with torch.no_grad():          # zero offsets: imm_cv_ct with its tuned values
            self.out.weight.zero_()
            self.out.bias.zero_()
        self.feature_q_m_s2 = float(feature_q_m_s2)
        self.h = self.state = self.det = None
        idx = {n: i for i, n in enumerate(self.names)}
        n_ct, high = spec.n_ct, spec.q_high_g is not None      # every CT mode of a bank takes the same offsets
        self._iq = [idx["q_cv_g"]] + [idx["q_ct_g"]] * n_ct + ([idx["q_high_g"]] if high else [])
        self._ip = [idx["p_stay_cv"]] + [idx["p_stay_ct"]] * n_ct + ([idx["p_stay_high"]] if high else [])
        self._iw = idx["sigma_omega_deg_s15"]

    # ---- the network and its parameters
    def offsets(self, obs, det, h):
        """``(delta (B, n_par), h')`` for observations ``obs (B, F)`` (float64), the IMM's detectors ``det`` and
        state ``h``."""
        h = self.gru(torch.cat((obs, det), 1), h)
        y = h
        for layer in self.head:
            y = torch.tanh(layer(y))
        return self.out(y), h

    def imm_parameters(self, delta):
        """The IMM's per-look arrays, components first, modes in the spec's order: ``q_m_s2 (M, B)``,
        ``sig_w2 (B,)`` (rad^2/s^3), ``log_Pi (M, M, B)``, from offsets ``delta (B, n_par)``."""
        s = self.pmap.transformed(delta, torch, self._pmap_t)
        q = torch.exp(s[:, self._iq]).T * G0_M_S2
        sig_w2 = torch.exp(2.0 * s[:, self._iw]) * (DEG * DEG)
        u = s[:, self._ip]
        log_Pi = ti.switch_log_probs(-torch.nn.functional.softplus(-u), -torch.nn.functional.softplus(u))
        return q, sig_w2, log_Pi.permute(1, 2, 0)

    def physical(self, delta):
        """The parameters in their units (g, deg/s^1.5, probabilities) ``(B, n_par)``, as the numpy inference
        gives them (for logs and tests)."""
        return self.pmap.physical(delta.detach().numpy())

    # ---- the ChainModel interface
    def reset_state(self, n_rows):
        self.h = torch.zeros((n_rows, self.hidden_size), dtype=DTYPE)
        eye = torch.eye(4, dtype=DTYPE)[:, :, None].repeat(1, 1, n_rows)
        self.state = ti.start(tc.ChainState(torch.zeros((4, n_rows), dtype=DTYPE), eye), self.consts)
        self.det = torch.as_tensor(initial_detectors(self.spec, n_rows))

    def start_rows(self, tracker, rows):
        """Rows ``rows`` have just been loaded: their modes at the common track start (``tracker.x/P[rows]``),
        zero GRU state, the start's detectors."""
        r = torch.as_tensor(np.asarray(rows, dtype=np.int64))
        new = ti.start(tc.ChainState.from_xP(tracker.x[rows], tracker.P[rows]), self.consts)
        st = [t.detach().clone() for t in self.state]
        for t, n in zip(st, new):
            t[..., r] = n
        self.state = ti.IMMState(*st)
        self.h = self.h.detach().clone()
        self.h[r] = 0.0
        self.det = self.det.detach().clone()
        self.det[r] = torch.as_tensor(initial_detectors(self.spec, len(r)))

    def begin_chunk(self, tracker):
        self.h, self.state, self.det = self.h.detach(), self.state.detach(), self.det.detach()
        if self.chain == "compiled" and torch.is_grad_enabled():
            # The carried states as leaves that require a gradient (which nobody reads): the chunk's first look is
            # then traced like the others, one compiled graph instead of two (compiling is the cost: ~1 min each).
            self.h.requires_grad_(True)
            for t in self.state:
                t.requires_grad_(True)

    def step(self, looks, j, obs):
        """Look ``j`` of ``looks`` for every row, reading ``obs (B, F)``: returns the combined estimate
        ``x (4, B)`` (components first) and the q (m/s^2, numpy) for the lockstep Tracker (``feature_q``)."""
        # compiled for training; a forward under torch.no_grad() (the tests' forward_episodes, diagnostics) runs
        # eagerly, where compiling another graph would cost more than it saves
        fn = _compiled() if self.chain == "compiled" and torch.is_grad_enabled() else look_step
        self.h, self.state, rec, self.det, delta = fn(self, obs, self.det, self.h, self.state, looks.dt_s[j],
                                                      looks.G[j], looks.z_m[j], looks.R_m2[j], looks.mask[j],
                                                      looks.rdot_at(j))
        self.record, self.delta = rec, delta
        return rec.x, np.full(looks.B, self.feature_q_m_s2)

    def architecture(self):
        return {"input_size": self.obs_size + self.n_det, "hidden_size": self.hidden_size,
                "head": list(self.head_sizes), "n_par": len(self.names)}

    def policy_weights(self):
        return gru_weights(self, weight_shapes(self.architecture()))

    def policy_config(self, cfg):
        return {"model": self.kind, "architecture": self.architecture(), "input_features": list(cfg.features),
                "detectors": list(detector_names(self.spec)), "parameters": list(self.names),
                "base_parameters": dict(self.base), "feature_q_g": self.feature_q_m_s2 / G0_M_S2,
                "output": "s = L + (H - L) sigmoid(u0 + out(head(h))) per parameter, L, H its range in log (noises) "
                          "or logit (stay probabilities) space, u0 at the base value; param = exp(s) or sigmoid(s)"}

    def inference(self, cfg, env_kwargs):
        """The numpy :class:`agents.policies.learned_imm.LearnedIMM` of the current weights."""
        return LearnedIMM(self.policy_weights(), self.policy_config(cfg), env_kwargs)

    def save_policy(self, directory, cfg, env_kwargs, weights=None):
        return save_learned_imm(directory, self.policy_weights() if weights is None else weights,
                                self.policy_config(cfg), env_kwargs)

    def validation_row(self, selection, cfg, env_kwargs):
        imm = self.inference(cfg, env_kwargs)
        return selection.score_runs(imm.run)[0]

    @classmethod
    def build(cls, hp, cfg):
        """Around the registered imm_cv_ct's tuned spec (hyperparameter ``imm`` ``imm_ct_bank``: the bank of CT
        modes'), the observation's chain at kf_tuned's q (with ``radial_velocity``: imm_cv_ct_rdot's or
        imm_ct_bank_rdot's and kf_tuned_rdot's, the trackers with the same measurements)."""
        from baselines.tuned_params import tuned_parameters
        rd = "_rdot" if cfg.radial_velocity else ""
        imm = hp.get("imm", "imm_cv_ct")
        return cls(len(cfg.features), hp["hidden_size"], hp["head"], tuned_imm_cv_ct_spec(imm + rd),
                   tuned_parameters()["kf" + rd]["q_g"] * G0_M_S2, chain=hp.get("chain", "compiled"))
