r"""Alpha-beta trackers: Kalata's steady-state gains and Kim & Lee's adaptive alpha-beta (seed 004).

Independent alpha-beta filters run on each Cartesian axis of the converted plots, vectorised over the batch
(B tracks) with a Python loop over scans only. Conventions: SI units, float64, batch axis first; for the usual
two axes the state is ``[x, y, vx, vy]`` (docs/architecture.md). No randomness.

Equations (Kim & Lee, "Adaptive alpha-beta tracker for TWS radar system")
-----------------------------------------------------------------------
* tracking index (eq 5): :math:`\lambda = \sigma_v T^2/\sigma_w` with :math:`\sigma_v` the acceleration standard
  deviation (m/s^2) of the piecewise-constant white-acceleration model (eq 1, same Q as ``filters.process_noise``)
  and :math:`\sigma_w` the measurement standard deviation (m). The paper calls :math:`\sigma_v` a "variance" but
  the formula (and Kalata) use the standard deviation; so do we.
* gains (eqs 6, 7): :math:`\alpha = -\tfrac18(\lambda^2 + 8\lambda - (\lambda+4)\sqrt{\lambda^2+8\lambda})`,
  :math:`\beta = \tfrac14(\lambda^2 + 4\lambda - \lambda\sqrt{\lambda^2+8\lambda})`; they satisfy eq 8,
  :math:`\beta = 2(2-\alpha) - 4\sqrt{1-\alpha}` (the Kalata relation; NOT Benedict-Bordner's
  :math:`\beta = \alpha^2/(2-\alpha)`), and :math:`\lambda^2 = \beta^2/(1-\alpha)`. They are exactly the
  steady-state Kalman gains :math:`[\alpha, \beta/T]` of the CV model with that Q (tested against
  ``filters.predict/update``). Stability (eqs 9, 10): :math:`0<\alpha<1`, :math:`0<\beta<4-2\alpha`.
* steady-state posterior covariance (eq 12):
  :math:`P_o = \sigma_w^2 [[\alpha, \beta/T], [\beta/T, \beta(2\alpha-\beta)/(2(1-\alpha)T^2)]]`.
* adaptive (eqs 13-17): per axis and per scan, :math:`\hat S_k` = mean of the last N squared innovations
  (eq 16 sums N+1 terms but divides by N; read as the mean of the last N, as in ``radar_env/filters/features.py``),
  :math:`\phi_k = (\hat S_k - (F P_o F^T)_{11} - \sigma_w^2)/(T^4/4)` (eq 15 with Q at unit acceleration
  variance, so :math:`\phi` estimates :math:`\sigma_v^2`), :math:`\hat\sigma_v^2 = \phi_k` if
  :math:`\phi_k\ge0` else :math:`\sigma_D^2` (eq 17); then eq 5 -> eqs 6, 7 give this scan's gains.
  :math:`P_o` in eq 15 is the tracker's current steady-state covariance (eq 12 at the previous update's gains,
  i.e. eq 13's :math:`P_{k-1}^+`). Until the window holds N detected innovations the gains come from
  :math:`\sigma_D^2`.
* unequal periods (our generalisation; the paper has one T): each window entry keeps its own
  :math:`\nu_i^2 - S_{0,i}` (:math:`S_{0,i}` = what eq 15 subtracts, at look i's gains and period) and its own
  :math:`T_i^4/4`, and :math:`\phi_k = \sum_i(\nu_i^2 - S_{0,i}) / \sum_i T_i^4/4` (the least-squares reading of
  :math:`E[\nu_i^2] = S_{0,i} + \sigma_v^2 T_i^4/4`); with a constant T this is eq 15 with :math:`S_0` averaged over the
  window. Eq 15 as printed divides the window mean by the CURRENT :math:`T^4/4`: with two sites (gaps alternating
  0.5 s / 3.5 s on ``seed002_two_radars``) that read up to :math:`10^6` m/s^2, gains went to alpha = 1, beta = 2
  and every track was lost (pooled RMSE 626 m, velocity 13.5 km/s; 9.8e7 m on ``random_radars``).
* physical bound ``q_max_m_s2`` (optional): :math:`\hat\sigma_v \le q_{max}`. The comparison tracker uses the
  largest q of the env's action set (8.1 g), so it is allowed no more maneuverability than any q-chooser.

Measured behaviour of the adaptive rule (tests/test_alpha_beta.py, sigma = 150 m, T = 1 s, N = 12)
------------------------------------------------------------------------------------------------
On the Kim & Lee +5 g / -5 g scenario the adaptive tracker's position RMSE over t in (25, 80] s is ~198 m
(eq 15) and ~165 m (``s0_mode="noise_only"``) against ~1690 m for the fixed tracker at q = 1 m/s^2.
But on a pure constant-velocity track (300 s, 100 runs, after 50 s) the adapted acceleration std does NOT come back
down: the median is ~88 m/s^2 (eq 15) / ~210 m/s^2 (noise_only), position RMSE ~153 m / ~147 m (about the 150 m of
the plots) against ~46 m for the fixed q = 1 tracker. (With eq 15's current-look S0 and T applied to the
whole window, as before the unequal-period rule: ~610 / ~420 m/s^2, ~217 / ~162 m.) Reasons: with N = 12 the window mean has a
relative std of ~0.4, so phi = 4 (S_hat - ...) / T^4 is of order sigma^2 / T^4 even without a maneuver, and
with eq 15 as printed, high gains amplify the plot noise into the innovations, which eq 15 reads as a
maneuver (a self-sustaining high-gain state). ``noise_only`` subtracts the innovation variance the current
gains actually produce on a non-maneuvering target, which removes the amplification term but not the window
noise. A smaller plot noise / longer window / a floor on phi would be needed for a usable non-maneuvering
accuracy; only the physical cap ``q_max_m_s2`` is offered here.

Missed detections, irregular time steps, start-up (our choices; the paper has a fixed T and no misses)
----------------------------------------------------------------------------------------------------
* A missed plot is predict-only: the output is the extrapolation of the last posterior, with covariance
  :math:`F P F^T + Q` (``Q`` at the current :math:`\sigma_v`). The next update uses ``T = t_k - t_last_update``
  (the whole gap) in eqs 5, 6, 7, 12 and 15, i.e. the gains of a steady-state tracker whose period equals the gap.
  This is an approximation (the true KF gain after a gap is not the steady-state one); it is exact for a
  regular scan with no misses. With fixed ``alpha, beta`` the velocity gain is ``beta / T`` with the actual T.
* Coincident plots (``dt < coincident_dt_s``, default 1 ms, e.g. two sites looking at the same instant): eqs 5-7 at
  T -> 0 give alpha = beta = 0 and a 0/0 velocity gain (NaN before the fix). Such a plot is a sequential Kalman
  update with the tracker's covariance propagated over dt (a merge of the two plots, Joseph form, SPD) and does
  not enter the eq 16 window; a second plot coincident with the first is merged into it (the two-point start
  waits for a plot at a later time).
* Design envelope: a constant scan period. With irregular looks the steady-state gains of each look's own gap
  are an approximation (the true KF gain depends on the previous gaps); measured on the held-out suites (100
  ``random_radars`` runs, 50 ``seed002_two_radars`` runs) the adaptive tracker is 172 m / 76 m against imm2's
  112 m / 44 m (fixed-gain alpha_beta 164 m / 74 m): finite and stable, but not competitive off its envelope.
* Start-up: the first plot sets the position (velocity 0, variance ``INIT_VEL_VAR``), the second sets the
  velocity by differencing (two-point start, covariance as ``filters.two_point_init``); alpha-beta from the third.
  Before the first plot the outputs are NaN.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radar_env.filters.features import MIN_DT_S, kim_lee_variance

__all__ = ["kalata_gains", "kalata_m", "tracking_index", "steady_state_covariance", "noise_only_innovation_variance",
           "run_alpha_beta", "AlphaBetaResult"]

INIT_VEL_VAR = 1e8
"""Velocity variance (m^2/s^2) after a single plot (velocity unknown)."""


def tracking_index(q_m_s2, sigma_m, T_s):
    """Kalata tracking index (eq 5) ``lambda = q T^2 / sigma`` (dimensionless); broadcasts."""
    return np.asarray(q_m_s2, dtype=np.float64) * np.asarray(T_s, dtype=np.float64) ** 2 / np.asarray(
        sigma_m, dtype=np.float64)


def kalata_gains(tracking_index):
    """Optimal alpha-beta gains (eqs 6, 7) for tracking indices ``lambda >= 0`` (any shape) -> ``(alpha, beta)``.

    Written in a cancellation-free form: with ``s = sqrt(lambda^2 + 8 lambda)`` and
    ``m = sqrt(1 - alpha) = (lambda + 4 - s)/4 = 4/(lambda + 4 + s)``, eq 6 is ``alpha = 1 - m^2`` and eq 7 is
    ``beta = 2 (1 - m)^2`` (equal to the printed forms, checked in the tests). ``lambda = 0`` gives (0, 0);
    ``lambda -> inf`` gives (1, 2)."""
    return _gains_of_m(kalata_m(tracking_index))


def _gains_of_m(m):
    """Eqs 6, 7 in ``m = sqrt(1 - alpha)``: ``(1 - m^2, 2 (1 - m)^2)``."""
    return 1.0 - m * m, 2.0 * (1.0 - m) ** 2


def kalata_m(tracking_index):
    """``m = sqrt(1 - alpha)`` of :func:`kalata_gains`' alpha, computed without cancellation: ``(lambda + 4 - s)/4 =
    4/(lambda + 4 + s)`` (``(lambda + 4)^2 - s^2 = 16``); 1 at ``lambda = 0``, -> 0 as ``lambda -> inf``, positive
    where ``1 - alpha`` rounds to 0."""
    lam = np.asarray(tracking_index, dtype=np.float64)
    s = np.sqrt(lam * lam + 8.0 * lam)
    return 4.0 / (lam + 4.0 + s)


def steady_state_covariance(alpha, beta, sigma_m, T_s, m=None):
    """Eq 12, posterior steady-state covariance per axis, ``(...,2,2)`` ordered [position, velocity]. Where ``alpha``
    is 1 the velocity variance is infinite, unless ``m`` (:func:`kalata_m`, for Kalata's gains) is given: then it
    is eq 12 in ``m``, ``4 (1 - m)^3 / (m T^2) sigma^2``, finite where ``1 - alpha`` only rounded to 0 (a tracking
    index above about 1e16)."""
    alpha, beta, sigma, T = np.broadcast_arrays(*(np.asarray(a, dtype=np.float64) for a in (alpha, beta, sigma_m, T_s)))
    s2 = sigma * sigma
    P = np.empty(alpha.shape + (2, 2))
    P[..., 0, 0] = alpha * s2
    P[..., 0, 1] = P[..., 1, 0] = beta / T * s2
    at_one = np.inf if m is None else 4.0 * (1.0 - np.asarray(m, dtype=np.float64)) ** 3 / (np.asarray(m) * T * T)
    with np.errstate(invalid="ignore", divide="ignore"):
        P[..., 1, 1] = np.where(alpha < 1.0, beta * (2.0 * alpha - beta) / (2.0 * (1.0 - alpha) * T * T), at_one) * s2
    return P


def noise_only_innovation_variance(alpha, beta, sigma_m):
    """Steady-state innovation variance (m^2) of an alpha-beta filter on a constant-velocity target with white
    position noise ``sigma`` (Benedict-Bordner noise-only covariance, predicted one step, plus the new noise):
    ``S = sigma^2 (1 + (2 alpha^2 + 2 beta + alpha beta) / (alpha (4 - 2 alpha - beta)))``; independent of T."""
    a, b = np.asarray(alpha, dtype=np.float64), np.asarray(beta, dtype=np.float64)
    s2 = np.asarray(sigma_m, dtype=np.float64) ** 2
    with np.errstate(invalid="ignore", divide="ignore"):
        return s2 * (1.0 + (2.0 * a * a + 2.0 * b + a * b) / (a * (4.0 - 2.0 * a - b)))


class AlphaBetaResult(NamedTuple):
    """Output of :func:`run_alpha_beta`; D = number of axes (2 for x, y)."""

    x: np.ndarray  # (B,K,2D) [positions..., velocities...], posterior at detected scans, prediction otherwise
    P: np.ndarray  # (B,K,2D,2D) per-axis covariance (eq 12 at updates, propagated over misses), block diagonal
    alpha: np.ndarray  # (B,K,D) gain used at scan k (NaN where no alpha-beta update)
    beta: np.ndarray  # (B,K,D)
    q_m_s2: np.ndarray  # (B,K,D) acceleration std behind the gains (adaptive: sqrt of eq 17)
    nu_m: np.ndarray  # (B,K,D) innovation z - x_pred (NaN where none)


def _bkd(a, B, K, D, name):
    a = np.asarray(a, dtype=np.float64)
    if a.ndim == 1 and a.shape[0] == B and B != K:
        a = a[:, None, None]
    elif a.ndim == 2:
        a = a[:, :, None]
    try:
        return np.broadcast_to(a, (B, K, D))
    except ValueError as e:
        raise ValueError(f"{name}: cannot broadcast shape {np.shape(a)} to (B,K,D)=({B},{K},{D})") from e


def run_alpha_beta(t_s, z_m, detected=None, sigma_m=None, R_m2=None, q_m_s2=None, alpha=None, beta=None,
                   adaptive=False, window=12, sigma_D2_m2_s4=None, s0_mode="eq15", q_max_m_s2=None,
                   coincident_dt_s=MIN_DT_S) -> AlphaBetaResult:
    """Run independent alpha-beta filters on each axis of converted plots.

    Args:
        t_s: plot times, (K,) or (B,K), seconds, strictly increasing along K.
        z_m: converted positions (B,K,D) (D = 2: x, y); NaN allowed where not detected.
        detected: bool (B,K) or None (all detected).
        sigma_m: measurement std per axis, scalar / (B,) / (B,K) / (B,K,D). If None, ``sqrt(diag(R_m2))``.
        R_m2: (B,K,D,D) plot covariance, used only when ``sigma_m`` is None (off-diagonal terms ignored).
        q_m_s2: acceleration std for the Kalata gains (fixed-gain mode), and the default for ``sigma_D2``.
        alpha, beta: fixed gains instead of ``q_m_s2`` (velocity gain ``beta / T``; not with ``adaptive``).
        adaptive: Kim & Lee adaptive gains (eqs 13-17) with a sliding window of ``window`` innovations.
        sigma_D2_m2_s4: eq 17 fallback maneuverability variance (m^2/s^4); default ``q_m_s2**2``.
        s0_mode: what eq 15 subtracts from ``S_hat``. ``"eq15"`` (as printed): ``(F P_o F^T)_11 + sigma^2`` with
            P_o of eq 12 at the current gains. ``"noise_only"`` (our stabilised variant): the innovation variance
            the current gains produce on a non-maneuvering target, :func:`noise_only_innovation_variance`. See the
            module notes: with eq 15 as printed the high-gain state is self-sustaining.
        q_max_m_s2: adaptive only: upper bound (m/s^2) on the adapted acceleration std, the target's physical
            maneuverability (None: unbounded, as in the paper). Without it the window noise alone drives the gains
            to alpha -> 1, beta -> 2 (the stability limit) at short or irregular periods.
        coincident_dt_s: a plot less than this after the last update (e.g. two sites looking at the same time) is
            a sequential Kalman update (a merge), not an alpha-beta step (whose gains vanish as T -> 0). Seconds, >= 0.
    Returns:
        :class:`AlphaBetaResult`.
    """
    z = np.asarray(z_m, dtype=np.float64)
    if z.ndim == 2:
        z = z[..., None]
    B, K, D = z.shape
    t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), (B, K))
    det = np.ones((B, K), bool) if detected is None else np.broadcast_to(np.asarray(detected, bool), (B, K))
    det = det & np.all(np.isfinite(z), axis=-1)
    if sigma_m is None:
        if R_m2 is None:
            raise ValueError("give sigma_m or R_m2")
        R = np.asarray(R_m2, dtype=np.float64)
        sig = np.sqrt(np.where(det[..., None], np.diagonal(R, axis1=-2, axis2=-1), 1.0))
    else:
        sig = _bkd(sigma_m, B, K, D, "sigma_m")
    fixed = alpha is not None or beta is not None
    if fixed and (alpha is None or beta is None):
        raise ValueError("give both alpha and beta")
    if fixed and adaptive:
        raise ValueError("fixed alpha/beta and adaptive are exclusive")
    if not fixed and q_m_s2 is None and not (adaptive and sigma_D2_m2_s4 is not None):
        raise ValueError("give q_m_s2, alpha/beta, or (adaptive) sigma_D2_m2_s4")
    if adaptive:
        sD2 = float(q_m_s2) ** 2 if sigma_D2_m2_s4 is None else float(sigma_D2_m2_s4)
        q_nom = np.full((B, D), np.sqrt(sD2))
    elif not fixed:
        q_nom = np.broadcast_to(np.asarray(q_m_s2, dtype=np.float64), (B,)).copy()[:, None] * np.ones((B, D))
    else:
        q_nom = np.zeros((B, D))
        a_fix = np.broadcast_to(np.asarray(alpha, dtype=np.float64), (B,))[:, None] * np.ones((B, D))
        b_fix = np.broadcast_to(np.asarray(beta, dtype=np.float64), (B,))[:, None] * np.ones((B, D))
    N = int(window)
    if N < 1:
        raise ValueError(f"window must be an integer >= 1, got {window!r}")
    if s0_mode not in ("eq15", "noise_only"):
        raise ValueError(f"s0_mode must be 'eq15' or 'noise_only', got {s0_mode!r}")
    if q_max_m_s2 is not None and not (np.isfinite(q_max_m_s2) and q_max_m_s2 > 0):
        raise ValueError(f"q_max_m_s2 must be a finite number > 0 (m/s^2) or None, got {q_max_m_s2!r}")
    if not (np.isfinite(coincident_dt_s) and coincident_dt_s >= 0):
        raise ValueError(f"coincident_dt_s must be a finite number >= 0 (s), got {coincident_dt_s!r}")

    pos = np.full((B, D), np.nan)
    vel = np.full((B, D), np.nan)
    Pp = np.full((B, D, 2, 2), np.nan)  # posterior per-axis covariance at t_post
    t_post = np.full(B, np.nan)
    n_det = np.zeros(B, dtype=np.int64)
    q_cur = q_nom.copy()
    ring = np.zeros((B, N, D))  # nu_i^2 - S0_i of the last N alpha-beta updates (m^2)
    ring_T4 = np.zeros((B, N))  # their T_i^4 / 4 (s^4)
    n_ring = np.zeros(B, dtype=np.int64)

    X = np.full((B, K, 2 * D), np.nan)
    PX = np.full((B, K, 2 * D, 2 * D), np.nan)
    A_out = np.full((B, K, D), np.nan)
    Bt_out = np.full((B, K, D), np.nan)
    Q_out = np.full((B, K, D), np.nan)
    NU = np.full((B, K, D), np.nan)
    ix = np.arange(D)

    for k in range(K):
        dk = det[:, k]
        zk = np.where(dk[:, None], z[:, k], 0.0)
        sk = sig[:, k]
        dt = t[:, k] - t_post  # NaN before the first plot
        dtD = dt[:, None]
        # prediction (per axis)
        pos_pr = pos + vel * dtD
        vel_pr = vel.copy()
        F = np.zeros((B, 1, 2, 2))
        F[..., 0, 0] = F[..., 1, 1] = 1.0
        F[..., 0, 1] = dtD
        G = np.stack([np.broadcast_to(dtD * dtD / 2.0, (B, D)), np.broadcast_to(dtD, (B, D))], axis=-1)  # (B,D,2)
        Q = (q_cur ** 2)[..., None, None] * G[..., :, None] * G[..., None, :]
        FPF = F @ Pp @ np.swapaxes(F, -1, -2)
        P_pr = FPF + Q
        pos_new, vel_new, P_new = pos_pr.copy(), vel_pr.copy(), P_pr.copy()

        # first plot
        m0 = dk & (n_det == 0)
        if np.any(m0):
            pos_new[m0] = zk[m0]
            vel_new[m0] = 0.0
            P0 = np.zeros((int(m0.sum()), D, 2, 2))
            P0[..., 0, 0] = sk[m0] ** 2
            P0[..., 1, 1] = INIT_VEL_VAR
            P_new[m0] = P0
        # a plot (practically) at the time of the last update, e.g. from a second site: eqs 5-7 at T -> 0 give
        # zero gains (0/0 velocity gain), which is not the information content of a second plot of the same
        # instant. It is processed as a sequential Kalman update with the tracker's own covariance propagated over
        # dt (F P F^T + Q), a merge of the two plots; it does not enter the eq 16 window (no acceleration content).
        coin = dk & (n_det >= 1) & (dt < coincident_dt_s)
        if np.any(coin):
            Pc = P_pr[coin]  # (n,D,2,2)
            s2c = sk[coin] ** 2
            Sc = Pc[..., 0, 0] + s2c
            Kc = Pc[..., :, 0] / Sc[..., None]  # (n,D,2) gain on the position innovation
            nuc = zk[coin] - pos_pr[coin]
            pos_new[coin] = pos_pr[coin] + Kc[..., 0] * nuc
            vel_new[coin] = vel_pr[coin] + Kc[..., 1] * nuc
            IKH = np.eye(2) - Kc[..., :, None] * np.array([1.0, 0.0])  # I - K H with H = [1, 0]
            Pj = IKH @ Pc @ np.swapaxes(IKH, -1, -2) + s2c[..., None, None] * Kc[..., :, None] * Kc[..., None, :]
            P_new[coin] = 0.5 * (Pj + np.swapaxes(Pj, -1, -2))  # Joseph form: symmetric positive definite
            NU[coin, k] = nuc
        # second plot: two-point start
        m1 = dk & (n_det == 1) & ~coin
        if np.any(m1):
            d1 = dt[m1][:, None]
            s2 = sk[m1] ** 2
            s2_prev = Pp[m1][..., 0, 0]
            vel_new[m1] = (zk[m1] - pos[m1]) / d1
            pos_new[m1] = zk[m1]
            P1 = np.empty((int(m1.sum()), D, 2, 2))
            P1[..., 0, 0] = s2
            P1[..., 0, 1] = P1[..., 1, 0] = s2 / d1
            P1[..., 1, 1] = (s2 + s2_prev) / d1 ** 2
            P_new[m1] = P1
        # alpha-beta update
        m2 = dk & (n_det >= 2) & ~coin
        if np.any(m2):
            nu = zk - pos_pr
            NU[m2, k] = nu[m2]
            if fixed:
                a_k, b_k = a_fix, b_fix
                q_used = np.full((B, D), np.nan)
            else:
                if adaptive:
                    # eq 15 generalised to a window of unequal periods: E[nu_i^2] = S0_i + sigma_v^2 T_i^4/4, so
                    # the estimate is sum(nu_i^2 - S0_i) / sum(T_i^4/4) over the window (= eq 15 when every T_i is
                    # the same). Each innovation is compared with its own S0 and T: mixing a 3.5 s innovation with
                    # the T^4/4 of a 0.5 s look (two sites) reads a maneuver of thousands of g.
                    if s0_mode == "eq15":
                        S0 = FPF[..., 0, 0] + sk ** 2
                    else:
                        with np.errstate(invalid="ignore", divide="ignore"):
                            a_prev, b_prev = kalata_gains(tracking_index(q_cur, sk, dtD))
                        S0 = noise_only_innovation_variance(a_prev, b_prev, sk)
                    slot = n_ring[m2] % N
                    ring[m2, slot] = nu[m2] ** 2 - S0[m2]
                    ring_T4[m2, slot] = 0.25 * dt[m2] ** 4
                    n_ring[m2] += 1
                    full = (n_ring >= N)[:, None]
                    den = ring_T4.sum(axis=1)[:, None]
                    with np.errstate(invalid="ignore", divide="ignore"):
                        phi = np.where(den > 0.0, ring.sum(axis=1) / den, -1.0)
                    var = kim_lee_variance(phi, sD2)
                    if q_max_m_s2 is not None:
                        var = np.minimum(var, float(q_max_m_s2) ** 2)  # physical bound on the maneuverability
                    q_new = np.where(full, np.sqrt(var), q_nom)
                    q_cur = np.where(m2[:, None], q_new, q_cur)
                q_used = q_cur
                with np.errstate(invalid="ignore", divide="ignore"):
                    m_k = kalata_m(tracking_index(q_cur, sk, dtD))
                    a_k, b_k = _gains_of_m(m_k)
            with np.errstate(invalid="ignore", divide="ignore"):
                pos_ab = pos_pr + a_k * nu
                vel_ab = vel_pr + b_k / dtD * nu
                P_ab = steady_state_covariance(a_k, b_k, sk, dtD, None if fixed else m_k)
            pos_new[m2], vel_new[m2], P_new[m2] = pos_ab[m2], vel_ab[m2], P_ab[m2]
            A_out[m2, k], Bt_out[m2, k], Q_out[m2, k] = a_k[m2], b_k[m2], q_used[m2]

        # outputs: posterior where detected, prediction otherwise (NaN before the first plot)
        X[:, k, :D] = np.where(dk[:, None], pos_new, pos_pr)
        X[:, k, D:] = np.where(dk[:, None], vel_new, vel_pr)
        Pk = np.where(dk[:, None, None, None], P_new, P_pr)
        PX[:, k] = 0.0
        PX[:, k, ix, ix] = Pk[..., 0, 0]
        PX[:, k, ix, D + ix] = PX[:, k, D + ix, ix] = Pk[..., 0, 1]
        PX[:, k, D + ix, D + ix] = Pk[..., 1, 1]
        no_track = n_det == 0
        X[no_track & ~dk, k] = np.nan
        PX[no_track & ~dk, k] = np.nan
        # state advance only where detected
        pos = np.where(dk[:, None], pos_new, pos)
        vel = np.where(dk[:, None], vel_new, vel)
        Pp = np.where(dk[:, None, None, None], P_new, Pp)
        t_post = np.where(dk, t[:, k], t_post)
        n_det = n_det + (dk & ~(coin & (n_det == 1)))  # a merged second plot is still the first
    return AlphaBetaResult(X, PX, A_out, Bt_out, Q_out, NU)
