"""Tests for baselines/konle.py (Konle's differential speed/heading EKF) and the 75 % blend."""

import numpy as np

from baselines.konle import blend_speed_heading, konle_measurement, run_konle
from radar_env.filters import kalman
from radar_env.filters.features import wrap_angle

DEG = np.pi / 180.0


def _truth(t, p0, speed, h0, omega):
    """Closed-form constant-speed track, heading h0 + omega t (clockwise), positions (…,2), headings (…)."""
    h = h0 + omega * t
    if omega == 0.0:
        p = p0 + speed * t[..., None] * np.array([np.sin(h0), np.cos(h0)])
    else:
        p = p0 + (speed / omega) * np.stack([np.cos(h0) - np.cos(h), np.sin(h) - np.sin(h0)], axis=-1)
    return p, h


def _stream(sites, periods, offsets, t_end):
    """Merged plot times/site index of several rotating radars, sorted by time."""
    ts, ss = [], []
    for i, (T, o) in enumerate(zip(periods, offsets)):
        tt = np.arange(o, t_end, T)
        ts.append(tt)
        ss.append(np.full(tt.size, i))
    t, s = np.concatenate(ts), np.concatenate(ss)
    order = np.argsort(t, kind="stable")
    return t[order], s[order], np.asarray(sites, dtype=float)[s[order]]


def _polar(p, site):
    d = p - site
    return np.hypot(d[..., 0], d[..., 1]), np.arctan2(d[..., 0], d[..., 1])


def test_measurement_jacobian_matches_eqs_6_9_and_finite_differences():
    x = np.array([230.0, 0.7, 1.0, 0.01])
    r1, al1, dt = 60e3, 0.3, 5.0
    h, H = konle_measurement(x, r1, al1, dt)
    v, phi = x[:2]
    # eqs 4, 5 with alpha2 = alpha1 + dalpha, r2 from the geometry
    al2 = al1 + h[1]
    r2 = r1 + h[0]
    assert np.isclose(h[0], v * dt * np.cos(phi - al2) - r1 * (1 - np.cos(al2 - al1)))
    assert np.isclose(h[1], np.arcsin(v * dt * np.sin(phi - al1) / r2))
    np.testing.assert_allclose(H[0, :2], [dt * np.cos(phi - al2), -v * dt * np.sin(phi - al2)], rtol=1e-9)
    np.testing.assert_allclose(H[1, :2], [np.sin(phi - al1) * r1 * dt / r2**2,
                                          v * dt * (v * dt + r1 * np.cos(phi - al1)) / r2**2], rtol=1e-9)
    for j, e in ((0, 1e-4), (1, 1e-7)):
        xp = x.copy(); xp[j] += e
        xm = x.copy(); xm[j] -= e
        fd = (konle_measurement(xp, r1, al1, dt)[0] - konle_measurement(xm, r1, al1, dt)[0]) / (2 * e)
        np.testing.assert_allclose(H[:, j], fd, rtol=1e-5)


def test_noise_free_straight_flight_exact():
    t, s, site = _stream([(0.0, 0.0), (40e3, -30e3)], [5.0, 12.0], [0.0, 2.0], 200.0)
    B = 3
    speeds = np.array([120.0, 250.0, 300.0])
    heads = np.array([45.0, -100.0, 179.0]) * DEG
    rng_, brg = np.zeros((B, t.size)), np.zeros((B, t.size))
    for b in range(B):
        p, _ = _truth(t, np.array([20e3, 50e3]), speeds[b], heads[b], 0.0)
        rng_[b], brg[b] = _polar(p, site)
    res = run_konle(t, site, rng_, brg, range_std_m=30.0, bearing_std_rad=0.1 * DEG, maneuver_gate=np.inf)
    ok = res.initialized
    assert ok[:, 10:].all()
    np.testing.assert_allclose(res.speed_m_s[:, 5:], np.broadcast_to(speeds[:, None], (B, t.size - 5)),
                               atol=1e-6)
    np.testing.assert_allclose(wrap_angle(res.heading_rad[:, 5:] - heads[:, None]), 0.0, atol=1e-9)
    assert np.all(res.speed_var_m2_s2[:, 5:] > 0) and np.all(res.heading_var_rad2[:, 5:] > 0)


def test_constant_turn_rate_sign_and_value():
    t, s, site = _stream([(0.0, 0.0)], [5.0], [0.0], 400.0)
    out = {}
    for omega in (3.0 * DEG, -3.0 * DEG):
        p, h = _truth(t, np.array([0.0, 60e3]), 200.0, 90 * DEG, omega)
        r, b = _polar(p, site)
        res = run_konle(t, site, r[None], b[None], range_std_m=30.0, bearing_std_rad=0.1 * DEG)
        w = res.turn_rate_rad_s[0, 20:]
        assert np.all(np.sign(w) == np.sign(omega))
        np.testing.assert_allclose(w, omega, rtol=0.02)
        np.testing.assert_allclose(wrap_angle(res.heading_rad[0, 20:] - h[20:]), 0.0, atol=0.2 * DEG)
        np.testing.assert_allclose(res.speed_m_s[0, 20:], 200.0, rtol=0.005)  # chord-length bias < 0.3 %
        out[omega] = float(np.mean(w)) / DEG
    print("constant turn: mean estimated turn rate (deg/s) for +3/-3 deg/s:", out)


def _position_kf_heading(t, z, R, det, q):
    B, K = z.shape[:2]
    x, P = kalman.two_point_init(z[:, 0], R[:, 0], t[0], z[:, 1], R[:, 1], t[1])
    H = np.full((B, K), np.nan)
    for k in range(2, K):
        dt = np.full(B, t[k] - t[k - 1])
        x, P = kalman.predict(x, P, kalman.transition_cv(dt), kalman.process_noise(dt, q))
        u = kalman.update(x, P, np.nan_to_num(z[:, k]), R[:, k], det[:, k])
        x, P = u.x, u.P
        H[:, k] = np.arctan2(x[:, 2], x[:, 3])
    return H


def test_registration_bias_cancels_in_differentials():
    """Two radars (periods 4 s and 6 s); the far radar (index 1) is in coverage only every other minute; the
    near radar (index 0) has a 0.2 deg azimuth registration bias. Heading RMSE after 120 s, 40 runs."""
    sites = [(0.0, 0.0), (60e3, -20e3)]
    t, s, site = _stream(sites, [4.0, 6.0], [0.0, 1.0], 400.0)
    K = t.size
    B = 40
    heading, speed = 60.0 * DEG, 250.0
    p, _ = _truth(t, np.array([-30e3, 40e3]), speed, heading, 0.0)
    r_true, b_true = _polar(p, site)
    sr, sa = 40.0, 0.1 * DEG
    rng = np.random.default_rng(11)
    nr = sr * rng.standard_normal((B, K))
    na = sa * rng.standard_normal((B, K))
    det = np.broadcast_to(~((s == 1) & ((t // 60) % 2 == 1)), (B, K))
    late = t > 120.0
    res = {}
    for bias_deg in (0.0, 0.2):
        r = r_true + nr
        b = b_true + na + np.where(s == 0, bias_deg * DEG, 0.0)
        # straight-flight tuning (low turn-rate noise), as restrictive as the position KF's q = 0.5 m/s^2
        kon = run_konle(t, site, r, b, det, range_std_m=sr, bearing_std_rad=sa, q_turn_rad_s2=1e-4)
        z = site + r[..., None] * np.stack([np.sin(b), np.cos(b)], axis=-1)
        J = np.zeros((B, K, 2, 2))
        J[..., 0, 0], J[..., 0, 1] = np.sin(b), r * np.cos(b)
        J[..., 1, 0], J[..., 1, 1] = np.cos(b), -r * np.sin(b)
        R = J @ np.diag([sr**2, sa**2]) @ np.swapaxes(J, -1, -2)
        h_kf = _position_kf_heading(t, z, R, det, q=0.5)
        e_kon = wrap_angle(kon.heading_rad[:, late] - heading)
        e_kf = wrap_angle(h_kf[:, late] - heading)
        e_sp = kon.speed_m_s[:, late] - speed
        res[bias_deg] = dict(konle_heading_rmse_deg=float(np.sqrt(np.mean(e_kon**2)) / DEG),
                             kf_heading_rmse_deg=float(np.sqrt(np.mean(e_kf**2)) / DEG),
                             konle_speed_rmse_m_s=float(np.sqrt(np.mean(e_sp**2))))
    print("registration bias 0 / 0.2 deg on radar 0:", res)
    d_kon = res[0.2]["konle_heading_rmse_deg"] - res[0.0]["konle_heading_rmse_deg"]
    d_kf = res[0.2]["kf_heading_rmse_deg"] - res[0.0]["kf_heading_rmse_deg"]
    assert abs(d_kon) < 0.05
    assert d_kf > 0.2
    assert res[0.2]["konle_speed_rmse_m_s"] < 1.1 * res[0.0]["konle_speed_rmse_m_s"]


def test_noisy_turn_no_divergence():
    """200 m/s east, then a 3 deg/s right turn for 60 s (180 deg), then straight; one radar, T = 5 s."""
    T = 5.0
    t = np.arange(0.0, 500.0, T)
    p0 = np.array([-40e3, 60e3])
    pA, _ = _truth(np.minimum(t, 200.0), p0, 200.0, 90 * DEG, 0.0)  # straight leg, frozen after 200 s
    p200 = p0 + 200.0 * 200.0 * np.array([1.0, 0.0])
    pB, hB = _truth(np.clip(t - 200.0, 0.0, 60.0), p200, 200.0, 90 * DEG, 3 * DEG)  # turn, frozen after 260 s
    pC, _ = _truth(np.maximum(t - 260.0, 0.0), np.zeros(2), 200.0, 270 * DEG, 0.0)  # displacement after 260 s
    p = np.where((t < 200)[:, None], pA, pB + pC)
    h = np.where(t < 200, 90 * DEG, hB)
    site = np.zeros((t.size, 2))
    r0, b0 = _polar(p, site)
    rng = np.random.default_rng(2)
    B, sr, sa = 20, 40.0, 0.1 * DEG
    r = r0 + sr * rng.standard_normal((B, t.size))
    b = b0 + sa * rng.standard_normal((B, t.size))
    k = run_konle(t, site, r, b, range_std_m=sr, bearing_std_rad=sa)
    e = wrap_angle(k.heading_rad - h) / DEG
    seg = {n: float(np.sqrt(np.mean(e[:, (t >= a) & (t < c)] ** 2)))
           for n, (a, c) in dict(straight=(100, 200), turn=(200, 270), after=(270, 350), late=(350, 500)).items()}
    print("noisy 3 deg/s turn, Konle heading RMSE (deg):", seg)
    assert seg["turn"] < 10.0 and seg["late"] < 5.0 and seg["straight"] < 5.0
    assert np.all(np.abs(e[:, t > 350]) < 30.0)  # no 180-degree flips


def test_blend_speed_heading():
    x = np.array([[1.0, 2.0, 0.0, 100.0], [5.0, 6.0, 100.0, 0.0]])
    out = blend_speed_heading(x, np.array([200.0, np.nan]), np.array([np.pi / 2, 0.0]))
    h = 0.75 * np.pi / 2
    np.testing.assert_allclose(out[0], [1.0, 2.0, 175.0 * np.sin(h), 175.0 * np.cos(h)])
    np.testing.assert_allclose(out[1], x[1])
    # short arc across +-pi
    y = np.array([0.0, 0.0, np.sin(179 * DEG), np.cos(179 * DEG)])
    o = blend_speed_heading(y, 1.0, -179 * DEG, weight=0.5)
    assert np.isclose(abs(np.arctan2(o[2], o[3])), np.pi)


def test_batched_equals_per_track_with_misses():
    rng = np.random.default_rng(9)
    t, s, site = _stream([(0.0, 0.0), (30e3, 10e3)], [5.0, 7.0], [0.0, 3.0], 150.0)
    B, K = 4, t.size
    r = np.empty((B, K))
    b = np.empty((B, K))
    for i in range(B):
        p, _ = _truth(t, np.array([-20e3, 40e3]) + 1e3 * i, 150.0 + 30 * i, 0.5 * i, 0.01 * (i - 1.5))
        r[i], b[i] = _polar(p, site)
    r += 30.0 * rng.standard_normal((B, K))
    b += 1e-3 * rng.standard_normal((B, K))
    det = rng.random((B, K)) > 0.2
    full = run_konle(t, site, np.where(det, r, np.nan), b, det, range_std_m=30.0, bearing_std_rad=1e-3)
    for i in range(B):
        one = run_konle(t, site, r[i:i + 1], b[i:i + 1], det[i:i + 1], range_std_m=30.0, bearing_std_rad=1e-3)
        np.testing.assert_allclose(one.x, full.x[i:i + 1], rtol=1e-10, atol=1e-12, equal_nan=True)
        np.testing.assert_array_equal(one.initialized, full.initialized[i:i + 1])
