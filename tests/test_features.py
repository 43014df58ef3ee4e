"""Maneuver features (radar_env/filters/features.py) against closed forms, exact noise-free kinematics and Monte Carlo.

Truth for the turn tests is built with ``filters.transition_ct`` (exact constant-speed coordinated turn, positive
turn rate = clockwise = right turn); bearings and radial velocities are computed exactly from the truth.
All randomness comes from seeded numpy Generators.
"""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radar_env.filters import features as ft
from radar_env.filters import kalman as kf

DEG = np.pi / 180.0
H = np.hstack([np.eye(2), np.zeros((2, 2))])


def _spd(rng, B, n, scale):
    A = rng.standard_normal((B, n, n))
    return scale * (A @ np.swapaxes(A, -1, -2) + n * np.eye(n))


def _state_at(x0, omega, dt):
    """Exact state after ``dt`` (B,) of a constant turn ``omega`` (B,) from ``x0`` (B,4)."""
    F = kf.transition_ct(dt, omega)
    return np.einsum("bij,bj->bi", F, x0)


def _bearing_rdot(x, site):
    dx, dy = x[:, 0] - site[:, 0], x[:, 1] - site[:, 1]
    r = np.hypot(dx, dy)
    return np.arctan2(dx, dy), (dx * x[:, 2] + dy * x[:, 3]) / r


def _random_turn_cases(rng, B):
    speed = rng.uniform(80.0, 300.0, B)
    h0 = rng.uniform(-np.pi, np.pi, B)
    x0 = np.stack([rng.uniform(-8e4, 8e4, B), rng.uniform(-8e4, 8e4, B), speed * np.sin(h0), speed * np.cos(h0)], 1)
    omega = rng.choice([-1.0, 1.0], B) * rng.uniform(0.5, 6.0, B) * DEG
    dt = rng.uniform(1.0, 12.0, B)
    site = rng.uniform(-2e5, 2e5, (B, 2))
    return x0, omega, dt, site, speed


# ------------------------------------------------------------------------------------------------ angles
def test_wrap_angle_range_identity_periodic():
    rng = np.random.default_rng(0)
    a = rng.uniform(-50.0, 50.0, 10000)
    w = ft.wrap_angle(a)
    assert np.all(w > -np.pi) and np.all(w <= np.pi)
    # same angle: differs by an integer multiple of 2pi
    k = (a - w) / (2 * np.pi)
    np.testing.assert_allclose(k, np.round(k), atol=1e-9)
    inside = rng.uniform(-np.pi + 1e-9, np.pi, 1000)
    np.testing.assert_array_equal(ft.wrap_angle(inside), inside)
    # periodic
    np.testing.assert_allclose(ft.wrap_angle(inside + 2 * np.pi * rng.integers(-5, 6, 1000)), inside, atol=1e-12)
    # boundary: -pi maps to +pi, pi stays, tiny negatives stay tiny
    assert ft.wrap_angle(-np.pi) == pytest.approx(np.pi)
    assert ft.wrap_angle(np.pi) == pytest.approx(np.pi)
    assert ft.wrap_angle(3 * np.pi) == pytest.approx(np.pi)
    assert ft.wrap_angle(-1e-20) == pytest.approx(-1e-20, abs=1e-18)
    assert ft.wrap_angle(-1e-20) > -np.pi


def test_heading_conventions():
    np.testing.assert_allclose(ft.heading_rad(np.array([0.0, 1.0, 0.0, -1.0]), np.array([1.0, 0.0, -1.0, 0.0])),
                               [0.0, np.pi / 2, np.pi, -np.pi / 2])
    assert ft.heading_rad(0.0, 0.0) == 0.0
    assert ft.adrian_heading_from_plots(np.array([[10.0, 0.0]]), np.array([[0.0, 0.0]]))[0] == pytest.approx(np.pi / 2)


# ------------------------------------------------------------------------------------------------ innovations
def test_nis_matches_numpy_inverse():
    rng = np.random.default_rng(1)
    B = 500
    S = _spd(rng, B, 2, rng.uniform(1.0, 1e4, B)[:, None, None])
    nu = rng.standard_normal((B, 2)) * 100.0
    ref = np.einsum("bi,bij,bj->b", nu, np.linalg.inv(S), nu)
    np.testing.assert_allclose(ft.nis(nu, S), ref, rtol=1e-10)
    # degenerate S -> 0, finite
    assert ft.nis(np.ones((1, 2)), np.zeros((1, 2, 2)))[0] == 0.0


def test_along_cross_sign_and_unit_variance():
    # northbound track, plot to the east (right) -> positive cross, zero along
    S = np.eye(2)[None] * 4.0
    out = ft.normalized_innovation_along_cross(np.array([[3.0, 0.0]]), S, np.array([[0.0, 200.0]]))
    np.testing.assert_allclose(out, [[0.0, 1.5]], atol=1e-15)
    # eastbound track, plot to the south is right of track; plot ahead is positive along
    out = ft.normalized_innovation_along_cross(np.array([[2.0, -4.0]]), S, np.array([[150.0, 0.0]]))
    np.testing.assert_allclose(out, [[1.0, 2.0]], atol=1e-15)
    # Monte Carlo: nu ~ N(0, S) -> each component ~ N(0,1)
    rng = np.random.default_rng(2)
    B = 40000
    S = _spd(rng, 1, 2, 50.0)[0]
    L = np.linalg.cholesky(S)
    nu = rng.standard_normal((B, 2)) @ L.T
    v = rng.standard_normal(2) * 100.0
    nac = ft.normalized_innovation_along_cross(nu, np.broadcast_to(S, (B, 2, 2)), np.broadcast_to(v, (B, 2)))
    se_var = np.sqrt(2.0 / B)  # std error of a sample variance of N(0,1)
    np.testing.assert_allclose(nac.var(axis=0), 1.0, atol=5 * se_var)
    np.testing.assert_allclose(nac.mean(axis=0), 0.0, atol=5 / np.sqrt(B))
    # zero velocity falls back to north/east axes, finite
    out = ft.normalized_innovation_along_cross(np.array([[1.0, 2.0]]), S[None], np.zeros((1, 2)))
    np.testing.assert_allclose(out, [[2.0 / np.sqrt(S[1, 1]), 1.0 / np.sqrt(S[0, 0])]])


# ------------------------------------------------------------------------------------------------ Bizup c_min
def _cmin_case(x0, omega, dt, site):
    x1 = _state_at(x0, omega, dt)
    b, rdot = _bearing_rdot(x1, site)
    return ft.c_min_m_s2(x0, b, rdot, dt), x1, b


def test_c_min_exact_for_constant_turn_named_geometries():
    # site at origin, target 50 km north of it heading east (tangential); also 60 km east heading north
    s = 240.0
    cases = []
    for pos, vel in [((0.0, 5e4), (s, 0.0)), ((6e4, 0.0), (0.0, s)), ((-3e4, -3e4), (s / np.sqrt(2), -s / np.sqrt(2)))]:
        for w in (3 * DEG, -3 * DEG, 1 * DEG, -5 * DEG):
            cases.append((*pos, *vel, w))
    c = np.array(cases)
    x0, omega = c[:, :4], c[:, 4]
    dt = np.full(len(c), 5.0)
    cm, _, _ = _cmin_case(x0, omega, dt, np.zeros((len(c), 2)))
    np.testing.assert_allclose(cm, s * np.abs(omega), rtol=1e-6)


def test_c_min_exact_random_geometries_and_upper_bounded():
    rng = np.random.default_rng(3)
    B = 4000
    x0, omega, dt, site, speed = _random_turn_cases(rng, B)
    cm, x1, b = _cmin_case(x0, omega, dt, site)
    true_acc = speed * np.abs(omega)
    # documented property: never above the true centripetal acceleration
    assert np.all(cm <= true_acc * (1 + 1e-9) + 1e-9)
    assert np.all(cm >= 0.0)
    # equality when the mirror heading (about the bearing line) is farther from h_prev than the true turn
    h_prev = np.arctan2(x0[:, 2], x0[:, 3])
    h_true = np.arctan2(x1[:, 2], x1[:, 3])
    mirror_turn = np.abs(ft.wrap_angle(2 * b - h_true - h_prev))
    gamma = np.abs(ft.wrap_angle(h_true - b))
    good = (mirror_turn > 1.5 * np.abs(omega * dt)) & (gamma > 10 * DEG) & (gamma < 170 * DEG)
    assert good.sum() > B // 3
    np.testing.assert_allclose(cm[good], true_acc[good], rtol=1e-6)
    # both left and right turns covered by the exact cases
    assert np.any(good & (omega > 0)) and np.any(good & (omega < 0))


def test_c_min_zero_on_straight_leg():
    rng = np.random.default_rng(4)
    x0, _, dt, site, speed = _random_turn_cases(rng, 500)
    cm, x1, b = _cmin_case(x0, np.zeros(500), dt, site)
    gamma = np.abs(ft.wrap_angle(np.arctan2(x1[:, 2], x1[:, 3]) - b))
    ok = (gamma > 5 * DEG) & (gamma < 175 * DEG)
    np.testing.assert_allclose(cm[ok], 0.0, atol=1e-5)
    # at any geometry it stays tiny compared with a 0.03 g threshold
    assert np.all(cm < 0.03 * 9.80665)


def test_c_min_fallbacks_finite():
    x = np.zeros((3, 4))
    out = ft.c_min_m_s2(x, np.array([0.1, 2.0, -3.0]), np.array([5.0, -1.0, 0.0]), np.array([0.0, 1.0, -1.0]))
    np.testing.assert_array_equal(out, 0.0)
    x = np.array([[0.0, 0.0, 100.0, 0.0]])
    out = ft.c_min_m_s2(x, np.array([0.0]), np.array([500.0]), np.array([0.0]))  # |rdot| > s, dt = 0
    assert np.all(np.isfinite(out)) and out[0] >= 0.0


# ------------------------------------------------------------------------------------------------ Adrian
def _adrian_sequence(rng, B, n, irregular):
    speed = rng.uniform(80.0, 300.0, B)
    h0 = rng.uniform(-np.pi, np.pi, B)
    x0 = np.stack([rng.uniform(-5e4, 5e4, B), rng.uniform(-5e4, 5e4, B), speed * np.sin(h0), speed * np.cos(h0)], 1)
    omega = rng.choice([-1.0, 1.0], B) * rng.uniform(0.5, 4.0, B) * DEG
    if irregular:
        gaps = rng.uniform(1.0, 8.0, (B, n + 1))
    else:
        gaps = np.full((B, n + 1), 5.0)
    t = np.concatenate([np.zeros((B, 1)), np.cumsum(gaps, axis=1)], axis=1) + rng.uniform(0, 100, (B, 1))
    z = np.stack([_state_at(x0, omega, t[:, j] - t[:, 0])[:, :2] for j in range(n + 2)], axis=1)
    v = np.stack([_state_at(x0, omega, t[:, j] - t[:, 0])[:, 2:] for j in range(n + 2)], axis=1)
    return z, t, v, omega


@pytest.mark.parametrize("irregular", [False, True])
@pytest.mark.parametrize("n", [1, 3, 4])
def test_adrian_alg1_and_alg2_exact_on_constant_turn(n, irregular):
    rng = np.random.default_rng(10 + n + 100 * irregular)
    B = 300
    z, t, v, omega = _adrian_sequence(rng, B, n, irregular)
    w1 = ft.adrian_turn_rate_alg1_rad_s(z, t)
    np.testing.assert_allclose(w1, omega, rtol=1e-7)
    w2 = ft.adrian_turn_rate_alg2_rad_s(v[:, -1], v[:, -1 - n], t[:, -1], t[:, -1 - n])
    np.testing.assert_allclose(w2, omega, rtol=1e-9)
    if not irregular:
        np.testing.assert_allclose(ft.adrian_mid_time_dt_s(t[:, -1], t[:, -2], t[:, 1], t[:, 0]), 5.0, rtol=1e-12)


def test_adrian_sign_right_turn_positive():
    x0 = np.array([[0.0, 0.0, 0.0, 200.0]])  # northbound
    t = np.arange(6.0)[None] * 5.0
    z = np.stack([_state_at(x0, np.array([2 * DEG]), t[:, j])[:, :2] for j in range(6)], axis=1)
    assert z[0, -1, 0] > 0  # drifted east: right turn
    assert ft.adrian_turn_rate_alg1_rad_s(z, t)[0] == pytest.approx(2 * DEG, rel=1e-9)
    v_new = _state_at(x0, np.array([2 * DEG]), np.array([20.0]))[:, 2:]
    assert ft.adrian_turn_rate_alg2_rad_s(v_new, x0[:, 2:], 20.0, 0.0)[0] == pytest.approx(2 * DEG, rel=1e-9)


def test_adrian_wraps_across_south():
    # heading crossing +-pi (southbound) must not produce a 2pi jump
    v_old = np.array([[-1.0, -100.0]])  # heading just below -pi... i.e. ~ -179.4 deg
    v_new = np.array([[1.0, -100.0]])  # ~ +179.4 deg: a left turn of ~1.15 deg
    w = ft.adrian_turn_rate_alg2_rad_s(v_new, v_old, 1.0, 0.0)[0]
    assert w == pytest.approx(-2 * np.arctan(0.01), rel=1e-12)


# ------------------------------------------------------------------------------------------------ FMA, Kim & Lee
def test_fading_memory_average_recursion():
    rng = np.random.default_rng(5)
    vals = rng.uniform(0, 100, 50)
    f = 0.0
    for k, x in enumerate(vals):
        f = ft.fading_memory_average(f, x, 0.1)
    ref = sum(0.1 * 0.9 ** (len(vals) - 1 - k) * x for k, x in enumerate(vals))
    assert f == pytest.approx(ref, rel=1e-12)
    assert ft.fading_memory_average(3.0, 7.0, 0.0) == 3.0
    assert ft.fading_memory_average(3.0, 7.0, 1.0) == 7.0


def test_kim_lee_variance_and_formulas():
    np.testing.assert_array_equal(ft.kim_lee_variance(np.array([-1.0, 0.0, 2.5]), 9.0), [9.0, 0.0, 2.5])
    # 2-D phi: S_hat = S0 + q^2 dt^4/4 I  ->  phi = q^2
    rng = np.random.default_rng(6)
    S0 = _spd(rng, 5, 2, 100.0)
    q2, dt = rng.uniform(0, 50, 5), rng.uniform(0.5, 10, 5)
    S_hat = S0 + (q2 * dt**4 / 4)[:, None, None] * np.eye(2)
    np.testing.assert_allclose(ft.kim_lee_phi_2d(S_hat, S0, dt), q2, rtol=1e-9, atol=1e-9)
    # 1-D eq 15
    assert ft.kim_lee_phi_1d(10.0 + 4.0 + 0.25 * 16 * 3.0, 4.0, 10.0, 2.0) == pytest.approx(3.0)
    # S0 = H F P F^T H^T + R
    P = _spd(rng, 5, 4, 10.0)
    R = _spd(rng, 5, 2, 3.0)
    F = kf.transition_cv(dt)
    np.testing.assert_allclose(ft.innovation_cov_without_process_noise(F, P, R), H @ F @ P @ np.swapaxes(F, 1, 2) @ H.T + R)


def test_kim_lee_phi_estimates_q_squared_monte_carlo():
    """CV target driven by piecewise-constant white acceleration of std q; KF with the SAME q. The innovations
    are then N(0, S) and white, so E[trace(nu nu^T) - trace(S0)] = trace(H Q H^T) = q^2 dt^4 / 2: the mean of
    phi is q^2. Tolerance: 5 standard errors estimated from the per-run means (runs are independent)."""
    rng = np.random.default_rng(7)
    B, K, burn = 300, 80, 20
    q, dt, sig = 4.0, 2.0, 3.0
    F = kf.transition_cv(np.full(B, dt))
    Q = kf.process_noise(np.full(B, dt), q)
    R = np.broadcast_to(np.eye(2) * sig**2, (B, 2, 2)).copy()
    G = np.array([[dt**2 / 2, 0], [0, dt**2 / 2], [dt, 0], [0, dt]])
    x_true = np.tile([0.0, 0.0, 100.0, 50.0], (B, 1))
    x = x_true + rng.standard_normal((B, 4)) * np.array([sig, sig, 2.0, 2.0])
    P = np.broadcast_to(np.diag([sig**2, sig**2, 4.0, 4.0]), (B, 4, 4)).copy()
    bank = ft.FeatureBank(B, window_kim_lee=12)
    phis = []
    t = 0.0
    for k in range(K):
        t += dt
        x_true = x_true @ F[0].T + rng.standard_normal((B, 2)) @ (q * G).T
        z = x_true[:, :2] + rng.standard_normal((B, 2)) * sig
        xp, Pp = kf.predict(x, P, F, Q)
        up = kf.update(xp, Pp, z, R)
        b, rd = _bearing_rdot(up.x, np.zeros((B, 2)))
        out = bank.update(x, xp, P, F, R, up.nu, up.S, up.x, z, np.full(B, t), np.full(B, dt), b, rd,
                          np.ones(B, bool), np.zeros(2))
        x, P = up.x, up.P
        if k >= burn:
            assert out["kim_lee_valid"].all()
            phis.append(out["kim_lee_phi_m2_s4"])
        else:
            assert out["kim_lee_valid"].all() == (k + 1 >= 12)
    phis = np.array(phis)  # (K-burn, B)
    run_means = phis.mean(axis=0)
    se = run_means.std(ddof=1) / np.sqrt(B)
    assert se < 0.1 * q**2  # the test has power
    assert abs(run_means.mean() - q**2) < 5 * se, (run_means.mean(), se)
    # the eq-17 output equals phi where phi >= 0 and the fallback (0 by default) elsewhere
    np.testing.assert_array_equal(out["kim_lee_q2_m2_s4"], np.maximum(out["kim_lee_phi_m2_s4"], 0.0))


# ------------------------------------------------------------------------------------------------ FeatureBank
def _random_inputs(rng, B, t_prev, p_det=0.7, degenerate=False):
    dt = rng.uniform(0.5, 10.0, B)
    if degenerate:
        dt = np.where(rng.random(B) < 0.3, 0.0, dt)
    t = t_prev + dt
    x_prev = rng.standard_normal((B, 4)) * np.array([3e4, 3e4, 150, 150])
    if degenerate:
        x_prev[rng.random(B) < 0.3, 2:] = 0.0
    F = kf.transition_cv(dt)
    x_prior = np.einsum("bij,bj->bi", F, x_prev)
    P = _spd(rng, B, 4, 50.0)
    R = _spd(rng, B, 2, 100.0)
    S = _spd(rng, B, 2, 500.0)
    nu = rng.standard_normal((B, 2)) * 30.0
    z = x_prior[:, :2] + nu
    if degenerate:
        z = np.where(rng.random((B, 1)) < 0.3, np.round(z / 1e5) * 1e5, z)  # often coincident plots
    x_post = x_prior + rng.standard_normal((B, 4)) * 5.0
    if degenerate:
        x_post[rng.random(B) < 0.3, 2:] = 0.0
    site = rng.uniform(-1e5, 1e5, (B, 2))
    b, rd = _bearing_rdot(np.concatenate([z, x_post[:, 2:]], 1) + np.array([1e-3, 0, 0, 0]), site)
    det = rng.random(B) < p_det
    return dict(x_prev=x_prev, x_prior=x_prior, P_post_prev=P, F=F, R=R, nu=nu, S=S, x_post=x_post, z=z, t_s=t,
                dt_s=dt, bearing_rad=b, radial_velocity_m_s=rd, detected=det, site_xy=site)


def _slice(inp, i):
    return {k: v[i:i + 1] for k, v in inp.items()}


def test_bank_batched_equals_separate_rows():
    rng = np.random.default_rng(8)
    B, K = 6, 40
    bank = ft.FeatureBank(B, n_adrian=3, window_kim_lee=5, sigma_D2_m2_s4=2.0)
    singles = [ft.FeatureBank(1, n_adrian=3, window_kim_lee=5, sigma_D2_m2_s4=2.0) for _ in range(B)]
    t = np.zeros(B)
    for k in range(K):
        inp = _random_inputs(rng, B, t)
        t = inp["t_s"]
        out = bank.update(**inp)
        for i, sb in enumerate(singles):
            o1 = sb.update(**_slice(inp, i))
            for key, val in out.items():
                np.testing.assert_allclose(val[i], o1[key][0], rtol=1e-12, atol=0, err_msg=key)
        if k == 25:  # partial reset of rows 1 and 4 in the batch = full reset of those single banks
            mask = np.array([False, True, False, False, True, False])
            bank.reset(mask)
            for i in np.flatnonzero(mask):
                singles[i].reset()


def test_bank_missed_detection_holds_and_buffers_untouched():
    rng = np.random.default_rng(9)
    B = 8
    bank = ft.FeatureBank(B, n_adrian=2, window_kim_lee=4)
    t = np.zeros(B)
    for _ in range(10):
        inp = _random_inputs(rng, B, t, p_det=1.0)
        t = inp["t_s"]
        prev = bank.update(**inp)
    names = ["plot_xy", "plot_t", "plot_idx", "plot_count", "outer", "outer_idx", "outer_count", "fma", "n_detections"]
    before = {nm: getattr(bank, nm).copy() for nm in names}
    inp = _random_inputs(rng, B, t)
    miss = ~inp["detected"]
    assert miss.any() and (~miss).any()
    out = bank.update(**inp)
    for nm in names:
        np.testing.assert_array_equal(getattr(bank, nm)[miss], before[nm][miss], err_msg=nm)
        assert not np.array_equal(getattr(bank, nm)[~miss], before[nm][~miss]) or nm in ("plot_count", "outer_count"), nm
    for key in ("nu_along", "nu_cross", "nis", "c_min_m_s2", "turn_rate_alg1_rad_s", "fma_innovation_m",
                "kim_lee_phi_m2_s4", "kim_lee_q2_m2_s4", "nu_along_fm", "nu_cross_fm", "nis_fm"):
        np.testing.assert_array_equal(out[key][miss], prev[key][miss], err_msg=key)
        if key != "kim_lee_q2_m2_s4":  # eq 17 clamps negative phi to the same fallback, so it may repeat
            assert np.all(out[key][~miss] != prev[key][~miss]), key
    # filter-output features update on misses too
    np.testing.assert_allclose(out["speed_m_s"], np.hypot(inp["x_post"][:, 2], inp["x_post"][:, 3]))
    np.testing.assert_allclose(out["range_m"], np.hypot(*(inp["x_post"][:, :2] - inp["site_xy"]).T))
    assert np.all(out["turn_rate_alg2_rad_s"][miss] != prev["turn_rate_alg2_rad_s"][miss])


def test_bank_reset_mask_only_masked_rows():
    rng = np.random.default_rng(11)
    B = 5
    a = ft.FeatureBank(B, n_adrian=2, window_kim_lee=3)
    b = ft.FeatureBank(B, n_adrian=2, window_kim_lee=3)
    t = np.zeros(B)
    for _ in range(8):
        inp = _random_inputs(rng, B, t, p_det=1.0)
        t = inp["t_s"]
        a.update(**inp)
        b.update(**inp)
    mask = np.array([True, False, False, True, False])
    a.reset(mask)
    for nm in ["plot_xy", "plot_t", "plot_idx", "plot_count", "head", "head_t", "head_idx", "head_count", "outer",
               "outer_idx", "outer_count", "fma", "n_detections"]:
        np.testing.assert_array_equal(getattr(a, nm)[~mask], getattr(b, nm)[~mask], err_msg=nm)
        assert not np.any(getattr(a, nm)[mask]), nm
    inp = _random_inputs(rng, B, t, p_det=1.0)
    oa, ob = a.update(**inp), b.update(**inp)
    for key in oa:
        np.testing.assert_array_equal(oa[key][~mask], ob[key][~mask], err_msg=key)
    assert not oa["turn_rate_alg1_valid"][mask].any() and ob["turn_rate_alg1_valid"].all()
    assert not oa["turn_rate_alg2_valid"][mask].any() and not oa["kim_lee_valid"][mask].any()
    assert oa["nu_valid"].all()


@pytest.mark.parametrize("n,N", [(1, 1), (3, 5), (4, 12)])
def test_bank_valid_flags_and_values_on_constant_turn(n, N):
    """Noise-free right and left turns fed through the bank: flags switch on after n+2 detected plots (alg 1),
    n+1 headings (alg 2, misses count) and N detections (Kim & Lee); the alg-1/alg-2 values are exact."""
    rng = np.random.default_rng(12 + n)
    B = 4
    omega = np.array([2.0, -3.0, 1.0, -1.5]) * DEG
    speed = np.array([200.0, 150.0, 250.0, 100.0])
    x0 = np.stack([rng.uniform(-1e4, 1e4, B), rng.uniform(-1e4, 1e4, B), speed * 0.6, speed * 0.8], 1)
    det_pattern = np.ones((30, B), bool)
    det_pattern[[3, 7, 8], 1] = False  # row 1 misses some scans
    bank = ft.FeatureBank(B, n_adrian=n, window_kim_lee=N)
    t = np.zeros(B)
    times = [t.copy()]
    x_prev = x0
    P = np.broadcast_to(np.eye(4) * 10.0, (B, 4, 4))
    R = np.broadcast_to(np.eye(2) * 25.0, (B, 2, 2))
    S = np.broadcast_to(np.eye(2) * 100.0, (B, 2, 2))
    ndet = np.zeros(B, int)
    for k in range(30):
        dt = rng.uniform(3.0, 7.0, B)
        t = t + dt
        times.append(t.copy())
        x = _state_at(x0, omega, t)
        det = det_pattern[k]
        ndet += det
        b, rd = _bearing_rdot(x, np.zeros((B, 2)))
        F = kf.transition_cv(dt)
        out = bank.update(x_prev, np.einsum("bij,bj->bi", F, x_prev), P, F, R, x[:, :2] - (F @ x_prev[..., None])[..., :2, 0],
                          S, x, x[:, :2], t, dt, b, rd, det, np.zeros(2))
        x_prev = x
        np.testing.assert_array_equal(out["turn_rate_alg1_valid"], ndet >= n + 2)
        np.testing.assert_array_equal(out["turn_rate_alg2_valid"], np.full(B, k + 1 >= n + 1))
        np.testing.assert_array_equal(out["kim_lee_valid"], ndet >= N)
        np.testing.assert_array_equal(out["nu_valid"], ndet >= 1)
        v1 = out["turn_rate_alg1_valid"]
        np.testing.assert_allclose(out["turn_rate_alg1_rad_s"][v1], omega[v1], rtol=1e-7)
        assert np.all(out["turn_rate_alg1_rad_s"][~v1] == 0.0)
        if out["turn_rate_alg2_valid"].all():
            np.testing.assert_allclose(out["turn_rate_alg2_rad_s"], omega, rtol=1e-9)
        # c_min from the exact previous state is exact for these (non-radial) geometries, or below
        cm = out["c_min_m_s2"]
        assert np.all(cm[det] <= speed[det] * np.abs(omega[det]) * (1 + 1e-9))


def test_bank_reset_seeding_with_plots_and_heading():
    rng = np.random.default_rng(13)
    B, n = 3, 2
    omega = np.array([2.0, -2.0, 4.0]) * DEG
    x0 = np.stack([np.zeros(B), np.zeros(B), np.full(B, 100.0), np.full(B, 180.0)], 1)
    bank = ft.FeatureBank(B, n_adrian=n, window_kim_lee=3)
    seed_t = np.stack([np.zeros(B), np.full(B, 4.0)], 1)
    seed_z = np.stack([_state_at(x0, omega, seed_t[:, j])[:, :2] for j in range(2)], 1)
    bank.reset(plots_xy=seed_z, plot_times_s=seed_t, x=_state_at(x0, omega, seed_t[:, 1]), t_s=seed_t[:, 1])
    t = seed_t[:, 1].copy()
    x_prev = _state_at(x0, omega, t)
    for k in range(n):  # n more plots complete the n+2 buffer; n more headings complete the n+1 buffer
        dt = rng.uniform(3.0, 6.0, B)
        t = t + dt
        x = _state_at(x0, omega, t)
        b, rd = _bearing_rdot(x, np.full((B, 2), 1e3))
        F = kf.transition_cv(dt)
        out = bank.update(x_prev, x, np.broadcast_to(np.eye(4), (B, 4, 4)), F, np.broadcast_to(np.eye(2), (B, 2, 2)),
                          np.zeros((B, 2)), np.broadcast_to(np.eye(2), (B, 2, 2)), x, x[:, :2], t, dt, b, rd,
                          np.ones(B, bool), np.array([1e3, 1e3]))
        x_prev = x
        assert out["turn_rate_alg1_valid"].all() == (k == n - 1)
        assert out["turn_rate_alg2_valid"].all() == (k == n - 1)
    np.testing.assert_allclose(out["turn_rate_alg1_rad_s"], omega, rtol=1e-7)
    np.testing.assert_allclose(out["turn_rate_alg2_rad_s"], omega, rtol=1e-9)


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**32 - 1), n=st.integers(1, 5), N=st.integers(1, 6), B=st.integers(1, 4))
def test_bank_outputs_finite_for_degenerate_inputs(seed, n, N, B):
    rng = np.random.default_rng(seed)
    bank = ft.FeatureBank(B, n_adrian=n, window_kim_lee=N, sigma_D2_m2_s4=1.0)
    t = np.zeros(B)
    for k in range(n + N + 3):
        inp = _random_inputs(rng, B, t, p_det=0.8, degenerate=True)
        if k % 3 == 0:  # fully degenerate scan: everything at rest, coincident plots, dt = 0
            for key in ("x_prev", "x_prior", "x_post", "nu", "radial_velocity_m_s", "dt_s", "bearing_rad"):
                inp[key] = np.zeros_like(inp[key])
            inp["z"] = np.zeros_like(inp["z"])
            inp["site_xy"] = np.zeros_like(inp["site_xy"])
            inp["t_s"] = t.copy()
        t = inp["t_s"]
        out = bank.update(**inp)
        for key, val in out.items():
            assert val.shape == (B,), key
            assert np.all(np.isfinite(val)), key
        assert np.all(out["c_min_m_s2"] >= 0.0) and np.all(out["kim_lee_q2_m2_s4"] >= 0.0)


def test_nis_chi_square_mean_and_variance():
    rng = np.random.default_rng(14)
    B = 40000
    S = _spd(rng, B, 2, 30.0)
    L = np.linalg.cholesky(S)
    nu = np.einsum("bij,bj->bi", L, rng.standard_normal((B, 2)))
    v = ft.nis(nu, S)
    # chi-square with 2 dof: mean 2, variance 4
    assert abs(v.mean() - 2.0) < 5 * np.sqrt(4.0 / B)
    assert abs(v.var() - 4.0) < 0.25


def test_c_min_rotation_invariant_and_mirror_symmetric():
    """Rotating the whole scene (site, target, velocities) leaves c_min unchanged; reflecting it (x -> -x) turns a
    right turn into a left turn with the same c_min."""
    rng = np.random.default_rng(15)
    B = 1000
    x0, omega, dt, site, _ = _random_turn_cases(rng, B)
    cm, _, _ = _cmin_case(x0, omega, dt, site)
    a = rng.uniform(-np.pi, np.pi, B)
    c, s = np.cos(a), np.sin(a)

    def rot(p):
        return np.stack([c * p[:, 0] - s * p[:, 1], s * p[:, 0] + c * p[:, 1]], 1)

    x0r = np.concatenate([rot(x0[:, :2]), rot(x0[:, 2:])], 1)
    cmr, _, _ = _cmin_case(x0r, omega, dt, rot(site))
    np.testing.assert_allclose(cmr, cm, rtol=1e-6, atol=1e-9)
    flip = np.array([-1.0, 1.0, -1.0, 1.0])
    cmm, _, _ = _cmin_case(x0 * flip, -omega, dt, site * flip[:2])
    np.testing.assert_allclose(cmm, cm, rtol=1e-6, atol=1e-9)


def test_bank_matches_formula_functions_with_misses():
    """The bank's ring buffers reproduce the stand-alone formulas fed with manually kept histories: FMA over
    detected |nu|, Kim & Lee S_hat = mean of the last N detected outer products, c_min / NIS / along-cross of the
    current scan, and the eq-17 fallback. F given as one (4,4) matrix and site as (2,) (broadcast forms)."""
    rng = np.random.default_rng(16)
    B, N, sD = 5, 4, 3.0
    bank = ft.FeatureBank(B, n_adrian=2, window_kim_lee=N, sigma_D2_m2_s4=sD, fma_weight=0.2, fm_weight=0.3)
    t = np.zeros(B)
    fma = np.zeros(B)
    fm = {k: np.zeros(B) for k in ("nu_along_fm", "nu_cross_fm", "nis_fm")}
    hist = [[] for _ in range(B)]
    site = np.array([1e4, -2e4])
    signs = set()
    for k in range(30):
        inp = _random_inputs(rng, B, t, p_det=0.6)
        inp["dt_s"] = np.full(B, 4.0)
        inp["t_s"] = t + 4.0
        inp["F"] = kf.transition_cv(4.0)[0]
        inp["site_xy"] = site
        inp["nu"] = inp["nu"] * 3.0  # innovations comparable to S0, so phi takes both signs
        t = inp["t_s"]
        out = bank.update(**inp)
        det, nu = inp["detected"], inp["nu"]
        fma = np.where(det, 0.8 * fma + 0.2 * np.hypot(nu[:, 0], nu[:, 1]), fma)
        np.testing.assert_allclose(out["fma_innovation_m"], fma, rtol=1e-12)
        nac = ft.normalized_innovation_along_cross(nu, inp["S"], inp["x_prior"][:, 2:])
        for key, sample in (("nu_along_fm", nac[:, 0]), ("nu_cross_fm", nac[:, 1]),
                            ("nis_fm", ft.nis(nu, inp["S"]))):
            fm[key] = np.where(det, 0.7 * fm[key] + 0.3 * sample, fm[key])
            np.testing.assert_allclose(out[key], fm[key], rtol=1e-12, atol=1e-15, err_msg=key)
        S0 = ft.innovation_cov_without_process_noise(inp["F"], inp["P_post_prev"], inp["R"])
        for i in range(B):
            if det[i]:
                hist[i].append(np.outer(nu[i], nu[i]))
                np.testing.assert_allclose(out["nis"][i], ft.nis(nu[i:i + 1], inp["S"][i:i + 1])[0], rtol=1e-12)
                cm = ft.c_min_m_s2(inp["x_prev"][i:i + 1], inp["bearing_rad"][i:i + 1],
                                   inp["radial_velocity_m_s"][i:i + 1], 4.0)[0]
                assert out["c_min_m_s2"][i] == pytest.approx(cm, rel=1e-12, abs=1e-300)
                nac = ft.normalized_innovation_along_cross(nu[i:i + 1], inp["S"][i:i + 1], inp["x_prior"][i:i + 1, 2:])
                np.testing.assert_allclose([out["nu_along"][i], out["nu_cross"][i]], nac[0], rtol=1e-12)
                if len(hist[i]) >= N:
                    S_hat = np.mean(hist[i][-N:], axis=0)
                    phi = ft.kim_lee_phi_2d(S_hat[None], S0[i:i + 1], 4.0)[0]
                    assert out["kim_lee_phi_m2_s4"][i] == pytest.approx(phi, rel=1e-9, abs=1e-9)
                    assert out["kim_lee_q2_m2_s4"][i] == pytest.approx(phi if phi >= 0 else sD, rel=1e-9, abs=1e-9)
                    signs.add(bool(phi >= 0))
        np.testing.assert_allclose(out["range_m"], np.hypot(*(inp["x_post"][:, :2] - site).T))
    assert any(len(h) > N for h in hist)
    assert signs == {True, False}  # both branches of eq 17 exercised


def test_fm_weight_must_be_a_fraction():
    for bad in (0.0, -0.1, 1.5):
        with pytest.raises(ValueError, match=r"fm_weight must be in \(0, 1\]"):
            ft.FeatureBank(2, fm_weight=bad)


def test_feature_bank_row_state_is_fully_listed():
    """take_rows/put_rows (used to step row subsets) must cover every per-row array of the bank."""
    from radar_env.filters.features import FeatureBank
    bank = FeatureBank(7)
    per_row = {k for k, v in vars(bank).items() if isinstance(v, np.ndarray) and v.shape[:1] == (7,)
               and k not in ("_rows", "_par")}  # _par: the parameter vector, not row state
    dicts = {k for k, v in vars(bank).items() if isinstance(v, dict) and v
             and all(isinstance(a, np.ndarray) and a.shape[:1] == (7,) for a in v.values())}
    assert per_row == set(FeatureBank._ROW_ARRAYS) and dicts == set(FeatureBank._ROW_DICTS)
    sub = bank.take_rows([1, 3])
    sub.fma[:] = 5.0
    bank.put_rows([1, 3], sub)
    assert np.array_equal(bank.fma, [0, 5, 0, 5, 0, 0, 0])
