r"""Konle's speed/heading EKF on differential measurements (seed 001), batched over tracks.

State ``s = [v, phi, a, omega]``: speed (m/s), heading (rad, clockwise from north), along-track acceleration
(m/s^2), turn rate (rad/s, positive = clockwise = right turn). Measurements: the differential
``z = (dr, dalpha) = (r2 - r1, wrap(alpha2 - alpha1))`` of two consecutive plots ``(r1, alpha1, t1)``,
``(r2, alpha2, t2)`` of the SAME sensor, valid at ``t_m = (t1 + t2)/2`` (eq 15 of section 2.6). A constant
registration (azimuth or range) bias of a sensor cancels in the differences, which is the point of the method.

Conventions versus the paper
----------------------------
* The paper's azimuth alpha and heading phi are both radar azimuths (clockwise from north), i.e. ours. With the
  unit vector ``u(theta) = (sin theta, cos theta)`` (east, north) and straight motion over ``dt`` the exact
  geometry gives, with ``c = v dt``, ``A = c sin(phi - alpha1)``, ``Bc = r1 + c cos(phi - alpha1)``:
  ``dr = hypot(A, Bc) - r1`` and ``dalpha = atan2(A, Bc)``. These are identical to eq 4
  (``dr = v dt cos(phi - alpha2) - r1 (1 - cos(alpha2 - alpha1))``) and eq 5
  (``dalpha = arcsin(v dt sin(phi - alpha1) / r2)``) without approximation, and their derivatives with
  ``r1, alpha1`` held fixed are exactly eqs 6-9 (``alpha2``, ``r2`` evaluated at the prediction). So the paper's
  sign conventions agree with ours; nothing is flipped. The chord of a constant turn points along the heading at
  the chord's mid-time, which is why the measurement is valid at ``t_m``; its length is ``v dt sinc(omega dt/2)``
  (taken as ``v dt``: a 0.3 % speed bias at 3 deg/s and dt = 5 s).
* Initialization eqs 16 and 18 print ``phi = arctan(dy/dx)`` (a mathematical, counter-clockwise-from-east angle);
  in our (and the radar's) convention the chord heading is ``atan2(dx, dy)``. Section 2.7 re-uses the numbers
  15-21 of section 2.6; "init eq N" below means section 2.7's.
* Eq 10 lost its layout: ``R = diag(2 sigma_r^2, 2 sigma_alpha^2)`` (each difference carries two plot errors).
* Eq 14's ``P+ = (I - K H) P-`` is replaced by the Joseph form (same value in exact arithmetic, stays SPD).

Readings of what the paper leaves open (parameters, documented here)
--------------------------------------------------------------------
* System model eqs 1-2: ``v += a dt exp(-dt/tau1)``, ``phi += omega dt exp(-dt/tau2)``; the maneuver states are
  read as relaxing, ``a *= exp(-dt/tau1)``, ``omega *= exp(-dt/tau2)``. The paper gives no values for the
  relaxation times (they "depend on the maneuver state"); defaults ``tau = inf`` (no relaxation, unbiased on a
  constant turn). The error propagation matrix ``Phi^c`` of eq 11 is not specified; the same (linear) ``Phi``
  is used: ``P- = Phi (P+ + Q) Phi^T`` (eq 11).
* System noise (section 2.5): ``Q = diag(0, 0, Q33, Q44)`` with a base white-noise part ``q_accel^2 |dt|``,
  ``q_turn^2 |dt|``, plus the maneuver increment "derived from the current measurement triple": the
  acceleration ``a3`` and turn rate ``omega3`` of init eqs 15-20 applied to the current plot and the two before
  it from the same sensor; the increment is ``max(0, |a3| - gate sigma_a3)^2`` (and likewise for omega), with
  ``sigma_a3 = sqrt(6) sigma_p / (dt dtm)`` and ``sigma_omega3 = sqrt(6) sigma_p / (d dtm)`` the noise-only
  standard deviations of the triple estimates (``sigma_p = max(sigma_r, r sigma_alpha)``, ``d`` the chord
  length, ``dtm`` the mid-time difference): the increment is zero ("non maneuver detection") unless the triple
  shows a maneuver above the noise.
* Time order (eqs 16-19): the paper rolls the filter back and re-processes. Here each differential is processed
  when its second plot arrives, at its validity time ``t_m``: the filter is propagated (forwards or, for an
  out-of-sequence differential from a slower sensor, backwards without process noise) to ``t_m`` and updated
  there. This is a cheaper approximation of the roll-back that keeps every output causal. The output at scan
  ``k`` is the estimate propagated to ``t_k``.
* ``(v, phi)`` and ``(-v, phi + pi)`` predict the same differentials; after each update a negative speed is
  mapped to the equivalent state with ``v >= 0`` (covariance transformed alike), which removes 180-degree flips.
* Three-plot start (init eqs 15-21): the first sensor of a track that collects three consecutive plots starts
  it with ``(v2, phi2, a, omega)`` at the mid-time of the last pair and ``P = (P0^-1 + H^T R^-1 H)^-1`` (eq 21)
  with the default covariance ``P0``, widened where the triple is noisier than ``P0`` says: speed and heading
  variances at least the chord's noise variance ``2 sigma_p^2 / dt^2`` and ``2 sigma_p^2 / d^2`` (capped at
  pi^2), and ``a, omega`` the triple estimates combined with the prior ``N(0, P0)`` (shrunk towards 0 by
  ``P0 / (P0 + sigma_a3^2)``). Eq 21's default alone let a noise-dominated triple (1 deg at 250 km, dt = 0.5 s:
  a3 ~ 10^4 m/s^2) start with a 5 m/s^2 std; the speed then ran to 10^5-10^6 m/s.
* Physical envelope (not in the paper): after the start and every update, and for the output, the state is
  projected onto ``0 <= v <= max_speed_m_s`` (1000 m/s), ``|a| <= max_accel_m_s2`` (10 g),
  ``|omega| <= max_turn_rate_rad_s`` (30 deg/s) -- the estimate projection of a constrained KF (P unchanged);
  the triple-based Q increment is capped at the same bounds.
* Re-initialisation (track maintenance, not in the paper): after ``reinit_count`` (3) consecutive differentials
  whose NIS exceeds ``reinit_nis`` (13.8, the 99.9 % point of chi^2 with 2 dof) the filter restarts from the
  sensor's next triple. A turn of ~100 deg between two plots (9.4 deg/s at T = 12 s) otherwise leaves the EKF
  locked 180 deg off for the rest of the track (8 of 10 runs in ``tests/test_tracker_robustness.py``).

Design envelope
---------------
The differential measurement assumes plot noise small against the chord ``v dt`` (the paper: 0.1 deg at 70 km,
about 120 m, against a 1 km chord). Far outside it the filter is stable but poor. Measured (20 runs, seed 5000,
one site, T = 0.5 s, 1 deg bearing noise, Pd 0.5, 200-300 km, 4.4 km cross-range; chord noise / chord ~ 60):
Konle's own heading RMSE ~80 deg and speed RMSE ~230 m/s; the blended position KF (``konle`` tracker) 4,960 m
against 1,600 m for ``kf_tuned`` and 1,380 m for ``imm2`` (before the start/envelope fix: 2,600 km). There the range
differential measures the radial speed (~210 m/s noise per pair) but the sign of the cross-range component, i.e.
which of the two mirror headings about the line of sight, comes only from the bearing differential (12 km/s noise
per pair): the EKF settles on one branch with a covariance far too small (heading NEES ~50), and 75 % of that
heading goes into the position KF. On the
held-out ``random_radars`` runs (100) it is 216 m against imm2's 112 m (331 m before); on
``seed002_two_radars`` (50) 63.8 m against 44.5 m (unchanged). Its losses on ``random_radars`` come from short
periods with large bearing noise (e.g. T = 1.2 s, 0.3 deg at 100 km: 520 m cross-range against a 230 m chord).
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np

from radar_env.filters.features import wrap_angle
from radar_env.filters.kalman import inv2

__all__ = ["run_konle", "KonleResult", "konle_measurement", "konle_transition", "blend_speed_heading"]

DEFAULT_P0_DIAG = (100.0**2, 1.0**2, 5.0**2, 0.05**2)
"""Default covariance of init eq 21: speed (m/s)^2, heading rad^2, accel (m/s^2)^2, turn rate (rad/s)^2."""


MAX_SPEED_M_S = 1000.0
"""Speed bound (m/s), about Mach 3: above any aircraft of the scenarios (random flights up to 600 kt)."""
MAX_ACCEL_M_S2 = 10.0 * 9.80665
"""Along-track acceleration bound (m/s^2), 10 g (Kim & Lee's scenario flies +-5 g along the line of sight)."""
REINIT_NIS = 13.8
"""NIS gate (2 dof, 99.9 %) of the re-initialisation rule."""
MAX_TURN_RATE_RAD_S = np.radians(30.0)
"""Turn-rate bound (rad/s), 30 deg/s (random scenarios cap turns at 20 deg/s)."""


def konle_transition(dt_s, tau_accel_s=np.inf, tau_turn_s=np.inf):
    """System matrix ``Phi (B,4,4)`` of eqs 1-3 for time steps ``dt_s (B,)`` (may be negative)."""
    dt = np.atleast_1d(np.asarray(dt_s, dtype=np.float64))
    e1 = np.exp(-dt / tau_accel_s)
    e2 = np.exp(-dt / tau_turn_s)
    Phi = np.zeros(dt.shape + (4, 4))
    Phi[..., 0, 0] = Phi[..., 1, 1] = 1.0
    Phi[..., 0, 2] = dt * e1
    Phi[..., 1, 3] = dt * e2
    Phi[..., 2, 2] = e1
    Phi[..., 3, 3] = e2
    return Phi


def konle_measurement(state, r1_m, alpha1_rad, dt_s):
    """Predicted differential ``h(x) = (dr, dalpha)`` (...,2) and its Jacobian ``H`` (...,2,4) (eqs 4-9).

    Args:
        state: (...,4) ``[v, phi, a, omega]``; r1_m, alpha1_rad: the first plot of the pair; dt_s = t2 - t1.
    """
    v, phi = state[..., 0], state[..., 1]
    dt = np.asarray(dt_s, dtype=np.float64)
    r1 = np.asarray(r1_m, dtype=np.float64)
    d = phi - np.asarray(alpha1_rad, dtype=np.float64)
    sd, cd = np.sin(d), np.cos(d)
    c = v * dt
    A = c * sd
    Bc = r1 + c * cd
    r2 = np.hypot(A, Bc)
    h = np.stack([r2 - r1, np.arctan2(A, Bc)], axis=-1)
    dA = np.stack([dt * sd, c * cd], axis=-1)  # d/d(v, phi)
    dB = np.stack([dt * cd, -c * sd], axis=-1)
    H = np.zeros(state.shape[:-1] + (2, 4))
    H[..., 0, :2] = (A[..., None] * dA + Bc[..., None] * dB) / r2[..., None]  # eqs 6, 7
    H[..., 1, :2] = (Bc[..., None] * dA - A[..., None] * dB) / (r2 * r2)[..., None]  # eqs 8, 9
    return h, H


class KonleResult(NamedTuple):
    """Output of :func:`run_konle`; NaN before a track's three-plot start."""

    speed_m_s: np.ndarray  # (B,K)
    heading_rad: np.ndarray  # (B,K) clockwise from north, in (-pi, pi]
    accel_m_s2: np.ndarray  # (B,K)
    turn_rate_rad_s: np.ndarray  # (B,K) positive = clockwise
    speed_var_m2_s2: np.ndarray  # (B,K)
    heading_var_rad2: np.ndarray  # (B,K)
    x: np.ndarray  # (B,K,4) [v, phi, a, omega] at t_k
    P: np.ndarray  # (B,K,4,4)
    initialized: np.ndarray  # (B,K) bool


def _sym(P):
    return 0.5 * (P + np.swapaxes(P, -1, -2))


def _sensor_ids(site_xy_m, B, K):
    flat = np.asarray(site_xy_m, dtype=np.float64).reshape(-1, 2)
    _, inv = np.unique(flat, axis=0, return_inverse=True)
    return inv.reshape(B, K)


def run_konle(t_s, site_xy_m, range_m, bearing_rad, detected=None, range_std_m=50.0, bearing_std_rad=1e-3,
              sensor_id=None, tau_accel_s=np.inf, tau_turn_s=np.inf, q_accel_m_s3=0.05, q_turn_rad_s2=3e-3,
              maneuver_gate=3.0, P0_diag=DEFAULT_P0_DIAG, max_speed_m_s=MAX_SPEED_M_S,
              max_accel_m_s2=MAX_ACCEL_M_S2, max_turn_rate_rad_s=MAX_TURN_RATE_RAD_S, reinit_nis=REINIT_NIS,
              reinit_count=3) -> KonleResult:
    """Run Konle's speed/heading EKF over a plot stream.

    Args:
        t_s: (K,) or (B,K) plot times, non-decreasing along K.
        site_xy_m: (B,K,2) or (K,2) position of the site that made plot k.
        range_m, bearing_rad: (B,K) polar plots (NaN allowed where not detected). Bearing clockwise from north.
        detected: (B,K) bool or None.
        range_std_m, bearing_std_rad: plot noise std, scalar or (B,K) (R of eq 10 doubles the variances).
        sensor_id: (B,K) int or None (then sensors are told apart by their site position).
        tau_accel_s, tau_turn_s: relaxation times of eqs 1-2 (default no relaxation).
        q_accel_m_s3, q_turn_rad_s2: base white-noise spectral std of acceleration and turn rate (not in the
            paper; the default turn value lets the filter follow a 3 deg/s turn at T = 5 s, sigma_alpha = 0.1 deg,
            70 km, where the triple-based increment alone stays below its noise gate).
        maneuver_gate: noise-sigma gate of the triple-based maneuver increment of Q (np.inf disables it).
        P0_diag: default covariance of init eq 21 (widened at the start where the triple is noisier).
        max_speed_m_s, max_accel_m_s2, max_turn_rate_rad_s: the physical envelope the state is projected onto
            after the start and every update (not in the paper; see the module notes). Each > 0.
        reinit_nis, reinit_count: track maintenance (not in the paper): after ``reinit_count`` consecutive
            updates whose differential NIS (2 dof) exceeds ``reinit_nis`` the filter restarts from the next
            three-plot triple of the sensor (``np.inf`` disables it).
    Returns:
        :class:`KonleResult` with per-scan ``(B,K)`` speed, heading, acceleration, turn rate and variances.
    """
    for nm, v in (("max_speed_m_s", max_speed_m_s), ("max_accel_m_s2", max_accel_m_s2),
                  ("max_turn_rate_rad_s", max_turn_rate_rad_s)):
        if not (np.isfinite(v) and v > 0):
            raise ValueError(f"{nm} must be a finite number > 0, got {v!r}")
    if not reinit_nis > 0:
        raise ValueError(f"reinit_nis must be > 0 (np.inf disables the re-initialisation), got {reinit_nis!r}")
    if int(reinit_count) != reinit_count or reinit_count < 1:
        raise ValueError(f"reinit_count must be an integer >= 1, got {reinit_count!r}")
    r_all = np.asarray(range_m, dtype=np.float64)
    B, K = r_all.shape
    t = np.broadcast_to(np.asarray(t_s, dtype=np.float64), (B, K))
    site = np.broadcast_to(np.asarray(site_xy_m, dtype=np.float64), (B, K, 2))
    al_all = np.asarray(bearing_rad, dtype=np.float64)
    det = np.ones((B, K), bool) if detected is None else np.broadcast_to(np.asarray(detected, bool), (B, K))
    det = det & np.isfinite(r_all) & np.isfinite(al_all)
    sr = np.broadcast_to(np.asarray(range_std_m, dtype=np.float64), (B, K))
    sa = np.broadcast_to(np.asarray(bearing_std_rad, dtype=np.float64), (B, K))
    sid = _sensor_ids(site, B, K) if sensor_id is None else np.broadcast_to(np.asarray(sensor_id), (B, K))
    S = int(sid.max()) + 1

    def _project(xs):
        """Estimate projection onto the physical envelope (speed in [0, max], |a|, |omega| <= max), heading
        wrapped: the active inequality constraints of a constrained KF (state only; P is left as computed)."""
        xs = xs.copy()
        xs[..., 0] = np.clip(xs[..., 0], 0.0, max_speed_m_s)
        xs[..., 1] = wrap_angle(xs[..., 1])
        xs[..., 2] = np.clip(xs[..., 2], -max_accel_m_s2, max_accel_m_s2)
        xs[..., 3] = np.clip(xs[..., 3], -max_turn_rate_rad_s, max_turn_rate_rad_s)
        return xs

    bi = np.arange(B)

    # per (track, sensor) memory of the last two plots: [t, r, alpha, x, y]
    mem1 = np.full((B, S, 5), np.nan)
    mem2 = np.full((B, S, 5), np.nan)
    x = np.zeros((B, 4))
    P = np.tile(np.diag(np.asarray(P0_diag, dtype=np.float64)), (B, 1, 1))
    t_f = np.zeros(B)
    init = np.zeros(B, dtype=bool)
    n_bad = np.zeros(B, dtype=np.int64)  # consecutive updates with NIS > reinit_nis

    X = np.full((B, K, 4), np.nan)
    PX = np.full((B, K, 4, 4), np.nan)
    INIT = np.zeros((B, K), bool)

    def _q(dt, extra_a2, extra_w2):
        Q = np.zeros(dt.shape + (4, 4))
        adt = np.abs(dt)
        Q[..., 2, 2] = q_accel_m_s3**2 * adt + extra_a2
        Q[..., 3, 3] = q_turn_rad_s2**2 * adt + extra_w2
        return Q

    for k in range(K):
        dk = det[:, k]
        s_k = sid[:, k]
        r2 = np.where(dk, r_all[:, k], 1.0)
        a2 = np.where(dk, al_all[:, k], 0.0)
        t2 = t[:, k]
        p2 = site[:, k] + r2[:, None] * np.stack([np.sin(a2), np.cos(a2)], axis=-1)
        m1 = mem1[bi, s_k]
        m0 = mem2[bi, s_k]
        has_pair = dk & np.isfinite(m1[:, 0])
        has_triple = has_pair & np.isfinite(m0[:, 0])
        t1, r1, al1 = m1[:, 0], m1[:, 1], m1[:, 2]
        dt12 = np.where(has_pair, t2 - t1, 1.0)
        t_m = np.where(has_pair, 0.5 * (t1 + t2), t_f)

        # triple estimates (init eqs 15-20)
        with np.errstate(invalid="ignore", divide="ignore"):
            d01 = m1[:, 3:5] - m0[:, 3:5]
            d12 = p2 - m1[:, 3:5]
            L1, L2 = np.hypot(d01[:, 0], d01[:, 1]), np.hypot(d12[:, 0], d12[:, 1])
            dt01 = t1 - m0[:, 0]
            v1, v2 = L1 / dt01, L2 / dt12
            h1, h2 = np.arctan2(d01[:, 0], d01[:, 1]), np.arctan2(d12[:, 0], d12[:, 1])
            dtm = 0.5 * (t2 - m0[:, 0])
            a3 = (v2 - v1) / dtm
            w3 = wrap_angle(h2 - h1) / dtm
            sig_p = np.maximum(sr[:, k], r2 * sa[:, k])
            sig_a3 = np.sqrt(6.0) * sig_p / (0.5 * (dt01 + dt12) * dtm)
            sig_w3 = np.sqrt(6.0) * sig_p / (np.maximum(0.5 * (L1 + L2), 1e-9) * dtm)
            ex_a2 = np.where(has_triple, np.maximum(0.0, np.abs(a3) - maneuver_gate * sig_a3), 0.0) ** 2
            ex_w2 = np.where(has_triple, np.maximum(0.0, np.abs(w3) - maneuver_gate * sig_w3), 0.0) ** 2
        # the increment is at most the physical bound (a noise-dominated triple can read 10^4 m/s^2)
        ex_a2 = np.minimum(np.nan_to_num(ex_a2, posinf=np.inf), max_accel_m_s2**2)
        ex_w2 = np.minimum(np.nan_to_num(ex_w2, posinf=np.inf), max_turn_rate_rad_s**2)

        z = np.stack([r2 - np.where(has_pair, r1, 0.0), wrap_angle(a2 - np.where(has_pair, al1, 0.0))], axis=-1)
        R = np.zeros((B, 2, 2))
        R[:, 0, 0] = 2.0 * sr[:, k] ** 2  # eq 10
        R[:, 1, 1] = 2.0 * sa[:, k] ** 2
        r1s = np.where(has_pair, r1, 1.0)
        al1s = np.where(has_pair, al1, 0.0)

        # --- three-plot start
        start = has_triple & (~init | (n_bad >= reinit_count))
        if np.any(start):
            # Eq 21's default P0 claims the speed to 100 m/s and a, omega to 5 m/s^2, 0.05 rad/s. The triple's own
            # noise can be orders of magnitude larger (1 deg at 250 km is 4.4 km cross-range: at dt = 0.5 s the
            # chord speed is off by ~12 km/s and a3 by ~10^4 m/s^2); a start that far outside its covariance never
            # recovers. So: speed and heading get P0 widened to the chord's noise variance; a and omega are the
            # triple estimate combined with the prior N(0, P0) (a noise-dominated triple starts near 0, the paper's
            # "non maneuver detection"); then eq 21 and the physical bounds.
            with np.errstate(invalid="ignore", divide="ignore"):
                var_v = 2.0 * sig_p**2 / dt12**2
                var_h = np.minimum(2.0 * sig_p**2 / np.maximum(L2, 1e-9) ** 2, np.pi**2)
                var_a, var_w = sig_a3**2, sig_w3**2
            p0 = np.asarray(P0_diag, dtype=np.float64)
            ka, kw = p0[2] / (p0[2] + var_a), p0[3] / (p0[3] + var_w)
            xs = np.stack([v2, h2, ka * a3, kw * w3], axis=-1)[start]
            P0s = np.zeros((int(start.sum()), 4, 4))
            P0s[:, 0, 0] = np.maximum(p0[0], var_v[start])
            P0s[:, 1, 1] = np.maximum(p0[1], var_h[start])
            P0s[:, 2, 2] = (ka * var_a)[start]
            P0s[:, 3, 3] = (kw * var_w)[start]
            _, Hs = konle_measurement(xs, r1s[start], al1s[start], dt12[start])
            Rinv = np.linalg.inv(R[start])
            info = np.linalg.inv(P0s) + np.swapaxes(Hs, -1, -2) @ Rinv @ Hs  # eq 21
            x[start] = _project(xs)
            P[start] = _sym(np.linalg.inv(info))
            t_f[start] = t_m[start]
            init = init | start
            n_bad[start] = 0

        # --- EKF update at t_m with the differential
        upd = has_pair & init & ~start
        if np.any(upd):
            dtp = np.where(upd, t_m - t_f, 0.0)
            Phi = konle_transition(dtp, tau_accel_s, tau_turn_s)
            fwd = (dtp > 0)[:, None, None]
            Q = np.where(fwd, _q(dtp, ex_a2, ex_w2), 0.0)
            x_pr = np.einsum("bij,bj->bi", Phi, x)
            P_pr = Phi @ (P + Q) @ np.swapaxes(Phi, -1, -2)  # eq 11
            h, H = konle_measurement(x_pr, r1s, al1s, dt12)
            nu = z - h
            nu[:, 1] = wrap_angle(nu[:, 1])
            Sm = H @ P_pr @ np.swapaxes(H, -1, -2) + R
            S_inv, _ = inv2(Sm)
            nis = np.einsum("bi,bij,bj->b", nu, S_inv, nu)
            n_bad = np.where(upd, np.where(nis > reinit_nis, n_bad + 1, 0), n_bad)
            Kg = P_pr @ np.swapaxes(H, -1, -2) @ S_inv  # eq 12
            x_up = x_pr + np.einsum("bij,bj->bi", Kg, nu)  # eq 13
            IKH = np.eye(4) - Kg @ H
            P_up = IKH @ P_pr @ np.swapaxes(IKH, -1, -2) + Kg @ R @ np.swapaxes(Kg, -1, -2)  # eq 14 (Joseph)
            P_up = 0.5 * (P_up + np.swapaxes(P_up, -1, -2))
            # (v, phi) and (-v, phi + pi) predict the same differentials: keep v >= 0 (a, P transformed alike)
            neg = x_up[:, 0] < 0.0
            if np.any(neg):
                J = np.diag([-1.0, 1.0, -1.0, 1.0])
                x_up[neg, 0] *= -1.0
                x_up[neg, 2] *= -1.0
                x_up[neg, 1] += np.pi
                P_up[neg] = J @ P_up[neg] @ J
            x_up = _project(x_up)
            x = np.where(upd[:, None], x_up, x)
            P = np.where(upd[:, None, None], P_up, P)
            t_f = np.where(upd, t_m, t_f)

        # --- memory of this sensor's plots
        new = np.stack([t2, r2, a2, p2[:, 0], p2[:, 1]], axis=-1)
        bd = bi[dk]
        mem2[bd, s_k[dk]] = mem1[bd, s_k[dk]]
        mem1[bd, s_k[dk]] = new[dk]

        # --- output at t_k
        dto = t2 - t_f
        Phi_o = konle_transition(dto, tau_accel_s, tau_turn_s)
        Q_o = np.where((dto > 0)[:, None, None], _q(dto, 0.0, 0.0), 0.0)
        xo = _project(np.einsum("bij,bj->bi", Phi_o, x))
        Po = Phi_o @ (P + Q_o) @ np.swapaxes(Phi_o, -1, -2)
        X[init, k] = xo[init]
        PX[init, k] = Po[init]
        INIT[:, k] = init

    return KonleResult(X[..., 0], X[..., 1], X[..., 2], X[..., 3], PX[..., 0, 0], PX[..., 1, 1], X, PX, INIT)


def blend_speed_heading(x_kf, speed_m_s, heading_rad, weight=0.75):
    """Replace ``weight`` (Konle: 75 %) of a position KF's speed and heading by Konle's estimates.

    Args:
        x_kf: (...,4) ``[x, y, vx, vy]``; speed_m_s, heading_rad: (...) Konle's estimates (NaN = not started,
            then the KF state is returned unchanged).
    Returns:
        (...,4) with positions unchanged and ``vx = s sin h``, ``vy = s cos h`` for the blended
        ``s = (1-w) s_kf + w s_konle`` and ``h = h_kf + w wrap(h_konle - h_kf)`` (blended along the short arc).
    """
    x_kf = np.asarray(x_kf, dtype=np.float64)
    s_kf = np.hypot(x_kf[..., 2], x_kf[..., 3])
    h_kf = np.arctan2(x_kf[..., 2], x_kf[..., 3])
    sp = np.asarray(speed_m_s, dtype=np.float64)
    hd = np.asarray(heading_rad, dtype=np.float64)
    ok = np.isfinite(sp) & np.isfinite(hd)
    w = float(weight)
    s = (1.0 - w) * s_kf + w * np.where(ok, sp, s_kf)
    h = h_kf + w * wrap_angle(np.where(ok, hd, h_kf) - h_kf)
    out = x_kf.copy()
    out[..., 2] = np.where(ok, s * np.sin(h), x_kf[..., 2])
    out[..., 3] = np.where(ok, s * np.cos(h), x_kf[..., 3])
    return out
