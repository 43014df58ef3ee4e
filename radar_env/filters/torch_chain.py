r"""The tracking chain in torch: the one differentiable copy of the filter RadarTrack-v0 runs, for training through it.

The same chain as :class:`radar_env.filters.tracking.Tracker` (the formulas of :mod:`radar_env.filters.kalman`, compiled in
:mod:`radar_env.filters.kernels`), written with torch operations so that a loss on the estimates can be differentiated with
respect to every process-noise level ``q`` (and turn rate ``omega``) that produced them. float64 throughout; equal to
the numba chain to 1e-11 relative or better on drawn episodes (the tests' bound is 1e-9: tests/test_torch_chain.py).
Per look ``j`` of a row::

    dt      = t[j] - t[j-1]                      (s; 0 for two sites looking at one time)
    F       = F_cv(dt)  or  F_ct(dt, omega_j)    (omega given: coordinated turn, positive = clockwise)
    Q       = q_j^2 Gamma Gamma^T                (Gamma = [dt^2/2, dt]^T per axis)
    x-, P-  = F x, sym(F P F^T + Q)
    x+, P+  = Joseph-form update with the converted plot z[j], R[j]; a missed look predicts through
    x+, P+  = EKF range-rate update (only with the looks' range-rate inputs: the chain's radial_velocity=True)

Data flow (see docs/training.md, "The differentiable chain")::

    state, looks = start_tracks(batch)           # torch two-hit start + warm-up from an EpisodeBatch, or
    state, looks = handover(tracker)             # the numba Tracker's state and looks, exactly (after load or later)
    out = run(state, looks, q)                   # q (B, J) m/s^2 -> ChainRun: x, P, priors, nu, S, NIS per look
    loss = pooled_position_mse(out.x, looks)     # what agents.evaluation.metrics pools, differentiable

Truncated backpropagation: ``looks.chunk(j0, j1)`` is a window of looks, ``run`` starts from any
:class:`ChainState` and returns the final one (``out.state.detach()`` cuts the graph between chunks);
:func:`step` / :func:`collect` do the same one look at a time when ``q`` comes from a policy that reads each look.

Layout. Inputs and outputs are batch-first (``x (B, J, 4)``, ``q (B, J)``). Inside, every tensor is
*components first, batch last* -- ``x (4, B)``, ``P (4, 4, B)``, looks ``(J, ..., B)`` -- so that each component
is a contiguous run of B numbers and every operation of the 4 x 4 algebra is an elementwise operation on contiguous
memory. On the 2-core machine this runs a look about 2x faster than the batch-first layout (whose small-matrix
products are strided) and far faster than ``bmm``, which loops over 4 x 4 products; per-look slices of tensors that
need a gradient are taken with ``unbind`` (one backward node for the chunk, where indexing would add a full-size
zero tensor per look). The building blocks (:func:`transition`, :func:`ct_entries`, :func:`process_noise`,
:func:`predict`, :func:`predict_cv`, :func:`propagate`, :func:`ct_omega_partials`, :func:`update`, :func:`nis`,
:func:`log_likelihood`, :func:`two_point_init`) take that layout with any trailing batch shape, e.g. ``(4, M, B)``
for M filters per row; :func:`propagate` and :func:`update` any state size (the 5-state CT-EKF of
:mod:`radar_env.filters.torch_imm`, the IMM built from these blocks).

What it is not: it does not compute the env's features or observation (the numba chain does; a trainer steps a
Tracker for them) and it has no known-input (clairvoyant) term. Only this module imports torch; ``radar_env``
imports without it.
"""

from __future__ import annotations

import functools
import math
from typing import NamedTuple

import numpy as np
import torch

from .kernels import MIN_RANGE_FOR_RDOT_M
from .tracking import MAX_Q_M_S2, TrackStart
from ..sim.looks import range_rate_inputs

__all__ = ["ChainState", "ChainLooks", "StepRecord", "ChainRun", "handover", "start_tracks", "looks_from_arrays",
           "run", "step", "collect", "transition", "ct_entries", "process_noise", "gamma_gamma_t", "predict",
           "predict_cv", "propagate", "ct_omega_partials", "update", "update_rdot", "nis", "log_likelihood", "two_point_init",
           "position_sq_error", "pooled_position_mse", "range_rate_args", "SERIES_THETA", "SERIES_THETA_PARTIALS"]

DTYPE = torch.float64
LOG_2PI = math.log(2.0 * math.pi)

SERIES_THETA = 1e-2
"""Below this ``|omega dt|`` the CT entries ``sin(th)/omega`` and ``(1 - cos th)/omega`` are their Taylor series (to
``th^6``; truncation < 1e-21 relative): smooth with finite gradients at ``omega = 0``, equal to the exact forms (and
to kernels.py's sinc forms) to rounding."""

SERIES_THETA_PARTIALS = 0.1
"""The same for the CT entries' derivatives in omega (:func:`ct_omega_partials`; series to ``th^9``, truncation
< 1e-16 relative at 0.1, as baselines/imm_cv_ct_runner.py's kernel evaluates them)."""


def _t(a, dtype=DTYPE):
    return torch.as_tensor(np.ascontiguousarray(a), dtype=dtype)


def _comp_first(a, n_tail):
    """numpy (B, J, *tail) -> torch (J, *tail, B), contiguous (``n_tail`` = len(tail))."""
    t = torch.as_tensor(np.ascontiguousarray(a))
    return t.permute(1, *range(2, 2 + n_tail), 0).contiguous()


# ================================================================================================== state, looks
class ChainState(NamedTuple):
    """Filter state of a batch: ``x_c (4, *batch)``, ``P_c (4, 4, *batch)`` (components first, see module
    docstring). ``x`` and ``P`` are batch-first views."""

    x_c: torch.Tensor
    P_c: torch.Tensor

    @property
    def x(self) -> torch.Tensor:
        """State ``(*batch, 4)``: ``[x, y, vx, vy]`` (m, m/s)."""
        return self.x_c.movedim(0, -1)

    @property
    def P(self) -> torch.Tensor:
        """Covariance ``(*batch, 4, 4)``."""
        return self.P_c.movedim((0, 1), (-2, -1))

    @classmethod
    def from_xP(cls, x, P) -> "ChainState":
        """From batch-first ``x (*batch, 4)``, ``P (*batch, 4, 4)`` (numpy or torch; copied, differentiable)."""
        x, P = torch.as_tensor(x, dtype=DTYPE), torch.as_tensor(P, dtype=DTYPE)
        return cls(x.movedim(-1, 0).clone(memory_format=torch.contiguous_format),
                   P.movedim((-2, -1), (0, 1)).clone(memory_format=torch.contiguous_format))

    def detach(self) -> "ChainState":
        """The same state cut from the autograd graph (between chunks of truncated backpropagation)."""
        return ChainState(self.x_c.detach(), self.P_c.detach())


class ChainLooks(NamedTuple):
    """The looks of B tracks from a common point on, aligned: column ``j`` of row ``b`` is look
    ``start_index[b] + j`` of its episode. Tensors are look-major and batch-last (module docstring); columns past a
    row's last look are padding (``dt = 0``, not detected, not scored), through which the state passes unchanged.

    Attributes:
        dt_s: (J, B) time since the previous look (the first column: since the state's look).
        detected: (J, B) bool; ``mask`` the same as float64 0/1.
        z_m: (J, 2, B) converted plot, 0 where missed.
        R_m2: (J, 2, 2, B) its covariance, the identity where missed (as kernels._update).
        truth: (J, 4, B) true state (for losses only).
        scored: (J, B) bool: a look of the episode (what agents.evaluation.metrics scores when the looks start
            right after the track start, as :func:`handover` after ``Tracker.load`` and :func:`start_tracks` give).
        G: (J, 4, 4, B) ``Gamma Gamma^T`` (``Q = q^2 G``).
        start_index: (B,) numpy int64, the look index of column 0.
        n_looks: (B,) numpy int64, the episodes' lengths (absolute).
        cols: (B, J) numpy int64, column -> look index clipped into the stored arrays (for :meth:`align`).
        rdot: None, or the range-rate inputs ``(rdot (J, B), var (J, B), site (J, 2, B))``: each detected look's
            radial velocity, its noise variance (inf: no range-rate update) and the site that looked; given, every
            look's position update is followed by :func:`update_rdot` (the chain's ``radial_velocity=True``).
    """

    dt_s: torch.Tensor
    detected: torch.Tensor
    mask: torch.Tensor
    z_m: torch.Tensor
    R_m2: torch.Tensor
    truth: torch.Tensor
    scored: torch.Tensor
    G: torch.Tensor
    start_index: np.ndarray
    n_looks: np.ndarray
    cols: np.ndarray
    rdot: tuple | None = None

    @property
    def B(self) -> int:
        return int(self.start_index.shape[0])

    @property
    def J(self) -> int:
        return int(self.dt_s.shape[0])

    @property
    def n_scored(self) -> torch.Tensor:
        """(B,) float64: scored looks per row."""
        return self.scored.sum(0).to(DTYPE)

    @property
    def scored_mask(self) -> torch.Tensor:
        """(B, J) bool, batch-first ``scored``."""
        return self.scored.T

    @property
    def look_index(self) -> np.ndarray:
        """(B, J) look index of each column (past ``n_looks`` on padding)."""
        return self.start_index[:, None] + np.arange(self.J)[None, :]

    def chunk(self, j0, j1=None) -> "ChainLooks":
        """Columns ``j0 .. j1-1`` (views): the looks of one window of truncated backpropagation."""
        s = slice(j0, j1)
        j0 = range(self.J)[s].start if self.J else 0
        return self._replace(dt_s=self.dt_s[s], detected=self.detected[s], mask=self.mask[s], z_m=self.z_m[s],
                             R_m2=self.R_m2[s], truth=self.truth[s], scored=self.scored[s], G=self.G[s],
                             start_index=self.start_index + j0, cols=self.cols[:, s],
                             rdot=None if self.rdot is None else tuple(a[s] for a in self.rdot))

    def rdot_at(self, j):
        """The range-rate inputs of column ``j`` (``(rdot (B,), var (B,), site (2, B))``), or None."""
        return None if self.rdot is None else tuple(a[j] for a in self.rdot)

    def align(self, a, dtype=DTYPE) -> torch.Tensor:
        """A per-look array ``a (B, K, ...)`` of the same rows (e.g. ``tracker.look_data("truth_turn_rate_rad_s")``
        or an EpisodeBatch field) at these columns, as a batch-first torch tensor ``(B, J, ...)``."""
        a = np.asarray(a)
        return _t(a[np.arange(self.B)[:, None], self.cols], dtype)


def looks_from_arrays(t_s, detected, z_m, R_m2, truth, n_looks, start, t_last_s, radial_velocity_m_s=None,
                      site_xy_m=None, radial_velocity_std_m_s=None) -> ChainLooks:
    """:class:`ChainLooks` from batch-first numpy arrays of B episodes, from look ``start[b]`` on.

    Args:
        t_s: (B, K) look times; detected: (B, K) bool; z_m: (B, K, 2); R_m2: (B, K, 2, 2); truth: (B, K, 4) (NaN
            allowed where not detected or past ``n_looks``).
        n_looks: (B,) looks of each episode; start: (B,) first look; t_last_s: (B,) time of the look the state
            belongs to (``dt`` of column 0 is ``t_s[start] - t_last_s``).
        radial_velocity_m_s (B, K), site_xy_m (B, K, 2), radial_velocity_std_m_s (B, K): optional; given, the
            looks carry the range-rate inputs (``ChainLooks.rdot``; a look whose value or std is not finite and
            positive, a missed look or padding gets none).
    """
    t_s, detected = np.asarray(t_s, np.float64), np.asarray(detected, bool)
    n_looks, start = np.asarray(n_looks, np.int64).reshape(-1), np.asarray(start, np.int64).reshape(-1)
    B, K = t_s.shape
    if np.any(start < 0) or np.any(start > n_looks) or np.any(n_looks > K):
        raise ValueError("looks_from_arrays: need 0 <= start <= n_looks <= K for every row")
    J = int((n_looks - start).max())
    cols = start[:, None] + np.arange(J)[None, :]
    valid = cols < n_looks[:, None]
    cols = np.minimum(cols, K - 1)
    rows = np.arange(B)[:, None]
    t = t_s[rows, cols]
    t_prev = np.concatenate([np.asarray(t_last_s, np.float64).reshape(B, 1), t[:, :-1]], axis=1)
    dt = np.where(valid, t - t_prev, 0.0)
    det = detected[rows, cols] & valid
    z = np.where(det[..., None], np.asarray(z_m, np.float64)[rows, cols], 0.0)
    R = np.where(det[..., None, None], np.asarray(R_m2, np.float64)[rows, cols], np.eye(2))
    R = 0.5 * (R + np.swapaxes(R, -1, -2))     # exact for the plots' (symmetric) covariances
    dt_c = _t(dt.T)
    rr = None
    if radial_velocity_m_s is not None:
        rd, var, site = range_rate_inputs((B, K), radial_velocity_m_s, site_xy_m, radial_velocity_std_m_s)
        var = np.where(det, var[rows, cols], np.inf)
        rr = (_t(np.where(det, rd[rows, cols], 0.0).T), _t(var.T), _comp_first(site[rows, cols], 1))
    return ChainLooks(dt_s=dt_c, detected=_t(det.T, torch.bool), mask=_t(det.T.astype(np.float64)),
                      z_m=_comp_first(z, 1), R_m2=_comp_first(R, 2),
                      truth=_comp_first(np.asarray(truth, np.float64)[rows, cols], 1), scored=_t(valid.T, torch.bool),
                      G=gamma_gamma_t(dt_c).movedim(2, 0).contiguous(), start_index=start.copy(),
                      n_looks=n_looks.copy(), cols=cols, rdot=rr)


def range_rate_args(get, on):
    """The range-rate arguments of :func:`looks_from_arrays` from a field getter, if ``on``."""
    return {"radial_velocity_m_s": get("radial_velocity_m_s"), "site_xy_m": get("site_xy_m"),
            "radial_velocity_std_m_s": get("radial_velocity_noise_std_m_s")} if on else {}


def handover(tracker, rows=None):
    """The numba :class:`radar_env.filters.tracking.Tracker`'s state and remaining looks, exactly (a copy, no link back).

    Call it after ``tracker.load`` (the state after the common track start: then ``looks.scored`` is what the
    evaluation scores) or at any later point. Args: ``rows`` (index array, default all). Returns
    ``(ChainState, ChainLooks)``; column 0 is each row's next look ``tracker.k``."""
    rows = np.arange(tracker.B) if rows is None else np.asarray(rows, dtype=np.int64).reshape(-1)
    get = lambda f: tracker.look_data(f)[rows]   # noqa: E731
    looks = looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"),
                              tracker.n_looks[rows], tracker.k[rows], tracker.t_last[rows],
                              **range_rate_args(get, tracker.radial_velocity))
    return ChainState.from_xP(tracker.x[rows], tracker.P[rows]), looks


def _track_start(track_start):
    if track_start is None:
        return TrackStart()
    return track_start if isinstance(track_start, TrackStart) else track_start.track_start


def start_tracks(batch, track_start=None):
    """The common track start in torch: two-hit initialisation from each row's first two detections at different
    times (:func:`radar_env.filters.tracking.init_looks`), then ``warmup_scans`` looks at ``warmup_q_m_s2``, as
    ``Tracker.load`` does (equal to it to rounding; tested).

    Args:
        batch: a :class:`radar_env.sim.episode.EpisodeBatch` (e.g. from :func:`radar_env.sim.draws.draw_episodes`) or a
            list of episodes.
        track_start: :class:`radar_env.filters.tracking.TrackStart`, an env config (its ``track_start``) or None (defaults).
    Returns:
        ``(ChainState, ChainLooks)`` after the warm-up; ``looks.scored`` marks the looks the evaluation scores.
    Raises:
        ValueError naming the episode when it has no two hits at different times or too few looks.
    """
    if not hasattr(batch, "valid"):
        from ..sim.episode import stack_episodes
        batch = stack_episodes(batch)
    ts = _track_start(track_start)
    W = int(ts.warmup_scans)
    t, n = batch.t_s, np.asarray(batch.n_looks, np.int64)
    det = batch.detected & batch.valid
    B = t.shape[0]
    rows = np.arange(B)
    i1 = det.argmax(axis=1)
    later = det & (t > t[rows, i1][:, None])
    i2 = later.argmax(axis=1)
    for b in np.flatnonzero(~later.any(axis=1) | (n < i2 + 1 + W)):
        if not later[b].any():
            raise ValueError(f"episode {batch.names[b]!r} needs two detected looks at different times for the "
                             "two-hit track start")
        raise ValueError(f"episode {batch.names[b]!r} has {n[b]} looks; the track start needs {i2[b] + 1 + W} "
                         f"(two hits at looks {i1[b]} and {i2[b]}, then {W} warm-up looks)")
    pick = lambda a, i, nt: _t(np.moveaxis(a[rows, i], 0, -1) if nt else a[rows, i])   # noqa: E731
    x0, P0 = two_point_init(pick(batch.z_m, i1, 1), pick(batch.R_m2, i1, 2), pick(t, i1, 0),
                            pick(batch.z_m, i2, 1), pick(batch.R_m2, i2, 2), pick(t, i2, 0))
    looks = looks_from_arrays(t, det, batch.z_m, batch.R_m2, batch.truth, n, i2 + 1, t[rows, i2],
                              **range_rate_args(lambda f: getattr(batch, f), ts.radial_velocity))
    warm = run(ChainState(x0, P0), looks.chunk(0, W), torch.full((B, W), ts.warmup_q_m_s2, dtype=DTYPE))
    return warm.state, looks.chunk(W)


# ================================================================================================= filter blocks
def transition(dt_s, omega_rad_s=None) -> torch.Tensor:
    """``F (4, 4, *batch)`` for ``dt_s (*batch)``: ``F_cv(dt)``, or ``F_ct(dt, omega)`` if ``omega_rad_s`` is given
    (radar_env.filters.kalman; ``omega = 0`` gives ``F_cv`` exactly). Differentiable in ``omega`` everywhere: below
    ``|omega dt| <`` :data:`SERIES_THETA` the entries are their Taylor series."""
    if omega_rad_s is None:
        one, zero = torch.ones_like(dt_s), torch.zeros_like(dt_s)
        a, b, c, s = dt_s, zero, one, zero
    else:
        dt_s, omega_rad_s = torch.broadcast_tensors(dt_s, omega_rad_s)
        one, zero = torch.ones_like(dt_s), torch.zeros_like(dt_s)
        a, b, c, s = ct_entries(dt_s, omega_rad_s)
    return torch.stack((one, zero, a, b, zero, one, -b, a, zero, zero, c, s, zero, zero, -s, c)).view(
        (4, 4) + tuple(dt_s.shape))


def ct_entries(dt_s, omega_rad_s):
    """The entries ``(a, b, c, s)`` of ``F_ct = [[I, [[a, b], [-b, a]]], [0, [[c, s], [-s, c]]]]`` (*batch, of
    tensors of the same shape): ``a = sin(th)/omega``, ``b = (1 - cos th)/omega``, ``c = cos th``, ``s = sin th``
    (``th = omega dt``), the first two by their Taylor series below ``|th| <`` :data:`SERIES_THETA`."""
    th = omega_rad_s * dt_s
    small = th.abs() < SERIES_THETA
    ths = torch.where(small, torch.ones_like(th), th)   # keeps the unused exact branch (and its gradient) finite
    t2 = th * th
    a = torch.where(small, dt_s * (1.0 + t2 * (-1.0 / 6.0 + t2 * (1.0 / 120.0 - t2 / 5040.0))),
                    dt_s * torch.sin(ths) / ths)
    h = torch.sin(0.5 * ths)
    b = torch.where(small, dt_s * th * (0.5 + t2 * (-1.0 / 24.0 + t2 * (1.0 / 720.0 - t2 / 40320.0))),
                    dt_s * (2.0 * h * h) / ths)
    return a, b, torch.cos(th), torch.sin(th)


def gamma_gamma_t(dt_s) -> torch.Tensor:
    """``Gamma Gamma^T (4, 4, *batch)`` of the piecewise-constant white acceleration: ``Q = q^2 Gamma Gamma^T``."""
    d2 = dt_s * dt_s
    pp, pv, vv, zero = 0.25 * d2 * d2, 0.5 * d2 * dt_s, d2, torch.zeros_like(dt_s)
    return torch.stack((pp, zero, pv, zero, zero, pp, zero, pv, pv, zero, vv, zero, zero, pv, zero, vv)).view(
        (4, 4) + tuple(dt_s.shape))


def process_noise(dt_s, q_m_s2) -> torch.Tensor:
    """``Q = q^2 Gamma Gamma^T (4, 4, *batch)`` (radar_env.filters.kalman.process_noise)."""
    return (q_m_s2 * q_m_s2) * gamma_gamma_t(dt_s)


def predict(x, P, F, Q):
    """``x- = F x``, ``P- = sym(F P F^T + Q)`` for any ``F``; ``x (4, *b)``, ``P, F, Q (4, 4, *b)``."""
    return (F * x[None]).sum(1), propagate(P, F, Q)


def propagate(P, F, Q):
    """``sym(F P F^T + Q)`` for ``P, F, Q (n, n, *b)`` (any n: an EKF passes its Jacobian as ``F``)."""
    FP = (F[:, :, None] * P[None]).sum(1)            # (F P)[i, j] = sum_k F[i, k] P[k, j]
    Pp = (FP[:, None] * F[None]).sum(2) + Q          # (F P F^T)[i, j] = sum_k FP[i, k] F[j, k]
    return 0.5 * (Pp + Pp.transpose(0, 1))


def ct_omega_partials(dt_s, omega_rad_s):
    """``(da/domega, db/domega)`` (*batch) of the CT entries ``a = sin(th)/omega``, ``b = (1 - cos th)/omega``
    (``th = omega dt``): ``dt^2 (th cos th - sin th) / th^2`` and ``dt^2 (th sin th - 1 + cos th) / th^2``, the
    turn-rate column of the CT-EKF's Jacobian (radar_env.filters.torch_imm). Below ``|th| <`` :data:`SERIES_THETA_PARTIALS`
    their Taylor series (to ``th^9``; the closed form of the first loses ``eps / th^2`` to cancellation), so
    they are smooth with finite gradients at ``omega = 0``."""
    dt_s, omega_rad_s = torch.broadcast_tensors(dt_s, omega_rad_s)
    th = omega_rad_s * dt_s
    small = th.abs() < SERIES_THETA_PARTIALS
    ths = torch.where(small, torch.ones_like(th), th)      # keeps the unused exact branch (and its gradient) finite
    t2 = th * th
    g1 = torch.where(small, th * (-1.0 / 3 + t2 * (1.0 / 30 + t2 * (-1.0 / 840 + t2 * (1.0 / 45360 - t2 / 3991680)))),
                     (ths * torch.cos(ths) - torch.sin(ths)) / (ths * ths))
    h = torch.sin(0.5 * ths)
    g2 = torch.where(small, 0.5 + t2 * (-1.0 / 8 + t2 * (1.0 / 144 + t2 * (-1.0 / 5760 + t2 / 403200))),
                     (ths * torch.sin(ths) - 2.0 * h * h) / (ths * ths))
    d2 = dt_s * dt_s
    return d2 * g1, d2 * g2


def predict_cv(x, P, dt_s, Q):
    """:func:`predict` with ``F = F_cv(dt_s)`` written out by 2 x 2 blocks (no 4 x 4 x 4 products; equal to the
    generic form to rounding). ``P`` must be exactly symmetric (every state of the chain is): then ``P-`` is
    exactly symmetric without a symmetrisation."""
    xp = torch.cat((x[:2] + dt_s * x[2:], x[2:]))
    P11, P12, P21, P22 = P[:2, :2], P[:2, 2:], P[2:, :2], P[2:, 2:]
    A = P11 + dt_s * (P12 + P21) + (dt_s * dt_s) * P22      # position block; P12 + P21 is exactly symmetric
    C = P12 + dt_s * P22                                     # position-velocity block
    return xp, torch.cat((torch.cat((A, C), 1), torch.cat((C.transpose(0, 1), P22), 1))) + Q


def update(x, P, z, R, mask):
    """Joseph-form update with a converted position plot (H = [I 0]), as kernels._update.

    Args:
        x (n, *b), P (n, n, *b): prior, any n >= 2 states, position first. z (2, *b), R (2, 2, *b): the plot,
            finite everywhere (:class:`ChainLooks` holds ``z = 0``, ``R = I`` where missed). mask (*b): 1.0
            detected, 0.0 missed (posterior = prior). All must have the same number of batch dimensions (``z``
            of M filters per row: ``z[:, None]``).
    Returns:
        ``(x+, P+, nu, S, S_inv)``: ``nu = z - H x-`` (0 where missed), ``S = P-[:2, :2] + R`` and its inverse
        (closed form).
    """
    S = P[:2, :2] + R
    s00, s01, s11 = S[0, 0], S[0, 1], S[1, 1]
    S_inv = torch.stack((s11, -s01, -s01, s00)).view(S.shape) / (s00 * s11 - s01 * s01)
    C = P[:, :2]                                              # P H^T (n, 2, *b)
    K = (C[:, :, None] * S_inv[None]).sum(1) * mask           # gain, 0 where missed
    nu = (z - x[:2]) * mask
    xo = x + (K * nu[None]).sum(1)
    # Joseph form with H = [I 0], grouped as kernels._update: P+ = (P - K C^T) + (K S - C) K^T  (K S - C ~ 0: it
    # carries the rounding of K that keeps P+ positive definite)
    g = (K[:, :, None] * S[None]).sum(1) - C
    Po = (P - (K[:, None] * C[None]).sum(2)) + (g[:, None] * K[None]).sum(2)
    return xo, 0.5 * (Po + Po.transpose(0, 1)), nu, S, S_inv


def update_rdot(x, P, rdot, var, site, mask):
    """The EKF range-rate update after the position update, as kernels._rdot_update: ``h(x) = u . v`` with ``u`` the
    unit line of sight from ``site``, Jacobian row ``[(v - h u) / r, u, 0...]``.

    Args:
        x (n, *b), P (n, n, *b): after the position update (n >= 4: position, velocity, ...). rdot (*b): the
            measured radial velocity (m/s); var (*b): its noise variance, inf for none; site (2, *b); mask (*b): 1.0
            detected. No update where masked, where ``var`` is not finite, or within ``MIN_RANGE_FOR_RDOT_M`` of the
            site.
    Returns:
        ``(x+, P+, log-likelihood)`` (the log-likelihood 0 where there was no update).
    """
    d = x[:2] - site
    r = torch.sqrt(d[0] * d[0] + d[1] * d[1])
    ok = mask * ((r >= MIN_RANGE_FOR_RDOT_M) & torch.isfinite(var)).to(DTYPE)
    r_s = torch.where(ok > 0.0, r, 1.0)
    u = d / r_s
    h = (u * x[2:4]).sum(0)
    row = torch.cat(((x[2:4] - h * u) / r_s, u))               # (4, *b)
    phi = (P[:, :4] * row[None]).sum(1)                         # P H^T (n, *b)
    s = (row * phi[:4]).sum(0) + torch.where(ok > 0.0, var, 1.0)
    nu = (rdot - h) * ok
    k = phi / s * ok
    Po = 0.5 * (P + P.transpose(0, 1)) - k[:, None] * phi[None]
    return x + k * nu, Po, -0.5 * (nu * nu / s + torch.log(2.0 * math.pi * s)) * ok


def nis(nu, S_inv) -> torch.Tensor:
    """Normalised innovation squared ``nu^T S^-1 nu`` (*b) of ``nu (2, *b)``, ``S_inv (2, 2, *b)``."""
    return (nu[:, None] * S_inv * nu[None]).sum((0, 1))


def log_likelihood(nu, S, S_inv, mask) -> torch.Tensor:
    """Gaussian log-likelihood of the innovation ``-(NIS + log det(2 pi S)) / 2`` (*b), 0 where ``mask`` is 0 (a
    missed look), as kernels._update returns it (the IMM's mode weights)."""
    log_det = torch.log(S[0, 0] * S[1, 1] - S[0, 1] * S[1, 0])
    return -0.5 * (nis(nu, S_inv) + 2.0 * LOG_2PI + log_det) * mask


def two_point_init(z1, R1, t1_s, z2, R2, t2_s):
    """Two-hit start ``x = [z2, (z2 - z1)/dt]``, ``P = [[R2, R2/dt], [R2/dt, (R1 + R2)/dt^2]]``; ``z (2, *b)``,
    ``R (2, 2, *b)``, ``t (*b)`` -> ``(x (4, *b), P (4, 4, *b))`` (radar_env.filters.kalman.two_point_init)."""
    dt = t2_s - t1_s
    Rd = R2 / dt
    P = torch.cat((torch.cat((R2, Rd), 1), torch.cat((Rd, (R1 + R2) / (dt * dt)), 1)), 0)
    return torch.cat((z2, (z2 - z1) / dt)), P


# ====================================================================================================== the chain
class StepRecord(NamedTuple):
    """One look of :func:`step` (components first): prior, posterior, innovation, its covariance and inverse."""

    x_prior: torch.Tensor
    P_prior: torch.Tensor
    x: torch.Tensor
    P: torch.Tensor
    nu: torch.Tensor
    S: torch.Tensor
    S_inv: torch.Tensor


class ChainRun:
    """The per-look outputs of :func:`run` / :func:`collect`, batch-first, and the final state. Each output is
    stacked from the per-look records when first read (an output never read costs nothing).

    Attributes:
        x, x_prior: (B, J, 4) posterior and prior states.
        P, P_prior: (B, J, 4, 4).
        nu: (B, J, 2) innovation (0 where missed); S: (B, J, 2, 2) its covariance; nis: (B, J) (0 where missed).
        state: the :class:`ChainState` after the last look.
        records: the :class:`StepRecord` of each look (components first).
    """

    def __init__(self, records, state):
        self.records, self.state = list(records), state

    def _stack(self, name):                 # J x (*comp, B) -> (B, J, *comp)
        a = torch.stack([getattr(r, name) for r in self.records])
        return a.permute(a.dim() - 1, 0, *range(1, a.dim() - 1))

    x = functools.cached_property(lambda self: self._stack("x"))
    P = functools.cached_property(lambda self: self._stack("P"))
    x_prior = functools.cached_property(lambda self: self._stack("x_prior"))
    P_prior = functools.cached_property(lambda self: self._stack("P_prior"))
    nu = functools.cached_property(lambda self: self._stack("nu"))
    S = functools.cached_property(lambda self: self._stack("S"))

    @functools.cached_property
    def nis(self):
        nu = torch.stack([r.nu for r in self.records], -2)            # (2, J, B)
        return nis(nu, torch.stack([r.S_inv for r in self.records], -2)).T   # the module's nis()


def _checked(name, v, shape, hi=None):
    """``v`` as float64 of ``shape`` (broadcast); ``ValueError`` naming it unless finite (and in ``[0, hi]``)."""
    v = torch.as_tensor(v, dtype=DTYPE)
    if v.shape != shape:
        try:
            v = v.expand(shape)
        except RuntimeError:
            raise ValueError(f"{name} must broadcast to {tuple(shape)}, got shape {tuple(v.shape)}") from None
    with torch.no_grad():
        ok = bool(torch.isfinite(v).all() if hi is None else ((v >= 0.0) & (v <= hi)).all())   # NaN fails too
    if not ok:
        raise ValueError(f"{name} must be finite" + ("" if hi is None else f" and in [0, {hi}]"))
    return v


def step(state: ChainState, looks: ChainLooks, j: int, q_m_s2, omega_rad_s=None):
    """Look ``j`` of ``looks`` from ``state``: predict with ``q_m_s2 (B,)`` (and ``F_ct(dt, omega_rad_s (B,))`` if
    given), update. Returns ``(new_state, StepRecord)``; :func:`collect` turns the records into a :class:`ChainRun`.
    ``q`` is checked (finite, in ``[0, MAX_Q_M_S2]``) as ``Tracker.step`` does."""
    B = looks.B
    q = _checked("q_m_s2", q_m_s2, (B,), MAX_Q_M_S2)
    Q = (q * q) * looks.G[j]
    if omega_rad_s is None:
        xp, Pp = predict_cv(state.x_c, state.P_c, looks.dt_s[j], Q)
    else:
        F = transition(looks.dt_s[j], _checked("omega_rad_s", omega_rad_s, (B,)))
        xp, Pp = predict(state.x_c, state.P_c, F, Q)
    x, P, nu, S, S_inv = update(xp, Pp, looks.z_m[j], looks.R_m2[j], looks.mask[j])
    if looks.rdot is not None:
        x, P, _ = update_rdot(x, P, *looks.rdot_at(j), looks.mask[j])
    return ChainState(x, P), StepRecord(xp, Pp, x, P, nu, S, S_inv)


def collect(records, state: ChainState) -> ChainRun:
    """:class:`ChainRun` (batch-first outputs) of the :class:`StepRecord` of consecutive looks and the final
    state."""
    return ChainRun(records, state)


def run(state: ChainState, looks: ChainLooks, q_m_s2, omega_rad_s=None) -> ChainRun:
    """Run the chain over every column of ``looks`` from ``state``.

    Args:
        state: the state at the look before column 0 (from :func:`handover`, :func:`start_tracks` or a previous
            chunk's ``run(...).state``).
        looks: the looks (or a chunk of them).
        q_m_s2: (B, J) process-noise level per look (m/s^2; anything that broadcasts, e.g. a float), finite and in
            ``[0, MAX_Q_M_S2]``; values on padding columns do not matter (dt = 0 there).
        omega_rad_s: optional (B, J) finite turn rate per look (rad/s, positive = clockwise): predict with
            ``F_ct(dt, omega)``.
    Returns:
        :class:`ChainRun`; its ``state`` is the state after the last column.
    """
    B, J = looks.B, looks.J
    if J == 0:
        raise ValueError("run: looks has no columns")
    q = _checked("q_m_s2", q_m_s2, (B, J), MAX_Q_M_S2).T
    Qs = ((q * q)[:, None, None] * looks.G).unbind(0)
    if omega_rad_s is not None:
        w = _checked("omega_rad_s", omega_rad_s, (B, J)).T
        Fs = transition(looks.dt_s, w).unbind(2)          # (4, 4, J, B) -> J x (4, 4, B)
    x, P = state.x_c, state.P_c
    records = []
    for j in range(J):
        if omega_rad_s is None:
            xp, Pp = predict_cv(x, P, looks.dt_s[j], Qs[j])
        else:
            xp, Pp = predict(x, P, Fs[j], Qs[j])
        x, P, nu, S, S_inv = update(xp, Pp, looks.z_m[j], looks.R_m2[j], looks.mask[j])
        if looks.rdot is not None:
            x, P, _ = update_rdot(x, P, *looks.rdot_at(j), looks.mask[j])
        records.append(StepRecord(xp, Pp, x, P, nu, S, S_inv))
    return ChainRun(records, ChainState(x, P))


# ========================================================================================================== losses
def position_sq_error(x, looks: ChainLooks) -> torch.Tensor:
    """(B, J) squared position error ``|x[..., :2] - truth|^2`` (m^2) of estimates ``x (B, J, >=2)``, 0 where the
    look is not scored."""
    e = x[..., :2] - looks.truth[:, :2].permute(2, 0, 1)
    return torch.where(looks.scored_mask, (e * e).sum(-1), 0.0)


def pooled_position_mse(x, looks: ChainLooks, n_scored_total=None) -> torch.Tensor:
    """Pooled position MSE (m^2) over the scored looks of every row, as agents.evaluation.metrics pools
    ``pos_rmse_m`` (its square): ``sum of squared errors / number of scored looks``.

    ``n_scored_total``: the denominator; for chunks of truncated backpropagation pass the whole batch's
    ``looks.n_scored.sum()`` so that the chunks' losses add up to the pooled MSE. Default: this ``looks``' count."""
    n = looks.scored.sum() if n_scored_total is None else n_scored_total
    return position_sq_error(x, looks).sum() / n
