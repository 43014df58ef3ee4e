r"""Hindsight bounds: the q schedule (and turn-rate schedule) that is best for each episode, chosen knowing the truth.

``hindsight_q`` is the ceiling of RadarTrack-v0's action space: for each episode, the whole sequence
:math:`q_k` (one per look after the common track start) that minimises that episode's position MSE after the track
start -- the metric the evaluation pools -- for the env's own chain (two-hit start and warm-up through
:class:`radar_env.filters.tracking.Tracker`, then ``F_cv(dt)``, ``Q = q_k^2 Gamma Gamma^T``, Joseph update). ``q_k`` is
restricted to the action range ``[q_min, q_max]`` of ``EnvConfig.q_levels_g`` (default 0.00182 g .. 8.11 g): an
agent of the env can only choose in that range, so a q-policy run with other levels or a rule whose q leaves the
range (``cmin``, ``kim_lee``) is not bounded by it on every episode (``q_range_g`` widens it).

``hindsight_q_turn`` also chooses a coordinated-turn rate :math:`\omega_k` per look (prediction with
``F_ct(dt, omega_k)``, :func:`radar_env.filters.kalman.transition_ct`), :math:`|\omega_k| \le` ``turn_rate_max_deg_s``
(default 20 deg/s, the random scenario's turn-rate cap ``RandomScenarioConfig.max_turn_rate_deg_s``): how much an
action that may also turn the prediction could add over q alone.

How they are computed
---------------------
The chain after the track start is written a second time as a compiled kernel (numba, float64,
:func:`_mse_grad_rows`) that returns each episode's MSE :math:`J_b = \frac{1}{n_b}\sum_k |\hat p_k - p_k|^2` over
its ``n_b`` scored looks *and* its exact gradient by a hand-written reverse (adjoint) pass through the same steps
(the formulas of :mod:`radar_env.filters.kalman`: ``F x``, ``F P F^T + q^2 G`` symmetrised, Joseph update). The tests check
the forward pass against the chain and against the project's differentiable chain (:func:`torch_forward`,
:mod:`radar_env.filters.torch_chain`), and the gradient against torch's autograd through it (itself checked against finite
differences in tests/test_torch_chain.py). Each episode and start is then minimised by its own L-BFGS
(:func:`_lbfgs_rows`, batched but row-independent: a two-loop recursion and an Armijo backtracking line search per
row) over ``s`` with :math:`\log q_k = c + h \sin s_k` (so ``q`` stays in ``[q_min, q_max]`` and reaches the bounds
exactly) and, for the turn bound, :math:`\omega_k = \omega_{max} \sin s'_k`. The objective of a row is its MSE
over its start's MSE. (scipy's bounded L-BFGS-B was tried: 1.17 spends ~10 ms per iteration at a few hundred
variables, 20x the MSE and gradient.) Starts:

* ``hindsight_q``: the tuned constant q (``kf_tuned``), the warm-up level 0.03 g (``kf_low``), and the
  clairvoyant-ish ``q_k = max(|a_true(t_k)|, 0.03 g)`` (``oracle_q``), each clipped into the range;
* ``hindsight_q_turn``: ``hindsight_q``'s schedule with ``omega = 0`` (so it is never worse than ``hindsight_q``)
  and with ``omega_k`` = the true turn rate at look k (clipped).

L-BFGS takes only steps that decrease the objective, so the answer (the best start's end point) is never worse
than any of its starts on any episode: ``kf_tuned`` and ``kf_low`` exactly, up to the ~1e-14 agreement of the
kernel and the chain.

The problem is not convex in ``q``: the answer is a local optimum (the best of a few), an *upper* bound on the true
ceiling's RMSE (the true best schedule can only be better). It is a lower bound on any q-policy's RMSE only up to
that non-convexity; tests/test_hindsight.py checks that it is below every q-policy of the comparison on every
episode of a small suite. The reported estimates are not the kernel's: the chosen schedules are re-run through the
library's chain (:class:`radar_env.filters.tracking.Tracker`, :func:`chain_forward`).

What it is not: a causal tracker. The schedule is fitted to the episode's own measurement noise as well as to its
maneuvers (one or two free numbers per look), so the bounds can fall below ``clairvoyant`` (measured on 100
``bizup2002`` runs: ``hindsight_q`` 135 m, ``hindsight_q_turn`` 83 m, ``clairvoyant`` 99 m, ``imm2`` 183 m) and their
covariances are not consistent (ANEES 20 and 199 there): read them as "no q-policy (turn-aware policy) can do
better than this", not as a target a filter can reach. They optimise position only (velocity RMSE is not lower).

Convergence (:class:`HindsightInfo`): iterations per episode, the final projected gradient norm of ``log J_b`` with
respect to ``(log q_k, omega_k / omega_max)`` (dimensionless), the relative improvement of ``J_b`` over the last
10 % of the iteration limit, and the wall time. torch is needed only by :func:`torch_forward` (the tests' oracle).
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from pathlib import Path

import numba
import numpy as np

from radar_env.common.numba_cache import drop_stale_kernels, package_sources
from radar_env.envs.observation import DEFAULT_Q_LEVELS_G
from radar_env.common.units import DEG, G0_M_S2

from .trackers import _loop, _Recorder, _start, _tracker
from .tuned_params import tuned_parameters

__all__ = ["run_hindsight_q", "run_hindsight_q_turn", "HindsightInfo", "torch_forward", "chain_forward", "kernel_forward",
           "DEFAULT_TURN_RATE_MAX_DEG_S", "DEFAULT_ITERATIONS"]

DEFAULT_TURN_RATE_MAX_DEG_S = 20.0
"""Bound on the hindsight turn rate (deg/s): the random scenario's turn-rate cap (``max_turn_rate_deg_s``)."""

DEFAULT_ITERATIONS = 300
"""L-BFGS iteration limit per start (measured: the last 10 % improve hindsight_q by ~1e-5 relative)."""


@dataclass
class HindsightInfo:
    """Convergence and cost of one hindsight optimisation (per-episode arrays have shape (B,)).

    Attributes:
        iterations: (B,) L-BFGS iterations of the best start.
        starts: names of the starts.
        best_start: (B,) index into ``starts`` of the start whose descent gave the answer.
        mse_m2: (B,) per-episode position MSE of the answer (the kernel's forward).
        start_mse_m2: (B, S) MSE of each start (iterate 0).
        grad_norm: (B,) projected gradient norm of ``log MSE`` w.r.t. the schedule at the last iterate of the best
            start (dimensionless: relative MSE change per unit of log q; omega in units of its bound; zero where a
            bound holds the schedule).
        last_improvement: (B,) relative decrease of the MSE over the last 10 % of the iteration limit.
        seconds: wall time of the optimisation.
    """

    iterations: np.ndarray
    starts: tuple
    best_start: np.ndarray
    mse_m2: np.ndarray
    start_mse_m2: np.ndarray
    grad_norm: np.ndarray
    last_improvement: np.ndarray
    seconds: float


def _torch_chain():
    try:
        from radar_env.filters import torch_chain
    except ImportError:   # pragma: no cover - depends on the install
        raise ValueError("torch_forward needs torch (pip install -e '.[train]')") from None
    return torch_chain


def _check_args(q_range_g, turn_rate_max_deg_s, iterations):
    iterations = DEFAULT_ITERATIONS if iterations is None else iterations
    try:
        lo, hi = (float(v) for v in q_range_g)
    except (TypeError, ValueError):
        raise ValueError(f"q_range_g must be (lo, hi) in g, got {q_range_g!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo < hi <= 100.0):
        raise ValueError(f"q_range_g must be (lo, hi) with 0 < lo < hi <= 100 g, got {q_range_g!r}")
    try:
        w = float(turn_rate_max_deg_s)
    except (TypeError, ValueError):
        w = np.nan
    if not (np.isfinite(w) and 0.0 < w <= 180.0):
        raise ValueError(f"turn_rate_max_deg_s must be in (0, 180] deg/s, got {turn_rate_max_deg_s!r}")
    if isinstance(iterations, bool) or not isinstance(iterations, (int, np.integer)) or not 0 <= iterations <= 100000:
        raise ValueError(f"iterations must be an integer in [0, 100000], got {iterations!r}")
    return lo, hi, w, int(iterations)


# ------------------------------------------------------------------------------------------------ problem data
class _Problem:
    """The looks after the common track start of B episodes, aligned at the start: column j of row b is look
    ``start_b + j``; ``mask`` marks the scored looks (each episode's looks from its start to its end)."""

    def __init__(self, episodes, cfg):
        tr, out = _tracker(episodes, cfg)
        self.tr, self.out = tr, out
        self.start = tr.k.copy()                     # first look after the track start
        self.n = tr.n_looks - self.start              # scored looks per episode (>= 1)
        B, J = tr.B, int(self.n.max())
        cols = self.start[:, None] + np.arange(J)[None, :]
        self.mask = np.arange(J)[None, :] < self.n[:, None]
        cols = np.minimum(cols, tr.look_data("t_s").shape[1] - 1)
        rows = np.arange(B)[:, None]
        get = lambda f: tr.look_data(f)[rows, cols]   # noqa: E731
        t = get("t_s")
        t_prev = np.concatenate([tr.t_last[:, None], t[:, :-1]], axis=1)
        self.dt = np.where(self.mask, t - t_prev, 0.0)
        self.det = get("detected") & self.mask
        self.z = np.where(self.det[..., None], get("z_m"), 0.0)
        self.R = np.where(self.det[..., None, None], get("R_m2"), np.eye(2))
        self.pos = get("truth")[..., :2]
        a = get("truth_accel_m_s2")
        self.accel_m_s2 = np.hypot(a[..., 0], a[..., 1])
        self.turn_rate_rad_s = get("truth_turn_rate_rad_s")
        self.x0, self.P0 = tr.x.copy(), tr.P.copy()
        self.B, self.J = B, J


# ------------------------------------------------------------------------------------------------ torch forward
def _torch_mse(prob, log_q, omega=None):
    """Per-row position MSE after the track start, differentiable in ``log_q`` (B, J) and ``omega`` (B, J) torch
    tensors: the project's differentiable chain (:mod:`radar_env.filters.torch_chain`) from the problem's track start."""
    tc = _torch_chain()
    state, looks = tc.handover(prob.tr)
    out = tc.run(state, looks, log_q.exp(), omega)
    return tc.position_sq_error(out.x, looks).sum(1) / looks.n_scored


def torch_forward(episodes, q_m_s2, turn_rate_rad_s=None, cfg=None):
    """Per-episode position MSE (m^2) after the track start of the torch chain for given schedules.

    ``q_m_s2`` (B, >= J) (and ``turn_rate_rad_s``), column j = look ``start_b + j`` (J = the most looks after a
    start; further columns are ignored); the tests' oracle for :func:`kernel_forward` and :func:`chain_forward`."""
    _torch_chain()
    import torch

    prob = _Problem(list(episodes), cfg)
    lq = torch.as_tensor(np.log(np.asarray(q_m_s2, dtype=np.float64)[:, :prob.J]))
    om = (None if turn_rate_rad_s is None
          else torch.as_tensor(np.asarray(turn_rate_rad_s, dtype=np.float64)[:, :prob.J]))
    with torch.no_grad():
        return _torch_mse(prob, lq, om).numpy()


# ------------------------------------------------------------------------------------------------ the chain
def chain_forward(episodes, q_m_s2, turn_rate_rad_s=None, name="hindsight_q", cfg=None):
    """Run the library's chain (:class:`radar_env.filters.tracking.Tracker`) with the schedule ``q_m_s2`` (B, J) (column j
    = look ``start_b + j``) and optionally ``turn_rate_rad_s`` (B, J) (CT prediction); returns the
    :class:`TrackRun` (``extra["turn_rate_deg_s"]`` when a turn rate is given)."""
    tr, out = _tracker(list(episodes), cfg)
    B, K = tr.B, int(tr.n_looks.max())
    q_m_s2 = np.asarray(q_m_s2, dtype=np.float64)
    w = None if turn_rate_rad_s is None else np.asarray(turn_rate_rad_s, dtype=np.float64)
    rec = _Recorder(name, B, K, extra=() if w is None else ("turn_rate_deg_s",))
    rec.put(np.arange(B), out.look_index, out.x, out.P, out.q_m_s2)
    start = out.look_index + 1
    rec.run.start_index[:] = start

    def step(rows):
        j = tr.k[rows] - start[rows]
        q = q_m_s2[rows, j]
        if w is None:
            o = tr.step(q, rows=None if rows.size == B else rows)
            rec.put(rows, o.look_index, o.x, o.P, q)
        else:
            o = tr.step(q, rows=None if rows.size == B else rows, turn_rate_rad_s=w[rows, j])
            rec.put(rows, o.look_index, o.x, o.P, q, turn_rate_deg_s=np.degrees(w[rows, j]))
        return o

    _loop(tr, out, step)
    return rec.run


# ------------------------------------------------------------------------------------------------ numba kernel
@numba.njit(cache=True)
def _mm(A, B):
    """A @ B for small matrices (explicit loops: BLAS calls cost more than the arithmetic at 4 x 4)."""
    out = np.zeros((A.shape[0], B.shape[1]))
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            a = A[i, k]
            for j in range(B.shape[1]):
                out[i, j] += a * B[k, j]
    return out


@numba.njit(cache=True)
def _mv(A, x):
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            out[i] += A[i, k] * x[k]
    return out


@numba.njit(cache=True)
def _ct_coeffs(dt, w):
    """F_ct entries a = sin(th)/w, b = (1 - cos th)/w, c = cos th, s = sin th (th = w dt) and their w-derivatives;
    a series below |th| = 1e-2 (error < 1e-14 relative), the exact forms elsewhere (b via 2 sin^2(th/2), no
    cancellation)."""
    th = w * dt
    s, c = np.sin(th), np.cos(th)
    if abs(th) < 1e-2:
        t2 = th * th
        a = dt * (1.0 - t2 / 6.0 + t2 * t2 / 120.0 - t2 * t2 * t2 / 5040.0)
        b = dt * th * (0.5 - t2 / 24.0 + t2 * t2 / 720.0 - t2 * t2 * t2 / 40320.0)
        da = dt * dt * th * (-1.0 / 3.0 + t2 / 30.0 - t2 * t2 / 840.0)
        db = dt * dt * (0.5 - t2 / 8.0 + t2 * t2 / 144.0 - t2 * t2 * t2 / 5760.0)
    else:
        a = s / w
        h = np.sin(0.5 * th)
        b = 2.0 * h * h / w
        da = (th * c - s) / (w * w)
        db = (th * s - 2.0 * h * h) / (w * w)
    return a, b, c, s, da, db, -dt * s, dt * c


@numba.njit(cache=True)
def _mse_grad_rows(x0, P0, dt, det, z, Rm, pos, n, lq, w, turn, want_grad):
    """Per-row position MSE after the track start and its gradient w.r.t. ``lq = log q`` (and ``w``, if ``turn``).

    Forward: F x, F P F^T + q^2 G symmetrised, and the Joseph update with H = [I 0] symmetrised. The chain's
    update (radar_env.filters.kernels._gain_update) computes the same posterior in R's principal axes with a PD floor: the
    two agree to rounding on ordinary looks and differ only where the floor acts (near-singular plots, long hard
    coasts), so a schedule optimised here is scored by the chain itself (chain_forward). Reverse: the adjoint of the same steps (matrix calculus, written out below). Rows are
    independent: a row's numbers do not depend on the other rows of the batch."""
    Rn, J = dt.shape
    mse = np.zeros(Rn)
    g_lq = np.zeros((Rn, J))
    g_w = np.zeros((Rn, J))
    Fs = np.zeros((J, 4, 4))
    xprev = np.zeros((J, 4))
    Pprev = np.zeros((J, 4, 4))
    Pps = np.zeros((J, 4, 4))
    xpost = np.zeros((J, 4))
    Ks = np.zeros((J, 4, 2))
    Sis = np.zeros((J, 2, 2))
    nus = np.zeros((J, 2))
    G = np.zeros((4, 4))
    for r in range(Rn):
        x = x0[r].copy()
        P = P0[r].copy()
        nr = n[r]
        sse = 0.0
        for j in range(nr):
            d = dt[r, j]
            F = Fs[j]
            F[:, :] = 0.0
            F[0, 0] = F[1, 1] = 1.0
            if turn:
                a, b, c, s, _, _, _, _ = _ct_coeffs(d, w[r, j])
            else:
                a, b, c, s = d, 0.0, 1.0, 0.0
            F[0, 2], F[0, 3], F[1, 2], F[1, 3] = a, b, -b, a
            F[2, 2], F[2, 3], F[3, 2], F[3, 3] = c, s, -s, c
            xprev[j] = x
            Pprev[j] = P
            q2 = np.exp(2.0 * lq[r, j])
            G[:, :] = 0.0
            G[0, 0] = G[1, 1] = d ** 4 / 4.0
            G[0, 2] = G[2, 0] = G[1, 3] = G[3, 1] = d ** 3 / 2.0
            G[2, 2] = G[3, 3] = d * d
            xp = _mv(F, x)
            Pp = _mm(_mm(F, P), F.T) + q2 * G
            Pp = 0.5 * (Pp + Pp.T)
            Pps[j] = Pp
            if det[r, j]:
                R = Rm[r, j]
                S = Pp[:2, :2] + R
                S = 0.5 * (S + S.T)
                dS = S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0]
                Si = np.empty((2, 2))
                Si[0, 0], Si[0, 1] = S[1, 1] / dS, -S[0, 1] / dS
                Si[1, 0], Si[1, 1] = -S[1, 0] / dS, S[0, 0] / dS
                K = _mm(Pp[:, :2], Si)
                nu = z[r, j] - xp[:2]
                x = xp + _mv(K, nu)
                M = Pp - _mm(K, Pp[:2, :])
                MHt = Pp[:, :2] - _mm(K, Pp[:2, :2])
                P = M + _mm(_mm(K, R) - MHt, K.T)
                P = 0.5 * (P + P.T)
                Ks[j], Sis[j], nus[j] = K, Si, nu
            else:
                x = xp
                P = Pp
            xpost[j] = x
            e0, e1 = x[0] - pos[r, j, 0], x[1] - pos[r, j, 1]
            sse += e0 * e0 + e1 * e1
        mse[r] = sse / nr
        if not want_grad:
            continue
        xbar = np.zeros(4)
        Pbar = np.zeros((4, 4))
        I4 = np.eye(4)
        for j in range(nr - 1, -1, -1):
            xbar[0] += 2.0 * (xpost[j, 0] - pos[r, j, 0]) / nr
            xbar[1] += 2.0 * (xpost[j, 1] - pos[r, j, 1]) / nr
            Pp = Pps[j]
            if det[r, j]:
                K, Si, nu, R = Ks[j], Sis[j], nus[j], Rm[r, j]
                A = I4.copy()
                A[:, :2] -= K
                Ps = 0.5 * (Pbar + Pbar.T)                       # P = sym(A Pp A^T + K R K^T)
                Ppbar = _mm(_mm(A.T, Ps), A)
                Abar = 2.0 * _mm(_mm(Ps, A), Pp)
                Kbar = -Abar[:, :2] + 2.0 * _mm(_mm(Ps, K), R)
                xpbar = _mv(A.T, xbar)                                # x = A xp + K z
                Kbar += np.outer(xbar, nu)
                Ppbar[:, :2] += _mm(Kbar, Si.T)                       # K = Pp H^T S^-1, S = sym(H Pp H^T + R)
                Sbar = -_mm(_mm(K.T, Kbar), Si.T)
                Ppbar[:2, :2] += 0.5 * (Sbar + Sbar.T)
            else:
                xpbar = xbar.copy()
                Ppbar = Pbar.copy()
            Ppbar = 0.5 * (Ppbar + Ppbar.T)                       # Pp = sym(F P F^T + q^2 G)
            d = dt[r, j]
            gq = d ** 4 / 4.0 * (Ppbar[0, 0] + Ppbar[1, 1]) + d * d * (Ppbar[2, 2] + Ppbar[3, 3]) \
                + d ** 3 / 2.0 * (Ppbar[0, 2] + Ppbar[2, 0] + Ppbar[1, 3] + Ppbar[3, 1])
            g_lq[r, j] = 2.0 * np.exp(2.0 * lq[r, j]) * gq
            F = Fs[j]
            if turn:
                Fbar = np.outer(xpbar, xprev[j]) + 2.0 * _mm(_mm(Ppbar, F), Pprev[j])
                _, _, _, _, da, db, dc, ds = _ct_coeffs(d, w[r, j])
                g_w[r, j] = (Fbar[0, 2] + Fbar[1, 3]) * da + (Fbar[0, 3] - Fbar[1, 2]) * db \
                    + (Fbar[2, 2] + Fbar[3, 3]) * dc + (Fbar[2, 3] - Fbar[3, 2]) * ds
            xbar = _mv(F.T, xpbar)
            Pbar = _mm(_mm(F.T, Ppbar), F)
    return mse, g_lq, g_w


def kernel_forward(episodes, q_m_s2, turn_rate_rad_s=None, cfg=None):
    """Per-episode position MSE (m^2) and its gradients ``(mse, d mse / d log q, d mse / d omega)`` from the
    compiled kernel the optimisation uses, for given schedules (B, J) (column j = look ``start_b + j``)."""
    prob = _Problem(list(episodes), cfg)
    lq = np.log(np.asarray(q_m_s2, dtype=np.float64)[:, :prob.J])
    turn = turn_rate_rad_s is not None
    w = np.asarray(turn_rate_rad_s, dtype=np.float64)[:, :prob.J] if turn else np.zeros_like(lq)
    return _mse_grad_rows(prob.x0, prob.P0, prob.dt, prob.det, prob.z, prob.R, prob.pos, prob.n, lq, w, turn, True)


# ------------------------------------------------------------------------------------------------ optimisation
@numba.njit(cache=True)
def _rowdot(A, B):
    """Row-wise dot products, summed in column order: exactly the same for a row whatever the batch's width, since
    a row's padding columns are exact zeros (numpy's einsum / sum group the terms by the array's length, so a row
    padded to a longer batch would round differently and its L-BFGS path, hence its schedule, would change)."""
    out = np.zeros(A.shape[0])
    for r in range(A.shape[0]):
        acc = 0.0
        for j in range(A.shape[1]):
            acc += A[r, j] * B[r, j]
        out[r] = acc
    return out


def _lbfgs_rows(fg, s0, iterations, memory=10):
    """Minimise R independent objectives at once: row r of ``s0 (R, J)`` is one problem, ``fg(s, rows) ->
    (f (n,), g (n, J))`` evaluates the given rows. L-BFGS (two-loop recursion per row, ``memory`` pairs) with a
    backtracking Armijo line search per row; every array operation is row by row, so a row's path does not
    depend on the other rows, nor on the batch's width (dot products by :func:`_rowdot`). Returns
    ``(s, f, g, nit, hist)`` with ``hist`` (iterations + 1, R) the objective after each iteration (monotone
    non-increasing: a step is taken only if it decreases f)."""
    R, J = s0.shape
    s = s0.copy()
    f, g = fg(s, np.arange(R))
    S = np.zeros((memory, R, J))
    Y = np.zeros((memory, R, J))
    rho = np.zeros((memory, R))
    n_pairs = np.zeros(R, dtype=np.int64)
    nit = np.zeros(R, dtype=np.int64)
    active = np.ones(R, dtype=bool)
    hist = [f.copy()]
    first = np.ones(R, dtype=bool)
    for _ in range(iterations):
        rows = np.flatnonzero(active)
        if rows.size == 0:
            hist.append(f.copy())
            continue
        q = g[rows].copy()
        alpha = np.zeros((memory, rows.size))
        np_r = n_pairs[rows]
        for i in range(memory):                       # newest pair first (index i = age)
            use = i < np_r
            a = np.where(use, rho[i, rows] * _rowdot(S[i, rows], q), 0.0)
            alpha[i] = a
            q -= a[:, None] * Y[i, rows]
        yy = _rowdot(Y[0, rows], Y[0, rows])
        gamma = np.where(np_r > 0, _rowdot(S[0, rows], Y[0, rows]) / np.where(yy > 0, yy, 1.0), 1.0)
        q *= gamma[:, None]
        for i in range(memory - 1, -1, -1):
            use = i < np_r
            bta = np.where(use, rho[i, rows] * _rowdot(Y[i, rows], q), 0.0)
            q += (alpha[i] - bta)[:, None] * S[i, rows]
        d = -q
        gd = _rowdot(g[rows], d)
        bad = ~(gd < 0)
        d[bad] = -g[rows][bad]                        # not a descent direction: steepest descent, forget history
        n_pairs[rows[bad]] = 0
        gd = _rowdot(g[rows], d)
        t = np.where(first[rows] | bad, 0.5 / np.maximum(np.abs(d).max(axis=1), 1e-300), 1.0)
        f_new, g_new = np.empty(rows.size), np.empty((rows.size, J))
        todo = np.arange(rows.size)
        ok = np.zeros(rows.size, dtype=bool)
        for _ in range(40):                           # halve the step until f decreases enough (Armijo)
            if todo.size == 0:
                break
            ft, gt = fg(s[rows[todo]] + t[todo, None] * d[todo], rows[todo])
            acc = ft <= f[rows[todo]] + 1e-4 * t[todo] * gd[todo]
            f_new[todo[acc]], g_new[todo[acc]] = ft[acc], gt[acc]
            ok[todo[acc]] = True
            todo = todo[~acc]
            t[todo] *= 0.5
        done = rows[~ok]                              # no decrease found: converged to rounding
        active[done] = False
        r_ok = rows[ok]
        step = t[ok, None] * d[ok]
        y = g_new[ok] - g[r_ok]
        sy = _rowdot(step, y)
        f_old = f[r_ok]
        s[r_ok] += step
        f[r_ok], g[r_ok] = f_new[ok], g_new[ok]
        nit[r_ok] += 1
        first[r_ok] = False
        keep = sy > 1e-12 * np.sqrt(_rowdot(step, step) * _rowdot(y, y))
        rk = r_ok[keep]
        S[:, rk] = np.roll(S[:, rk], 1, axis=0)
        Y[:, rk] = np.roll(Y[:, rk], 1, axis=0)
        rho[:, rk] = np.roll(rho[:, rk], 1, axis=0)
        S[0, rk], Y[0, rk], rho[0, rk] = step[keep], y[keep], 1.0 / sy[keep]
        n_pairs[rk] = np.minimum(n_pairs[rk] + 1, memory)
        # converged: relative decrease below 1e-13 (rounding of a ~1e-16-accurate MSE sum)
        active[r_ok[(f_old - f[r_ok]) <= 1e-13 * np.abs(f_old)]] = False
        hist.append(f.copy())
    return s, f, g, nit, np.array(hist)


def _optimise(prob, starts_lq, starts_w, lq_bounds, w_max, iterations):
    """L-BFGS per episode and start (:func:`_lbfgs_rows`, all rows at once) on ``s`` with ``log q = c + h sin(s)``
    (and ``omega = w_max sin(s_w)``): the box ``[log q_min, log q_max]`` is reached exactly at ``s = +-pi/2``, so no
    bound handling is needed. The objective of a row is its MSE over its start's MSE. Returns the best schedules
    per episode and a HindsightInfo."""
    B, S = prob.B, len(starts_lq)
    J = prob.J
    turn = starts_w is not None
    c, h = 0.5 * (lq_bounds[0] + lq_bounds[1]), 0.5 * (lq_bounds[1] - lq_bounds[0])
    inner = 1.0 - 1e-9      # starts strictly inside the box: sin'(s) = 0 on the bound would pin them there
    rep = lambda a: np.repeat(a, S, axis=0)   # noqa: E731 - row b * S + s = episode b, start s
    data = [rep(a) for a in (prob.x0, prob.P0, prob.dt, prob.det, prob.z, prob.R, prob.pos, prob.n)]
    mask = rep(prob.mask)
    s_q = np.arcsin(np.clip((np.stack(starts_lq, 1).reshape(B * S, J) - c) / h, -inner, inner))
    s_w = (np.arcsin(np.clip(np.stack(starts_w, 1).reshape(B * S, J) / w_max, -inner, inner)) if turn
           else np.zeros((B * S, J)))
    s0 = np.concatenate([s_q, s_w], axis=1) if turn else s_q

    def schedule(sv):
        lq = c + h * np.sin(sv[:, :J])
        w = w_max * np.sin(sv[:, J:]) if turn else np.zeros_like(lq)
        return lq, w

    def mse_grad(sv, rows):
        lq, w = schedule(sv)
        m, gq, gw = _mse_grad_rows(*(a[rows] for a in data), lq, w, turn, True)
        if not np.all(np.isfinite(m)):
            raise FloatingPointError("hindsight: the kernel produced a non-finite MSE")
        return m, gq, gw

    m0, _, _ = mse_grad(s0, np.arange(B * S))

    def fg(sv, rows):
        m, gq, gw = mse_grad(sv, rows)
        g = gq * h * np.cos(sv[:, :J])
        if turn:
            g = np.concatenate([g, gw * w_max * np.cos(sv[:, J:])], axis=1)
        g = np.where(np.concatenate([mask[rows]] * (2 if turn else 1), axis=1), g, 0.0)
        return m / m0[rows], g / m0[rows, None]

    s_end, f_end, _, nit, hist = _lbfgs_rows(fg, s0, iterations)
    m_end = f_end * m0
    lq, w = schedule(s_end)
    m_chk, gq, gw = mse_grad(s_end, np.arange(B * S))
    # projected gradient of log MSE in (log q, omega / w_max): zero where a bound holds it
    gq, gw = gq / m_chk[:, None], gw * (w_max or 0.0) / m_chk[:, None]
    at = lambda y, lo, hi, g: ((y <= lo + 1e-9) & (g > 0)) | ((y >= hi - 1e-9) & (g < 0))  # noqa: E731
    gq_free = np.where(at(lq, *lq_bounds, gq) | ~mask, 0.0, gq)
    gn = _rowdot(gq_free, gq_free)
    if turn:
        gw_free = np.where(at(w / (w_max or 1.0), -1.0, 1.0, gw) | ~mask, 0.0, gw)
        gn += _rowdot(gw_free, gw_free)
    k_tail = max(1, int(np.ceil(0.1 * iterations)))
    tail = (hist[-1 - min(k_tail, len(hist) - 1)] - hist[-1]) / hist[-1]
    best_s = np.minimum(m_end, m0).reshape(B, S).argmin(axis=1)   # m_end <= m0: L-BFGS only takes decreasing steps
    r = np.arange(B) * S + best_s
    q = np.exp(lq[r])
    q = np.where(prob.mask, q, q[:, :1])          # padding, never stepped
    info = HindsightInfo(iterations=nit[r], starts=(), best_start=best_s, mse_m2=m_end[r],
                         start_mse_m2=m0.reshape(B, S), grad_norm=np.sqrt(gn[r]), last_improvement=tail[r],
                         seconds=0.0)
    return q, (np.where(prob.mask, w[r], 0.0) if turn else None), info


def _q_range_g(cfg, q_range_g):
    levels = getattr(cfg, "q_levels_g", DEFAULT_Q_LEVELS_G)   # the action range of the env config (or default)
    return (levels[0], levels[-1]) if q_range_g is None else q_range_g


def _q_starts(prob, cfg, lo, hi):
    """Start schedules (m/s^2, clipped into the range): kf_tuned's q, the warm-up level, the oracle-ish q."""
    shape = (prob.B, prob.J)
    floor = _start(cfg).warmup_q_m_s2
    starts = {"kf_tuned": np.full(shape, tuned_parameters()["kf"]["q_g"] * G0_M_S2),
              "warmup_level": np.full(shape, floor),
              "true_accel": np.maximum(prob.accel_m_s2, floor)}
    return {k: np.clip(v, lo * G0_M_S2, hi * G0_M_S2) for k, v in starts.items()}


def _hindsight_q(episodes, cfg, q_range_g, iterations):
    lo, hi, _, iterations = _check_args(_q_range_g(cfg, q_range_g), DEFAULT_TURN_RATE_MAX_DEG_S, iterations)
    t0 = time.perf_counter()
    prob = _Problem(episodes, cfg)
    starts = _q_starts(prob, cfg, lo, hi)
    bounds = (float(np.log(lo * G0_M_S2)), float(np.log(hi * G0_M_S2)))
    q, _, info = _optimise(prob, [np.log(s) for s in starts.values()], None, bounds, None, iterations)
    info.starts, info.seconds = tuple(starts), time.perf_counter() - t0
    return prob, q, info


def run_hindsight_q(episodes, name="hindsight_q", cfg=None, q_range_g=None,
                    iterations=None, return_info=False):
    """``hindsight_q``: the best per-episode q schedule for the CV KF, chosen knowing the truth (module docstring).

    Args:
        episodes: list of :class:`radar_env.sim.episode.Episode`.
        cfg: the env config (track start, warm-up, q levels); default the env's defaults (:func:`baselines.trackers._start`).
        q_range_g: ``(lo, hi)`` in g, the range q may take; default the action range of ``cfg.q_levels_g``.
        iterations: L-BFGS iteration limit per start (default :data:`DEFAULT_ITERATIONS`).
        return_info: also return the :class:`HindsightInfo`.
    Returns:
        :class:`TrackRun` of the chain run with the chosen schedule (``q_m_s2`` = the schedule), or
        ``(run, info)``.
    """
    episodes = list(episodes)
    _, q, info = _hindsight_q(episodes, cfg, q_range_g, iterations)
    run = chain_forward(episodes, q, name=name, cfg=cfg)
    return (run, info) if return_info else run


def run_hindsight_q_turn(episodes, name="hindsight_q_turn", cfg=None, q_range_g=None,
                         turn_rate_max_deg_s=DEFAULT_TURN_RATE_MAX_DEG_S, iterations=None, return_info=False):
    """``hindsight_q_turn``: per-episode q and turn-rate schedules for a CT-prediction KF, chosen knowing the truth,
    ``|omega| <= turn_rate_max_deg_s`` (module docstring). Starts from ``hindsight_q``'s answer (computed here)
    with omega = 0, so it is never worse than it. Arguments as :func:`run_hindsight_q`; ``info`` (if returned) is
    ``(info_turn, info_q)``; ``info_turn.seconds`` includes the ``hindsight_q`` stage."""
    episodes = list(episodes)
    lo, hi, w_deg, iterations = _check_args(_q_range_g(cfg, q_range_g), turn_rate_max_deg_s, iterations)
    t0 = time.perf_counter()
    prob, q, info_q = _hindsight_q(episodes, cfg, q_range_g, iterations)
    w_max = w_deg * DEG
    bounds = (float(np.log(lo * G0_M_S2)), float(np.log(hi * G0_M_S2)))
    lq = np.log(q)
    w_true = np.clip(prob.turn_rate_rad_s, -w_max, w_max)
    q2, w, info = _optimise(prob, [lq, lq], [np.zeros_like(lq), w_true], bounds, w_max, iterations)
    info.starts, info.seconds = ("hindsight_q", "hindsight_q+true_turn_rate"), time.perf_counter() - t0
    run = chain_forward(episodes, q2, w, name=name, cfg=cfg)
    return (run, (info, info_q)) if return_info else run


# numba keys each cached kernel on its own file only, and these read radar_env's constants: drop the cached kernels
# of this folder when a source of radar_env or baselines changed (radar_env.common.numba_cache)
drop_stale_kernels(_mm, package_sources(Path(__file__).parents[1] / "radar_env", Path(__file__).parent))
