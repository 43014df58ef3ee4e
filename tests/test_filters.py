"""Filter math against closed forms, against FilterPy (an independent implementation), and for consistency."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st
from scipy import stats
from scipy.integrate import solve_ivp

from radar_env import filters as kf
from radar_env.units import G0_M_S2

H = np.hstack([np.eye(2), np.zeros((2, 2))])


def _random_spd(rng, n, scale):
    A = rng.standard_normal((n, n))
    return scale * (A @ A.T + n * np.eye(n))


def _measurement_stream(rng, steps, detect_prob=0.85):
    dts = rng.uniform(1.0, 12.0, steps)
    zs = np.cumsum(rng.normal(200.0, 300.0, (steps, 2)), axis=0) + 5e4
    Rs = np.stack([_random_spd(rng, 2, 200.0) for _ in range(steps)])
    det = rng.random(steps) < detect_prob
    qs = rng.uniform(0.0, 30.0, steps)
    return dts, zs, Rs, det, qs


# ------------------------------------------------------------------------------------------------ closed forms
def test_ct_transition_matches_ode_integration():
    for w, dt in [(0.05, 17.0), (-0.2, 5.0), (1e-7, 10.0), (0.0, 3.0)]:
        x0 = np.array([1000.0, -2000.0, 120.0, -40.0])
        sol = solve_ivp(lambda t, s: [s[2], s[3], w * s[3], -w * s[2]], [0, dt], x0, rtol=1e-12, atol=1e-10)
        np.testing.assert_allclose(kf.transition_ct(dt, w)[0] @ x0, sol.y[:, -1], rtol=1e-9, atol=1e-6)


def test_ct_turn_is_clockwise_for_positive_rate():
    # Heading north, right turn (positive rate) for a quarter circle ends heading east, displaced north-east.
    v, w = 100.0, 0.1
    x = kf.transition_ct(np.pi / 2 / w, w)[0] @ np.array([0.0, 0.0, 0.0, v])
    np.testing.assert_allclose(x, [v / w, v / w, v, 0.0], atol=1e-9)


def test_ct_reduces_to_cv_and_composes():
    np.testing.assert_array_equal(kf.transition_ct(4.0, 0.0), kf.transition_cv(4.0))
    F = kf.transition_ct(np.array([3.0, 4.0]), 0.07)
    np.testing.assert_allclose(F[1] @ F[0], kf.transition_ct(7.0, 0.07)[0], atol=1e-12)


def test_process_noise_closed_form():
    dt, q = 5.0, 0.3 * G0_M_S2
    G = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
    np.testing.assert_allclose(kf.process_noise(dt, q)[0], q**2 * G @ G.T, rtol=1e-15)


def test_two_point_init_covariance_is_exact():
    rng = np.random.default_rng(0)
    R1, R2 = _random_spd(rng, 2, 100.0), _random_spd(rng, 2, 50.0)
    dt, truth = 5.0, np.array([1e4, 2e4, 150.0, -60.0])
    n = 100_000
    z1 = truth[:2] - dt * truth[2:] + rng.multivariate_normal(np.zeros(2), R1, n)
    z2 = truth[:2] + rng.multivariate_normal(np.zeros(2), R2, n)
    x, P = kf.two_point_init(z1, np.broadcast_to(R1, (n, 2, 2)), 0.0, z2, np.broadcast_to(R2, (n, 2, 2)), dt)
    err = x - truth
    np.testing.assert_allclose(np.cov(err.T), P[0], rtol=0.03, atol=0.02 * np.abs(P[0]).max())


# ----------------------------------------------------------------------------------------------- vs FilterPy
def test_kf_matches_filterpy_and_batched_equals_loop():
    from filterpy.kalman import KalmanFilter

    rng = np.random.default_rng(1)
    B, steps = 5, 60
    streams = [_measurement_stream(rng, steps) for _ in range(B)]
    x = np.array([[5e4, 5e4, 100.0, -50.0]] * B)
    P = np.stack([_random_spd(rng, 4, 1e3) for _ in range(B)])
    ref = []
    for b in range(B):
        f = KalmanFilter(dim_x=4, dim_z=2)
        f.x, f.P, f.H = x[b].copy(), P[b].copy(), H.copy()
        ref.append(f)
    for k in range(steps):
        dt = np.array([s[0][k] for s in streams])
        z = np.array([s[1][k] for s in streams])
        R = np.array([s[2][k] for s in streams])
        det = np.array([s[3][k] for s in streams])
        q = np.array([s[4][k] for s in streams])
        w = np.where(np.arange(B) % 2 == 0, 0.0, 0.03)  # CT and CV modes share predict
        F, Q = kf.transition_ct(dt, w), kf.process_noise(dt, q)
        xp, Pp = kf.predict(x, P, F, Q)
        res = kf.update(xp, Pp, np.where(det[:, None], z, np.nan), R, det)
        for b in range(B):  # the loop over single tracks (batch of one) must give the same numbers
            xb, Pb = kf.predict(x[b : b + 1], P[b : b + 1], F[b : b + 1], Q[b : b + 1])
            rb = kf.update(xb, Pb, z[b : b + 1], R[b : b + 1], det[b : b + 1])
            np.testing.assert_allclose(rb.x[0], res.x[b], rtol=1e-13)
            np.testing.assert_allclose(rb.P[0], res.P[b], rtol=1e-13)
            f = ref[b]
            f.predict(F=F[b], Q=Q[b])
            if det[b]:
                f.update(z[b], R=R[b])
                np.testing.assert_allclose(res.loglik[b], f.log_likelihood, rtol=1e-9)
                np.testing.assert_allclose(res.nu[b], f.y, rtol=1e-8, atol=1e-8 * np.abs(f.y).max())
            np.testing.assert_allclose(res.x[b], f.x, rtol=1e-8)
            np.testing.assert_allclose(res.P[b], f.P, rtol=1e-8, atol=1e-10 * np.abs(f.P).max())
        x, P = res.x, res.P


def test_imm_matches_filterpy_imm_estimator():
    from filterpy.kalman import IMMEstimator, KalmanFilter

    rng = np.random.default_rng(2)
    T, steps = 5.0, 80
    qs = [0.03 * G0_M_S2, 2.0 * G0_M_S2]
    Pi = np.array([[0.95, 0.05], [0.1, 0.9]])
    mu0 = np.array([0.9, 0.1])
    truth = np.array([3e4, 4e4, 150.0, 0.0])
    F = kf.transition_cv(T)[0]
    x0 = truth + rng.normal(0, [50, 50, 5, 5])
    P0 = np.diag([2500.0, 2500.0, 100.0, 100.0])
    fps = []
    for q in qs:
        f = KalmanFilter(dim_x=4, dim_z=2)
        f.x, f.P, f.H, f.F, f.Q = x0.copy(), P0.copy(), H.copy(), F.copy(), kf.process_noise(T, q)[0]
        fps.append(f)
    imm = IMMEstimator(fps, mu0.copy(), Pi)
    log_mu = np.log(mu0)[None]
    xm, Pm = np.stack([x0, x0])[None], np.stack([P0, P0])[None]
    Fm, Qm = np.stack([F, F])[None], np.stack([kf.process_noise(T, q)[0] for q in qs])[None]
    for k in range(steps):
        w = 0.08 if 30 <= k < 45 else 0.0  # a hard turn so that the mode probabilities move
        truth = kf.transition_ct(T, w)[0] @ truth
        R = np.diag([80.0**2, 150.0**2])
        z = truth[:2] + rng.multivariate_normal(np.zeros(2), R)
        for f in fps:
            f.R = R
        imm.predict()
        imm.update(z)
        r = kf.imm_step(log_mu, xm, Pm, np.log(Pi), Fm, Qm, z[None], R[None])
        log_mu, xm, Pm = r.log_mu, r.x_modes, r.P_modes
        np.testing.assert_allclose(np.exp(log_mu[0]), imm.mu, rtol=1e-8, atol=1e-12)
        np.testing.assert_allclose(r.x[0], imm.x, rtol=1e-8)
        np.testing.assert_allclose(r.P[0], imm.P, rtol=1e-8, atol=1e-10 * np.abs(imm.P).max())



def test_imm_log_space_survives_vanishing_likelihood():
    """A 40-sigma innovation underflows a linear-space likelihood product; the log-space IMM stays finite."""
    log_mu = np.log([[0.5, 0.5]])
    x = np.zeros((1, 2, 4))
    P = np.broadcast_to(np.eye(4), (1, 2, 4, 4)).copy()
    F = np.broadcast_to(kf.transition_cv(1.0)[0], (1, 2, 4, 4))
    Q = np.stack([kf.process_noise(1.0, 0.0)[0], kf.process_noise(1.0, 1e3)[0]])[None]
    r = kf.imm_step(log_mu, x, P, np.log([[0.9, 0.1], [0.1, 0.9]]), F, Q, np.array([[60.0, 0.0]]), np.eye(2)[None])
    assert np.all(np.isfinite(r.log_mu)) and np.exp(r.log_mu[0, 1]) > 0.999
    assert np.all(np.isfinite(r.x)) and np.all(np.isfinite(r.P))


# ------------------------------------------------------------------------------------------------ consistency
def test_nees_and_nis_inside_chi_square_bounds():
    """CV truth driven by white acceleration of known q, filtered with that q: ANEES/ANIS in their 95% bounds."""
    rng = np.random.default_rng(3)
    N, K, T, q = 300, 60, 5.0, 1.5
    R = np.array([[900.0, 300.0], [300.0, 2500.0]])
    F = kf.transition_cv(T)[0]
    Gam = np.array([[T**2 / 2, 0], [0, T**2 / 2], [T, 0], [0, T]])
    P = np.broadcast_to(np.diag([1e4, 1e4, 400.0, 400.0]), (N, 4, 4)).copy()
    truth = np.array([2e4, 1e4, 100.0, 50.0]) + rng.multivariate_normal(np.zeros(4), P[0], N)
    x = np.broadcast_to(np.array([2e4, 1e4, 100.0, 50.0]), (N, 4)).copy()
    Lr = np.linalg.cholesky(R)
    anees, anis = [], []
    for _ in range(K):
        truth = truth @ F.T + rng.normal(0.0, q, (N, 2)) @ Gam.T
        z = truth[:, :2] + rng.standard_normal((N, 2)) @ Lr.T
        xp, Pp = kf.predict(x, P, np.broadcast_to(F, (N, 4, 4)), kf.process_noise(T, q))
        res = kf.update(xp, Pp, z, np.broadcast_to(R, (N, 2, 2)))
        x, P = res.x, res.P
        e = truth - x
        anees.append(np.mean(np.einsum("bi,bij,bj->b", e, np.linalg.inv(P), e)))
        anis.append(np.mean(res.nis))
    anees, anis = np.array(anees), np.array(anis)
    lo4, hi4 = stats.chi2.ppf([0.025, 0.975], 4 * N) / N
    lo2, hi2 = stats.chi2.ppf([0.025, 0.975], 2 * N) / N
    # Each scan's average is a 95% test: expect about 95% inside; the overall averages must be inside their bounds.
    assert np.mean((anees > lo4) & (anees < hi4)) >= 0.85
    assert np.mean((anis > lo2) & (anis < hi2)) >= 0.85
    # Errors are correlated from scan to scan, so N*K degrees of freedom would overstate the information in the
    # run average; the per-scan N-run bound is the honest band for it too.
    assert lo4 < anees.mean() < hi4
    assert lo2 < anis.mean() < hi2


def test_mismatched_q_is_detected_by_nees():
    """The consistency test can fail: a filter with q ten times too small is far outside the bound."""
    rng = np.random.default_rng(4)
    N, K, T, q = 200, 40, 5.0, 3.0
    F = kf.transition_cv(T)[0]
    Gam = np.array([[T**2 / 2, 0], [0, T**2 / 2], [T, 0], [0, T]])
    P = np.broadcast_to(np.diag([1e4, 1e4, 400.0, 400.0]), (N, 4, 4)).copy()
    x = np.zeros((N, 4))
    truth = rng.multivariate_normal(np.zeros(4), P[0], N)
    R = np.broadcast_to(100.0**2 * np.eye(2), (N, 2, 2))
    nees = []
    for _ in range(K):
        truth = truth @ F.T + rng.normal(0.0, q, (N, 2)) @ Gam.T
        z = truth[:, :2] + rng.normal(0, 100.0, (N, 2))
        res = kf.update(*kf.predict(x, P, np.broadcast_to(F, (N, 4, 4)), kf.process_noise(T, q / 10)), z, R)
        x, P = res.x, res.P
        e = truth - x
        nees.append(np.mean(np.einsum("bi,bij,bj->b", e, np.linalg.inv(P), e)))
    assert np.mean(nees[10:]) > 2 * stats.chi2.ppf(0.975, 4 * N) / N


# ---------------------------------------------------------------------------------------------- robustness
@settings(max_examples=60, deadline=None)
@given(
    q_g=st.lists(st.floats(0.0, 100.0), min_size=25, max_size=25),
    dts=st.lists(st.floats(0.05, 60.0), min_size=25, max_size=25),
    det=st.lists(st.booleans(), min_size=25, max_size=25),
    range_m=st.floats(500.0, 4e5),
    bearing=st.floats(-np.pi, np.pi),
    sr=st.floats(1.0, 500.0),
    sb_deg=st.floats(0.01, 2.0),
    omega=st.floats(-0.5, 0.5),
)
def test_any_q_any_geometry_keeps_P_spd_and_finite(q_g, dts, det, range_m, bearing, sr, sb_deg, omega):
    sb = np.radians(sb_deg)
    s, c = np.sin(bearing), np.cos(bearing)
    J = np.array([[s, range_m * c], [c, -range_m * s]])
    R = J @ np.diag([sr**2, sb**2]) @ J.T
    x = np.array([[range_m * s, range_m * c, 200.0, 0.0]])
    P = np.diag([R[0, 0], R[1, 1], 1e4, 1e4])[None]
    for q, dt, d in zip(q_g, dts, det):
        xp, Pp = kf.predict(x, P, kf.transition_ct(dt, omega), kf.process_noise(dt, q * G0_M_S2))
        z = xp[:, :2] + np.array([[3 * sr, -2 * sr]])
        res = kf.update(xp, Pp, np.where(d, z, np.nan), R[None], np.array([d]))
        x, P = res.x, res.P
        assert np.all(np.isfinite(x)) and np.all(np.isfinite(P))
        assert np.all(np.isfinite(res.nis)) and np.all(np.isfinite(res.loglik))
        assert np.array_equal(P, np.swapaxes(P, -1, -2))
        assert np.linalg.eigvalsh(P[0]).min() > 0.0
