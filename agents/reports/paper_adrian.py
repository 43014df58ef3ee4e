r"""Adrian (seed 003) computed exactly as his Mathcad sheet does, with our filter and radar functions.

His definitions (seed 003, "Radar Simulator" and "Turnrate Estimation Algorithm 1/2"), all reproduced here:

* Truth: ``x_i = F(w) x_{i-1} + v_i`` over ``N = n m = 130 x 48 = 6240`` looks of ``t = 5`` s (48 leaves, each
  ``n1 = 54`` looks straight, 12 looks of a 180 deg left turn at 3 deg/s, 54 straight, 10 looks of a 150 deg right
  turn), with a position random walk ``v_i = (nvx_i, 0, nvx_i, 0)``: the *same* draw ``nvx_i ~ N(0, sqrt(sigma_v))``
  added to both positions, ``sigma_v = sigma_va t^2 / 2 = 12.263`` (so sd 3.50 m per look), speed untouched.
  The sensor sits at the mean truth position; polar noise ``sigma_rho = 0.04`` NM, ``sigma_theta = 0.07`` deg.
* Reference turn rate ``wx_i = csub(hx_i, hx_{i-1}) / t``: the backward difference of truth headings over
  ``(t_{i-1}, t_i]``.
* Algorithm 1: ``h4_i`` = heading of ``z_i - z_{i-4}``, ``wr4_i = csub(h4_i, h4_{i-1}) / t``; algorithm 2: the KF
  predicts with ``F(w_{i-1})`` and ``w_i = csub(h(y_i), h(y_{i-4})) / (4 t)``. Errors are **absolute**,
  ``|w - wx|``, over ``i = 5..N``; his figures are ``stdev`` (population) and ``max`` of them.
* Both KFs start from the first two plots (``y_1 = (z_1, (z_1 - z_0)/t)``), ``P = diag(r, 2r/t^2, r, 2r/t^2)``
  with ``r = max(R_00, R_11)`` of plot 1, ``Q = sigma_a^2 Gamma Gamma^T``, no warm-up.
* Position "noise": ``Stdev`` (sample standard deviation) of the Euclidean distance to the truth over
  ``i = 4..N``; reductions ``1 - sigma_yx / sigma_zx`` and ``1 - max_yx / max_zx``.

Mathcad pads the undefined first elements of ``ewr4`` / ``dix`` with zeros and ``stdev`` would include them
(5 of 6241 entries); we take only the defined range (the effect is below the last printed digit).

Each run is one realisation of his worksheet (his ``rnorm`` streams: ``nvx``, then range, then bearing noise, from
one generator seeded per run). Conventions inside: his headings are mathematical angles (counter-clockwise from
east), his ``F(w)`` is ours (:func:`radar_env.filters.kalman.transition_ct`, clockwise) at ``-w``; state order ours.
"""

from __future__ import annotations

import numpy as np

from radar_env.filters.kalman import predict, process_noise, transition_ct, update
from radar_env.sim.radar import cartesian_from_polar, converted_covariance, polar_from_cartesian
from radar_env.common.units import DEG, NM_M

__all__ = ["ADRIAN_G_M_S2", "adrian_geometry", "adrian_truth", "adrian_plots", "adrian_kf",
           "adrian_reference_turn_rate", "adrian_alg1", "adrian_quantities", "adrian_worksheet"]

ADRIAN_G_M_S2 = 9.81
"""Adrian's gravity (his ``sigma_va = 0.1 * 9.81``, which gives his printed ``sigma_v = 12.263``)."""
T_S = 5.0
SIGMA_RHO_M = 0.04 * NM_M
SIGMA_THETA_RAD = 0.07 * DEG
OMEGA_RAD_S = 3.0 * DEG
V0_M_S = 200 * NM_M / 3600.0
H0_RAD = 45.0 * DEG          # his start "heading" 45 deg: the velocity (v0 sin h0, v0 cos h0)
LEAVES = 48                  # m = 4 * 12


def adrian_geometry():
    """His look counts ``(n1, n2, n3, n)``: straight until ``n1``, left turn until ``n2``, straight until ``n3``,
    right turn until ``n`` (130 looks per leaf)."""
    n1 = int(round(15 * NM_M / (V0_M_S * T_S)))
    turn = np.pi / (OMEGA_RAD_S * T_S)
    n2 = n1 + turn
    n3 = n2 + n1
    n = int(round(n3 + 5 / 6 * turn))
    return n1, n2, n3, n


def _ccw(w):
    """Adrian's counter-clockwise F(w) as our (clockwise-positive) transition matrix."""
    return transition_ct(T_S, -np.asarray(w, dtype=np.float64))


def adrian_truth(rng, runs, leaves=LEAVES, sigma_va_m_s2=0.1 * ADRIAN_G_M_S2, random_walk=True):
    """Truth ``(runs, N+1, 4)`` ``[x, y, vx, vy]`` of his recursion, and the rate used on each step ``(N+1,)``
    (rad/s, counter-clockwise positive; entry i is the rate of step i-1 -> i)."""
    n1, n2, n3, n = adrian_geometry()
    N = n * leaves
    i = np.arange(N + 1)
    ph = np.mod(i, n)
    w = np.where(ph < n1, 0.0, np.where(ph < n2, OMEGA_RAD_S, np.where(ph < n3, 0.0, -OMEGA_RAD_S)))
    sd = np.sqrt(0.5 * sigma_va_m_s2 * T_S ** 2) if random_walk else 0.0   # rnorm(.., 0, sqrt(sigma_v))
    nvx = sd * rng.standard_normal((runs, N + 1))
    F = {v: _ccw(v)[0] for v in (0.0, OMEGA_RAD_S, -OMEGA_RAD_S)}
    x = np.empty((runs, N + 1, 4))
    x[:, 0] = [0.0, 0.0, V0_M_S * np.sin(H0_RAD), V0_M_S * np.cos(H0_RAD)]
    x[:, 0, :2] += nvx[:, 0, None]
    for k in range(1, N + 1):
        x[:, k] = x[:, k - 1] @ F[float(w[k])].T
        x[:, k, :2] += nvx[:, k, None]
    return x, w


def adrian_plots(rng, truth):
    """Polar noise added at the sensor in the flower's centre: ``z (runs, N+1, 2)``, ``R (runs, N+1, 2, 2)`` at
    the measured range and bearing (his ``R(a_0, a_1)``)."""
    runs, K, _ = truth.shape
    site = truth[..., :2].mean(axis=1)                      # s_x, s_y: mean truth position, per run
    rho, theta, _ = polar_from_cartesian(truth, site[:, None, :])
    rho_m = rho + SIGMA_RHO_M * rng.standard_normal((runs, K))
    theta_m = theta + SIGMA_THETA_RAD * rng.standard_normal((runs, K))
    z = cartesian_from_polar(rho_m, theta_m, site[:, None, :])
    return z, converted_covariance(rho_m, theta_m, SIGMA_RHO_M, SIGMA_THETA_RAD)


def _heading(vx, vy):
    return np.arctan2(vy, vx)                               # his atan2(vx, vy) in Mathcad's argument order


def _csub(a, b):
    """His ``csub``: angle difference wrapped to (-pi, pi]."""
    d = a - b
    return d + (d <= -np.pi) * 2 * np.pi - (d > np.pi) * 2 * np.pi


def adrian_kf(z, R, sigma_a_m_s2, n=4, turn_rate=True):
    """His ``KF(n)`` (``turn_rate=True``, algorithm 2) or ``kf(0)`` (linear). ``sigma_a_m_s2`` scalar or (rows,)
    for ``z (rows, N+1, 2)``. Returns the updated states ``y (rows, N+1, 4)`` (NaN at i = 0) and ``w``."""
    rows, K, _ = z.shape
    y = np.full((rows, K, 4), np.nan)
    w = np.zeros((rows, K))
    y[:, 1] = np.concatenate([z[:, 1], (z[:, 1] - z[:, 0]) / T_S], axis=-1)
    r = np.maximum(R[:, 1, 0, 0], R[:, 1, 1, 1])
    P = np.zeros((rows, 4, 4))
    P[:, 0, 0] = P[:, 1, 1] = r
    P[:, 2, 2] = P[:, 3, 3] = 2 * r / T_S ** 2
    Q = process_noise(np.full(rows, T_S), sigma_a_m_s2)
    x = y[:, 1]
    for i in range(2, K):
        F = _ccw(w[:, i - 1]) if turn_rate else _ccw(np.zeros(rows))
        x, P = predict(x, P, F, Q)
        x, P = update(x, P, z[:, i], R[:, i])[:2]
        y[:, i] = x
        if turn_rate and i > n:
            w[:, i] = _csub(_heading(x[:, 2], x[:, 3]), _heading(y[:, i - n, 2], y[:, i - n, 3])) / (n * T_S)
    return y, w


def _dist(a, truth):
    return np.hypot(a[..., 0] - truth[..., 0], a[..., 1] - truth[..., 1])


def adrian_reference_turn_rate(truth):
    """His ``wx_i = csub(hx_i, hx_{i-1}) / t`` (rad/s, counter-clockwise positive), NaN at i = 0: the backward
    difference of the truth's headings over ``(t_{i-1}, t_i]``."""
    hx = _heading(truth[..., 2], truth[..., 3])
    wx = np.full(hx.shape, np.nan)
    wx[..., 1:] = _csub(hx[..., 1:], hx[..., :-1]) / T_S
    return wx


def adrian_alg1(z, n=4):
    """His algorithm 1 ``wr4_i = csub(h4_i, h4_{i-1}) / t`` with ``h4_i`` the heading of ``z_i - z_{i-n}``
    (rad/s, counter-clockwise positive), NaN for i <= n."""
    h = np.full(z.shape[:-1], np.nan)
    h[..., n:] = _heading(z[..., n:, 0] - z[..., :-n, 0], z[..., n:, 1] - z[..., :-n, 1])
    w = np.full(h.shape, np.nan)
    w[..., n + 1:] = _csub(h[..., n + 1:], h[..., n:-1]) / T_S
    return w


def adrian_quantities(truth, z, y_alg2, w_alg2, y_lin):
    """His figures per run (arrays over runs): turn-rate error stdev / max of algorithms 1 and 2 (deg/s, absolute
    errors, i = 5..N), plot and KF position Stdev / max (m, i = 4..N), reductions; plus, labelled ``rms_*`` /
    ``signed_*``, the same data under our definitions (signed-error std, RMS distance, 1 - RMS ratio)."""
    wx = adrian_reference_turn_rate(truth)
    wr4 = adrian_alg1(z)
    s5, s4 = np.s_[:, 5:], np.s_[:, 4:]
    e1 = np.degrees(wr4 - wx)[s5]
    e2 = np.degrees(w_alg2 - wx)[s5]
    dz, d2, dl = _dist(z, truth)[s4], _dist(y_alg2, truth)[s4], _dist(y_lin, truth)[s4]
    sz, s2, sl = (np.std(d, axis=1, ddof=1) for d in (dz, d2, dl))
    mz, m2, ml = (np.max(d, axis=1) for d in (dz, d2, dl))
    rz, r2, rl = (np.sqrt(np.mean(d ** 2, axis=1)) for d in (dz, d2, dl))
    return {
        "alg1_std_deg_s": np.std(np.abs(e1), axis=1), "alg1_max_deg_s": np.max(np.abs(e1), axis=1),
        "alg2_std_deg_s": np.std(np.abs(e2), axis=1), "alg2_max_deg_s": np.max(np.abs(e2), axis=1),
        "plot_std_nm": sz / NM_M, "plot_max_nm": mz / NM_M,
        "alg2_pos_std_nm": s2 / NM_M, "alg2_pos_max_nm": m2 / NM_M,
        "linear_pos_std_nm": sl / NM_M, "linear_pos_max_nm": ml / NM_M,
        "reduction_alg2": 1 - s2 / sz, "reduction_linear": 1 - sl / sz,
        "max_reduction_alg2": 1 - m2 / mz, "max_reduction_linear": 1 - ml / mz,
        "signed_alg1_std_deg_s": np.std(e1, axis=1), "signed_alg2_std_deg_s": np.std(e2, axis=1),
        "rms_plot_m": rz, "rms_alg2_m": r2, "rms_linear_m": rl,
        "rms_reduction_alg2": 1 - r2 / rz, "rms_reduction_linear": 1 - rl / rz,
    }


def adrian_worksheet(runs=10, seed=0, sigma_a_g=(0.10, 0.15, 0.20, 0.25), truth_sigma_va_g=0.1):
    """Run his sheet ``runs`` times (one generator, ``default_rng(seed)``) for each KF process noise in
    ``sigma_a_g`` (his g = 9.81; the truth's random walk stays at ``truth_sigma_va_g``). Returns
    ``{sigma_a_g: quantities}`` with every quantity an array over runs (see :func:`adrian_quantities`)."""
    if int(runs) < 1:
        raise ValueError(f"runs must be >= 1, got {runs!r}")
    rng = np.random.default_rng(seed)
    truth, _ = adrian_truth(rng, int(runs), sigma_va_m_s2=truth_sigma_va_g * ADRIAN_G_M_S2)
    z, R = adrian_plots(rng, truth)
    S = len(sigma_a_g)
    rep = lambda a: np.repeat(a, S, axis=0)  # noqa: E731  rows: run-major, sigma_a minor
    qa = np.tile(np.asarray(sigma_a_g, dtype=np.float64) * ADRIAN_G_M_S2, int(runs))
    y2, w2 = adrian_kf(rep(z), rep(R), qa, turn_rate=True)
    yl, _ = adrian_kf(rep(z), rep(R), qa, turn_rate=False)
    out = {}
    for j, g in enumerate(sigma_a_g):
        sl = np.s_[j::S]
        out[float(g)] = adrian_quantities(truth, z, y2[sl], w2[sl], yl[sl])
    return out


if __name__ == "__main__":
    raise SystemExit("error: agents.reports.paper_adrian is a library module of the paper checks; run: python -m "
                     "agents.reports.paper_checks")
