r"""The CV chain of :mod:`radar_env.filters.torch_chain` compiled: a numba forward and a hand-written numba adjoint.

:func:`cv_run` is :func:`radar_env.filters.torch_chain.run` for the CV model (no turn rate) restricted to what the
q-policy trainer needs: the posterior states ``x (B, J, 4)`` of a chunk, differentiable with respect to the
process-noise levels ``q (B, J)``, and the final :class:`~radar_env.filters.torch_chain.ChainState` (detached).
One :class:`torch.autograd.Function` replaces the torch chain's dozens of autograd nodes per look: the forward runs every
row's looks in one numba loop and stores each look's prior (and, with range rate, the state between the position
and the range-rate update); the backward runs the reverse (adjoint) pass over the stored looks in numba.

Per look, as torch_chain (the same formulas, in the same order, so the outputs agree to rounding)::

    x-, P-  = F_cv(dt) x, F_cv P F_cv^T + q^2 Gamma Gamma^T
    x+, P+  = Joseph-form position update (H = [I 0], plot z, R); a missed look or padding: x+, P+ = x-, P-
    x+, P+  = EKF range-rate update (only when ``looks.rdot`` is given: the chain's radial_velocity=True)

The adjoint reverses the forward term by term in its own grouping (Joseph form, closed-form 2 x 2 inverse), as
torch autograd does on torch_chain: at a huge q the posterior cancels large terms, and the same grouping keeps the
rounding of the two gradients alike. Covariance adjoints are kept symmetric, which is exact because every covariance
perturbation of the chain is symmetric. Gradients flow to ``q`` only: the trainer starts each chunk from the numba
Tracker's (constant) state, so a ``state`` that requires a gradient is refused.

Layout: batch first throughout (the looks are copied out of :class:`~radar_env.filters.torch_chain.ChainLooks`'
components-first layout once per chunk: the kernels run row by row). Like torch_chain, this module imports torch;
``radar_env`` imports without it.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

from .kernels import MIN_RANGE_FOR_RDOT_M
from .torch_chain import DTYPE, ChainLooks, ChainState
from .tracking import MAX_Q_M_S2

__all__ = ["cv_run", "CompiledCVChain"]


# ============================================================================================= numba kernels
@njit(cache=True)
def _predict(x, P, dt, q, xp, Pp):
    """``xp, Pp = F_cv(dt) x, F P F^T + q^2 G`` into ``xp (4,)``, ``Pp (4, 4)`` (torch_chain.predict_cv's order)."""
    for a in range(2):
        xp[a] = x[a] + dt * x[a + 2]
        xp[a + 2] = x[a + 2]
    d2 = dt * dt
    q2 = q * q
    pp, pv, vv = q2 * (0.25 * d2 * d2), q2 * (0.5 * d2 * dt), q2 * d2
    for a in range(2):
        for c in range(2):
            A = P[a, c] + dt * (P[a, c + 2] + P[a + 2, c]) + d2 * P[a + 2, c + 2]
            C = P[a, c + 2] + dt * P[a + 2, c + 2]
            Ct = P[c, a + 2] + dt * P[c + 2, a + 2]          # C^T[a, c] = C[c, a]
            g = 1.0 if a == c else 0.0
            Pp[a, c] = A + g * pp
            Pp[a, c + 2] = C + g * pv
            Pp[a + 2, c] = Ct + g * pv
            Pp[a + 2, c + 2] = P[a + 2, c + 2] + g * vv


@njit(cache=True)
def _inv2(S, W):
    """``W = S^-1`` of a 2 x 2 ``S`` by the closed form torch_chain.update uses."""
    s00, s01, s11 = S[0, 0], S[0, 1], S[1, 1]
    det = s00 * s11 - s01 * s01
    W[0, 0], W[0, 1], W[1, 0], W[1, 1] = s11 / det, -s01 / det, -s01 / det, s00 / det


@njit(cache=True)
def _update(xp, Pp, z0, z1, R, x, P, S, W, K, g, Po):
    """Joseph-form position update of a detected look (torch_chain.update's grouping) into ``x``, ``P``; ``S``,
    ``W``, ``K``, ``g``, ``Po``: scratch."""
    for a in range(2):
        for c in range(2):
            S[a, c] = Pp[a, c] + R[a, c]
    _inv2(S, W)
    for i in range(4):
        for a in range(2):
            K[i, a] = Pp[i, 0] * W[0, a] + Pp[i, 1] * W[1, a]
    n0, n1 = z0 - xp[0], z1 - xp[1]
    for i in range(4):
        x[i] = xp[i] + (K[i, 0] * n0 + K[i, 1] * n1)
        for a in range(2):
            g[i, a] = (K[i, 0] * S[0, a] + K[i, 1] * S[1, a]) - Pp[i, a]
    for i in range(4):
        for j in range(4):
            Po[i, j] = (Pp[i, j] - (K[i, 0] * Pp[j, 0] + K[i, 1] * Pp[j, 1])) + (g[i, 0] * K[j, 0] + g[i, 1] * K[j, 1])
    for i in range(4):
        for j in range(4):
            P[i, j] = 0.5 * (Po[i, j] + Po[j, i])


@njit(cache=True)
def _rdot_ok(x, sx, sy, var):
    """Whether a detected look gets the range-rate update (torch_chain.update_rdot's test)."""
    dx, dy = x[0] - sx, x[1] - sy
    return math.sqrt(dx * dx + dy * dy) >= MIN_RANGE_FOR_RDOT_M and math.isfinite(var)


@njit(cache=True)
def _rdot_terms(x, P, sx, sy, rdot, var, row, phi):
    """The range-rate update's terms at ``(x, P)``: fills ``row (4,)`` (Jacobian) and ``phi = P row (4,)``; returns
    ``(r, u0, u1, h, s, nu)``."""
    d0, d1 = x[0] - sx, x[1] - sy
    r = math.sqrt(d0 * d0 + d1 * d1)
    u0, u1 = d0 / r, d1 / r
    h = u0 * x[2] + u1 * x[3]
    row[0], row[1], row[2], row[3] = (x[2] - h * u0) / r, (x[3] - h * u1) / r, u0, u1
    s = 0.0
    for i in range(4):
        phi[i] = P[i, 0] * row[0] + P[i, 1] * row[1] + P[i, 2] * row[2] + P[i, 3] * row[3]
    for i in range(4):
        s += row[i] * phi[i]
    return r, u0, u1, h, s + var, rdot - h


@njit(cache=True)
def _rdot_update(x, P, sx, sy, rdot, var, row, phi):
    """The EKF range-rate update of ``(x, P)`` in place (torch_chain.update_rdot, an update that takes place)."""
    _, _, _, _, s, nu = _rdot_terms(x, P, sx, sy, rdot, var, row, phi)
    for i in range(4):
        x[i] = x[i] + phi[i] / s * nu
    for i in range(4):          # sym(P) - k phi^T, with P read before it is written: lower triangle from a copy
        for j in range(i + 1):
            sij = 0.5 * (P[i, j] + P[j, i])
            P[i, j], P[j, i] = sij - phi[i] / s * phi[j], sij - phi[j] / s * phi[i]


@njit(cache=True)
def k_cv_forward(x0, P0, q, dt, mask, z, R, use_rdot, rd, rvar, site, x_out, xp_s, Pp_s, xm_s, Pm_s, x_end, P_end):
    """The CV chain over a chunk, every row.

    Args:
        x0 (4, B), P0 (4, 4, B): the state before column 0. q, dt, mask (B, J); z (B, J, 2); R (B, J, 2, 2)
            (batch first: a row's looks are contiguous). use_rdot: range-rate updates with rd, rvar (B, J),
            site (B, J, 2).
    Writes:
        x_out (B, J, 4): posteriors. xp_s (B, J, 4), Pp_s (B, J, 4, 4): priors (for the adjoint). xm_s, Pm_s (same
        shapes, only with use_rdot): the state after the position update. x_end (4, B), P_end (4, 4, B): the state
        after the last column.
    """
    B, J = dt.shape
    x, P = np.empty(4), np.empty((4, 4))
    xp, Pp = np.empty(4), np.empty((4, 4))
    S, W, Rl = np.empty((2, 2)), np.empty((2, 2)), np.empty((2, 2))
    K, g, Po = np.empty((4, 2)), np.empty((4, 2)), np.empty((4, 4))
    row, phi = np.empty(4), np.empty(4)
    for b in range(B):
        for i in range(4):
            x[i] = x0[i, b]
            for k in range(4):
                P[i, k] = P0[i, k, b]
        for j in range(J):
            _predict(x, P, dt[b, j], q[b, j], xp, Pp)
            for i in range(4):
                xp_s[b, j, i] = xp[i]
                for k in range(4):
                    Pp_s[b, j, i, k] = Pp[i, k]
            if mask[b, j] != 0.0:
                for a in range(2):
                    for c in range(2):
                        Rl[a, c] = R[b, j, a, c]
                _update(xp, Pp, z[b, j, 0], z[b, j, 1], Rl, x, P, S, W, K, g, Po)
            else:
                for i in range(4):       # posterior = prior (exactly: the prior is exactly symmetric)
                    x[i] = xp[i]
                    for k in range(4):
                        P[i, k] = Pp[i, k]
            if use_rdot:
                for i in range(4):
                    xm_s[b, j, i] = x[i]
                    for k in range(4):
                        Pm_s[b, j, i, k] = P[i, k]
                if mask[b, j] != 0.0 and _rdot_ok(x, site[b, j, 0], site[b, j, 1], rvar[b, j]):
                    _rdot_update(x, P, site[b, j, 0], site[b, j, 1], rd[b, j], rvar[b, j], row, phi)
            for i in range(4):
                x_out[b, j, i] = x[i]
        for i in range(4):
            x_end[i, b] = x[i]
            for k in range(4):
                P_end[i, k, b] = P[i, k]


@njit(cache=True)
def _sym(A):
    for i in range(4):
        for j in range(i):
            v = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = v
            A[j, i] = v


@njit(cache=True)
def _rdot_adjoint(xm, Pm, sx, sy, rdot, var, xb, Pb, row, phi, kb, phib):
    """Reverse of the range-rate update at its input ``(xm, Pm)``: ``xb``, ``Pb`` (the adjoints of its output,
    ``Pb`` symmetric) become those of its input, in place. ``kb``, ``phib``: scratch."""
    r, u0, u1, h, s, nu = _rdot_terms(xm, Pm, sx, sy, rdot, var, row, phi)
    # x+ = x + k nu, P+ = sym(P) - k phi^T, k = phi / s
    nub = 0.0
    for i in range(4):
        kb[i] = xb[i] * nu - (Pb[i, 0] * phi[0] + Pb[i, 1] * phi[1] + Pb[i, 2] * phi[2] + Pb[i, 3] * phi[3])
        nub += phi[i] / s * xb[i]
    sb = 0.0
    for i in range(4):
        # from -k phi^T (k = phi / s) and from k's own phi
        phib[i] = -(Pb[0, i] * phi[0] + Pb[1, i] * phi[1] + Pb[2, i] * phi[2] + Pb[3, i] * phi[3]) / s + kb[i] / s
        sb -= kb[i] * phi[i] / (s * s)
    hb = -nub
    # s = row . phi + var ; phi = P row
    rowb0, rowb1, rowb2, rowb3 = sb * phi[0], sb * phi[1], sb * phi[2], sb * phi[3]
    for i in range(4):
        phib[i] += sb * row[i]
    for i in range(4):
        rowb0 += Pm[i, 0] * phib[i]
        rowb1 += Pm[i, 1] * phib[i]
        rowb2 += Pm[i, 2] * phib[i]
        rowb3 += Pm[i, 3] * phib[i]
    for i in range(4):
        for k in range(4):
            Pb[i, k] += phib[i] * row[k]
    _sym(Pb)
    # row = [(v - h u) / r, u]
    w0, w1 = rowb0 / r, rowb1 / r
    vb0, vb1 = w0, w1
    hb -= w0 * u0 + w1 * u1
    ub0, ub1 = rowb2 - h * w0, rowb3 - h * w1
    rb = -(rowb0 * row[0] + rowb1 * row[1]) / r
    # h = u . v
    ub0 += hb * xm[2]
    ub1 += hb * xm[3]
    vb0 += hb * u0
    vb1 += hb * u1
    # u = d / r, r = |d|
    rb -= (ub0 * u0 + ub1 * u1) / r
    xb[0] += ub0 / r + rb * u0
    xb[1] += ub1 / r + rb * u1
    xb[2] += vb0
    xb[3] += vb1


@njit(cache=True)
def _update_adjoint(Pp, xp, z0, z1, R, xb, Pb, xpb, Ppb, S, W, C, K, g, Kb, Cb, gb, Wb):
    """Reverse of :func:`_update` (a detected look) at its prior ``(xp, Pp)``: from the adjoints ``xb``, ``Pb``
    (symmetric) of the posterior, adds those of the prior to ``xpb``, ``Ppb`` (which hold copies of ``xb``, ``Pb``:
    the identity paths) and symmetrises ``Ppb``. It follows the forward's own grouping (Joseph form, closed-form
    inverse) term by term: at a huge q (P- >> R) the posterior cancels large terms, and reversing the same terms
    keeps the rounding that of torch autograd on torch_chain.update (a shorter, equal form differs by ~1e-7
    relative there). The rest: scratch."""
    for a in range(2):
        for c in range(2):
            S[a, c] = Pp[a, c] + R[a, c]
    _inv2(S, W)
    n0, n1 = z0 - xp[0], z1 - xp[1]
    for i in range(4):
        C[i, 0], C[i, 1] = Pp[i, 0], Pp[i, 1]
    for i in range(4):
        for a in range(2):
            K[i, a] = C[i, 0] * W[0, a] + C[i, 1] * W[1, a]
    for i in range(4):
        for a in range(2):
            g[i, a] = (K[i, 0] * S[0, a] + K[i, 1] * S[1, a]) - C[i, a]
    # Po = (P- - K C^T) + g K^T  (its adjoint is Pb: P+ = sym(Po), Pb symmetric)
    for i in range(4):
        for a in range(2):
            PbC, Pbg, PbK = 0.0, 0.0, 0.0
            for k in range(4):
                PbC += Pb[i, k] * C[k, a]
                Pbg += Pb[i, k] * g[k, a]
                PbK += Pb[i, k] * K[k, a]
            Kb[i, a] = Pbg - PbC
            Cb[i, a] = -PbK
            gb[i, a] = PbK
    # g = K S - C
    for i in range(4):
        for a in range(2):
            Kb[i, a] += gb[i, 0] * S[a, 0] + gb[i, 1] * S[a, 1]
            Cb[i, a] -= gb[i, a]
    Sb00, Sb01, Sb10, Sb11 = 0.0, 0.0, 0.0, 0.0
    for k in range(4):
        Sb00 += K[k, 0] * gb[k, 0]
        Sb01 += K[k, 0] * gb[k, 1]
        Sb10 += K[k, 1] * gb[k, 0]
        Sb11 += K[k, 1] * gb[k, 1]
    # x+ = x- + K nu, nu = z - x-[:2]
    nb0, nb1 = 0.0, 0.0
    for i in range(4):
        Kb[i, 0] += xb[i] * n0
        Kb[i, 1] += xb[i] * n1
        nb0 += K[i, 0] * xb[i]
        nb1 += K[i, 1] * xb[i]
    xpb[0] -= nb0
    xpb[1] -= nb1
    # K = C W
    for a in range(2):
        for c in range(2):
            Wb[a, c] = 0.0
    for i in range(4):
        for a in range(2):
            Cb[i, a] += Kb[i, 0] * W[a, 0] + Kb[i, 1] * W[a, 1]
            for c in range(2):
                Wb[a, c] += C[i, a] * Kb[i, c]
    # W = [[s11, -s01], [-s01, s00]] / det, det = s00 s11 - s01^2 (S[0, 1] stands for both off-diagonals)
    s00, s01, s11 = S[0, 0], S[0, 1], S[1, 1]
    det = s00 * s11 - s01 * s01
    detb = -(Wb[0, 0] * s11 - (Wb[0, 1] + Wb[1, 0]) * s01 + Wb[1, 1] * s00) / (det * det)
    Sb00 += Wb[1, 1] / det + detb * s11
    Sb11 += Wb[0, 0] / det + detb * s00
    Sb01 += -(Wb[0, 1] + Wb[1, 0]) / det - 2.0 * s01 * detb
    # S = P-[:2, :2] + R, C = P-[:, :2]
    Ppb[0, 0] += Sb00
    Ppb[0, 1] += Sb01
    Ppb[1, 0] += Sb10
    Ppb[1, 1] += Sb11
    for i in range(4):
        Ppb[i, 0] += Cb[i, 0]
        Ppb[i, 1] += Cb[i, 1]
    _sym(Ppb)



@njit(cache=True)
def k_cv_backward(gx, q, dt, mask, z, R, use_rdot, rd, rvar, site, xp_s, Pp_s, xm_s, Pm_s, gq):
    """Reverse pass of :func:`k_cv_forward`: ``gx (B, J, 4)`` = dLoss/dx_out -> ``gq (B, J)`` = dLoss/dq. The
    final state carries no gradient (it is detached between chunks)."""
    B, J = dt.shape
    xb, Pb = np.empty(4), np.empty((4, 4))
    xpb, Ppb = np.empty(4), np.empty((4, 4))
    Pp, xm, Pm = np.empty((4, 4)), np.empty(4), np.empty((4, 4))
    S, W, Wb = np.empty((2, 2)), np.empty((2, 2)), np.empty((2, 2))
    C, K, gm = np.empty((4, 2)), np.empty((4, 2)), np.empty((4, 2))
    Kb, Cb, gb = np.empty((4, 2)), np.empty((4, 2)), np.empty((4, 2))
    row, phi, kb, phib = np.empty(4), np.empty(4), np.empty(4), np.empty(4)
    for b in range(B):
        for i in range(4):
            xb[i] = 0.0
            for k in range(4):
                Pb[i, k] = 0.0
        for j in range(J - 1, -1, -1):
            for i in range(4):
                xb[i] += gx[b, j, i]
            det = mask[b, j] != 0.0
            if use_rdot and det:
                for i in range(4):
                    xm[i] = xm_s[b, j, i]
                    for k in range(4):
                        Pm[i, k] = Pm_s[b, j, i, k]
                if _rdot_ok(xm, site[b, j, 0], site[b, j, 1], rvar[b, j]):
                    _rdot_adjoint(xm, Pm, site[b, j, 0], site[b, j, 1], rd[b, j], rvar[b, j], xb, Pb, row, phi,
                                  kb, phib)
            for i in range(4):
                xpb[i] = xb[i]
                for k in range(4):
                    Pp[i, k] = Pp_s[b, j, i, k]
                    Ppb[i, k] = Pb[i, k]
            if det:
                _update_adjoint(Pp, xp_s[b, j], z[b, j, 0], z[b, j, 1], R[b, j], xb, Pb, xpb, Ppb, S, W, C, K,
                                gm, Kb, Cb, gb, Wb)
            # prior: x- = F x, P- = F P F^T + q^2 G
            d = dt[b, j]
            d2 = d * d
            g = (0.25 * d2 * d2) * (Ppb[0, 0] + Ppb[1, 1]) + (0.5 * d2 * d) * (Ppb[0, 2] + Ppb[2, 0] + Ppb[1, 3]
                                                                             + Ppb[3, 1]) + d2 * (Ppb[2, 2] + Ppb[3, 3])
            gq[b, j] = 2.0 * q[b, j] * g
            for a in range(2):
                xb[a] = xpb[a]
                xb[a + 2] = d * xpb[a] + xpb[a + 2]
            for a in range(2):
                for c in range(2):
                    A11, A12, A21, A22 = Ppb[a, c], Ppb[a, c + 2], Ppb[a + 2, c], Ppb[a + 2, c + 2]
                    Pb[a, c] = A11
                    Pb[a, c + 2] = d * A11 + A12
                    Pb[a + 2, c] = d * A11 + A21
                    Pb[a + 2, c + 2] = d2 * A11 + d * (A12 + A21) + A22


# ============================================================================================== autograd
def _np(t):
    return t.detach().numpy()


def _rows(t):
    """A ChainLooks tensor ``(J, *comp, B)`` as a contiguous numpy ``(B, J, *comp)``."""
    return np.ascontiguousarray(np.moveaxis(_np(t), -1, 0))


class CompiledCVChain(torch.autograd.Function):
    """``x (B, J, 4) = chain(q (B, J))`` over one chunk (the state and looks fixed): numba forward, numba adjoint.
    Use through :func:`cv_run`."""

    @staticmethod
    def forward(ctx, q, x0, P0, looks):
        B, J = looks.B, looks.J
        rr = looks.rdot is not None
        # batch first (one copy each): the kernels run row by row, and ChainLooks' components-first layout would
        # put each of a look's inputs on another cache line (it cost half the kernels' time)
        arrs = (_rows(looks.dt_s), _rows(looks.mask), _rows(looks.z_m), _rows(looks.R_m2))
        if rr:
            rd, rvar, site = (_rows(a) for a in looks.rdot)
        else:
            rd = rvar = np.empty((0, 0))
            site = np.empty((0, 0, 0))
        qn = np.ascontiguousarray(_np(q))
        x_out = np.empty((B, J, 4))
        xp_s, Pp_s = np.empty((B, J, 4)), np.empty((B, J, 4, 4))
        xm_s, Pm_s = (np.empty((B, J, 4)), np.empty((B, J, 4, 4))) if rr else (np.empty((0, 0, 0)),
                                                                               np.empty((0, 0, 0, 0)))
        x_end, P_end = np.empty((4, B)), np.empty((4, 4, B))
        k_cv_forward(_np(x0), _np(P0), qn, *arrs, rr, rd, rvar, site, x_out, xp_s, Pp_s, xm_s, Pm_s, x_end, P_end)
        if not (np.isfinite(x_out).all() and np.isfinite(P_end).all()):
            raise FloatingPointError("compiled CV chain: a state is not finite (the looks or the state are bad)")
        ctx.saved = (qn, arrs, rr, rd, rvar, site, xp_s, Pp_s, xm_s, Pm_s)
        ctx.end = (torch.from_numpy(x_end), torch.from_numpy(P_end))
        ctx.mark_non_differentiable(*ctx.end)
        return torch.from_numpy(x_out), *ctx.end

    @staticmethod
    def backward(ctx, gx, _gx_end, _gP_end):
        qn, arrs, rr, rd, rvar, site, xp_s, Pp_s, xm_s, Pm_s = ctx.saved
        gq = np.empty_like(qn)
        k_cv_backward(np.ascontiguousarray(gx.numpy(), dtype=np.float64), qn, *arrs, rr, rd, rvar, site, xp_s, Pp_s,
                      xm_s, Pm_s, gq)
        if not np.isfinite(gq).all():
            raise FloatingPointError("compiled CV chain: the gradient with respect to q is not finite")
        return torch.from_numpy(gq), None, None, None


def cv_run(state: ChainState, looks: ChainLooks, q_m_s2):
    """:func:`radar_env.filters.torch_chain.run` of the CV model, compiled (module docstring).

    Args:
        state: the state before column 0; constant (a state that requires a gradient raises ``ValueError``: the
            adjoint stops at ``q``).
        looks: the chunk's :class:`~radar_env.filters.torch_chain.ChainLooks` (with or without range rate).
        q_m_s2: (B, J) tensor, finite and in ``[0, MAX_Q_M_S2]`` (``ValueError`` otherwise); may require a gradient.
    Returns:
        ``(x, state_end)``: posteriors ``x (B, J, 4)`` (differentiable with respect to ``q_m_s2``) and the state
        after the last column (detached). ``FloatingPointError`` if a state or the gradient is not finite.
    """
    B, J = looks.B, looks.J
    if J == 0:
        raise ValueError("cv_run: looks has no columns")
    if state.x_c.requires_grad or state.P_c.requires_grad:
        raise ValueError("cv_run: the compiled chain differentiates with respect to q only; pass a detached state")
    q = torch.as_tensor(q_m_s2, dtype=DTYPE)
    if q.shape != (B, J):
        raise ValueError(f"q_m_s2 must have shape {(B, J)}, got {tuple(q.shape)}")
    with torch.no_grad():
        if not bool(((q >= 0.0) & (q <= MAX_Q_M_S2)).all()):        # NaN fails too
            raise ValueError(f"q_m_s2 must be finite and in [0, {MAX_Q_M_S2}]")
    x0, P0 = state.x_c.contiguous(), state.P_c.contiguous()
    x, x_end, P_end = CompiledCVChain.apply(q, x0, P0, looks)
    return x, ChainState(x_end, P_end)
