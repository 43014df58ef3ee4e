"""Tests for baselines/alpha_beta.py (Kalata gains, Kim & Lee adaptive alpha-beta)."""

import numpy as np
import pytest

from baselines.alpha_beta import (kalata_gains, noise_only_innovation_variance, run_alpha_beta,
                                  steady_state_covariance, tracking_index)
from radar_env.filters import kalman

G0 = 9.80665


def test_gains_eqs_6_7_8_and_stability():
    lam = np.logspace(-4, 3, 400)
    a, b = kalata_gains(lam)
    s = np.sqrt(lam**2 + 8 * lam)
    np.testing.assert_allclose(a, -(lam**2 + 8 * lam - (lam + 4) * s) / 8, rtol=1e-9, atol=1e-12)  # eq 6
    np.testing.assert_allclose(b, (lam**2 + 4 * lam - lam * s) / 4, rtol=1e-6, atol=1e-12)  # eq 7
    np.testing.assert_allclose(b, 2 * (2 - a) - 4 * np.sqrt(1 - a), rtol=1e-9, atol=1e-12)  # eq 8
    np.testing.assert_allclose(lam**2, b**2 / (1 - a), rtol=1e-9)
    assert np.all((a > 0) & (a < 1) & (b > 0) & (b < 2) & (4 - 2 * a - b > 0))
    assert np.all(np.diff(a) > 0) and np.all(np.diff(b) > 0)


@pytest.mark.parametrize("q,sigma,T", [(1.0, 150.0, 1.0), (20.0, 50.0, 5.0), (0.3, 200.0, 10.0)])
def test_kalata_equals_steady_state_kf(q, sigma, T):
    x = np.zeros((1, 4))
    P = np.eye(4)[None] * 1e6
    F, Q = kalman.transition_cv(T), kalman.process_noise(T, q)
    R = np.eye(2)[None] * sigma**2
    for _ in range(3000):
        x, P = kalman.predict(x, P, F, Q)
        P_pr = P
        P = kalman.update(x, P, np.zeros((1, 2)), R).P
    K = P_pr[0, :, :2] @ np.linalg.inv(P_pr[0, :2, :2] + R[0])
    a, b = kalata_gains(tracking_index(q, sigma, T))
    np.testing.assert_allclose([K[0, 0], K[2, 0]], [a, b / T], rtol=1e-6)
    Po = steady_state_covariance(a, b, sigma, T)  # eq 12 = posterior KF covariance
    np.testing.assert_allclose(Po, P[0][np.ix_([0, 2], [0, 2])], rtol=1e-6)


def test_straight_line_exact_no_noise_with_misses_and_irregular_dt():
    rng = np.random.default_rng(0)
    B, K = 3, 60
    t = np.cumsum(rng.uniform(0.5, 2.0, (B, K)), axis=1)
    v = np.array([[100.0, -50.0], [0.0, 240.0], [-30.0, 3.0]])
    p0 = np.array([[1e4, 2e4], [-5e3, 0.0], [0.0, 0.0]])
    z = p0[:, None] + v[:, None] * t[..., None]
    det = rng.random((B, K)) > 0.2
    det[:, :3] = True
    zz = np.where(det[..., None], z, np.nan)
    for kw in (dict(q_m_s2=2.0), dict(alpha=0.5, beta=0.2), dict(q_m_s2=1.0, adaptive=True)):
        r = run_alpha_beta(t, zz, det, sigma_m=100.0, **kw)
        np.testing.assert_allclose(r.x[:, 1:, :2], z[:, 1:], atol=1e-6)
        np.testing.assert_allclose(r.x[:, 1:, 2:], np.broadcast_to(v[:, None], (B, K - 1, 2)), atol=1e-8)
        assert r.P.shape == (B, K, 4, 4) and np.all(np.isfinite(r.P[:, 1:]))


def _kim_lee_truth(t):
    """Closed-form position and velocity of the Kim & Lee 1-D scenario at times t (s): 120 m/s, CV to 25 s,
    +5 g to 35 s, CV to 65 s, -5 g to 75 s, CV to 100 s."""
    bps = np.array([0.0, 25.0, 35.0, 65.0, 75.0, np.inf])
    acc = np.array([0.0, 5 * G0, 0.0, -5 * G0, 0.0])
    x = np.zeros_like(t)
    v = np.full_like(t, 120.0)
    for i in range(5):
        d = np.clip(t - bps[i], 0.0, bps[i + 1] - bps[i])
        x += v * d + 0.5 * acc[i] * d * d  # v is the speed at the start of segment i where d > 0
        v = v + acc[i] * d
    return x, v


def test_kim_lee_adaptive_beats_low_q_fixed_during_maneuver():
    t = np.arange(1.0, 101.0)
    xt, vt = _kim_lee_truth(t)
    assert abs(vt.max() - 610.3) < 1.0  # "maximum speed of about 610 m/s"
    rng = np.random.default_rng(7)
    B = 100
    z = xt[None, :, None] + 150.0 * rng.standard_normal((B, t.size, 1))
    fixed = run_alpha_beta(t, z, sigma_m=150.0, q_m_s2=1.0)
    adapt = run_alpha_beta(t, z, sigma_m=150.0, q_m_s2=1.0, adaptive=True, window=12)
    adapt_n = run_alpha_beta(t, z, sigma_m=150.0, q_m_s2=1.0, adaptive=True, window=12, s0_mode="noise_only")
    man = (t > 25) & (t <= 80)
    rm = {n: float(np.sqrt(np.mean((r.x[:, man, 0] - xt[man]) ** 2))) for n, r in
          (("fixed_q1", fixed), ("adaptive_eq15", adapt), ("adaptive_noise_only", adapt_n))}
    print("Kim&Lee position RMSE over t in (25, 80] s:", rm)
    assert rm["adaptive_eq15"] < 0.3 * rm["fixed_q1"]
    assert rm["adaptive_noise_only"] < 0.3 * rm["fixed_q1"]
    # the adapted acceleration std rises during the maneuver
    q = np.median(adapt.q_m_s2[:, :, 0], axis=0)
    assert q[30:40].max() > 20.0


def test_noise_only_variance_matches_simulation():
    a, b = kalata_gains(0.5)
    rng = np.random.default_rng(3)
    t = np.arange(2000.0)
    z = 10.0 * rng.standard_normal((4, t.size, 1))
    r = run_alpha_beta(t, z, sigma_m=10.0, alpha=a, beta=b)
    S = np.mean(r.nu_m[:, 200:, 0] ** 2)
    assert abs(S / noise_only_innovation_variance(a, b, 10.0) - 1) < 0.05


def test_batched_equals_per_track():
    rng = np.random.default_rng(5)
    B, K = 4, 40
    t = np.cumsum(rng.uniform(0.5, 3.0, (B, K)), axis=1)
    z = np.cumsum(rng.normal(0, 300.0, (B, K, 2)), axis=1)
    det = rng.random((B, K)) > 0.3
    sig = rng.uniform(20.0, 200.0, (B, K, 2))
    full = run_alpha_beta(t, z, det, sigma_m=sig, q_m_s2=3.0, adaptive=True, window=5)
    for b in range(B):
        one = run_alpha_beta(t[b:b + 1], z[b:b + 1], det[b:b + 1], sigma_m=sig[b:b + 1], q_m_s2=3.0,
                             adaptive=True, window=5)
        np.testing.assert_allclose(one.x, full.x[b:b + 1], rtol=1e-12, equal_nan=True)
        np.testing.assert_allclose(one.P, full.P[b:b + 1], rtol=1e-12, equal_nan=True)


def test_velocity_variance_stays_finite_where_one_minus_alpha_rounds_to_zero():
    """A very large tracking index (a 1e-6 m radar on a maneuvering target): alpha rounds to 1 and eq 12 divided by
    1 - alpha = 0 (main: P_vv = inf, the run counted failed). In m = sqrt(1 - alpha) it is 4 (1 - m)^3 / (m T^2)."""
    from baselines.alpha_beta import kalata_m
    T, sigma = 2.0, 3.0
    for lam in (1e1, 1e2, 1e3):       # the two forms agree where 1 - alpha keeps its digits (eq 12 is used there)
        a, b = kalata_gains(lam)
        np.testing.assert_allclose(steady_state_covariance(a, b, sigma, T, kalata_m(lam))[1, 1],
                                   4.0 * (1.0 - kalata_m(lam)) ** 3 / (kalata_m(lam) * T * T) * sigma ** 2, rtol=1e-9)
    a, b = kalata_gains(1e20)
    assert a == 1.0
    assert steady_state_covariance(a, b, sigma, T)[1, 1] == np.inf          # without m: no finite value to give
    P = steady_state_covariance(a, b, sigma, T, kalata_m(1e20))
    assert np.isfinite(P).all() and P[1, 1] > 1e9 * sigma ** 2
