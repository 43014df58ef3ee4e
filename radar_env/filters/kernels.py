r"""Compiled kernels of the tracking chain: the one copy of the filter, feature and preview math.

Everything here is numba ``@njit(cache=True)`` (nopython, no fastmath, so results agree with plain float64
arithmetic to rounding) and works on float64 / int64 / bool arrays with the batch axis first. Per-row scalar code
(functions starting ``_``) is written once and called by the batched kernels (``k_*``), which loop over rows.
The equations are in :mod:`radar_env.filters.kalman` (Kalman / IMM), :mod:`radar_env.filters.features` (features) and
:mod:`radar_env.filters.tracking` (the chain and the preview); those modules are the public numpy-array API and call
these kernels.

Layouts (module constants, compile-time constants inside the kernels):

* a look row ``L_*``: the episode data of one look packed into ``W_LOOK`` float64 columns (flags as 0/1): the
  simulation's data format, defined in :mod:`radar_env.sim.looks` (the episode drawer writes it) and re-exported
  here;
* the tracker's state ``st (B, W_ST)`` float (``S_*``: x, P, time of the last look) and ``it (B, W_IT)`` int
  (``I_*``: next look, looks in the episode; the look cursor, also from :mod:`radar_env.sim.looks`);
* the feature-bank state of one track: ``bf`` (float: ring buffers, FMA, held values), ``bi`` (int: ring-buffer
  indices and counts), ``bb`` (bool: validity flags), offsets from :func:`bank_offsets`;
* one step's output row ``O_*`` (float), ``OB_*`` (bool) and the feature columns ``FB_*`` (bank) / ``FP_*``
  (preview).

Kernels that can fail return an int status (0 = ok) and change nothing when they fail, so that the Python layer
can raise a ``ValueError`` naming the value.
"""

from __future__ import annotations

import math
import types
from pathlib import Path

import numpy as np
from numba import njit

from ..common.arrays import c_array  # noqa: F401  (re-exported: the kernels' array type)
from ..common.numba_cache import drop_stale_kernels, package_sources
from ..sim.looks import (I_K, I_N, L_BEAR, L_BSTD, L_DET, L_MAN, L_R, L_RANGE, L_RDOT,  # noqa: F401
                         L_RDSTD, L_RSTD, L_SITE, L_T, L_TACC, L_TRUTH, L_TTURN, L_Z, LOOK_COLUMNS, W_IT, W_LOOK)
from ..sim.motion import _transition, k_transition  # noqa: F401  (the CT motion model the truth uses too)

TWO_PI = 2.0 * math.pi
LOG_2PI = math.log(2.0 * math.pi)
MIN_SPEED_M_S = 1e-6
MIN_DT_S = 1e-3

# --------------------------------------------------------------------------------------------- step output layout
O_T, O_DT, O_Q, O_XPR, O_PPR, O_X, O_P, O_NU, O_S, O_NIS = 0, 1, 2, 3, 7, 23, 27, 43, 45, 49
O_Z, O_R, O_SITE, O_RANGE, O_BEAR, O_RDOT, O_RSTD, O_BSTD, O_TRUTH, O_TACC = 50, 52, 56, 58, 59, 60, 61, 62, 63, 67
W_OUT = 69
OB_DET, OB_MAN, OB_DONE = 0, 1, 2
W_OUTB = 3

# feature columns: bank floats, then preview floats; bank flags
BANK_HELD = ("nu_along", "nu_cross", "nis", "c_min_m_s2", "turn_rate_alg1_rad_s", "fma_innovation_m",
             "kim_lee_phi_m2_s4", "nu_along_fm", "nu_cross_fm", "nis_fm", "kim_lee_q2_m2_s4")
H_NUA, H_NUC, H_NIS, H_CMIN, H_A1, H_FMA, H_PHI, H_NUAFM, H_NUCFM, H_NISFM, H_Q2 = range(11)
N_HELD = 11
BANK_FLOAT_KEYS = ("turn_rate_alg2_rad_s",) + BANK_HELD + ("speed_m_s", "heading_rad", "range_m")
FB_A2, FB_HELD, FB_SPEED, FB_HEAD, FB_RANGE = 0, 1, 12, 13, 14
W_BANK_OUT = 15
BANK_FLAG_KEYS = ("nu_valid", "fma_valid", "turn_rate_alg1_valid", "turn_rate_alg2_valid", "kim_lee_valid")
FBB_NU, FBB_FMA, FBB_A1, FBB_A2, FBB_KL = 0, 1, 2, 3, 4
W_BANK_OUTB = 5
PREVIEW_KEYS = ("next_nu_along", "next_nu_cross", "next_nis", "next_q_fit_m_s2", "next_c_min_m_s2",
                "next_los_accel_m_s2", "next_rdot_nu", "next_dt_s", "next_meas_std_m", "next_detected")
FP_NUA, FP_NUC, FP_NIS, FP_QFIT, FP_CMIN, FP_LOSA, FP_RDNU, FP_DT, FP_STD, FP_DET = range(10)
W_PREVIEW = 10
W_FEAT = W_BANK_OUT + W_PREVIEW

# bank int / bool state columns
BI_PIDX, BI_PCNT, BI_HIDX, BI_HCNT, BI_OIDX, BI_OCNT, BI_NDET = range(7)
W_BANK_I = 7
BB_NU, BB_A1, BB_KL = 0, 1, 2
W_BANK_B = 3

# chain parameters (float64 vector): the feature bank's, then the filter's range-rate option (PAR_RDOT: the scale of
# the radar's radial-velocity noise std used in the update; 0 = position only)
PAR_N, PAR_NKL, PAR_KLMIN, PAR_FMA_W, PAR_FM_W, PAR_SD2, PAR_MIN_DT, PAR_RDOT = range(8)
W_PAR = 8

# packed tracker state: floats ``st (B, W_ST)`` (posterior x, P, time of the last processed look) and ints
# ``it (B, W_IT)`` (next look to process, looks in the episode; I_K, I_N, W_IT from sim.looks): few kernel arguments
S_X, S_P, S_T = 0, 4, 20
W_ST = 21


def bank_offsets(n, N):
    """Column offsets of the float bank state: ``(plot_xy, plot_t, head, head_t, outer, fma, last, width)``."""
    L1, L2 = n + 2, n + 1
    pxy = 0
    pt = pxy + 2 * L1
    hd = pt + L1
    ht = hd + L2
    ou = ht + L2
    fma = ou + 4 * N
    last = fma + 1
    return pxy, pt, hd, ht, ou, fma, last, last + N_HELD


_bank_offsets = njit(cache=True)(bank_offsets)


# =================================================================================================== scalar math
@njit(cache=True)
def _process_noise(dt, q, Q):
    q2 = q * q
    dt2 = dt * dt
    pp, pv, vv = q2 * (dt2 * dt2) / 4.0, q2 * (dt2 * dt) / 2.0, q2 * dt2
    for i in range(4):
        for j in range(4):
            Q[i, j] = 0.0
    Q[0, 0] = Q[1, 1] = pp
    Q[0, 2] = Q[2, 0] = Q[1, 3] = Q[3, 1] = pv
    Q[2, 2] = Q[3, 3] = vv


@njit(cache=True)
def _propagate(x, P, F, xo, FPF, FP):
    """xo = F x, FPF = F P F^T (not symmetrised); FP (4,4) scratch. xo/FPF may not alias x/P."""
    for i in range(4):
        acc = 0.0
        for j in range(4):
            acc += F[i, j] * x[j]
        xo[i] = acc
    for i in range(4):
        for j in range(4):
            acc = 0.0
            for m in range(4):
                acc += F[i, m] * P[m, j]
            FP[i, j] = acc
    for i in range(4):
        for j in range(4):
            acc = 0.0
            for m in range(4):
                acc += FP[i, m] * F[j, m]
            FPF[i, j] = acc


@njit(cache=True, inline="always")
def _symmetrize(A):
    """A = (A + A^T) / 2 in place (square): rounding must not make a covariance asymmetric."""
    n = A.shape[0]
    for i in range(n):
        for j in range(i + 1, n):
            v = 0.5 * (A[i, j] + A[j, i])
            A[i, j] = v
            A[j, i] = v


@njit(cache=True)
def _predict(x, P, F, Q, u, has_u, xo, Po, FP):
    """x- = F x (+ u), P- = sym(F P F^T + Q); FP (4,4) scratch. xo/Po may not alias x/P."""
    _propagate(x, P, F, xo, Po, FP)
    for i in range(4):
        if has_u:
            xo[i] += u[i]
        for j in range(4):
            Po[i, j] += Q[i, j]
    _symmetrize(Po)


PD_FLOOR_REL = 64.0 * np.finfo(np.float64).eps
"""First step of :func:`_pd_floor` (1.4e-14): the least addition it tries, relative to each block's variance."""

PD_MIN_EIG = 2.0 ** -45
"""Least smallest eigenvalue (2.8e-14, 128 eps) of a covariance's correlation matrix ``H = D^-1/2 P D^-1/2``
(D = diag P) that :func:`_chol_ok` accepts. Any Cholesky factorisation in float64 (LAPACK's, numpy's, ours) runs to
the end on a positive definite P whose ``lambda_min(H)`` exceeds ``n gamma_(n+1)``, about 20 eps for n = 4 and 30
eps for n = 5 (Demmel 1989; Higham, Accuracy and Stability of Numerical Algorithms, 2nd ed., Thm 10.7): a factor of
4 or more to spare for the check's own rounding. A margin on each Cholesky pivot (64 eps of its diagonal) was not
enough: after 1,000 s coasts at 2 g the env gave an exactly positive definite P with ``lambda_min(H)`` = 1.3 eps,
which our check accepted and numpy's Cholesky refused."""


@njit(cache=True)   # a call, not inlined: inlined twice in _pd_floor it cost 0.8 s more first-use compilation
def _chol_ok(P, n):
    """Whether the symmetric P (n x n, n = 4 or 5; lower triangle read) is positive definite with a margin every
    Cholesky implementation honours: ``1 / trace(H^-1) > PD_MIN_EIG``, a lower bound (within a factor n) on the
    smallest eigenvalue of P's correlation matrix H. ``trace(H^-1) = sum_i P_ii (P^-1)_ii``, from P's Cholesky
    factor L as the columns of ``L^-1``; each pivot is first checked against the same margin (pivot k over its
    diagonal is ``1 / (H_k^-1)_kk`` of H's leading k + 1 rows and columns ``H_k``, at least ``lambda_min(H)``).
    Scale-free: the units of the blocks do not matter. Written out: no scratch array in the hot path.

    Fast path (an ordinary covariance): every pivot at least ``2^-8`` of its diagonal bounds ``trace(H^-1)`` without
    computing it. H's factor has rows of unit norm and diagonal >= ``s^-1`` (s = 16), so ``|(L^-1)_ij| <= s^2 (1 +
    s)^(i-j-1)`` below the diagonal and ``trace(H^-1) <= n s^2 + sum_(i>j) s^4 (1 + s)^(2(i-j-1)) < 1.7e12`` for
    n <= 5, below ``1 / PD_MIN_EIG`` = 3.5e13."""
    m = PD_MIN_EIG
    fast = 0.00390625   # 2^-8
    p = P[0, 0]
    if not (p > 0.0 and math.isfinite(p)):
        return False
    r0 = 1.0 / math.sqrt(p)                  # r_k = 1 / L_kk
    l10, l20, l30 = P[1, 0] * r0, P[2, 0] * r0, P[3, 0] * r0
    p = P[1, 1] - l10 * l10
    if not p > m * P[1, 1]:
        return False
    clear = p > fast * P[1, 1]
    r1 = 1.0 / math.sqrt(p)
    l21, l31 = (P[2, 1] - l20 * l10) * r1, (P[3, 1] - l30 * l10) * r1
    p = P[2, 2] - l20 * l20 - l21 * l21
    if not p > m * P[2, 2]:
        return False
    clear = clear and p > fast * P[2, 2]
    r2 = 1.0 / math.sqrt(p)
    l32 = (P[3, 2] - l30 * l20 - l31 * l21) * r2
    p = P[3, 3] - l30 * l30 - l31 * l31 - l32 * l32
    if not p > m * P[3, 3]:
        return False
    clear = clear and p > fast * P[3, 3]
    if n == 4 and clear:
        return True
    r3 = 1.0 / math.sqrt(p)
    if n == 5:
        l40 = P[4, 0] * r0
        l41 = (P[4, 1] - l40 * l10) * r1
        l42 = (P[4, 2] - l40 * l20 - l41 * l21) * r2
        l43 = (P[4, 3] - l40 * l30 - l41 * l31 - l42 * l32) * r3
        p4 = P[4, 4] - l40 * l40 - l41 * l41 - l42 * l42 - l43 * l43
        if not p4 > m * P[4, 4]:
            return False
        if clear and p4 > fast * P[4, 4]:
            return True
    # M = L^-1 (lower triangular, M_kk = r_k); (P^-1)_ii = sum_k M_ki^2
    m10 = -l10 * r0 * r1
    m21 = -l21 * r1 * r2
    m20 = -(l20 * r0 + l21 * m10) * r2
    m32 = -l32 * r2 * r3
    m31 = -(l31 * r1 + l32 * m21) * r3
    m30 = -(l30 * r0 + l31 * m10 + l32 * m20) * r3
    c0 = r0 * r0 + m10 * m10 + m20 * m20 + m30 * m30
    c1 = r1 * r1 + m21 * m21 + m31 * m31
    c2 = r2 * r2 + m32 * m32
    c3 = r3 * r3
    if n == 4:
        return (P[0, 0] * c0 + P[1, 1] * c1 + P[2, 2] * c2 + P[3, 3] * c3) * m < 1.0
    r4 = 1.0 / math.sqrt(p4)
    m43 = -l43 * r3 * r4
    m42 = -(l42 * r2 + l43 * m32) * r4
    m41 = -(l41 * r1 + l42 * m21 + l43 * m31) * r4
    m40 = -(l40 * r0 + l41 * m10 + l42 * m20 + l43 * m30) * r4
    tr = (P[0, 0] * (c0 + m40 * m40) + P[1, 1] * (c1 + m41 * m41) + P[2, 2] * (c2 + m42 * m42)
          + P[3, 3] * (c3 + m43 * m43) + P[4, 4] * (r4 * r4))
    return tr * m < 1.0


@njit(cache=True)   # not inlined: one compilation for every caller (it was 2 x _chol_ok in each), called with an int64 n
def _pd_floor(Po, n, P):
    """Keep the symmetric posterior ``Po`` (n x n, n = 4 or 5: position, velocity, [turn rate]) of the prior ``P``
    positive definite as float64 can represent it. The update subtracts prior-sized numbers, so a posterior variance
    is known only to about eps x the prior's; one that is tiny against the prior (a near-singular or perfect plot,
    a coast of minutes at 100 g before the update, nanometre noise) can come out slightly negative. Then, and only
    then (:func:`_chol_ok` fails: not positive definite with the margin ``PD_MIN_EIG`` every Cholesky honours),
    each block's diagonal gets ``tau`` x the block's largest prior (or posterior) variance, ``tau`` from
    ``PD_FLOOR_REL`` up by factors of 16 until the check passes: the least such addition on that grid, in each
    block's units, a few hundred eps of its scale. Changes nothing on ordinary looks."""
    if _chol_ok(Po, n):
        return
    sp = max(abs(Po[0, 0]), abs(Po[1, 1]), abs(P[0, 0]), abs(P[1, 1]))
    sv = max(abs(Po[2, 2]), abs(Po[3, 3]), abs(P[2, 2]), abs(P[3, 3]))
    sw = max(abs(Po[4, 4]), abs(P[4, 4])) if n == 5 else 0.0
    if not (math.isfinite(sp) and math.isfinite(sv) and math.isfinite(sw)):
        return      # a non-finite covariance: nothing a floor can mend (the trackers report it as failed)
    if not sp > 0.0:    # degenerate (a zero position block): borrow the other block's scale
        sp = max(sv, 1.0)
    if not sv > 0.0:
        sv = sp
    if n == 5 and not sw > 0.0:
        sw = sv
    tau_done, tau = 0.0, PD_FLOOR_REL
    while tau <= 1.0:
        d = tau - tau_done
        Po[0, 0] += d * sp
        Po[1, 1] += d * sp
        Po[2, 2] += d * sv
        Po[3, 3] += d * sv
        if n == 5:
            Po[4, 4] += d * sw
        tau_done = tau
        if _chol_ok(Po, n):
            return
        tau *= 16.0


@njit(cache=True)
def _plot_frame(p00, p01, p11, r00, r01, r11):
    """The frame of a plot covariance R's principal axes (its range and cross-range directions): the rotation
    ``G = [[c, s], [-s, c]]`` onto them, ``R' = diag(l1, l2)``, the position block ``A' = G A G^T`` of the prior
    ``A = [[p00, p01], [p01, p11]]`` and ``S'^-1 = (A' + R')^-1`` with ``det S'``; returns
    ``(c, s, l1, l2, a0, a1, a01, i00, i01, i11, det_s)``. There R is diagonal and S' graded, so ``S'^-1`` stays
    accurate for a near-singular R (a condition number up to 1/eps: 100 km range noise with a fine bearing, a
    target passing the site), where the closed-form inverse of S itself cancels away; ``det S'`` is summed from
    non-negative terms (``det A' + l1 a1 + l2 a0 + l1 l2``), positive for any R != 0 and A' with a positive
    diagonal."""
    c, s, l1, l2 = _r_frame(r00, r01, r11)
    a0, a1, a01, i00, i01, i11, det_s = _prior_in_frame(p00, p01, p11, c, s, l1, l2)
    return c, s, l1, l2, a0, a1, a01, i00, i01, i11, det_s


@njit(cache=True)
def _r_frame(r00, r01, r11):
    """The part of :func:`_plot_frame` that depends on the plot's R alone: ``(c, s, l1, l2)``. A filter updating many
    priors with one plot (the particle filter) computes it once per look instead of once per prior (its atan2, cos
    and sin), with the same numbers."""
    th = 0.5 * math.atan2(2.0 * r01, r00 - r11)
    c, s = math.cos(th), math.sin(th)
    cs, cc, ss = c * s, c * c, s * s
    l1 = max(r00 * cc + 2.0 * r01 * cs + r11 * ss, 0.0)
    l2 = max(r00 * ss - 2.0 * r01 * cs + r11 * cc, 0.0)
    return c, s, l1, l2


@njit(cache=True)
def _prior_in_frame(p00, p01, p11, c, s, l1, l2):
    """The rest of :func:`_plot_frame`, in R's frame ``(c, s, l1, l2)`` (:func:`_r_frame`): ``(a0, a1, a01, i00,
    i01, i11, det_s)``."""
    cs, cc, ss = c * s, c * c, s * s
    a0 = p00 * cc + 2.0 * p01 * cs + p11 * ss
    a1 = p00 * ss - 2.0 * p01 * cs + p11 * cc
    a01 = (p11 - p00) * cs + p01 * (cc - ss)
    det_s = max(a0 * a1 - a01 * a01, 0.0) + l1 * a1 + l2 * a0 + l1 * l2
    s0, s1 = a0 + l1, a1 + l2
    return a0, a1, a01, s1 / det_s, -a01 / det_s, s0 / det_s, det_s


@njit(cache=True)
def _plot_nis(p00, p01, p11, r00, r01, r11, nu0, nu1):
    """``(NIS, det S)`` of the innovation ``nu`` with ``S = A + R`` (A = [[p00, p01], [p01, p11]]), computed in R's
    principal axes (:func:`_plot_frame`)."""
    c, s, _, _, _, _, _, i00, i01, i11, det_s = _plot_frame(p00, p01, p11, r00, r01, r11)
    n0, n1 = c * nu0 + s * nu1, -s * nu0 + c * nu1
    return n0 * n0 * i00 + 2.0 * n0 * n1 * i01 + n1 * n1 * i11, det_s


@njit(cache=True)
def _gain_update(x, P, n, nu0, nu1, r00, r01, r11, xo, Po):
    """Posterior of an n-state (n = 4 or 5, position first) Kalman update with a position plot (H = [I 0],
    innovation ``nu``, covariance ``R = [[r00, r01], [r01, r11]]``); returns ``(nis, det S)``.

    Computed in the frame of R's principal axes (:func:`_plot_frame`: the position rotated by ``G``, R diagonal,
    ``S'^-1`` accurate for a near-singular R): ``K' = P'H^T S'^-1``, ``x+ = x + K nu``; the covariance as
    ``P+' H^T = K' R'`` (position rows and columns) and ``P+[2:, 2:] = P[2:, 2:] - K'[2:] P'[:2, 2:]`` (the other
    states), rotated back, symmetrised and floored by :func:`_pd_floor`. (``P - K H P`` or the Joseph form subtract
    prior-sized terms in the position block: a rounding error of eps x the prior, above the posterior itself after
    a hard coast.) The same numbers as the textbook update to rounding. xo/Po must not alias x/P."""
    c, s, l1, l2 = _r_frame(r00, r01, r11)
    return _gain_update_in_frame(x, P, n, nu0, nu1, c, s, l1, l2, xo, Po)


@njit(cache=True, inline="always")
def _gain_update_in_frame(x, P, n, nu0, nu1, c, s, l1, l2, xo, Po):
    """:func:`_gain_update` given R's frame ``(c, s, l1, l2)`` (:func:`_r_frame`): the same numbers."""
    a0, a1, a01, i00, i01, i11, det_s = _prior_in_frame(P[0, 0], 0.5 * (P[0, 1] + P[1, 0]), P[1, 1], c, s, l1, l2)
    cs, cc, ss = c * s, c * c, s * s
    for j in range(2, n):                                # B' = G B, kept in Po's top-right block until the end
        Po[0, j] = c * P[0, j] + s * P[1, j]
        Po[1, j] = -s * P[0, j] + c * P[1, j]
    n0, n1 = c * nu0 + s * nu1, -s * nu0 + c * nu1       # nu' = G nu
    # position rows: K'_pos = A' S'^-1, A+' = K'_pos R'
    k00, k01 = a0 * i00 + a01 * i01, a0 * i01 + a01 * i11
    k10, k11 = a01 * i00 + a1 * i01, a01 * i01 + a1 * i11
    d0, d1 = k00 * n0 + k01 * n1, k10 * n0 + k11 * n1
    xo[0] = x[0] + (c * d0 - s * d1)                     # G^T (K'_pos nu')
    xo[1] = x[1] + (s * d0 + c * d1)
    q00, q11 = k00 * l1, k11 * l2
    q01 = 0.5 * (k01 * l2 + k10 * l1)
    # the other states: K'_i = B'_i^T S'^-1; their rows of P+ (position columns rotated back, then the block)
    for i in range(2, n):
        b0, b1 = Po[0, i], Po[1, i]
        ki0, ki1 = b0 * i00 + b1 * i01, b0 * i01 + b1 * i11
        xo[i] = x[i] + (ki0 * n0 + ki1 * n1)
        for j in range(2, n):
            Po[i, j] = P[i, j] - (ki0 * Po[0, j] + ki1 * Po[1, j])
        e0, e1 = ki0 * l1, ki1 * l2
        Po[i, 0] = c * e0 - s * e1
        Po[i, 1] = s * e0 + c * e1
    for i in range(2, n):
        Po[0, i] = Po[i, 0]
        Po[1, i] = Po[i, 1]
        for j in range(i + 1, n):
            v = 0.5 * (Po[i, j] + Po[j, i])
            Po[i, j] = v
            Po[j, i] = v
    Po[0, 0] = q00 * cc - 2.0 * q01 * cs + q11 * ss      # A+ = G^T A+' G
    Po[1, 1] = q00 * ss + 2.0 * q01 * cs + q11 * cc
    v = (q00 - q11) * cs + q01 * (cc - ss)
    Po[0, 1] = v
    Po[1, 0] = v
    _pd_floor(Po, n, P)
    return n0 * n0 * i00 + 2.0 * n0 * n1 * i01 + n1 * n1 * i11, det_s


MIN_RANGE_FOR_RDOT_M = 1.0
"""A predicted position closer than this to the site gets no range-rate update (the line of sight is undefined)."""


@njit(cache=True)
def _rdot_update(x, P, n, rdot, sx, sy, var, xo, Po):
    """The EKF update of an n-state (n = 4 or 5: position, velocity[, turn rate]) ``(x, P)`` with a measured radial
    velocity ``rdot`` (m/s, positive receding) from the site ``(sx, sy)``, variance ``var``: ``h(x) = u . v`` with
    ``u`` the unit line of sight from the site, Jacobian row ``[(vx - h ux) / r, (vy - h uy) / r, ux, uy, 0]``.
    Writes the posterior into ``xo``, ``Po`` (not aliasing ``x``, ``P``), symmetrised and floored like the position
    update; returns the log-likelihood ``-(nu^2 / s + log(2 pi s)) / 2`` (0, posterior = prior, within
    ``MIN_RANGE_FOR_RDOT_M`` of the site or for a variance that is not finite and positive: no measurement)."""
    dx, dy = x[0] - sx, x[1] - sy
    r = math.hypot(dx, dy)
    for i in range(n):
        xo[i] = x[i]
        for j in range(n):
            Po[i, j] = P[i, j]
    if not (r >= MIN_RANGE_FOR_RDOT_M and math.isfinite(var) and var > 0.0):
        return 0.0
    ux, uy = dx / r, dy / r
    h = ux * x[2] + uy * x[3]
    H0, H1, H2, H3 = (x[2] - h * ux) / r, (x[3] - h * uy) / r, ux, uy
    s = var                     # H P H^T + var: H is zero beyond the velocity
    for i in range(4):
        s += (P[i, 0] * H0 + P[i, 1] * H1 + P[i, 2] * H2 + P[i, 3] * H3) * (H0, H1, H2, H3)[i]
    nu = rdot - h
    for i in range(n):
        phi = P[i, 0] * H0 + P[i, 1] * H1 + P[i, 2] * H2 + P[i, 3] * H3
        xo[i] = x[i] + phi * nu / s
        for j in range(i + 1):
            phj = P[j, 0] * H0 + P[j, 1] * H1 + P[j, 2] * H2 + P[j, 3] * H3
            v = 0.5 * (P[i, j] + P[j, i]) - phi * phj / s
            Po[i, j] = v
            Po[j, i] = v
    _pd_floor(Po, n, P)
    return -0.5 * (nu * nu / s + math.log(2.0 * math.pi * s))


@njit(cache=True)
def _rdot_look(x, P, lk, scale, xs, Ps):
    """The range-rate update of the chain's 4-state ``(x, P)`` in place with look ``lk``'s radial velocity, its site
    and the radar's noise std times ``scale`` (:func:`_rdot_update`; a look whose radial velocity or std is not
    finite, or whose std is not positive, leaves the estimate as it is). ``xs (4,)``, ``Ps (4, 4)``: scratch.
    Returns the update's log-likelihood (0 without one)."""
    rd, sd = lk[L_RDOT], lk[L_RDSTD] * scale
    if not (math.isfinite(rd) and math.isfinite(sd) and sd > 0.0):
        return 0.0
    ll = _rdot_update(x, P, np.int64(4), rd, lk[L_SITE], lk[L_SITE + 1], sd * sd, xs, Ps)
    for i in range(4):
        x[i] = xs[i]
        for j in range(4):
            P[i, j] = Ps[i, j]
    return ll


@njit(cache=True)
def _propagate_cv(x, P, dt, xo, FPF):
    """:func:`_propagate` for ``F = F_cv(dt)`` in closed form: the same products and sums in the same order, without
    the multiplications by the zeros and ones of F (equal bit for bit up to the sign of an exact zero)."""
    xo[0] = x[0] + dt * x[2]
    xo[1] = x[1] + dt * x[3]
    xo[2] = x[2]
    xo[3] = x[3]
    for j in range(4):   # F P: rows 0, 1 gain dt times rows 2, 3
        FPF[0, j] = P[0, j] + dt * P[2, j]
        FPF[1, j] = P[1, j] + dt * P[3, j]
        FPF[2, j] = P[2, j]
        FPF[3, j] = P[3, j]
    for i in range(4):   # (F P) F^T: columns 0, 1 gain dt times columns 2, 3
        FPF[i, 0] = FPF[i, 0] + FPF[i, 2] * dt
        FPF[i, 1] = FPF[i, 1] + FPF[i, 3] * dt


@njit(cache=True)
def _predict_cv(x, P, dt, q, u, has_u, xo, Po):
    """:func:`_predict` for the CV model, ``F_cv(dt)`` and ``Q = q^2 Gamma Gamma^T`` in closed form (the same
    operations: every entry of Q is added, zeros included)."""
    _propagate_cv(x, P, dt, xo, Po)
    q2 = q * q
    dt2 = dt * dt
    pp, pv, vv = q2 * (dt2 * dt2) / 4.0, q2 * (dt2 * dt) / 2.0, q2 * dt2
    for i in range(4):
        if has_u:
            xo[i] += u[i]
        for j in range(4):
            d = i - j
            if i == j:
                Po[i, j] += pp if i < 2 else vv
            elif d == 2 or d == -2:
                Po[i, j] += pv
            else:
                Po[i, j] += 0.0
    _symmetrize(Po)


@njit(cache=True)
def _update(x, P, z, R, det, xo, Po, nu, S):
    """:func:`_update_nis` and the Gaussian log-likelihood of the innovation (0 on a missed look)."""
    nis, det_s = _update_nis(x, P, z, R, det, xo, Po, nu, S)
    if not det:
        return 0.0, 0.0
    return nis, -0.5 * (nis + 2.0 * LOG_2PI + math.log(det_s))


@njit(cache=True, inline="always")
def _update_nis(x, P, z, R, det, xo, Po, nu, S):
    """Kalman update with a converted position plot (H = [I 0]) by :func:`_gain_update`. Writes the posterior into
    xo, Po, the innovation and its covariance into nu, S. A missed look (``det`` False)
    leaves the prior unchanged (S from R = I, nu = 0, NIS 0, det S 0; :func:`_pd_floor` only where the prior is
    not positive definite with the margin of :func:`_chol_ok`). Returns ``(nis, det S)``: the env's step needs no
    log-likelihood, so its logarithm is taken only by :func:`_update`. xo/Po must not alias x/P."""
    if det:
        r00, r01, r10, r11 = R[0, 0], R[0, 1], R[1, 0], R[1, 1]
        nu0, nu1 = z[0] - x[0], z[1] - x[1]
    else:
        r00, r01, r10, r11 = 1.0, 0.0, 0.0, 1.0
        nu0, nu1 = 0.0, 0.0
    s00 = P[0, 0] + r00
    s11 = P[1, 1] + r11
    s01 = 0.5 * ((P[0, 1] + r01) + (P[1, 0] + r10))
    S[0, 0], S[0, 1], S[1, 0], S[1, 1] = s00, s01, s01, s11
    nu[0], nu[1] = nu0, nu1
    if not det:
        for i in range(4):
            xo[i] = x[i]
            for j in range(4):
                Po[i, j] = P[i, j]
        _pd_floor(Po, np.int64(4), P)
        return 0.0, 0.0
    return _gain_update(x, P, np.int64(4), nu0, nu1, r00, 0.5 * (r01 + r10), r11, xo, Po)


@njit(cache=True)
def _two_point_init(z1, R1, t1, z2, R2, t2, xo, Po):
    dt = t2 - t1
    dt2 = dt * dt
    xo[0], xo[1] = z2[0], z2[1]
    xo[2], xo[3] = (z2[0] - z1[0]) / dt, (z2[1] - z1[1]) / dt
    for i in range(2):
        for j in range(2):
            Po[i, j] = R2[i, j]
            Po[i, 2 + j] = R2[i, j] / dt
            Po[2 + i, j] = R2[i, j] / dt
            Po[2 + i, 2 + j] = (R1[i, j] + R2[i, j]) / dt2


# ------------------------------------------------------------------------------------------------ feature scalars
@njit(cache=True)
def _wrap(a):
    """Wrap to (-pi, pi] (same rule as features.wrap_angle)."""
    if a > -math.pi and a <= math.pi:
        return a
    m = math.pi - a
    m = m - TWO_PI * math.floor(m / TWO_PI)  # numpy mod for a positive divisor
    if m >= TWO_PI:
        m -= TWO_PI
    r = math.pi - m
    if r <= -math.pi:
        r += TWO_PI
    return r


@njit(cache=True)
def _mod2pi(a):
    m = a - TWO_PI * math.floor(a / TWO_PI)
    if m >= TWO_PI:
        m -= TWO_PI
    return m


@njit(cache=True)
def _nis(n0, n1, a, b, c, d):
    det = a * d - b * c
    if det > 0.0:
        return (d * n0 * n0 - (b + c) * n0 * n1 + a * n1 * n1) / det
    return 0.0


@njit(cache=True)
def _along_cross(n0, n1, a, b, c, d, vx, vy):
    """(nu_along, nu_cross) normalised; axes north/east below MIN_SPEED_M_S, 0 where a variance is <= 0."""
    return _along_cross_s(n0, n1, a, b, c, d, vx, vy, math.hypot(vx, vy))


@njit(cache=True)
def _along_cross_s(n0, n1, a, b, c, d, vx, vy, s):
    """:func:`_along_cross` with the speed ``s = hypot(vx, vy)`` given: the step computes each speed once and
    hands it to every feature that needs it (the same value, so the same bits)."""
    if s > MIN_SPEED_M_S:
        inv = 1.0 / s
        ax, ay = vx * inv, vy * inv
    else:
        ax, ay = 0.0, 1.0
    cx, cy = ay, -ax
    pa = ax * n0 + ay * n1
    pc = cx * n0 + cy * n1
    va = a * ax * ax + (b + c) * ax * ay + d * ay * ay
    vc = a * cx * cx + (b + c) * cx * cy + d * cy * cy
    na = pa / math.sqrt(va) if va > 0.0 else 0.0
    nc = pc / math.sqrt(vc) if vc > 0.0 else 0.0
    return na, nc


@njit(cache=True)
def _c_min(vx, vy, bearing, rdot, dt, min_dt):
    s = math.hypot(vx, vy)
    if not s > MIN_SPEED_M_S:
        return 0.0
    return _c_min_sh(s, math.atan2(vx, vy), bearing, rdot, dt, min_dt)


@njit(cache=True)
def _c_min_sh(s, h_prev, bearing, rdot, dt, min_dt):
    """:func:`_c_min` from the speed ``s = hypot(vx, vy)`` and heading ``h_prev = atan2(vx, vy)`` (computed once
    per look by the caller; ``h_prev`` is read only above MIN_SPEED_M_S)."""
    if not s > MIN_SPEED_M_S:
        return 0.0
    r = rdot / s
    r = min(max(r, -1.0), 1.0)
    gamma = math.acos(r)
    d0 = _mod2pi(bearing + gamma - h_prev)
    d1 = _mod2pi(bearing - gamma - h_prev)
    dmin = min(min(d0, TWO_PI - d0), min(d1, TWO_PI - d1))
    return s * dmin / max(dt, min_dt)


# ==================================================================================================== feature bank
@njit(cache=True)
def _bank_push_plot(bf, bi, n, zx, zy, t):
    L = n + 2
    i = bi[BI_PIDX]
    bf[2 * i] = zx
    bf[2 * i + 1] = zy
    bf[2 * L + i] = t
    bi[BI_PIDX] = (i + 1) % L
    bi[BI_PCNT] = min(bi[BI_PCNT] + 1, L)


@njit(cache=True)
def _bank_push_heading(bf, bi, n, hd, h, t):
    L = n + 1
    i = bi[BI_HIDX]
    bf[hd + i] = h
    bf[hd + L + i] = t
    bi[BI_HIDX] = (i + 1) % L
    bi[BI_HCNT] = min(bi[BI_HCNT] + 1, L)


@njit(cache=True)
def _bank_reset(bf, bi, bb, n, seed_xy, seed_t, n_seed, x, t, seed_heading):
    """Zero one row's bank state, then push ``n_seed`` seed plots (oldest first) and, if ``seed_heading``, the
    heading of ``x`` at ``t``."""
    for j in range(bf.shape[0]):
        bf[j] = 0.0
    for j in range(bi.shape[0]):
        bi[j] = 0
    for j in range(bb.shape[0]):
        bb[j] = False
    for j in range(n_seed):
        _bank_push_plot(bf, bi, n, seed_xy[j, 0], seed_xy[j, 1], seed_t[j])
    if seed_heading:
        hd = 3 * (n + 2)
        _bank_push_heading(bf, bi, n, hd, math.atan2(x[2], x[3]), t)


@njit(cache=True, inline="always")
def _bank_update(bf, bi, bb, par, x_prev, x_prior, P_prev, F, R, nu, S, x_post, z, t, dt, bearing, rdot, det,
                 site, of, ob):
    """One scan of one row's feature bank (see features.FeatureBank.update); writes the float outputs into
    ``of`` (W_BANK_OUT, columns FB_*) and the flags into ``ob`` (W_BANK_OUTB)."""
    n, N, klmin = int(par[PAR_N]), int(par[PAR_NKL]), int(par[PAR_KLMIN])
    fma_w, fm_w, sD2, min_dt = par[PAR_FMA_W], par[PAR_FM_W], par[PAR_SD2], par[PAR_MIN_DT]
    pxy, pt, hd, ht, ou, fma, last, _ = _bank_offsets(n, N)
    # --- innovation features (held on misses)
    if det:
        s_prior = math.hypot(x_prior[2], x_prior[3])
        na, nc = _along_cross_s(nu[0], nu[1], S[0, 0], S[0, 1], S[1, 0], S[1, 1], x_prior[2], x_prior[3], s_prior)
        bf[last + H_NUA] = na
        bf[last + H_NUC] = nc
        bf[last + H_NIS] = _nis(nu[0], nu[1], S[0, 0], S[0, 1], S[1, 0], S[1, 1])
        bf[last + H_NUAFM] = (1.0 - fm_w) * bf[last + H_NUAFM] + fm_w * na
        bf[last + H_NUCFM] = (1.0 - fm_w) * bf[last + H_NUCFM] + fm_w * nc
        bf[last + H_NISFM] = (1.0 - fm_w) * bf[last + H_NISFM] + fm_w * bf[last + H_NIS]
        # the CV prediction without input keeps the velocity, so its speed is the prior's (reused when equal;
        # hypot ignores the sign of a zero)
        same_v = x_prev[2] == x_prior[2] and x_prev[3] == x_prior[3]
        s_prev = s_prior if same_v else math.hypot(x_prev[2], x_prev[3])
        bf[last + H_CMIN] = (_c_min_sh(s_prev, math.atan2(x_prev[2], x_prev[3]), bearing, rdot, dt, min_dt)
                             if s_prev > MIN_SPEED_M_S else 0.0)
        bi[BI_NDET] += 1
        # --- FMA of |nu|
        bf[fma] = (1.0 - fma_w) * bf[fma] + fma_w * math.hypot(nu[0], nu[1])
    bf[last + H_FMA] = bf[fma]
    # --- Adrian algorithm 1 (plots)
    if det:
        _bank_push_plot(bf, bi, n, z[0], z[1], t)
        L = n + 2
        if bi[BI_PCNT] >= L:
            i = bi[BI_PIDX]  # oldest slot = plot k-1-n
            ik, ikm1, ikmn, ikm1mn = (i - 1 + L) % L, (i - 2 + L) % L, (i + 1) % L, i
            h_k = math.atan2(bf[2 * ik] - bf[2 * ikmn], bf[2 * ik + 1] - bf[2 * ikmn + 1])
            h_km1 = math.atan2(bf[2 * ikm1] - bf[2 * ikm1mn], bf[2 * ikm1 + 1] - bf[2 * ikm1mn + 1])
            dmid = 0.5 * (bf[pt + ik] + bf[pt + ikmn]) - 0.5 * (bf[pt + ikm1] + bf[pt + ikm1mn])
            bf[last + H_A1] = _wrap(h_k - h_km1) / max(dmid, min_dt)
            bb[BB_A1] = True
    # --- Adrian algorithm 2 (filtered headings, every update)
    h_post = math.atan2(x_post[2], x_post[3])
    _bank_push_heading(bf, bi, n, hd, h_post, t)
    j = bi[BI_HIDX]  # oldest slot = heading k-n
    a2_ok = bi[BI_HCNT] >= n + 1
    of[FB_A2] = _wrap(h_post - bf[hd + j]) / max(t - bf[ht + j], min_dt) if a2_ok else 0.0
    # --- Kim & Lee (window of detected innovations)
    if det:
        k = bi[BI_OIDX]
        o = ou + 4 * k
        bf[o], bf[o + 1], bf[o + 2], bf[o + 3] = nu[0] * nu[0], nu[0] * nu[1], nu[1] * nu[0], nu[1] * nu[1]
        bi[BI_OIDX] = (k + 1) % N
        bi[BI_OCNT] = min(bi[BI_OCNT] + 1, N)
        cnt = bi[BI_OCNT]
        if cnt >= klmin:
            s00 = 0.0
            s11 = 0.0
            for m in range(N):
                s00 += bf[ou + 4 * m]
                s11 += bf[ou + 4 * m + 3]
            c = float(max(cnt, 1))
            # trace of S0 = H F P+ F^T H^T + R (rows 0, 1 of F)
            tr0 = 0.0
            for r in range(2):
                acc = 0.0
                for a in range(4):
                    fpa = 0.0
                    for b in range(4):
                        fpa += F[r, b] * P_prev[b, a]
                    acc += fpa * F[r, a]
                tr0 += acc + R[r, r]
            dtf = max(dt, min_dt)
            dt2 = dtf * dtf
            phi = ((s00 / c + s11 / c) - tr0) / (0.5 * (dt2 * dt2))
            bf[last + H_PHI] = phi
            bf[last + H_Q2] = phi if phi >= 0.0 else sD2
            bb[BB_KL] = True
    for m in range(N_HELD):
        of[FB_HELD + m] = bf[last + m]
    of[FB_SPEED] = math.hypot(x_post[2], x_post[3])     # (the step's preview reuses FB_SPEED and FB_HEAD)
    of[FB_HEAD] = h_post
    of[FB_RANGE] = math.hypot(x_post[0] - site[0], x_post[1] - site[1])
    nu_valid = bi[BI_NDET] > 0
    ob[FBB_NU] = nu_valid
    ob[FBB_FMA] = nu_valid
    ob[FBB_A1] = bb[BB_A1]
    ob[FBB_A2] = a2_ok
    ob[FBB_KL] = bb[BB_KL]


# ========================================================================================================= preview
@njit(cache=True)
def _preview(x, P, t, det, t_next, z, R, bearing, rdot, rdot_std, site, min_dt, FPF, xh, of):
    """Features of the next plot against the q-free prediction (see tracking.preview_next_plot) into ``of``
    (W_PREVIEW). ``det`` False (missed or no next look) gives 0 for every plot feature. FPF (4,4) and xh (4,) are
    scratch."""
    _preview_sh(x, P, t, det, t_next, z, R, bearing, rdot, rdot_std, site, min_dt, FPF, xh, of,
                math.hypot(x[2], x[3]), math.atan2(x[2], x[3]))


@njit(cache=True, inline="always")
def _preview_sh(x, P, t, det, t_next, z, R, bearing, rdot, rdot_std, site, min_dt, FPF, xh, of, speed, heading):
    """:func:`_preview` with ``speed = hypot(x[2], x[3])`` and ``heading = atan2(x[2], x[3])`` given (the step
    takes them from the feature bank, which computed them from the same posterior)."""
    dt = t_next - t
    for m in range(W_PREVIEW):
        of[m] = 0.0
    of[FP_DT] = dt
    if not det:
        return
    _propagate_cv(x, P, dt, xh, FPF)
    s00 = FPF[0, 0] + R[0, 0]
    s01 = FPF[0, 1] + R[0, 1]
    s10 = FPF[1, 0] + R[1, 0]
    s11 = FPF[1, 1] + R[1, 1]
    n0, n1 = z[0] - xh[0], z[1] - xh[1]
    na, nc = _along_cross_s(n0, n1, s00, s01, s10, s11, xh[2], xh[3], speed)   # xh's velocity is x's
    of[FP_NUA], of[FP_NUC] = na, nc
    of[FP_NIS] = _nis(n0, n1, s00, s01, s10, s11)
    dtf = max(dt, min_dt)
    dt2 = dtf * dtf
    phi = ((n0 * n0 + n1 * n1) - (s00 + s11)) / (0.5 * (dt2 * dt2))
    of[FP_QFIT] = math.sqrt(max(phi, 0.0))
    of[FP_CMIN] = _c_min_sh(speed, heading, bearing, rdot, dt, min_dt)
    l0, l1 = xh[0] - site[0], xh[1] - site[1]
    rng = max(math.hypot(l0, l1), 1.0)
    rdot_hat = (l0 * xh[2] + l1 * xh[3]) / rng
    of[FP_LOSA] = (rdot - rdot_hat) / max(dt, MIN_DT_S)
    u0, u1 = l0 / rng, l1 / rng
    hv = ((xh[2] - rdot_hat * u0) / rng, (xh[3] - rdot_hat * u1) / rng, u0, u1)
    s_r = 0.0
    for i in range(4):
        acc = 0.0
        for j in range(4):
            acc += FPF[i, j] * hv[j]
        s_r += hv[i] * acc
    s_r += rdot_std * rdot_std
    of[FP_RDNU] = (rdot - rdot_hat) / math.sqrt(s_r)
    of[FP_STD] = math.sqrt(0.5 * (R[0, 0] + R[1, 1]))
    of[FP_DET] = 1.0


# =================================================================================================== tracker step
@njit(cache=True)
def _scratch():
    """Scratch of :func:`_step_row`: F, Q, FP (4,4), u (4,), R (2,2), zz (2,), xh (4,)."""
    return (np.empty((4, 4)), np.empty((4, 4)), np.empty((4, 4)), np.zeros(4), np.empty((2, 2)), np.empty(2),
            np.empty(4))


# The per-look chain (_step_row, _update_nis, _bank_update, _preview_sh; the env's _emit, _encode_row,
# _reward_terms) is inlined at numba's IR level into the few kernels that call it (k_env, k_tracker_step, the k_*
# wrappers): as separate functions each call passed dozens of array structs and kept the reference counts of the
# views it made, about a quarter of the env's step at 1,024 rows (docs/speed.md). Each kernel compiles its own
# copy; the env's first use compiles only k_env, so its compilation time is unchanged. The arithmetic is the same.
@njit(cache=True, inline="always")
def _step_row(r, q, w, ct, known_input, st, it, looks, bf, bi, bb, par, xp, Pp, xo, Po, nu, S, of, ofb, F, Q, FP,
              u, R, zz, xh):
    """One look of tracker row ``r``: predict (CV in closed form; CT, or a known input, through F), update,
    features, preview. The state (``st``, ``it``, bank) is updated in place; the prior into ``xp``, ``Pp``, the
    posterior into ``xo``, ``Po``, the innovation into ``nu``, ``S``, the features into ``of`` (W_FEAT) and
    ``ofb`` (W_BANK_OUTB). Returns the NIS. F..zz: scratch (:func:`_scratch`). Reads the look data where it
    lies (``looks[r, k]``) and copies none of it."""
    kk = it[r, I_K]
    lk = looks[r, kk]
    t = lk[L_T]
    xr = st[r, S_X:S_X + 4]
    Pr = st[r, S_P:S_P + 16].reshape((4, 4))
    dt = t - st[r, S_T]
    det = lk[L_DET] != 0.0
    _transition(dt, w, ct, F)   # the bank's Kim & Lee term and the known input use F
    if known_input:
        tp = looks[r, kk - 1]
        for i in range(4):
            acc = 0.0
            for j in range(4):
                acc += F[i, j] * tp[L_TRUTH + j]
            u[i] = lk[L_TRUTH + i] - acc
    if ct:
        _process_noise(dt, q, Q)
        _predict(xr, Pr, F, Q, u, known_input, xp, Pp, FP)
    else:
        _predict_cv(xr, Pr, dt, q, u, known_input, xp, Pp)
    for i in range(2):
        zz[i] = lk[L_Z + i]
        for j in range(2):
            R[i, j] = lk[L_R + 2 * i + j]
    nis, _ = _update_nis(xp, Pp, zz, R, det, xo, Po, nu, S)
    if det and par[PAR_RDOT] > 0.0:     # the radial velocity after the position (xh, FP: free scratch here)
        _rdot_look(xo, Po, lk, par[PAR_RDOT], xh, FP)
    # feature bank: plot inputs zeroed where missed (held features ignore them)
    if not det:
        zz[0] = zz[1] = 0.0
        for i in range(2):
            for j in range(2):
                R[i, j] = 0.0
    bear = lk[L_BEAR] if det else 0.0
    rd = lk[L_RDOT] if det else 0.0
    _bank_update(bf[r], bi[r], bb[r], par, xr, xp, Pr, F, R, nu, S, xo, zz, t, dt, bear, rd, det,
                 lk[L_SITE:L_SITE + 2], of[:W_BANK_OUT], ofb)
    # state
    for i in range(4):
        xr[i] = xo[i]
        for j in range(4):
            Pr[i, j] = Po[i, j]
    st[r, S_T] = t
    it[r, I_K] = kk + 1
    has_next = kk + 1 < it[r, I_N]
    ln = looks[r, min(kk + 1, looks.shape[1] - 1)]
    det_n = has_next and ln[L_DET] != 0.0
    t_n = ln[L_T] if has_next else t
    for i in range(2):
        for j in range(2):
            R[i, j] = ln[L_R + 2 * i + j]
    # the bank's speed and heading are those of xr (its x_post, copied above): not computed a second time
    _preview_sh(xr, Pr, t, det_n, t_n, ln[L_Z:L_Z + 2], R, ln[L_BEAR], ln[L_RDOT], ln[L_RDSTD],
                ln[L_SITE:L_SITE + 2], MIN_DT_S, FP, xh, of[W_BANK_OUT:], of[FB_SPEED], of[FB_HEAD])
    return nis


@njit(cache=True)
def _check_q(q, max_q):
    for i in range(q.shape[0]):
        v = q[i]
        if not (v >= 0.0 and v <= max_q):  # NaN fails too
            return i
    return -1


@njit(cache=True)
def k_tracker_step(rows, all_rows, q, w, ct, known_input, max_q, n_rep, st, it, looks, bf, bi, bb, par, o, ob, oi):
    """Tracker.step for ``rows`` (or every row if ``all_rows``), ``n_rep`` looks in a row at the same q (1 for a
    step, ``warmup_scans`` for the warm-up of a track start); the outputs are those of the last look:
    ``o (n, W_OUT + W_FEAT)`` float, ``ob (n, W_OUTB + W_BANK_OUTB)`` bool, ``oi (n,)`` look index. Returns
    (status, index): status 1 = q[index] out of range, 2 = row of index i has not n_rep looks left; nothing is
    changed then."""
    n = q.shape[0]
    bad = _check_q(q, max_q)
    if bad >= 0:
        return 1, bad
    for i in range(n):
        r = i if all_rows else rows[i]
        if it[r, I_K] + n_rep > it[r, I_N]:
            return 2, i
    F, Q, FP, u, R, zz, xh = _scratch()
    xp = np.empty(4)
    Pp = np.empty((4, 4))
    for i in range(n):
        r = i if all_rows else rows[i]
        oo = o[i]
        xo = oo[O_X:O_X + 4]
        Po = oo[O_P:O_P + 16].reshape((4, 4))
        nu = oo[O_NU:O_NU + 2]
        S = oo[O_S:O_S + 4].reshape((2, 2))
        for _ in range(n_rep):
            kk = it[r, I_K]
            oi[i] = kk
            t_prev = st[r, S_T]
            nis = _step_row(r, q[i], w[i] if ct else 0.0, ct, known_input, st, it, looks, bf, bi, bb, par, xp, Pp,
                            xo, Po, nu, S, oo[W_OUT:], ob[i, W_OUTB:], F, Q, FP, u, R, zz, xh)
        # the wide output row of the public StepOutput: prior, the look's data
        lk = looks[r, kk]
        oo[O_T], oo[O_DT], oo[O_Q], oo[O_NIS] = lk[L_T], lk[L_T] - t_prev, q[i], nis
        for a in range(4):
            oo[O_XPR + a] = xp[a]
            for c in range(4):
                oo[O_PPR + 4 * a + c] = Pp[a, c]
        for a in range(2):
            oo[O_Z + a] = lk[L_Z + a]
            oo[O_SITE + a] = lk[L_SITE + a]
            oo[O_TACC + a] = lk[L_TACC + a]
        for a in range(4):
            oo[O_R + a] = lk[L_R + a]
            oo[O_TRUTH + a] = lk[L_TRUTH + a]
        oo[O_RANGE], oo[O_BEAR], oo[O_RDOT] = lk[L_RANGE], lk[L_BEAR], lk[L_RDOT]
        oo[O_RSTD], oo[O_BSTD] = lk[L_RSTD], lk[L_BSTD]
        ob[i, OB_DET] = lk[L_DET] != 0.0
        ob[i, OB_MAN] = lk[L_MAN] != 0.0
        ob[i, OB_DONE] = it[r, I_K] >= it[r, I_N]
    return 0, 0


@njit(cache=True)
def _track_start_row(r, i1, i2, st, it, looks, bf, bi, bb, par, seed_xy, seed_t, R1, R2):
    """Two-hit start of row ``r`` from looks ``i1``, ``i2`` (tracking.init_looks): two-point initialisation, the
    next look to process, and the feature bank reset and seeded with the two plots and the start heading.
    seed_xy, R1, R2 (2,2) and seed_t (2,) are scratch."""
    l1, l2 = looks[r, i1], looks[r, i2]
    for a in range(2):
        seed_xy[0, a], seed_xy[1, a] = l1[L_Z + a], l2[L_Z + a]
        for b in range(2):
            R1[a, b], R2[a, b] = l1[L_R + 2 * a + b], l2[L_R + 2 * a + b]
    seed_t[0], seed_t[1] = l1[L_T], l2[L_T]
    x = st[r, S_X:S_X + 4]
    _two_point_init(seed_xy[0], R1, l1[L_T], seed_xy[1], R2, l2[L_T], x, st[r, S_P:S_P + 16].reshape((4, 4)))
    it[r, I_K] = i2 + 1
    st[r, S_T] = l2[L_T]
    _bank_reset(bf[r], bi[r], bb[r], int(par[PAR_N]), seed_xy, seed_t, 2, x, l2[L_T], True)


@njit(cache=True)
def k_track_start(rows, i1s, i2s, st, it, looks, bf, bi, bb, par):
    """:func:`_track_start_row` for ``rows`` (episode data already in ``looks``). The warm-up is then
    ``k_tracker_step`` with ``n_rep = warmup_scans``."""
    seed_xy = np.empty((2, 2))
    seed_t = np.empty(2)
    R1 = np.empty((2, 2))
    R2 = np.empty((2, 2))
    for i in range(rows.shape[0]):
        _track_start_row(rows[i], i1s[i], i2s[i], st, it, looks, bf, bi, bb, par, seed_xy, seed_t, R1, R2)


# ================================================================================================ batched filters
@njit(cache=True)
def k_process_noise(dt, q, Q):
    for b in range(dt.shape[0]):
        _process_noise(dt[b], q[b], Q[b])


@njit(cache=True)
def k_predict(x, P, F, Q, u, has_u, xo, Po):
    FP = np.empty((4, 4))
    for b in range(x.shape[0]):
        _predict(x[b], P[b], F[b], Q[b], u[b] if has_u else u[0], has_u, xo[b], Po[b], FP)


@njit(cache=True)
def k_update(x, P, z, R, det, xo, Po, nu, S, nis, loglik):
    for b in range(x.shape[0]):
        nis[b], loglik[b] = _update(x[b], P[b], z[b], R[b], det[b], xo[b], Po[b], nu[b], S[b])


@njit(cache=True)
def k_two_point_init(z1, R1, t1, z2, R2, t2, xo, Po):
    for b in range(z1.shape[0]):
        _two_point_init(z1[b], R1[b], t1[b], z2[b], R2[b], t2[b], xo[b], Po[b])


# =================================================================================================== feature bank
@njit(cache=True)
def k_bank_update(bf, bi, bb, par, x_prev, x_prior, P_prev, F, R, nu, S, x_post, z, t, dt, bearing, rdot, det,
                  site, of, ob):
    for b in range(x_prev.shape[0]):
        _bank_update(bf[b], bi[b], bb[b], par, x_prev[b], x_prior[b], P_prev[b], F[b], R[b], nu[b], S[b],
                     x_post[b], z[b], t[b], dt[b], bearing[b], rdot[b], det[b], site[b], of[b], ob[b])


@njit(cache=True)
def k_bank_reset(rows, bf, bi, bb, n, seed_xy, seed_t, n_seed, x, t, seed_heading):
    for i in range(rows.shape[0]):
        r = rows[i]
        _bank_reset(bf[r], bi[r], bb[r], n, seed_xy[i], seed_t[i], n_seed, x[i], t[i], seed_heading)


@njit(cache=True)
def k_preview(x, P, t, det, t_next, z, R, bearing, rdot, rdot_std, site, min_dt, of):
    FPF = np.empty((4, 4))
    xh = np.empty(4)
    for b in range(x.shape[0]):
        _preview(x[b], P[b], t[b], det[b], t_next[b], z[b], R[b], bearing[b], rdot[b], rdot_std[b], site[b],
                 min_dt, FPF, xh, of[b])


# ============================================================================================================ IMM
@njit(cache=True)
def _logsumexp(a, n):
    m = -np.inf
    for i in range(n):
        if a[i] > m:
            m = a[i]
    if not math.isfinite(m):
        m = 0.0
    s = 0.0
    for i in range(n):
        s += math.exp(a[i] - m)
    return m + math.log(s)


@njit(cache=True)
def _imm_mix(log_mu, log_Pi, x, P, x0, P0, log_c, a, col):
    """Mixing of one row: log_mu (M,), log_Pi (M,M), x (M,4), P (M,4,4) -> x0, P0, log_c. a (M,M), col (M,)
    scratch."""
    M = log_mu.shape[0]
    for i in range(M):
        for j in range(M):
            a[i, j] = log_Pi[i, j] + log_mu[i]
    for j in range(M):
        for i in range(M):
            col[i] = a[i, j]
        log_c[j] = _logsumexp(col, M)
    for i in range(M):
        for j in range(M):
            a[i, j] = math.exp(a[i, j] - log_c[j])  # mixing weights mu_{i|j}
    for j in range(M):
        for d in range(4):
            acc = 0.0
            for i in range(M):
                acc += a[i, j] * x[i, d]
            x0[j, d] = acc
        for d in range(4):
            for e in range(4):
                acc = 0.0
                for i in range(M):
                    acc += a[i, j] * (P[i, d, e] + (x[i, d] - x0[j, d]) * (x[i, e] - x0[j, e]))
                P0[j, d, e] = acc
        _symmetrize(P0[j])


@njit(cache=True)
def _imm_combine(log_mu, x, P, xc, Pc):
    M = log_mu.shape[0]
    for d in range(4):
        acc = 0.0
        for m in range(M):
            acc += math.exp(log_mu[m]) * x[m, d]
        xc[d] = acc
    for d in range(4):
        for e in range(4):
            acc = 0.0
            for m in range(M):
                acc += math.exp(log_mu[m]) * (P[m, d, e] + (x[m, d] - xc[d]) * (x[m, e] - xc[e]))
            Pc[d, e] = acc
    _symmetrize(Pc)


@njit(cache=True)
def k_imm_mix(log_mu, log_Pi, x, P, x0, P0, log_c):
    B, M = log_mu.shape
    a = np.empty((M, M))
    col = np.empty(M)
    for b in range(B):
        _imm_mix(log_mu[b], log_Pi[b], x[b], P[b], x0[b], P0[b], log_c[b], a, col)


@njit(cache=True)
def k_imm_mode_probabilities(log_c, loglik, out):
    B, M = log_c.shape
    for b in range(B):
        for m in range(M):
            out[b, m] = log_c[b, m] + loglik[b, m]
        s = _logsumexp(out[b], M)
        for m in range(M):
            out[b, m] -= s


@njit(cache=True)
def k_imm_combine(log_mu, x, P, xc, Pc):
    for b in range(log_mu.shape[0]):
        _imm_combine(log_mu[b], x[b], P[b], xc[b], Pc[b])


@njit(cache=True)
def k_imm_step(log_mu, x_modes, P_modes, log_Pi, F, Q, z, R, det, rdot, rdot_var, site, o_log_mu, o_x, o_P, o_xc,
               o_Pc, o_loglik, o_nis, o_nu, o_S):
    """One IMM cycle per row (see filters.imm_step): mix, mode-matched predict and update (the position, then, where
    ``rdot_var[b]`` is finite, the radial velocity ``rdot[b]`` from ``site[b]``: its likelihood joins the mode's),
    mode probabilities, combination, and the innovation of the combined prediction (of the position)."""
    B, M = log_mu.shape
    a = np.empty((M, M))
    col = np.empty(M)
    x0 = np.empty((M, 4))
    P0 = np.empty((M, 4, 4))
    log_c = np.empty(M)
    xp = np.empty((M, 4))
    Pp = np.empty((M, 4, 4))
    FP = np.empty((4, 4))
    u = np.zeros(4)
    nu = np.empty(2)
    S = np.empty((2, 2))
    lc = np.empty(M)
    xpc = np.empty(4)
    Ppc = np.empty((4, 4))
    xs = np.empty(4)
    for b in range(B):
        _imm_mix(log_mu[b], log_Pi[b], x_modes[b], P_modes[b], x0, P0, log_c, a, col)
        for m in range(M):
            _predict(x0[m], P0[m], F[b, m], Q[b, m], u, False, xp[m], Pp[m], FP)
            _, o_loglik[b, m] = _update(xp[m], Pp[m], z[b], R[b], det[b], o_x[b, m], o_P[b, m], nu, S)
            if det[b] and rdot_var[b] < math.inf:
                o_loglik[b, m] += _rdot_update(o_x[b, m], o_P[b, m], np.int64(4), rdot[b], site[b, 0], site[b, 1], rdot_var[b],
                                               xs, FP)
                o_x[b, m] = xs
                o_P[b, m] = FP
        for m in range(M):
            o_log_mu[b, m] = log_c[m] + o_loglik[b, m]
        s = _logsumexp(o_log_mu[b], M)
        for m in range(M):
            o_log_mu[b, m] -= s
        _imm_combine(o_log_mu[b], o_x[b], o_P[b], o_xc[b], o_Pc[b])
        # innovation of the combined prediction (normalised predicted mode probabilities)
        s = _logsumexp(log_c, M)
        for m in range(M):
            lc[m] = log_c[m] - s
        _imm_combine(lc, xp, Pp, xpc, Ppc)
        if det[b]:
            r00, r01, r10, r11 = R[b, 0, 0], R[b, 0, 1], R[b, 1, 0], R[b, 1, 1]
            n0, n1 = z[b, 0] - xpc[0], z[b, 1] - xpc[1]
        else:
            r00, r01, r10, r11 = 1.0, 0.0, 0.0, 1.0
            n0, n1 = 0.0, 0.0
        s00, s11 = Ppc[0, 0] + r00, Ppc[1, 1] + r11
        s01 = 0.5 * ((Ppc[0, 1] + r01) + (Ppc[1, 0] + r10))
        o_S[b, 0, 0], o_S[b, 0, 1], o_S[b, 1, 0], o_S[b, 1, 1] = s00, s01, s01, s11
        o_nu[b, 0], o_nu[b, 1] = n0, n1
        if det[b]:
            o_nis[b] = _plot_nis(Ppc[0, 0], 0.5 * (Ppc[0, 1] + Ppc[1, 0]), Ppc[1, 1], r00, 0.5 * (r01 + r10), r11,
                                 n0, n1)[0]
        else:
            o_nis[b] = 0.0


@njit(cache=True)
def k_imm_run(t, z, R, det, rdot, rdot_var, site, n_looks, k_start, t_start, log_mu0, x0, P0, log_Pi, q, w, o_x, o_P,
              o_log_mu):
    """The IMM over every look of every row (filters.imm_filter): row b filters looks ``k_start[b] ..
    n_looks[b] - 1`` from the mode states ``log_mu0[b]`` (M,), ``x0[b]`` (M, 4), ``P0[b]`` (M, 4, 4) at time
    ``t_start[b]``; mode m predicts with ``F_ct(dt, w[m])`` and ``Q(dt, q[m])``, exactly as transition_ct and
    process_noise, and each look is one k_imm_step on a one-row view (``rdot``, ``rdot_var``, ``site``: the
    range-rate inputs, ``rdot_var`` inf for none). Writes the combined estimate ``o_x[b, k]``,
    ``o_P[b, k]`` and the posterior log mode probabilities ``o_log_mu[b, k]`` of every filtered look."""
    M = q.shape[0]
    F = np.empty((1, M, 4, 4))
    Q = np.empty((1, M, 4, 4))
    lPi = np.empty((1, M, M))
    lPi[0] = log_Pi
    lm = np.empty((1, M))
    xm = np.empty((1, M, 4))
    Pm = np.empty((1, M, 4, 4))
    n_lm = np.empty((1, M))
    n_xm = np.empty((1, M, 4))
    n_Pm = np.empty((1, M, 4, 4))
    xc = np.empty((1, 4))
    Pc = np.empty((1, 4, 4))
    ll = np.empty((1, M))
    nis = np.empty(1)
    nu = np.empty((1, 2))
    S = np.empty((1, 2, 2))
    for b in range(t.shape[0]):
        lm[0] = log_mu0[b]
        xm[0] = x0[b]
        Pm[0] = P0[b]
        t_last = t_start[b]
        for k in range(k_start[b], n_looks[b]):
            dt = t[b, k] - t_last
            for m in range(M):
                _transition(dt, w[m], True, F[0, m])
                _process_noise(dt, q[m], Q[0, m])
            k_imm_step(lm, xm, Pm, lPi, F, Q, z[b, k:k + 1], R[b, k:k + 1], det[b, k:k + 1], rdot[b, k:k + 1],
                       rdot_var[b, k:k + 1], site[b, k:k + 1], n_lm, n_xm, n_Pm, xc, Pc, ll, nis, nu, S)
            lm[:] = n_lm
            xm[:] = n_xm
            Pm[:] = n_Pm
            o_x[b, k] = xc[0]
            o_P[b, k] = Pc[0]
            o_log_mu[b, k] = n_lm[0]
            t_last = t[b, k]


# The particle filter (radar_env.filters.rbpf) updates thousands of particles per look: its copy of the update keeps
# the covariance floor and its check inlined (a call per particle cost it about 3 %), while the env's chain calls the
# one compiled _pd_floor (first use: inlined into every update it cost seconds of compilation). Same arithmetic.
def _with_globals(fn, **names):
    """A copy of the plain function ``fn`` whose global ``names`` resolve to other objects."""
    return types.FunctionType(fn.__code__, dict(fn.__globals__, **names), fn.__name__, fn.__defaults__,
                              fn.__closure__)


_pd_floor_inlined = njit(inline="always")(_with_globals(_pd_floor.py_func,
                                                       _chol_ok=njit(inline="always")(_chol_ok.py_func)))
_gain_update_in_frame_inlined = njit(inline="always")(
    _with_globals(_gain_update_in_frame.py_func, _pd_floor=_pd_floor_inlined))
""":func:`_gain_update_in_frame` with :func:`_pd_floor` inlined (the particle filter's per-particle update)."""


# numba keys each cached kernel on its own file only: drop this folder's cached kernels when any source of
# radar_env changed (radar_env.common.numba_cache), before a kernel of this or another module here loads from the cache
drop_stale_kernels(k_update, package_sources(Path(__file__).parents[1]))
