"""Recurrent q-policies trained by backpropagation (:mod:`agents.training.backprop`), run in numpy, saved without
pickle.

A policy is a GRU over the env's observations (``RadarTrack-v0`` with ``action_type="continuous"``): at every look
it reads the observation, updates its hidden state ``h`` and outputs the continuous action
``a = tanh(head(h))`` in [-1, 1], which the env maps to ``q = q_min (q_max / q_min)^((a + 1) / 2)``
(:func:`radar_env.envs.core.actions_to_q_m_s2`). The GRU is torch's (``torch.nn.GRUCell``; gates in the order r, z, n)::

    r = sigmoid(W_ir x + b_ir + W_hr h + b_hr)
    z = sigmoid(W_iz x + b_iz + W_hz h + b_hz)
    n = tanh(W_in x + b_in + r * (W_hn h + b_hn))
    h' = (1 - z) * n + z * h

evaluated here in float64 numpy (equal to the torch cell to 1e-12: tests/test_backprop.py), so evaluation and
acting need no torch.

A checkpoint is three files in one folder: ``policy.npz`` (the weights, float64 arrays; read with
``np.load(allow_pickle=False)``: loading it runs no code, unlike an SB3 zip, which is a pickle), ``policy.json``
(format, model kind, architecture, input features, action range) and ``env_config.json`` (the ``RadarTrack-v0``
arguments it was trained with, as for SB3 policies: :func:`agents.policies.bundle.make_policy_env` reads it).

Two ways to act:

* in the evaluation, :class:`RecurrentQPolicy` is a *stateful* ``choose_q`` for
  :func:`baselines.trackers.run_q_policy`: ``reset(rows)`` clears the hidden state of rows that start an episode
  and ``policy(obs_rows, rows) -> q (n,)`` m/s^2 steps those rows;
* in the env, :meth:`RecurrentQPolicy.predict` works like sb3-contrib's ``RecurrentPPO.predict``: it takes the
  observation(s), the recurrent state it returned last time (None at the start) and ``episode_start`` (True where
  an episode has just begun: the state is cleared there), and returns ``(actions, state)``::

      policy, cfg = load_recurrent_policy("agents/bundled/backprop/policy.npz")
      env = make_policy_env("agents/bundled/backprop/policy.npz")
      obs, info = env.reset(seed=0)
      state, start = None, True
      while True:
          action, state = policy.predict(obs, state, episode_start=start)
          obs, reward, terminated, truncated, info = env.step(action)
          if terminated or truncated:
              break
          start = False
"""

from __future__ import annotations

import math
from pathlib import Path

import numba
import numpy as np

from radar_env.envs.core import actions_to_q_m_s2
from radar_env.common.units import G0_M_S2

__all__ = ["FORMAT", "VERSION", "POLICY_FILE", "RecurrentQPolicy", "gru_cell", "save_recurrent_policy",
           "load_recurrent_policy", "is_recurrent_checkpoint", "weight_shapes"]

FORMAT = "radar-track-recurrent-policy"
VERSION = 1
PRECISIONS = ("float64", "float32")
"""A network's forward precision (:class:`RecurrentQPolicy`'s ``precision``)."""
POLICY_FILE = "policy.npz"
"""File name of the weights; ``policy.json`` and ``env_config.json`` sit beside it."""


def _sigmoid(v):
    return 1.0 / (1.0 + np.exp(-v))


@numba.njit(cache=True)
def _linear(x, wT):
    n, F = x.shape
    H = wT.shape[1]
    out = np.zeros((n, H), dtype=x.dtype)      # float64, or float32 for a float32 forward (x and wT float32)
    F4 = F - F % 4
    i = 0
    while i < n:
        # four rows and four inputs at a time: each weight load serves four rows, each load and store of an output
        # four inputs; every out[i, h] is still summed over f = 0 .. F-1 in order, one product at a time, so the
        # result is the plain loop's to the bit (tested); the h loop is vectorised (lanes are different outputs). The
        # four rows are written out: a loop over them inside the h loop measured as fast on wide layers but 4x slower
        # on a 16-wide one, and outside it (no weight reuse across rows) 1.4-1.9x slower on wide layers
        if n - i >= 4:
            for f in range(0, F4, 4):
                a00, a01, a02, a03 = x[i, f], x[i, f + 1], x[i, f + 2], x[i, f + 3]
                a10, a11, a12, a13 = x[i + 1, f], x[i + 1, f + 1], x[i + 1, f + 2], x[i + 1, f + 3]
                a20, a21, a22, a23 = x[i + 2, f], x[i + 2, f + 1], x[i + 2, f + 2], x[i + 2, f + 3]
                a30, a31, a32, a33 = x[i + 3, f], x[i + 3, f + 1], x[i + 3, f + 2], x[i + 3, f + 3]
                for h in range(H):
                    w0, w1, w2, w3 = wT[f, h], wT[f + 1, h], wT[f + 2, h], wT[f + 3, h]
                    o = out[i, h]
                    o += a00 * w0
                    o += a01 * w1
                    o += a02 * w2
                    o += a03 * w3
                    out[i, h] = o
                    o = out[i + 1, h]
                    o += a10 * w0
                    o += a11 * w1
                    o += a12 * w2
                    o += a13 * w3
                    out[i + 1, h] = o
                    o = out[i + 2, h]
                    o += a20 * w0
                    o += a21 * w1
                    o += a22 * w2
                    o += a23 * w3
                    out[i + 2, h] = o
                    o = out[i + 3, h]
                    o += a30 * w0
                    o += a31 * w1
                    o += a32 * w2
                    o += a33 * w3
                    out[i + 3, h] = o
            for f in range(F4, F):
                a0, a1, a2, a3 = x[i, f], x[i + 1, f], x[i + 2, f], x[i + 3, f]
                for h in range(H):
                    w = wT[f, h]
                    out[i, h] += a0 * w
                    out[i + 1, h] += a1 * w
                    out[i + 2, h] += a2 * w
                    out[i + 3, h] += a3 * w
            i += 4
        else:
            for f in range(F):
                a = x[i, f]
                for h in range(H):
                    out[i, h] += a * wT[f, h]
            i += 1
    return out


def linear(x, w, dtype=np.float64):
    """``x (n, F) @ w.T``, each output summed over ``f = 0 .. F-1`` in that order, whatever ``n`` and the machine:
    a row's result does not depend on the rows that share its batch (BLAS kernels for one row and for several
    round differently, which the evaluation's batch-independence test refuses) nor on the CPU's vector width
    (numpy's einsum, used before 2026-12-04, accumulates in SIMD lanes). Compiled (:func:`_linear`). ``w``
    column-major (:func:`layer_weights`) is read without a copy; a narrow output (9 to 63 columns, not a multiple of
    16) is computed with zero weights up to the next multiple of 16 and cut: the compiled loop over the outputs
    seems to run vectorised in blocks of 16 only (measured: a 128 -> 12 layer took 1.8x the time of a 128 -> 16 one).
    ``dtype`` float32: inputs, weights, products and sums in float32 (twice the lanes: about 2x faster), the same
    order; the result float32."""
    wT = np.ascontiguousarray(np.asarray(w, dtype=dtype).T)
    x = np.ascontiguousarray(x, dtype=dtype)
    H = wT.shape[1]
    if 8 < H < 64 and H % 16:
        wT = np.concatenate([wT, np.zeros((wT.shape[0], 16 - H % 16), dtype=dtype)], 1)
        return _linear(x, wT)[:, :H]
    return _linear(x, wT)


def layer_weights(weights, dtype=np.float64):
    """A network's weight arrays as float64 (or ``dtype``), each matrix stored column-major: :func:`linear` reads
    ``w.T`` of such an array in place (a C-ordered ``(F, H)`` view) instead of copying every matrix at every look."""
    out = {}
    for k, v in weights.items():
        a = np.asarray(v, dtype=dtype)
        out[k] = np.asfortranarray(a) if a.ndim == 2 else np.ascontiguousarray(a)
    return out


def gru_cell(x, h, w_ih, w_hh, b_ih, b_hh, dtype=np.float64):
    """One GRU step (torch's ``GRUCell`` equations, module docstring): ``x (n, F)``, ``h (n, H)`` -> ``h' (n, H)``;
    ``dtype`` float32: in float32 (``h`` and the weights given in float32 too)."""
    gi = linear(x, w_ih, dtype) + b_ih
    gh = linear(h, w_hh, dtype) + b_hh
    H = h.shape[1]
    r = _sigmoid(gi[:, :H] + gh[:, :H])
    z = _sigmoid(gi[:, H:2 * H] + gh[:, H:2 * H])
    n = np.tanh(gi[:, 2 * H:] + r * gh[:, 2 * H:])
    return (1.0 - z) * n + z * h


def weight_shapes(arch):
    """``{name: shape}`` of a policy's weights for ``arch`` (``input_size``, ``hidden_size``, ``head``: sizes of
    the tanh layers between the GRU and the output, may be empty; ``n_out``: outputs, 1 unless given)."""
    F, H = int(arch["input_size"]), int(arch["hidden_size"])
    shapes = {"gru.weight_ih": (3 * H, F), "gru.weight_hh": (3 * H, H), "gru.bias_ih": (3 * H,),
              "gru.bias_hh": (3 * H,)}
    prev = H
    for i, n in enumerate(arch.get("head", [])):
        shapes[f"head.{i}.weight"], shapes[f"head.{i}.bias"] = (int(n), prev), (int(n),)
        prev = int(n)
    n_out = int(arch.get("n_out", 1))
    shapes["out.weight"], shapes["out.bias"] = (n_out, prev), (n_out,)
    return shapes


class RecurrentQPolicy:
    """A trained recurrent q-policy (module docstring), float64 numpy.

    Args:
        weights: ``{name: array}`` as :func:`weight_shapes` names them.
        arch: the architecture (``input_size``, ``hidden_size``, ``head``; ``n_out`` 2 for a turn-aware policy).
        q_levels_g: the env's q levels; their first and last bound the action (``RadarTrack-v0``'s action map).
        turn_rate_max_rad_s: a turn-aware policy's (``model`` ``cv_turn``, ``n_out`` 2) turn-rate bound: its second
            output ``a_1`` gives ``omega = turn_rate_max_rad_s * a_1`` (rad/s, positive = clockwise), the rate of
            the coordinated-turn prediction ``F_ct(dt, omega)``; 0 (default) for a q-policy.
        precision: ``"float64"`` (default: the trained network's numbers, equal to torch's to 1e-12) or
            ``"float32"`` (weights, state and arithmetic in float32, the same summation order: about 1.4x faster on
            the CPU; the actions differ from float64's by float32 rounding, about 1e-6). :meth:`with_precision`.

    A turn-aware policy (:attr:`turn_aware`) returns ``(q, omega)`` from :meth:`__call__`, which
    :func:`baselines.trackers.run_q_policy` passes to the chain; it has no ``RadarTrack-v0`` action (the env's action
    is q), so :meth:`predict` refuses it.
    """

    def __init__(self, weights, arch, q_levels_g, turn_rate_max_rad_s=0.0, precision="float64"):
        if precision not in PRECISIONS:
            raise ValueError(f"RecurrentQPolicy: precision must be one of {list(PRECISIONS)}, got {precision!r}")
        self.precision = precision
        self.dtype = np.dtype(precision).type
        self._weights, self._q_levels_g = weights, q_levels_g
        self.arch = dict(arch)
        self.w = layer_weights(weights, self.dtype)
        self.n_head = len(self.arch.get("head", []))
        self.input_size, self.hidden_size = int(arch["input_size"]), int(arch["hidden_size"])
        self.levels_m_s2 = np.asarray(q_levels_g, dtype=np.float64) * G0_M_S2
        self._h = np.zeros((0, self.hidden_size), dtype=self.dtype)
        self.n_out = int(self.arch.get("n_out", 1))
        self.turn_rate_max_rad_s = float(turn_rate_max_rad_s)
        if (self.n_out == 2) != (self.turn_rate_max_rad_s > 0) or self.n_out not in (1, 2):
            raise ValueError(f"RecurrentQPolicy: n_out {self.n_out} with turn_rate_max_rad_s "
                             f"{self.turn_rate_max_rad_s!r}: a q-policy has one output and no turn rate, a turn-aware "
                             "one two outputs and a positive turn-rate bound")

    def with_precision(self, precision):
        """The same policy run in ``precision`` (``"float64"`` or ``"float32"``), a new object (no state shared)."""
        return RecurrentQPolicy(self._weights, self.arch, self._q_levels_g, self.turn_rate_max_rad_s, precision)

    @property
    def turn_aware(self):
        """Whether the policy also sets the prediction's turn rate (``(q, omega)`` per look)."""
        return self.n_out == 2

    # ---- the network
    def initial_state(self, n):
        """The recurrent state of ``n`` rows at an episode start (zeros, ``(n, hidden_size)``, in the policy's
        precision)."""
        return np.zeros((int(n), self.hidden_size), dtype=self.dtype)

    def act(self, obs, h):
        """One look: ``obs (n, F)``, state ``h (n, H)`` -> ``(actions (n,) in [-1, 1], new state (n, H))`` (the
        q action; a turn-aware policy's turn-rate action is :meth:`act_all`'s second column), both in the policy's
        precision (:meth:`predict` and the evaluation's call return float64 actions and q)."""
        a, h = self.act_all(obs, h)
        return a[:, 0], h

    def act_all(self, obs, h):
        """One look: ``obs (n, F)``, state ``h (n, H)`` -> ``(actions (n, n_out) in [-1, 1], new state (n, H))``."""
        w, dt = self.w, self.dtype
        x = np.asarray(obs, dtype=dt).reshape(-1, self.input_size)
        h = gru_cell(x, np.asarray(h, dtype=dt).reshape(x.shape[0], self.hidden_size), w["gru.weight_ih"],
                     w["gru.weight_hh"], w["gru.bias_ih"], w["gru.bias_hh"], dt)
        y = h
        for i in range(self.n_head):
            y = np.tanh(linear(y, w[f"head.{i}.weight"], dt) + w[f"head.{i}.bias"])
        return np.tanh(linear(y, w["out.weight"], dt) + w["out.bias"]), h

    def q_of_actions(self, actions):
        """The env's action map: actions in [-1, 1] -> q (m/s^2)."""
        return actions_to_q_m_s2(np.asarray(actions, dtype=np.float64).reshape(-1, 1), "continuous",
                                 self.levels_m_s2)

    # ---- the evaluation's stateful choose_q (baselines.trackers.run_q_policy)
    def reset(self, rows):
        """Rows ``rows`` (index array) start an episode: their hidden state is cleared."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        need = int(rows.max()) + 1 if rows.size else 0
        if need > self._h.shape[0]:
            self._h = np.concatenate([self._h, np.zeros((need - self._h.shape[0], self.hidden_size), self.dtype)])
        self._h[rows] = 0.0

    def __call__(self, obs, rows):
        """q (m/s^2) for the next look of rows ``rows`` from their observations ``obs (n, F)``; advances their
        state (``reset`` them first)."""
        rows = np.asarray(rows, dtype=np.int64).reshape(-1)
        a, self._h[rows] = self.act_all(obs, self._h[rows])
        q = self.q_of_actions(a[:, 0])
        return (q, self.turn_rate_max_rad_s * a[:, 1].astype(np.float64)) if self.turn_aware else q

    # ---- acting in the env (as sb3-contrib's RecurrentPPO.predict)
    def predict(self, observation, state=None, episode_start=None, deterministic=True):
        """The action(s) for ``observation`` (``(F,)`` from a single env or ``(n, F)`` from a vector env).

        Args:
            state: what the previous call returned (``(n, H)``), or None at the start (zeros).
            episode_start: bool, scalar or ``(n,)``: True where the observation is an episode's first (after a reset);
                the state of those rows is cleared first. None: no row starts (but a None ``state`` is zeros).
            deterministic: accepted for compatibility; the policy is deterministic.
        Returns:
            ``(actions, state)``: float64 actions in [-1, 1], shape ``(1,)`` for a single observation or ``(n, 1)``,
            for ``env.step``; the new state to pass next time.
        """
        if self.turn_aware:
            raise ValueError("a turn-aware policy (model 'cv_turn') sets the prediction's turn rate, which "
                             "RadarTrack-v0's action (q) cannot carry: run it with baselines.trackers.run_q_policy or "
                             "radar-track evaluate --learned")
        obs = np.asarray(observation, dtype=np.float64)
        single = obs.ndim == 1
        obs = obs.reshape(-1, self.input_size)
        n = obs.shape[0]
        h = self.initial_state(n) if state is None else np.array(state, dtype=self.dtype).reshape(n, self.hidden_size)
        if episode_start is not None:
            h[np.broadcast_to(np.asarray(episode_start, dtype=bool).reshape(-1), (n,))] = 0.0
        a, h = self.act(obs, h)
        a = a.astype(np.float64, copy=False)
        return (a.reshape(1) if single else a.reshape(n, 1)), h


# ------------------------------------------------------------------------------------------------ checkpoints
def _checked_shapes(meta_file, arch):
    """:func:`weight_shapes` of ``arch`` from ``meta_file``, every size a positive int (ValueError, one line)."""
    ok = isinstance(arch, dict) and all(isinstance(arch.get(k), int) and not isinstance(arch.get(k), bool)
                                        and 0 < arch[k] <= 65536 for k in ("input_size", "hidden_size"))
    head = arch.get("head", []) if isinstance(arch, dict) else None
    ok = ok and isinstance(head, list) and all(isinstance(n, int) and not isinstance(n, bool) and 0 < n <= 65536
                                               for n in head)
    n_out = arch.get("n_out", 1) if isinstance(arch, dict) else None
    if not ok or not isinstance(n_out, int) or isinstance(n_out, bool) or not 0 < n_out <= 64:
        raise ValueError(f"{meta_file}: field 'architecture' must give input_size, hidden_size (positive ints), head "
                         f"(a list of them) and optionally n_out, got {arch!r}"[:300])
    return weight_shapes(arch)


def is_recurrent_checkpoint(path):
    """Whether ``path`` names a recurrent-policy checkpoint: an ``.npz`` with its ``policy.json`` beside it (the
    ``policy.npz`` beside an SB3 zip is that zip's numpy export: its folder's ``policy.json`` names an SB3 kind)."""
    path = Path(path)
    return path.suffix == ".npz" and path.with_suffix(".json").is_file() and not path.with_suffix(".zip").is_file()


def save_recurrent_policy(directory, weights, config, env_kwargs):
    """Write a checkpoint into ``directory``: ``policy.npz`` (``weights``), ``policy.json`` (``config``: must hold
    ``model`` and ``architecture``; the format and version are added) and ``env_config.json`` (``env_kwargs``).
    Returns the path of ``policy.npz``."""
    from agents.policies.layout import write_weights_folder     # kind: agents.policies.learned
    return write_weights_folder(directory, "gru_q_policy", FORMAT, VERSION, weights, config, env_kwargs)


def load_recurrent_policy(path):
    """Load a checkpoint (``policy.npz`` with ``policy.json`` and ``env_config.json`` beside it).

    Returns ``(RecurrentQPolicy, EnvConfig)``. Raises ``ValueError`` naming the file for a missing file, another
    format or version, a model kind this version cannot run, weights of the wrong shapes or not finite, or an env
    config that does not match the policy's input (features x frame_stack) or is not continuous."""
    from agents.policies import checks
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy file {str(path)!r} does not exist (or is not a file)")
    meta_file, env_file = path.with_suffix(".json"), path.with_name("env_config.json")
    for f in (meta_file, env_file):
        if not f.is_file():
            raise ValueError(f"{path}: no {f.name} beside it (a recurrent policy is {POLICY_FILE}, policy.json and "
                             "env_config.json in one folder; the policy.npz beside an SB3 zip is its numpy export: "
                             "give the .zip)")
    meta = checks.read_json_object(meta_file, "a recurrent-policy config (a JSON object)")
    if meta.get("format") != FORMAT:
        raise ValueError(f"{meta_file}: not a recurrent-policy config (format {meta.get('format')!r}, "
                         f"expected {FORMAT!r})")
    if isinstance(meta.get("version"), bool) or meta.get("version") != VERSION:
        raise ValueError(f"{meta_file}: version {meta.get('version')!r}; this package reads version {VERSION}")
    if meta.get("model") not in ("cv", "cv_turn"):
        raise ValueError(f"{meta_file}: model {meta.get('model')!r}; this loader runs the 'cv' model (a GRU choosing "
                         "the CV filter's q) and 'cv_turn' (q and the prediction's turn rate)")
    arch = meta.get("architecture")
    shapes = _checked_shapes(meta_file, arch)
    w_max = 0.0
    if meta["model"] == "cv_turn":
        w_max = meta.get("turn_rate_max_rad_s")
        if (isinstance(w_max, bool) or not isinstance(w_max, (int, float)) or not math.isfinite(w_max)
                or not 0 < w_max <= math.pi):
            raise ValueError(f"{meta_file}: field 'turn_rate_max_rad_s' must be a number in (0, pi], got {w_max!r}"[:300])
    if int(arch.get("n_out", 1)) != (2 if meta["model"] == "cv_turn" else 1):
        raise ValueError(f"{meta_file}: model {meta['model']!r} has {2 if meta['model'] == 'cv_turn' else 1} "
                         f"output(s), architecture n_out is {arch.get('n_out', 1)!r}")
    weights = checks.read_npz(path)
    checks.check_weights(path, weights, shapes)
    _, cfg = checks.check_env_config(env_file)
    feats = meta.get("input_features", list(cfg.features))
    if not isinstance(feats, list) or not all(isinstance(f, str) for f in feats):
        raise ValueError(f"{meta_file}: field 'input_features' must be a list of feature names, got {feats!r}"[:300])
    rng = meta.get("q_range_m_s2")
    if rng is not None and (not isinstance(rng, list) or len(rng) != 2):
        raise ValueError(f"{meta_file}: field 'q_range_m_s2' must be [q_min, q_max], got {rng!r}"[:300])
    if rng is not None:
        checks.check_finite_numbers(meta_file, rng, "q_range_m_s2")
    if cfg.action_type != "continuous":
        raise ValueError(f"{env_file}: a recurrent policy acts with action_type='continuous', got {cfg.action_type!r}")
    n_in = len(cfg.features) * cfg.frame_stack
    if n_in != shapes["gru.weight_ih"][1] or list(meta.get("input_features", cfg.features)) != list(cfg.features):
        raise ValueError(f"{path}: the policy reads {shapes['gru.weight_ih'][1]} inputs "
                         f"({meta.get('input_features')}) but {env_file.name} gives {len(cfg.features)} features x "
                         f"frame_stack {cfg.frame_stack} ({list(cfg.features)})")
    if not all(math.isfinite(float(v)) for v in cfg.q_levels_g):
        raise ValueError(f"{env_file}: q_levels_g must be finite")
    if rng is not None:     # the action -> q map it was trained with (first and last q level)
        levels = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
        if not np.allclose([levels[0], levels[-1]], np.asarray(rng, dtype=np.float64), rtol=1e-9, atol=0.0):
            raise ValueError(f"{env_file}: q_levels_g span {levels[0]:.6g}-{levels[-1]:.6g} m/s^2, but the policy was "
                             f"trained with q from {float(rng[0]):.6g} to {float(rng[1]):.6g} m/s^2 (recorded in "
                             f"{meta_file.name}); give its training q_levels_g")
    return RecurrentQPolicy(weights, arch, cfg.q_levels_g, w_max), cfg
