r"""End-to-end training by backpropagation through the project's own filter: ``radar-track train --method backprop``.

RadarTrack-v0's loss, the position error after the track start, is a differentiable function of every q the
policy chose, through the Kalman filter. This trainer minimises it by gradient descent: a causal recurrent policy
(a GRU over the env's observation) outputs q at every look, the differentiable chain
(:mod:`radar_env.filters.torch_chain`) filters with it, and the pooled position MSE is backpropagated through the filter's
states into the network. The trained network is a policy like any other: a numpy GRU runs it in the evaluation and
in the env (:mod:`agents.policies.recurrent`), with no torch.

One look of one training row (the *lockstep*)::

    obs_{j-1}  --(GRU, detached input)-->  a_j = tanh(head(h_j))  -->  q_j = q_min (q_max/q_min)^((a_j+1)/2)
    torch chain:  x_j, P_j = step(x_{j-1}, P_{j-1}, plot j; q_j)            (gradient flows through q_j, x, P)
    numba chain:  Tracker.step(q_j.detach()) -> StepOutput -> ObservationLayout.encode -> obs_j   (as the env)

The numba :class:`radar_env.filters.tracking.Tracker` and :meth:`radar_env.envs.observation.ObservationLayout.encode` compute the
observation exactly as ``RadarTrack-v0`` does (the env's own code, so the network reads in training what it reads
when acting; tested bit for bit against the env), and the torch chain carries the gradient.

Streaming truncated backpropagation. ``batch_episodes`` rows (>= 1,000 episodes side by side) each play one episode
after another, drawn by the batched drawer (:func:`radar_env.sim.draws.draw_episodes`, one call per chunk for every row
that needs a new episode) from the training flights (``env_kwargs``: the bundled PPO policy's last-stage
distribution by default). One optimiser step per chunk of ``chunk_looks`` looks of every row: the loss is the
pooled position MSE over the chunk's looks after the track start (those :mod:`agents.evaluation.metrics` scores),
backpropagated, the gradient norm clipped, an Adam step taken; then the graph is cut (the filter state and the GRU
state are detached; the CV model re-reads its filter state from the numba Tracker, an exact copy). A row whose
episode ended mid-chunk pads until the chunk ends (about half a chunk per episode); no row waits for the batch's
longest episode. So every optimiser step's gradient comes from one chunk of ``batch_episodes`` episodes, and the
looks are weighted as the pooled RMSE weights them.

Seeds. Row ``r`` of a run with training seed ``S`` plays the episodes of ``numpy.random.default_rng([S, s0, r])``
(``s0`` = 0, or the step a resumed run restarted from), a stream inside the training seed range
(``S < 900_000``: disjoint from the selection suites ``900_000 + i`` and from the held-out evaluation seeds
``10_000_000 + i``). Validation: :class:`agents.training.selection.SelectionSuites` (the SB3 callback's scorer:
training-range seeds ``900_000 + i``, the policy / imm2 RMSE ratio, geometric mean over ``select_on``), every
``eval_every`` steps and at the end; the best checkpoint is kept.

The model interface (:class:`ChainModel`): ``--tracker cv`` (default) is the q-policy above; ``--tracker
imm_cv_ct`` the learned IMM (:mod:`agents.training.learned_imm`: imm_cv_ct whose per-look parameters a GRU sets,
through the torch IMM). A model plugs in by subclassing it and naming itself in :data:`MODELS`; the trainer
(drawing, lockstep, chunks, loss, optimiser, validation, checkpoints, run folder) is shared. Each model has its
default hyperparameter file (:data:`HP_FILES`).

The run folder (``<out>/<name>.partial/`` until complete, then ``<out>/<name>/``), as ``radar-track train``'s:
``config.json``, ``args.json``, ``command.txt``, ``env_config.json``, ``policy.npz`` + ``policy.json`` (final
weights; kind ``gru_q_policy`` or ``learned_imm_gru``), ``training.json`` + ``choice.json`` (the learned-tracker
layout, :mod:`agents.policies.learned`: ``radar-track evaluate --learned <run>`` reads it), ``best/`` (the best
validation checkpoint, its ``selection.json``, ``training.json`` and ``choice.json``), ``checkpoints/last.npz`` +
``last.json`` (weights, Adam moments, step, history: what a resume needs), ``tb/`` (TensorBoard scalars),
``summary.json``. A run that fails or is killed stays ``<name>.partial/``; running the same command again resumes it
from its last checkpoint (the same configuration is required, else a one-line refusal); a finished ``<name>/`` is
never overwritten.
"""

from __future__ import annotations

import json
import math
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch

from radar_env.filters import torch_chain as tc
from radar_env.envs.config import EnvConfig
from radar_env.envs.core import actions_to_q_m_s2
from radar_env.sim.draws import draw_episodes
from radar_env.envs.observation import DEFAULT_FEATURES, DETECTOR_FEATURES, ObservationLayout, measurement_sigma_m
from radar_env.common.units import G0_M_S2

from agents.evaluation.metrics import jsonable
from agents.policies.checks import env_kwargs_from_json
from agents.policies.recurrent import RecurrentQPolicy, save_recurrent_policy, weight_shapes
from agents.training.selection import SELECTION_SEED_BASE, SelectionSuites
from agents.training.runs import (CHECKPOINT_ERRORS, EVAL_SCENARIOS_HP, SELECT_ON_HP, TRAIN_SCENARIOS, adam_arrays,
                                  apply_cli_overrides, checkpoint_refusal, load_adam, load_hyperparams, resumable,
                                  run_cli, run_paths, write_checkpoint, write_run_files, writing_run)

__all__ = ["ChainModel", "CVQModel", "MODELS", "HP_FILES", "HP_SPEC", "HP_OPTIONAL", "CHAINS", "LOSSES", "check_hp",
           "train_backprop", "chunk_looks", "observe",
           "make_model", "StreamingTrainer", "lockstep", "forward_episodes", "optimiser_step", "MAX_TRAIN_SEED"]

DTYPE = torch.float64
LOSSES = ("position_mse", "normalised")
"""``position_mse``: the pooled position MSE (m^2, divided by ``loss_scale_m^2``), what the evaluation's pooled RMSE
squares; ``normalised``: the squared position error in units of the plot noise (the env's ``reward_type="squared"``:
``|e|^2 / sigma^2`` with ``sigma`` the per-axis RMS plot noise at the true range), pooled over the same looks, which
weighs a look on a precise radar as much as one on a coarse radar."""
MAX_TRAIN_SEED = SELECTION_SEED_BASE
"""Training seeds ``S`` lie in ``[0, 900_000)``: below the selection suites' seeds."""
CHAINS = ("compiled", "torch")
"""How a model's chain runs (hyperparameter ``chain``, optional, default ``compiled``). The CV model: ``compiled``,
the look loop steps only the GRU, the numba Tracker and the observation, then the compiled CV chain
(:mod:`radar_env.filters.compiled_chain`, numba forward and adjoint) runs the chunk at once
(:meth:`CVQModel.chunk_forward`); ``torch``, the reference: the lockstep over the torch chain, one look at a
time. ``imm_cv_ct`` (the learned IMM): ``compiled``, its look (GRU, parameters, torch IMM) under ``torch.compile``
(:func:`agents.training.learned_imm.look_step`; needs a C++ compiler); ``torch``, eager. The same gradient to
rounding either way."""


# ================================================================================================= the models
class ChainModel(torch.nn.Module):
    """What the trainer needs of a differentiable tracker model. Subclass it, name it in :data:`MODELS`.

    The trainer owns the rows' episodes, the numba :class:`radar_env.filters.tracking.Tracker` stepped in lockstep (it gives
    the env's observation), the chunks, the loss and the optimiser. A model keeps, per row, its network's recurrent
    state and its own torch filter state, and implements:

    * :meth:`reset_state` ``(n_rows)``: allocate that state for ``n_rows`` rows;
    * :meth:`start_rows` ``(tracker, rows)``: rows ``rows`` have just been loaded (the common track start is done;
      ``tracker.x[rows]``, ``tracker.P[rows]`` is the start state): clear their recurrent state, start their filter;
    * :meth:`begin_chunk` ``(tracker)``: cut the autograd graph before a chunk (detach every carried tensor);
    * :meth:`step` ``(looks, j, obs) -> (x (4, B), tracker_q (B,))``: one look ``j`` of the chunk's
      :class:`radar_env.filters.torch_chain.ChainLooks` for every row, reading the observation ``obs (B, F)`` (float64,
      detached) of the look before: returns the position estimate the loss scores (components first, see
      torch_chain) and the q (m/s^2, numpy) the trainer steps the numba Tracker with, for the next observation
      (a turn-aware model returns a third entry, the turn rate (rad/s, numpy) the Tracker predicts with);
    * :meth:`architecture` (JSON-able dict), :meth:`policy_weights` (``{name: numpy array}``) and
      :meth:`policy_config` (the ``policy.json`` entries): the checkpoint its inference code loads;
    * :meth:`save_policy` ``(directory, cfg, env_kwargs, weights=None)``: write that checkpoint (its format);
    * :meth:`validation_row` ``(selection, cfg, env_kwargs)``: the current weights scored by the numpy inference on
      the :class:`agents.training.selection.SelectionSuites` (its ``score`` or ``score_runs`` row);
    * :meth:`build` ``(hp, cfg)`` (class method): the untrained model for the hyperparameters and the env config.

    Rows whose episode has ended are still passed to :meth:`step` until the chunk ends (padding columns of
    ``looks``: ``dt = 0``, not detected, not scored), so a model may compute anything there.
    """

    kind = ""

    def reset_state(self, n_rows):
        raise NotImplementedError

    def start_rows(self, tracker, rows):
        raise NotImplementedError

    def begin_chunk(self, tracker):
        raise NotImplementedError

    def step(self, looks, j, obs):
        raise NotImplementedError

    def chunk_forward(self, tracker, layout, obs, looks):
        """The chunk's position estimates ``x (B, J, 4)`` (a graph), stepping ``tracker`` through the chunk and
        updating ``obs`` in place (:func:`lockstep`'s contract). Default: :func:`lockstep` over :meth:`step`; a model
        may override it with a faster equivalent (:meth:`CVQModel.chunk_forward`)."""
        return lockstep(self, tracker, layout, obs, looks)

    def architecture(self):
        raise NotImplementedError

    def policy_weights(self):
        raise NotImplementedError

    def policy_config(self, cfg):
        raise NotImplementedError

    def save_policy(self, directory, cfg, env_kwargs, weights=None):
        raise NotImplementedError

    def validation_row(self, selection, cfg, env_kwargs):
        raise NotImplementedError

    @classmethod
    def build(cls, hp, cfg):
        raise NotImplementedError


class CVQModel(ChainModel):
    """The CV Kalman filter of RadarTrack-v0 with q chosen per look by a GRU over the env's observation
    (``--tracker cv``): the policy :class:`agents.policies.recurrent.RecurrentQPolicy` runs.

    Args:
        input_size: entries of the observation. hidden_size: GRU width. head: widths of tanh layers between the
            GRU and the output (may be empty).
        q_levels_m_s2: the env's q levels; the action ``a = tanh(.)`` maps to ``q`` as the env maps continuous
            actions (:func:`radar_env.envs.core.actions_to_q_m_s2`).
        q_init_m_s2: the q the untrained network outputs at every look (its output layer is zero, its bias gives
            this q): kf_tuned's, so training starts from the tuned constant-q filter.
        turn_rate_max_rad_s: 0 (default): the network outputs q only. Positive: it also outputs a coordinated-turn
            rate ``omega = turn_rate_max_rad_s * a_1`` (``a_1 = tanh(.)``, second output; 0 untrained) and the
            filter predicts with ``F_ct(dt, omega)`` (:func:`radar_env.filters.torch_chain.transition`; the numba
            Tracker's ``step(q, turn_rate_rad_s=omega)``): the turn-aware q-policy (``policy.json`` model ``cv_turn``). Its chunk
            is the torch lockstep (the compiled chain is the CV model's).
        turn_gain: the turn-rate output's pre-activation is ``turn_gain * out(y)_1``: Adam moves every weight by
            about the learning rate per step whatever its gradient, so this sets how fast omega may move (the saved
            weights hold the product: the numpy policy has no gain).
    """

    kind = "cv"

    def __init__(self, input_size, hidden_size, head, q_levels_m_s2, q_init_m_s2, chain="compiled",
                 turn_rate_max_rad_s=0.0, turn_gain=1.0):
        super().__init__()
        if chain not in CHAINS:
            raise ValueError(f"chain must be one of {list(CHAINS)}, got {chain!r}")
        if not (math.isfinite(turn_rate_max_rad_s) and 0.0 <= turn_rate_max_rad_s <= math.pi):
            raise ValueError(f"turn_rate_max_rad_s must be in [0, pi] rad/s, got {turn_rate_max_rad_s!r}")
        self.w_max = float(turn_rate_max_rad_s)
        self.chain = "torch" if self.w_max > 0 else chain
        self.levels_m_s2 = np.asarray(q_levels_m_s2, dtype=np.float64)
        self.l0, self.l1 = math.log10(self.levels_m_s2[0]), math.log10(self.levels_m_s2[-1])
        if not self.levels_m_s2[0] < q_init_m_s2 < self.levels_m_s2[-1]:
            raise ValueError(f"q_init_m_s2 {q_init_m_s2!r} must lie inside the action range "
                             f"({self.levels_m_s2[0]!r}, {self.levels_m_s2[-1]!r}) m/s^2")
        self.input_size, self.hidden_size, self.head_sizes = int(input_size), int(hidden_size), [int(n) for n in head]
        self.gru = torch.nn.GRUCell(self.input_size, self.hidden_size, dtype=DTYPE)
        layers, prev = [], self.hidden_size
        for n in self.head_sizes:
            layers.append(torch.nn.Linear(prev, n, dtype=DTYPE))
            prev = n
        self.head = torch.nn.ModuleList(layers)
        self.n_out = 2 if self.w_max > 0 else 1
        self.turn_gain = float(turn_gain)
        self.register_buffer("out_scale", torch.tensor([1.0, self.turn_gain][:self.n_out], dtype=DTYPE),
                             persistent=False)
        self.out = torch.nn.Linear(prev, self.n_out, dtype=DTYPE)
        a0 = 2.0 * (math.log10(q_init_m_s2) - self.l0) / (self.l1 - self.l0) - 1.0
        with torch.no_grad():
            self.out.weight.zero_()
            self.out.bias.zero_()
            self.out.bias[0] = math.atanh(a0)
        self.h = self.state = None
        self.chunk_q = None

    # ---- the network
    def action(self, obs, h):
        """``(a (B,), h' (B, H))`` for observations ``obs (B, F)`` and state ``h`` (``a (B, 2)`` with a turn rate)."""
        h = self.gru(obs, h)
        return self._head(h), h

    def _head(self, h):
        """``a = tanh(out(head(h)))`` over any leading axes of ``h (..., H)``: ``(...)`` (``(..., 2)`` with a turn
        rate: the q action, then the turn-rate action)."""
        y = h
        for layer in self.head:
            y = torch.tanh(layer(y))
        if self.n_out == 1:
            return torch.tanh(self.out(y))[..., 0]
        return torch.tanh(self.out(y) * self.out_scale)

    def q_of_action(self, a):
        """The env's action map in torch (differentiable)."""
        return torch.pow(10.0, self.l0 + 0.5 * (a + 1.0) * (self.l1 - self.l0))

    # ---- the ChainModel interface
    def reset_state(self, n_rows):
        self.h = torch.zeros((n_rows, self.hidden_size), dtype=DTYPE)
        self.state = tc.ChainState(torch.zeros((4, n_rows), dtype=DTYPE),
                                   torch.eye(4, dtype=DTYPE)[:, :, None].repeat(1, 1, n_rows))

    def start_rows(self, tracker, rows):
        self.h = self.h.detach().clone()
        self.h[torch.as_tensor(rows)] = 0.0

    def begin_chunk(self, tracker):
        # the filter state from the numba chain, exactly (the torch chain equals it to ~1e-11 anyway): detached
        self.h = self.h.detach()
        self.state = tc.ChainState.from_xP(tracker.x, tracker.P)

    def step(self, looks, j, obs):
        a, self.h = self.action(obs, self.h)
        if self.n_out > 1:
            w = self.w_max * a[:, 1]
            self.state, rec = tc.step(self.state, looks, j, self.q_of_action(a[:, 0]), w)
            q_np = actions_to_q_m_s2(a[:, 0].detach().numpy().reshape(-1, 1), "continuous", self.levels_m_s2)
            return rec.x, q_np, w.detach().numpy()
        self.state, rec = tc.step(self.state, looks, j, self.q_of_action(a))
        # the numba Tracker gets the env's own map of the action (bit for bit what RadarTrack-v0 would use)
        q_np = actions_to_q_m_s2(a.detach().numpy().reshape(-1, 1), "continuous", self.levels_m_s2)
        return rec.x, q_np

    def chunk_forward(self, tracker, layout, obs, looks):
        """The chunk with the compiled chain (``chain = "compiled"``; ``"torch"``: :func:`lockstep` over :meth:`step`).

        The observation never depends on the differentiable chain (the numba Tracker makes it), so the chain need
        not run look by look: the loop steps only the GRU (with its graph), the head without a graph for the
        Tracker's q, the Tracker and the env's layout (the next observation); then, once, the head over all looks'
        GRU states gives ``q (B, J)`` and the compiled chain (:func:`radar_env.filters.compiled_chain.cv_run`: numba
        forward and adjoint, one autograd node) the estimates. The GRU's states are the same tensors in both; the
        head's product over ``(B, J, H)`` instead of ``(B, H)`` may round differently, so the q the gradient is
        taken at equals the q the Tracker stepped with to ~1e-16 relative (``self.chunk_q = (tracker q, chain q)``
        of the last chunk; tested to 1e-12). The GRU keeps torch's autograd: a hand-written reverse pass of it (numba
        gates, products per look) measured no faster, the cell being bound by its products.
        """
        if self.chain == "torch":
            return super().chunk_forward(tracker, layout, obs, looks)
        from radar_env.filters.compiled_chain import cv_run
        B, J = looks.B, looks.J
        active = looks.scored.numpy()
        h = self.h.detach()
        hs = []
        q_tr = np.empty((B, J))
        for j in range(J):
            h = self.gru(torch.from_numpy(obs.astype(np.float64)), h)
            hs.append(h)
            with torch.no_grad():
                a = self._head(h)
            # the Tracker gets the env's own map of the action (bit for bit what RadarTrack-v0 would use)
            q = q_tr[:, j] = actions_to_q_m_s2(a.numpy().reshape(-1, 1), "continuous", self.levels_m_s2)
            observe(tracker, layout, obs, q, active[j])
        self.h = h.detach()
        q = self.q_of_action(self._head(torch.stack(hs, 1)))
        self.chunk_q = (q_tr, q.detach().numpy())
        x, self.state = cv_run(self.state, looks, q)
        return x

    def start_from(self, path, cfg):
        """Start from a trained recurrent q-policy (``policy.npz`` of :mod:`agents.policies.recurrent`, read without
        pickle and checked by its loader): its GRU and head, and its q output; a turn-aware model's turn-rate output
        stays zero (omega 0: the start filters exactly as the given policy). Its observation (features) and
        architecture must be this model's, else ``ValueError`` naming ``--hp init_from``."""
        from agents.policies.recurrent import load_recurrent_policy
        try:
            pol, pcfg = load_recurrent_policy(path)
        except ValueError as e:
            raise ValueError(f"--hp init_from: {e}") from None
        if list(pcfg.features) != list(cfg.features) or pol.hidden_size != self.hidden_size or \
                list(pol.arch.get("head", [])) != self.head_sizes:
            raise ValueError(f"--hp init_from: {path} reads {len(pcfg.features)} features with GRU "
                             f"{pol.hidden_size} and head {pol.arch.get('head', [])}; this model: "
                             f"{len(cfg.features)} features, GRU {self.hidden_size}, head {self.head_sizes}")
        if pol.n_out > self.n_out:
            raise ValueError(f"--hp init_from: {path} is a turn-aware policy; this model outputs q only (give "
                             "--hp turn_rate_max_deg_s to continue it)")
        w = pol.w
        with torch.no_grad():
            for name, t in (("gru.weight_ih", self.gru.weight_ih), ("gru.weight_hh", self.gru.weight_hh),
                            ("gru.bias_ih", self.gru.bias_ih), ("gru.bias_hh", self.gru.bias_hh)):
                t.copy_(torch.from_numpy(w[name]))
            for i, layer in enumerate(self.head):
                layer.weight.copy_(torch.from_numpy(w[f"head.{i}.weight"]))
                layer.bias.copy_(torch.from_numpy(w[f"head.{i}.bias"]))
            self.out.weight.zero_()
            self.out.bias.zero_()
            for r in range(pol.n_out):      # a turn-aware source's turn row holds its gain: unfolded by ours
                self.out.weight[r] = torch.from_numpy(w["out.weight"][r]) / self.out_scale[r]
                self.out.bias[r] = float(w["out.bias"][r]) / self.out_scale[r]

    def architecture(self):
        arch = {"input_size": self.input_size, "hidden_size": self.hidden_size, "head": list(self.head_sizes)}
        if self.n_out > 1:
            arch["n_out"] = self.n_out
        return arch

    def policy_weights(self):
        w = gru_weights(self, weight_shapes(self.architecture()))
        if self.n_out > 1:          # the gain folded into the output layer: the numpy policy computes the same
            scale = self.out_scale.numpy()
            w["out.weight"], w["out.bias"] = w["out.weight"] * scale[:, None], w["out.bias"] * scale
        return w

    def policy_config(self, cfg):
        conf = {"model": self.kind, "architecture": self.architecture(), "input_features": list(cfg.features),
                "q_range_m_s2": [float(self.levels_m_s2[0]), float(self.levels_m_s2[-1])],
                "action": "a = tanh(out(head(h))) in [-1, 1]; q = q_min (q_max / q_min)^((a + 1) / 2)"}
        if self.n_out > 1:
            conf["model"] = "cv_turn"
            conf["turn_rate_max_rad_s"] = self.w_max
            conf["action"] += ("; a second output a_1 gives the turn rate omega = turn_rate_max_rad_s a_1 (rad/s, "
                               "positive = clockwise) of the prediction F_ct(dt, omega)")
        return conf

    def inference_policy(self, cfg):
        """The numpy policy of the current weights."""
        return RecurrentQPolicy(self.policy_weights(), self.architecture(), cfg.q_levels_g, self.w_max)

    def save_policy(self, directory, cfg, env_kwargs, weights=None):
        return save_recurrent_policy(directory, self.policy_weights() if weights is None else weights,
                                     self.policy_config(cfg), env_kwargs)

    def validation_row(self, selection, cfg, env_kwargs):
        return selection.score(self.inference_policy(cfg), cfg)[0]

    @classmethod
    def build(cls, hp, cfg):
        """Over the env's observation, starting at kf_tuned's q."""
        from baselines.tuned_params import tuned_parameters
        levels = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
        return cls(len(cfg.features) * cfg.frame_stack, hp["hidden_size"], hp["head"], levels,
                   tuned_parameters()["kf"]["q_g"] * G0_M_S2, chain=hp.get("chain", "compiled"),
                   turn_rate_max_rad_s=math.radians(hp.get("turn_rate_max_deg_s", 0.0)),
                   turn_gain=hp.get("turn_gain", 1.0))


def gru_weights(model, shapes):
    """``{name: numpy array}`` of a model's ``gru``, ``head`` layers and ``out`` layer under the names the numpy
    inference reads (:func:`agents.policies.recurrent.weight_shapes`), checked against ``shapes``."""
    w = {"gru.weight_ih": model.gru.weight_ih, "gru.weight_hh": model.gru.weight_hh, "gru.bias_ih": model.gru.bias_ih,
         "gru.bias_hh": model.gru.bias_hh, "out.weight": model.out.weight, "out.bias": model.out.bias}
    for i, layer in enumerate(model.head):
        w[f"head.{i}.weight"], w[f"head.{i}.bias"] = layer.weight, layer.bias
    out = {k: v.detach().numpy().copy() for k, v in w.items()}
    assert {k: v.shape for k, v in out.items()} == {k: tuple(v) for k, v in shapes.items()}
    return out


MODELS = {"cv": ("agents.training.backprop", "CVQModel"),
          "imm_cv_ct": ("agents.training.learned_imm", "LearnedIMMModel")}
"""``--tracker`` name -> the (module, class) of its :class:`ChainModel` (imported when built): ``cv``, the CV
filter's q per look (the policy ``policy_bp``); ``imm_cv_ct``, the learned IMM (``policy_imm_bp``)."""

HP_FILES = {"cv": "backprop", "imm_cv_ct": "backprop_imm_cv_ct"}
"""``--tracker`` name -> its default hyperparameter file ``agents/training/hyperparams/<name>.toml``."""


def make_model(hp, cfg):
    """The model of ``hp["tracker"]`` (:data:`MODELS`) for the env config ``cfg``."""
    import importlib
    name = hp["tracker"]
    if name not in MODELS:
        raise ValueError(f"--tracker: unknown model {name!r}; valid: {sorted(MODELS)}")
    module, cls = MODELS[name]
    return getattr(importlib.import_module(module), cls).build(hp, cfg)


# ============================================================================================ hyperparameters
def _int(lo, hi=None):
    return (lambda v: isinstance(v, int) and not isinstance(v, bool) and v >= lo and (hi is None or v <= hi),
            f"an integer >= {lo}" + ("" if hi is None else f" and <= {hi}"))


def _num(lo, hi=None, open_lo=False):
    def ok(v):
        return (isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)
                and (v > lo if open_lo else v >= lo) and (hi is None or v <= hi))
    return ok, f"a number {'>' if open_lo else '>='} {lo}" + ("" if hi is None else f" and <= {hi}")


IMM_SPECS = ("imm_cv_ct", "imm_ct_bank")
"""The classical IMMs a learned IMM may be built around (hyperparameter ``imm``, ``--tracker imm_cv_ct`` only): its
modes and the tuned values its untrained weights give."""

HP_SPEC = {
    "tracker": ((lambda v: v in MODELS), f"one of {sorted(MODELS)}"),
    "n_steps": _int(1),
    "batch_episodes": _int(1),
    "chunk_looks": _int(1, 10_000),
    "learning_rate": _num(0.0, 1.0, open_lo=True),
    "lr_final_fraction": _num(0.0, 1.0),
    "max_grad_norm": _num(0.0, None, open_lo=True),
    "loss": ((lambda v: v in LOSSES), f"one of {list(LOSSES)}"),
    "loss_scale_m": _num(0.0, None, open_lo=True),
    "hidden_size": _int(1, 4096),
    "head": ((lambda v: isinstance(v, list) and len(v) <= 8 and all(
        isinstance(n, int) and not isinstance(n, bool) and 1 <= n <= 4096 for n in v)),
        "a list of at most 8 layer widths in [1, 4096]"),
    "eval_every": _int(1),
    "eval_scenarios": EVAL_SCENARIOS_HP,
    "select_on": SELECT_ON_HP,
    "env_kwargs": ((lambda v: isinstance(v, dict)), "a JSON object of RadarTrack-v0 arguments"),
    "chain": ((lambda v: v in CHAINS), f"one of {list(CHAINS)}"),
    "turn_rate_max_deg_s": _num(0.0, 180.0),
    "turn_gain": _num(0.0, 1.0, open_lo=True),
    "init_from": ((lambda v: isinstance(v, str) and v != ""), "the path of a trained q-policy's policy.npz"),
    "imm": ((lambda v: v in IMM_SPECS), f"one of {list(IMM_SPECS)}"),
}
"""Every hyperparameter of ``--method backprop`` (``agents/training/hyperparams/backprop.toml`` documents them):
``{key: (check, what it must be)}``."""
HP_OPTIONAL = ("chain", "turn_rate_max_deg_s", "turn_gain", "init_from", "imm")
"""Keys that may be absent (then their default: ``chain`` ``compiled``, ``turn_rate_max_deg_s`` 0 (q only),
``turn_gain`` 1, no ``init_from``, ``imm`` ``imm_cv_ct``); absent from the recipes' files, so that their runs'
``config.json`` (what a resume compares) is the same as before the key existed. ``turn_rate_max_deg_s``,
``turn_gain`` and ``init_from`` are the CV model's (``tracker`` ``cv``), ``imm`` the learned IMM's."""



def check_hp(hp):
    """Validate ``hp`` (``ValueError`` naming ``--hp KEY``, what it must be and the value given); returns ``(hp,
    env_kwargs, cfg)`` with the env arguments completed (continuous actions, the features pinned) and checked."""
    hp = dict(hp)
    for k, v in hp.items():
        if k not in HP_SPEC:
            raise ValueError(f"--hp {k}: unknown hyperparameter for --method backprop; valid: {sorted(HP_SPEC)}")
        ok, what = HP_SPEC[k]
        if not ok(v):
            raise ValueError(f"--hp {k}: must be {what}, got {v!r}")
    missing = [k for k in HP_SPEC if k not in hp and k not in HP_OPTIONAL]
    if missing:
        raise ValueError(f"--hp: missing hyperparameter(s) {missing} (agents/training/hyperparams/backprop.toml "
                         "gives every one)")
    cv_only = [k for k in ("turn_rate_max_deg_s", "turn_gain", "init_from") if k in hp and hp["tracker"] != "cv"]
    if cv_only:
        raise ValueError(f"--hp {cv_only[0]}: an option of the CV q-policy (--tracker cv), not of "
                         f"{hp['tracker']!r}")
    if "imm" in hp and hp["tracker"] != "imm_cv_ct":
        raise ValueError(f"--hp imm: an option of the learned IMM (--tracker imm_cv_ct), not of {hp['tracker']!r}")
    bad = [n for n in hp["select_on"] if n not in hp["eval_scenarios"]]
    if bad:
        raise ValueError(f"--hp select_on: {bad} are not among the validation suites (eval_scenarios) "
                         f"{list(hp['eval_scenarios'])}")
    env_kwargs = dict(hp["env_kwargs"])
    if env_kwargs.get("scenario", "random") not in TRAIN_SCENARIOS:
        raise ValueError(f"--env-kwargs: training uses the random scenario generators only (scenario must be one of "
                         f"{list(TRAIN_SCENARIOS)}, got {env_kwargs['scenario']!r})")
    if env_kwargs.setdefault("action_type", "continuous") != "continuous":
        raise ValueError(f"--env-kwargs: action_type must be 'continuous' for --method backprop (the network outputs "
                         f"a continuous action), got {env_kwargs['action_type']!r}")
    if env_kwargs.get("frame_stack", 1) != 1:
        raise ValueError(f"--env-kwargs: frame_stack must be 1 for --method backprop (the GRU carries the history), "
                         f"got {env_kwargs['frame_stack']!r}")
    env_kwargs.setdefault("features", list(DEFAULT_FEATURES))   # pinned: the default list may grow
    det = [f for f in env_kwargs["features"] if f in DETECTOR_FEATURES]
    if det:
        raise ValueError(f"--env-kwargs: features {det} are not supported by --method backprop (its lockstep does "
                         f"not run the detectors' IMMs; PPO and the other SB3 algorithms take them)")
    try:
        cfg = EnvConfig.from_kwargs(**env_kwargs_from_json(env_kwargs))
    except (TypeError, ValueError) as e:
        raise ValueError(f"--env-kwargs: {e}") from None
    hp["env_kwargs"] = env_kwargs
    from agents.training.runs import check_rows_fit
    check_rows_fit("--hp batch_episodes", int(hp["batch_episodes"]))     # before any allocation
    return hp, env_kwargs, cfg


# ================================================================================================ the trainer
class StreamingTrainer:
    """The lockstep, streaming truncated backpropagation of the module docstring, for one model.

    Args:
        model: a :class:`ChainModel`. cfg: the env config (observation, track start, training flights).
        batch_episodes: rows. chunk_looks: looks per optimiser step. seed: training seed ``S``. loss: one of
            :data:`LOSSES`.
        stream_start: ``s0`` of the rows' streams (0 for a fresh run; the resumed step otherwise).
        rngs: the rows' generators instead (tests: a row seeded like a single env's ``reset(seed=...)`` plays the
            env's episodes).
    """

    def __init__(self, model, cfg, batch_episodes, chunk_looks, seed, stream_start=0, rngs=None,
                 loss="position_mse"):
        self.model, self.cfg, self.loss = model, cfg, loss
        self.B, self.C = int(batch_episodes), int(chunk_looks)
        lv = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
        self.layout = ObservationLayout(cfg.features, lv[0], lv[-1])
        self.tracker = cfg.track_start.tracker(self.B)
        self.rngs = (list(rngs) if rngs is not None else
                     [np.random.default_rng([int(seed), int(stream_start), r]) for r in range(self.B)])
        self.obs = np.zeros((self.B, len(cfg.features)), dtype=np.float32)
        self.episodes_done = self.row_looks = self.scored_looks = 0
        model.reset_state(self.B)
        self._load(np.arange(self.B))

    def _load(self, rows):
        """New episodes into ``rows``: one batched draw, the track start, the first observation (as env.reset)."""
        cfg = self.cfg
        batch = draw_episodes(cfg.scenario, cfg.radar, cfg.random_scenario_config, [self.rngs[r] for r in rows],
                              cfg.warmup_scans)
        out = self.tracker.load(rows, [batch.episode(i) for i in range(rows.size)])
        self.obs[rows] = self.layout.encode(out, cfg.track_start.warmup_q_m_s2)
        self.model.start_rows(self.tracker, rows)

    def chunk(self):
        """One chunk of every row: returns ``(loss, looks)``, the chunk's loss (:data:`LOSSES`: pooled over its
        scored looks; a graph to backpropagate) and its :class:`radar_env.filters.torch_chain.ChainLooks`."""
        tr = self.tracker
        ended = np.flatnonzero(tr.k >= tr.n_looks)
        if ended.size:
            self.episodes_done += int(ended.size)
            self._load(ended)
        self.model.begin_chunk(tr)
        k0 = tr.k.copy()
        cut = np.minimum(tr.n_looks, k0 + self.C)
        looks = chunk_looks(tr, k0, cut)
        get = tr.look_data
        active = looks.scored.numpy()                              # (J, B): the row has a look at column j
        x = self.model.chunk_forward(tr, self.layout, self.obs, looks)
        self.row_looks += self.B * looks.J
        self.scored_looks += int(active.sum())
        if self.loss == "position_mse":
            return tc.pooled_position_mse(x, looks), looks
        at = lambda f: get(f)[np.arange(self.B)[:, None], looks.cols]   # noqa: E731 - (B, J) at the columns
        truth, site = at("truth"), at("site_xy_m")
        sig = measurement_sigma_m(np.hypot(*(truth[..., :2] - site).transpose(2, 0, 1)), at("range_noise_std_m"),
                                  at("bearing_noise_std_rad"))
        w = torch.from_numpy(np.where(active.T, 1.0 / sig ** 2, 0.0))
        return (tc.position_sq_error(x, looks) * w).sum() / looks.scored.sum(), looks


def chunk_looks(tracker, k0, cut):
    """:func:`radar_env.filters.torch_chain.looks_from_arrays` of every row's looks ``k0[b] .. cut[b] - 1`` (the
    tracker's stored looks; ``t_last`` the tracker's), read through :meth:`radar_env.filters.tracking.Tracker.look_window`
    (only the chunk's looks are gathered) and equal to building it from ``tracker.look_data`` (tested): the looks'
    ``start_index``, ``n_looks`` and ``cols`` index the tracker's stored looks, as there."""
    J = int((cut - k0).max())
    get = tracker.look_window(k0, max(J, 1))
    looks = tc.looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"), cut - k0,
                                 np.zeros_like(k0), tracker.t_last, **tc.range_rate_args(get, tracker.radial_velocity))
    cols = np.minimum(k0[:, None] + np.arange(looks.J)[None, :], tracker.look_data("t_s").shape[1] - 1)
    return looks._replace(start_index=k0.copy(), n_looks=np.asarray(cut, np.int64).copy(), cols=cols)


def lockstep(model, tracker, layout, obs, looks, on_look=None):
    """The columns of ``looks`` (the next looks of every row of ``tracker``): the model steps each, reading ``obs
    (B, F)`` (float32, the env's observation; updated in place with the next ones), and the numba ``tracker`` steps
    the rows that have the look with the model's q, whose output the env's ``layout`` encodes. Returns the model's
    position estimates ``x (B, J, 4)`` (a graph); ``on_look(j)`` (optional) is called after each model step."""
    active = looks.scored.numpy()
    xs = []
    for j in range(looks.J):
        x, q, *w = model.step(looks, j, torch.from_numpy(obs.astype(np.float64)))
        xs.append(x)
        if on_look is not None:
            on_look(j)
        observe(tracker, layout, obs, q, active[j], w[0] if w else None)
    return torch.stack(xs).permute(2, 0, 1)                      # (J, 4, B) -> (B, J, 4)


def observe(tracker, layout, obs, q, active, turn_rate_rad_s=None):
    """The numba ``tracker`` steps the rows that have this look (``active (B,)``) with their ``q (B,)`` (and turn rate
    ``(B,)``, if given); ``obs (B, F)`` takes, in place, those rows' next observation (the env's ``layout`` encoding of
    the step's output)."""
    rows = np.flatnonzero(active)
    w = turn_rate_rad_s
    if rows.size == obs.shape[0]:
        obs[:] = layout.encode(tracker.step(q, turn_rate_rad_s=w), q)
    elif rows.size:
        q = q[rows]
        obs[rows] = layout.encode(tracker.step(q, rows=rows, turn_rate_rad_s=None if w is None else w[rows]), q)


def forward_episodes(model, episodes, cfg, on_look=None):
    """``model`` over whole ``episodes`` from the common track start of ``cfg``, in one chunk and without chunking
    the graph (tests and diagnostics): ``(x (B, J, 4), looks)``, the looks after the start as
    :class:`radar_env.filters.torch_chain.ChainLooks`."""
    episodes = list(episodes)
    B = len(episodes)
    lv = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
    layout = ObservationLayout(cfg.features, lv[0], lv[-1])
    tr = cfg.track_start.tracker(B)
    out = tr.load(np.arange(B), episodes)
    obs = np.asarray(layout.encode(out, cfg.track_start.warmup_q_m_s2), dtype=np.float32)
    model.reset_state(B)
    model.start_rows(tr, np.arange(B))
    model.begin_chunk(tr)
    get = tr.look_data
    looks = tc.looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"), tr.n_looks,
                                 tr.k.copy(), tr.t_last, **tc.range_rate_args(get, tr.radial_velocity))
    return lockstep(model, tr, layout, obs, looks, on_look), looks


# ================================================================================================ checkpoints
def _save_resume(part, model, opt, meta, best_weights):
    """``checkpoints/last.npz`` (weights, Adam moments, the best checkpoint's policy weights and ``meta`` as a JSON
    string) written then renamed, so a kill leaves the previous checkpoint or the new one, never a mix; ``last.json``
    beside it is ``meta`` again, for reading (and for checkpoints written before 2026-12-06, which lack it in the
    npz)."""
    arrays = {f"model/{k}": v.detach().numpy() for k, v in model.state_dict().items()}
    arrays.update({f"best/{k}": v for k, v in (best_weights or {}).items()})
    arrays.update(adam_arrays(opt))
    write_checkpoint(part, arrays, meta)


def _load_resume(part, model, opt):
    """Restore ``model`` and ``opt`` from ``checkpoints/last.*``; returns ``(meta, best policy weights or None)``.
    A checkpoint that cannot be read, or that does not fit the run, is a ``ValueError`` of one line naming it."""
    d = part / "checkpoints"
    try:
        with np.load(d / "last.npz", allow_pickle=False) as z:
            meta = json.loads(str(z["meta_json"]) if "meta_json" in z.files else (d / "last.json").read_text())
            weights = {k[len("model/"):]: torch.from_numpy(z[k].copy()) for k in z.files if k.startswith("model/")}
            best = {k[len("best/"):]: z[k].copy() for k in z.files if k.startswith("best/")} or None
            adam = {k: z[k].copy() for k in z.files if k.startswith("adam/")}
        missing = [k for k in RESUME_META_KEYS if k not in meta]
        if missing:
            raise ValueError(f"its meta has no {missing}")
        if best is not None and not any(r.get("timesteps") == meta["best_step"] for r in meta["history"]):
            raise ValueError(f"its history has no row of its best step {meta['best_step']}")
        model.load_state_dict(weights)
        load_adam(opt, adam)
    except CHECKPOINT_ERRORS as e:
        raise checkpoint_refusal(part, e) from None
    return meta, best


RESUME_META_KEYS = ("step", "best_ratio", "best_step", "history", "episodes_done", "row_looks", "scored_looks",
                    "train_s", "wall_s", "resumed_at")
"""What a checkpoint's meta must hold for :func:`_run` to go on from it (the keys a new run starts with)."""


def _save_policy(directory, model, cfg, env_kwargs, extra=None, weights=None):
    """The policy checkpoint of ``model`` (its current weights, or ``weights``) in ``directory``; ``extra`` as
    ``selection.json``."""
    path = model.save_policy(directory, cfg, env_kwargs, weights)
    if extra is not None:
        (Path(directory) / "selection.json").write_text(json.dumps(jsonable(extra), indent=1, allow_nan=False))
    return path


RESUME_IGNORES = ("chain",)
"""Config keys a resume does not compare: how the chain runs, not what it computes (``chain``: the same gradient to
rounding), so a run started with ``compiled`` may go on with ``torch`` (e.g. on a machine without a C++ compiler)."""


def _resumable(part, config):
    """Whether ``part`` holds a checkpoint of a run with this ``config`` (:func:`agents.training.runs.resumable`;
    the keys of :data:`RESUME_IGNORES` may differ)."""
    return resumable(part, config, RESUME_IGNORES)


# =================================================================================================== training
def _lr_at(hp, step):
    """Cosine decay from ``learning_rate`` to ``lr_final_fraction`` of it over ``n_steps``."""
    f = hp["lr_final_fraction"]
    c = 0.5 * (1.0 + math.cos(math.pi * min(step / max(hp["n_steps"], 1), 1.0)))
    return hp["learning_rate"] * (f + (1.0 - f) * c)


def optimiser_step(trainer, opt, hp):
    """One optimiser step: a chunk of every row, its loss backpropagated (divided by ``loss_scale_m^2`` for
    ``position_mse``), the gradient norm clipped at ``max_grad_norm``, an Adam step. Returns ``(loss, grad norm
    before clipping)``; ``FloatingPointError`` if the gradient is not finite."""
    loss, _ = trainer.chunk()
    scale = hp["loss_scale_m"] ** 2 if hp["loss"] == "position_mse" else 1.0
    opt.zero_grad(set_to_none=True)
    (loss / scale).backward()
    grad_norm = float(torch.nn.utils.clip_grad_norm_(trainer.model.parameters(), hp["max_grad_norm"]))
    if not math.isfinite(grad_norm):
        raise FloatingPointError(f"the gradient is not finite (loss {float(loss.detach())!r})")
    opt.step()
    return float(loss.detach()), grad_norm


def train_backprop(hp, seed=0, out="runs", progress=True, verbose=1, command=None, args=None, run_name=None,
                   on_selection=None):
    """Train a model by backpropagation (module docstring) with hyperparameters ``hp`` (a dict as in
    ``agents/training/hyperparams/backprop.toml``; every key required, see :data:`HP_SPEC`). Returns the run folder.

    ``on_selection(row)`` (optional) is called after each validation (``row`` as in ``summary.json``'s
    ``selection_history``; ``timesteps`` there counts optimiser steps); the sweeps report it to Ray Tune.
    Everything is checked (``ValueError``) before the run folder is made."""
    torch.set_num_threads(1)
    # numba's thread pool too: the lockstep kernels gain little from it, and two runs side by side on a small
    # machine, each with a pool of every core, ran 8x slower per step (spinning threads), not 2x
    import numba
    numba.set_num_threads(1)
    hp, env_kwargs, cfg = check_hp(hp)
    seed = int(seed)
    if not 0 <= seed < MAX_TRAIN_SEED:
        raise ValueError(f"--seed: training seeds for --method backprop must lie in [0, {MAX_TRAIN_SEED}) (below the "
                         f"selection suites' seeds), got {seed}")
    run, part = run_paths(out, run_name, f"backprop_{hp['tracker']}_s{seed}_{time.strftime('%Y%m%d-%H%M%S')}")
    config = {"method": "backprop", "env_id": "RadarTrack-v0", "seed": seed, **hp}
    resume = part.exists() and _resumable(part, config)
    torch.manual_seed(seed)
    model = make_model(hp, cfg)
    if hp.get("init_from"):
        if not hasattr(model, "start_from"):
            raise ValueError(f"--hp init_from: the {hp['tracker']!r} model cannot start from a trained policy")
        model.start_from(hp["init_from"], cfg)      # a resume then loads its own checkpoint over it
    opt = torch.optim.Adam(model.parameters(), lr=hp["learning_rate"])
    try:
        selection = SelectionSuites(hp["eval_scenarios"], SELECTION_SEED_BASE, hp["select_on"])
    except ValueError as e:
        raise ValueError(f"--hp eval_scenarios / select_on: {e}") from None
    with writing_run(run, part, resumable=True, keep=resume):
        best = None
        if resume:
            (part / "FAILED").unlink(missing_ok=True)
            meta, best = _load_resume(part, model, opt)
            if best is not None:        # best/ as the checkpoint knows it (a kill may have left a newer one)
                row = next(r for r in meta["history"] if r["timesteps"] == meta["best_step"])
                _save_policy(part / "best", model, cfg, env_kwargs, row, weights=best)
            if verbose:
                print(f"resuming {part} from step {meta['step']}", file=sys.stderr, flush=True)
        else:
            write_run_files(part, config, args, command, env_kwargs)
            meta = {"step": 0, "best_ratio": None, "best_step": None, "history": [], "episodes_done": 0,
                    "row_looks": 0, "scored_looks": 0, "train_s": 0.0, "wall_s": 0.0, "resumed_at": []}
        summary = _run(model, opt, hp, cfg, env_kwargs, seed, part, selection, meta, best, resume, progress,
                       verbose, on_selection)
        _save_policy(part, model, cfg, env_kwargs)
        (part / "summary.json").write_text(json.dumps(jsonable(summary), indent=1, allow_nan=False))
        from agents.policies.learned import read_kind, write_run_layout
        write_run_layout(part, read_kind(part)[0], jsonable(summary))      # training.json, choice.json
    if verbose:
        print(f"run: {run}\n{summary['steps']} steps, {summary['episodes_done']} episodes in {summary['wall_s']:.0f} s "
              f"({summary['episodes_per_s']:.0f} training episodes/s, {summary['row_looks_per_s']:.0f} row-looks/s "
              f"excluding validation); best selection ratio policy/imm2 {summary['best_selection_ratio']:.3f} at step "
              f"{summary['best_step']} ({summary['best_wall_s']:.0f} s)")
    return run


def _run(model, opt, hp, cfg, env_kwargs, seed, part, selection, meta, best_weights, resume, progress, verbose,
         on_selection):
    from torch.utils.tensorboard import SummaryWriter
    start = int(meta["step"])
    if resume:
        meta["resumed_at"].append(start)
    trainer = StreamingTrainer(model, cfg, hp["batch_episodes"], hp["chunk_looks"], seed, stream_start=start,
                               loss=hp["loss"])
    writer = SummaryWriter(str(part / "tb"))
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=hp["n_steps"], initial=start, desc="backprop", unit="step", file=sys.stderr)
    wall0, train0 = float(meta["wall_s"]), float(meta["train_s"])
    t_start = time.perf_counter()
    train_s = 0.0
    base = {k: int(meta[k]) for k in ("episodes_done", "row_looks", "scored_looks")}
    best_w = [best_weights]

    def checkpoint(step):
        meta.update(step=step, wall_s=wall0 + time.perf_counter() - t_start, train_s=train0 + train_s,
                    **{k: base[k] + getattr(trainer, k) for k in base})
        _save_resume(part, model, opt, meta, best_w[0])

    def validate(step):
        """Score the current weights, keep them if best, checkpoint, then report (a callback that raises, e.g. a
        sweep stopping the trial, leaves a consistent checkpoint)."""
        row = model.validation_row(selection, cfg, env_kwargs)
        row = {"timesteps": step, **row, "wall_s": wall0 + time.perf_counter() - t_start,
               "episodes_done": base["episodes_done"] + trainer.episodes_done}
        best = meta["best_ratio"]
        improved = math.isfinite(row["selection_ratio"]) and (best is None or row["selection_ratio"] < best)
        row["best"] = bool(improved)
        if improved:
            meta["best_ratio"], meta["best_step"], meta["best_wall_s"] = row["selection_ratio"], step, row["wall_s"]
            best_w[0] = model.policy_weights()
            _save_policy(part / "best", model, cfg, env_kwargs, row)
        meta["history"].append(row)
        for k, v in row.items():
            if k.endswith("_ratio_imm2") or k == "selection_ratio":
                writer.add_scalar(f"eval/{k}", v if math.isfinite(v) else float("nan"), step)
        writer.add_scalar("eval/best_selection_ratio", meta["best_ratio"] or float("nan"), step)
        writer.flush()
        checkpoint(step)
        if on_selection is not None:
            on_selection(dict(row))
        if verbose and bar is None:
            print(f"[eval @ step {step}] selection ratio {row['selection_ratio']:.4f}"
                  f"{' *best*' if improved else ''} ({row['eval_s']:.1f} s)", file=sys.stderr, flush=True)
        return row

    if not meta["history"] or meta["history"][-1]["timesteps"] != start:
        validate(start)
    step = start
    while step < hp["n_steps"]:
        t0 = time.perf_counter()
        for g in opt.param_groups:
            g["lr"] = _lr_at(hp, step)
        loss, grad_norm = optimiser_step(trainer, opt, hp)
        step += 1
        dt = time.perf_counter() - t0
        train_s += dt
        rmse = math.sqrt(loss)           # m, or plot sigmas (loss "normalised")
        writer.add_scalar("train/chunk_rms_error", rmse, step)
        writer.add_scalar("train/grad_norm", grad_norm, step)
        writer.add_scalar("train/learning_rate", opt.param_groups[0]["lr"], step)
        writer.add_scalar("train/episodes_per_s", trainer.episodes_done / max(train_s, 1e-9), step)
        writer.add_scalar("train/row_looks_per_s", trainer.row_looks / max(train_s, 1e-9), step)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(rms=f"{rmse:.3g}", best=f"{meta['best_ratio'] or float('nan'):.4f}")
        if step % hp["eval_every"] == 0 or step == hp["n_steps"]:
            validate(step)
    if bar is not None:
        bar.close()
    writer.close()
    train_total = train0 + train_s
    done = {k: base[k] + getattr(trainer, k) for k in base}
    hist = meta["history"]
    return {"method": "backprop", "tracker": hp["tracker"], "steps": step, "episodes_done": done["episodes_done"],
            "row_looks": done["row_looks"], "scored_looks": done["scored_looks"],
            "wall_s": wall0 + time.perf_counter() - t_start, "train_s": train_total,
            "validation_s": float(sum(r["eval_s"] for r in hist)),
            "episodes_per_s": done["episodes_done"] / max(train_total, 1e-9),
            "row_looks_per_s": done["row_looks"] / max(train_total, 1e-9),
            "scored_looks_per_s": done["scored_looks"] / max(train_total, 1e-9),
            "best_selection_ratio": meta["best_ratio"], "best_step": meta["best_step"],
            "best_wall_s": meta.get("best_wall_s"), "resumed_at": meta["resumed_at"],
            "loadavg_1min_at_end": os.getloadavg()[0], "torch_threads": torch.get_num_threads(),
            "selection_history": hist}


# ======================================================================================================= CLI
def main_from_args(args, argv):
    """``radar-track train --method backprop`` (called by :func:`agents.training.train.main` with its parsed
    arguments). Returns the run folder."""
    for opt, v in (("--algo", args.algo), ("--action-type", args.action_type), ("--timesteps", args.timesteps),
                   ("--n-envs", args.n_envs)):
        if v is not None:
            raise SystemExit(f"error: {opt} applies to --method ppo; --method backprop takes --hp n_steps=N, "
                             "--hp batch_episodes=N (agents/training/hyperparams/backprop.toml)")
    if args.tracker is not None and args.tracker not in MODELS:
        raise SystemExit(f"error: --tracker: unknown model {args.tracker!r}; valid: {sorted(MODELS)}")
    try:   # each model's own defaults, unless a file is given
        hp = load_hyperparams(HP_FILES[args.tracker or "cv"], args.hyperparams)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    hp = apply_cli_overrides(hp, args.env_kwargs, args.hp)
    if args.tracker is not None:
        hp["tracker"] = args.tracker
    command = " ".join(["radar-track", "train", *map(shlex.quote, argv)])
    return run_cli(lambda: train_backprop(hp, seed=args.seed, out=args.out, progress=not args.no_progress,
                                         verbose=0 if args.quiet else 1, command=command, args=vars(args),
                                         run_name=args.name), command, args.out)
