"""radar_env/applications.py: closest approach, conflict warning, intercept course and simulation, encounters.

Checks are against brute force on fine time grids, exact noise-free propagation and the law-of-sines construction
of seed 002 (eqs 23-29, with the quadrant fixed). All randomness comes from seeded numpy Generators.
"""

import warnings

import numpy as np
import pytest

from radar_env import applications as ap
from radar_env.common.units import KNOT_M_S, NM_M


def _random_pairs(rng, B):
    p1 = rng.uniform(-5e4, 5e4, (B, 2))
    p2 = rng.uniform(-5e4, 5e4, (B, 2))
    v1 = rng.uniform(-300, 300, (B, 2))
    v2 = rng.uniform(-300, 300, (B, 2))
    return p1, v1, p2, v2


def _brute_cpa(p1, v1, p2, v2, t_max, n=200001):
    tg = np.linspace(0.0, t_max, n)
    rel = (p2 - p1)[:, None, :] + (v2 - v1)[:, None, :] * tg[None, :, None]
    d = np.hypot(rel[..., 0], rel[..., 1])
    i = np.argmin(d, axis=1)
    return tg[i], d[np.arange(len(i)), i], tg[1] - tg[0]


def test_closest_approach_matches_brute_force():
    rng = np.random.default_rng(1)
    p1, v1, p2, v2 = _random_pairs(rng, 40)
    t, d = ap.closest_approach(p1, v1, p2, v2)
    assert t.shape == d.shape == (40,)
    t_max = 2000.0
    assert np.all(t < t_max)  # grid covers all optima (|dp| <= 1.5e5 m, |dv| random)
    tb, db, step = _brute_cpa(p1, v1, p2, v2, t_max)
    rel_speed = np.hypot(*(v2 - v1).T)
    # the grid minimum can only be >= the true minimum, and within step*|dv| of it
    assert np.all(db >= d - 1e-6)
    assert np.all(db - d <= step * rel_speed + 1e-6)
    assert np.all(np.abs(tb - t) <= step + 1e-9)
    assert np.any(t == 0.0) and np.any(t > 0.0)  # both diverging and converging cases drawn


def test_closest_approach_diverging_and_parallel():
    t, d = ap.closest_approach([0.0, 0.0], [100.0, 0.0], [1000.0, 0.0], [200.0, 0.0])  # opening
    assert t == 0.0 and d == pytest.approx(1000.0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        t, d = ap.closest_approach(np.zeros((3, 2)), np.full((3, 2), 50.0), [[3.0, 4.0]] * 3, np.full((3, 2), 50.0))
    assert np.all(t == 0.0) and np.allclose(d, 5.0) and np.all(np.isfinite(d))
    # head-on: meet exactly
    t, d = ap.closest_approach([0.0, 0.0], [0.0, 100.0], [0.0, 10000.0], [0.0, -100.0])
    assert t == pytest.approx(50.0) and d == pytest.approx(0.0, abs=1e-9)
    assert np.ndim(t) == 0


def test_closest_approach_broadcasts_single_against_batch():
    rng = np.random.default_rng(2)
    p1, v1, p2, v2 = _random_pairs(rng, 5)
    t, d = ap.closest_approach(p1[0], v1[0], p2, v2)
    for i in range(5):
        ti, di = ap.closest_approach(p1[0], v1[0], p2[i], v2[i])
        assert t[i] == ti and d[i] == di


def test_closest_approach_rejects_bad_shape():
    with pytest.raises(ValueError):
        ap.closest_approach(np.zeros(3), np.zeros(3), np.zeros(3), np.zeros(3))


def test_conflict_warning_threshold_and_lookahead_edges():
    # aircraft 2 passes aircraft 1 at CPA distance 1000 m at t = 100 s
    p1, v1 = np.array([0.0, 0.0]), np.array([0.0, 0.0])
    p2, v2 = np.array([-20000.0, 1000.0]), np.array([200.0, 0.0])
    w = ap.conflict_warning(p1, v1, p2, v2, threshold_m=1000.0 + 1e-6, lookahead_s=200.0)
    assert w.warning and w.t_cpa_s == pytest.approx(100.0) and w.d_cpa_m == pytest.approx(1000.0)
    assert not ap.conflict_warning(p1, v1, p2, v2, threshold_m=1000.0 - 1e-6, lookahead_s=200.0).warning
    assert not ap.conflict_warning(p1, v1, p2, v2, threshold_m=1000.0, lookahead_s=200.0).warning  # strict
    # threshold 2000 m: separation drops below it at t = 100 - sqrt(3)*1000/200 s
    t_in = 100.0 - np.sqrt(3.0) * 5.0
    w = ap.conflict_warning(p1, v1, p2, v2, threshold_m=2000.0, lookahead_s=t_in + 1e-3)
    assert w.warning and w.t_entry_s == pytest.approx(t_in, rel=1e-12)
    assert w.d_min_window_m < 2000.0
    w = ap.conflict_warning(p1, v1, p2, v2, threshold_m=2000.0, lookahead_s=t_in - 1e-3)
    assert not w.warning and w.t_entry_s == pytest.approx(t_in, rel=1e-12)
    # diverging: passed in the past -> no warning, no entry (the paper's discriminant test would fire)
    w = ap.conflict_warning(p1, v1, [20000.0, 1000.0], v2, threshold_m=2000.0, lookahead_s=1e4)
    assert not w.warning and np.isinf(w.t_entry_s) and w.t_cpa_s == 0.0
    # already inside
    w = ap.conflict_warning(p1, v1, [10.0, 0.0], v2, threshold_m=2000.0, lookahead_s=0.0)
    assert w.warning and w.t_entry_s == 0.0
    with pytest.raises(ValueError):
        ap.conflict_warning(p1, v1, p2, v2, 1.0, -1.0)


def test_conflict_warning_batch_matches_brute_force():
    rng = np.random.default_rng(3)
    p1, v1, p2, v2 = _random_pairs(rng, 200)
    thr, la = 8000.0, 120.0
    w = ap.conflict_warning(p1, v1, p2, v2, thr, la)
    _, db, _ = _brute_cpa(p1, v1, p2, v2, la, n=20001)
    margin = np.abs(db - thr) > 20.0  # avoid grid-resolution ties
    assert np.array_equal(w.warning[margin], (db < thr)[margin])
    assert w.warning.sum() > 5 and (~w.warning).sum() > 5
    # entry time is where the separation equals the threshold
    hit = np.isfinite(w.t_entry_s) & (w.t_entry_s > 0)
    rel = (p2 - p1) + (v2 - v1) * w.t_entry_s[:, None]
    assert np.allclose(np.hypot(*rel[hit].T), thr, rtol=1e-9)


def _propagate(p, v, t):
    return p + v * np.asarray(t)[..., None]


def test_intercept_course_meets_target_noise_free():
    rng = np.random.default_rng(4)
    B = 300
    pi_ = rng.uniform(-5e4, 5e4, (B, 2))
    pt = rng.uniform(-5e4, 5e4, (B, 2))
    vt = rng.uniform(-300, 300, (B, 2))
    s = rng.uniform(100, 500, B)
    c = ap.intercept_course(pi_, s, pt, vt)
    assert c.feasible.sum() > 100 and (~c.feasible).sum() > 5
    f = c.feasible
    vi = s[:, None] * np.stack([np.sin(c.heading_rad), np.cos(c.heading_rad)], -1)
    ti = c.time_to_intercept_s[f]
    miss = np.hypot(*(_propagate(pi_[f], vi[f], ti) - _propagate(pt[f], vt[f], ti)).T)
    assert np.max(miss) < 1e-6
    # earliest: before t_int the interceptor on any heading cannot reach the target, i.e. |dp + vt t| > s t
    tt = c.time_to_intercept_s[f] * rng.uniform(0.0, 0.999, f.sum())
    gap = np.hypot(*_propagate(pt[f] - pi_[f], vt[f], tt).T) - s[f] * tt
    assert np.all(gap > 0)
    # infeasible: no intercept at any time on a grid, heading at the target, time inf
    nf = ~f
    assert np.all(np.isinf(c.time_to_intercept_s[nf]))
    assert np.allclose(c.heading_rad[nf], np.arctan2(*(pt - pi_)[nf].T))
    tg = np.linspace(0, 5000, 5001)
    rel = (pt - pi_)[nf][:, None, :] + vt[nf][:, None, :] * tg[None, :, None]
    assert np.all(np.hypot(rel[..., 0], rel[..., 1]) - s[nf][:, None] * tg > 0)


def test_intercept_course_infeasible_target_faster_opening():
    c = ap.intercept_course([0.0, 0.0], 200.0, [0.0, 10000.0], [0.0, 300.0])
    assert not c.feasible and np.isinf(c.time_to_intercept_s) and c.heading_rad == pytest.approx(0.0)
    assert not np.isnan(c.time_to_intercept_s)
    # equal speed, tail chase: never; equal speed head-on: meet half-way
    assert not ap.intercept_course([0.0, 0.0], 300.0, [0.0, 1e4], [0.0, 300.0]).feasible
    c = ap.intercept_course([0.0, 0.0], 300.0, [0.0, 1e4], [0.0, -300.0])
    assert c.feasible and c.time_to_intercept_s == pytest.approx(1e4 / 600.0) and c.heading_rad == 0.0
    # faster target crossing close in front of the interceptor is catchable (two roots; earliest taken)
    c = ap.intercept_course([0.0, 0.0], 200.0, [-5000.0, 1000.0], [300.0, 0.0])
    assert c.feasible
    vi = 200.0 * np.array([np.sin(c.heading_rad), np.cos(c.heading_rad)])
    t = c.time_to_intercept_s
    assert np.hypot(*(vi * t - (np.array([-5000.0, 1000.0]) + np.array([300.0, 0.0]) * t))) < 1e-6
    with pytest.raises(ValueError):
        ap.intercept_course([0.0, 0.0], 0.0, [1.0, 1.0], [0.0, 0.0])


def test_intercept_course_agrees_with_paper_law_of_sines():
    """Seed 002 eqs 23-29 with gamma from atan2 and the lead on the side the target is moving to."""
    rng = np.random.default_rng(5)
    B = 100
    pi_ = rng.uniform(-5e4, 5e4, (B, 2))
    pt = rng.uniform(-5e4, 5e4, (B, 2))
    vt = rng.uniform(-200, 200, (B, 2))
    s = rng.uniform(300, 500, B)  # interceptor faster: always feasible
    c = ap.intercept_course(pi_, s, pt, vt)
    assert np.all(c.feasible)
    D = np.hypot(*(pt - pi_).T)
    vT = np.hypot(*vt.T)
    beta = np.arccos(np.sum((pi_ - pt) * vt, 1) / (D * vT))  # eq 26
    tau = np.arcsin(vT / s * np.sin(beta))  # eqs 24-25
    gamma = np.arctan2(*(pt - pi_).T)
    side = np.sign(vt[:, 0] * np.cos(gamma) - vt[:, 1] * np.sin(gamma))  # clockwise component of vt
    alpha = gamma + side * tau
    assert np.allclose(np.angle(np.exp(1j * (alpha - c.heading_rad))), 0.0, atol=1e-9)
    # the paper's literal eq 29, acos(dy/D) - tau, is wrong for targets west of the interceptor
    west = (pt - pi_)[:, 0] < 0
    literal = np.arccos((pt - pi_)[:, 1] / D) - tau
    err = np.abs(np.angle(np.exp(1j * (literal - c.heading_rad))))
    assert np.all(err[west] > 1e-3)


def _straight_target(B, K, dt, rng):
    t = np.arange(K) * dt
    p0 = np.stack([rng.uniform(20e3, 40e3, B), rng.uniform(20e3, 40e3, B)], -1)
    h = rng.uniform(-np.pi, np.pi, B)
    v = 200.0 * np.stack([np.sin(h), np.cos(h)], -1)
    truth = p0[:, None, :] + v[:, None, :] * t[None, :, None]
    states = np.concatenate([truth, np.broadcast_to(v[:, None, :], truth.shape)], -1)
    return t, truth, states


def test_simulate_intercept_perfect_track_captures():
    rng = np.random.default_rng(6)
    t, truth, states = _straight_target(50, 80, 5.0, rng)
    r = ap.simulate_intercept(truth, states, t, [0.0, 0.0], 400.0, capture_radius_m=50.0)
    assert r.miss_distance_m.shape == (50,) and r.interceptor_xy_m.shape == (50, 80, 2)
    assert np.max(r.miss_distance_m) < 1e-6
    assert np.all(np.isfinite(r.capture_time_s))
    # capture time equals the one-shot intercept time (minus the radius over the closing speed, bounded)
    c = ap.intercept_course(np.zeros(2), 400.0, truth[:, 0], states[:, 0, 2:])
    assert np.all(r.capture_time_s <= c.time_to_intercept_s + 1e-9)
    assert np.all(r.capture_time_s >= c.time_to_intercept_s - 50.0 / 200.0 - 1e-9)
    # single (K, 2) case agrees with row 0
    r0 = ap.simulate_intercept(truth[0], states[0], t, [0.0, 0.0], 400.0, 50.0)
    assert r0.miss_distance_m == r.miss_distance_m[0] and r0.capture_time_s == r.capture_time_s[0]


def test_simulate_intercept_per_row_scan_clocks_equal_one_row_at_a_time():
    """times_s (B, K): every row flown on its own clock gives, bit for bit, what that row gives alone."""
    rng = np.random.default_rng(7)
    t, truth, states = _straight_target(6, 40, 5.0, rng)
    times = t[None] + rng.uniform(0.0, 4.0, (6, 1)) + np.cumsum(rng.uniform(0.0, 0.5, (6, 40)), axis=1)
    noisy = states + rng.normal(0.0, 30.0, states.shape)
    start = rng.uniform(-1e3, 1e3, (6, 2))
    r = ap.simulate_intercept(truth, noisy, times, start, 400.0, 50.0)
    for b in range(6):
        rb = ap.simulate_intercept(truth[b], noisy[b], times[b], start[b], 400.0, 50.0)
        assert rb.miss_distance_m == r.miss_distance_m[b] and rb.capture_time_s == r.capture_time_s[b]
        assert np.array_equal(rb.interceptor_xy_m, r.interceptor_xy_m[b])
    with pytest.raises(ValueError, match="times_s"):
        ap.simulate_intercept(truth, noisy, times[..., None], start, 400.0, 50.0)
    # rows of different lengths padded to one K: each equals its unpadded self
    n = np.array([40, 2, 17, 33, 40, 9])
    rp = ap.simulate_intercept(truth, noisy, times, start, 400.0, 50.0, n_looks=n)
    for b in range(6):
        rb = ap.simulate_intercept(truth[b, :n[b]], noisy[b, :n[b]], times[b, :n[b]], start[b], 400.0, 50.0)
        assert rb.miss_distance_m == rp.miss_distance_m[b] and rb.capture_time_s == rp.capture_time_s[b]
        assert np.array_equal(rb.interceptor_xy_m, rp.interceptor_xy_m[b, :n[b]])
        assert np.array_equal(rb.feasible, rp.feasible[b, :n[b] - 1]) and not rp.feasible[b, n[b] - 1:].any()
    with pytest.raises(ValueError, match="n_looks"):
        ap.simulate_intercept(truth, noisy, times, start, 400.0, 50.0, n_looks=np.full(6, 1))


def test_simulate_intercept_noisy_track_misses_more():
    rng = np.random.default_rng(7)
    t, truth, states = _straight_target(200, 80, 5.0, rng)
    r_clean = ap.simulate_intercept(truth, states, t, [0.0, 0.0], 400.0, 50.0)
    noisy_small = states + rng.normal(0, 1, states.shape) * np.array([30.0, 30.0, 3.0, 3.0])
    noisy_large = states + rng.normal(0, 1, states.shape) * np.array([300.0, 300.0, 30.0, 30.0])
    r_small = ap.simulate_intercept(truth, noisy_small, t, [0.0, 0.0], 400.0, 50.0)
    r_large = ap.simulate_intercept(truth, noisy_large, t, [0.0, 0.0], 400.0, 50.0)
    m0, m1, m2 = (r.miss_distance_m.mean() for r in (r_clean, r_small, r_large))
    assert m0 < 1e-6 < m1 < m2
    assert np.mean(np.isfinite(r_large.capture_time_s)) < np.mean(np.isfinite(r_clean.capture_time_s))


def test_simulate_intercept_pure_pursuit_when_infeasible():
    # target faster and running away: never feasible, interceptor flies at it, miss = initial gap grows
    t = np.arange(11) * 1.0
    truth = np.stack([np.zeros(11), 1000.0 + 300.0 * t], -1)
    states = np.concatenate([truth, np.tile([0.0, 300.0], (11, 1))], -1)
    r = ap.simulate_intercept(truth, states, t, [0.0, 0.0], 200.0, 10.0)
    assert not r.feasible.any()
    assert np.allclose(r.interceptor_xy_m[:, 0], 0.0) and np.allclose(r.interceptor_xy_m[:, 1], 200.0 * t)
    assert r.miss_distance_m == pytest.approx(1000.0) and np.isinf(r.capture_time_s)


@pytest.mark.parametrize("conflict", [True, False])
def test_two_aircraft_encounter_prescribed_cpa(conflict):
    rng = np.random.default_rng(8)
    e = ap.two_aircraft_encounter(rng, conflict, n=500, t_cpa_s=240.0)
    cpa = ap.closest_approach(e.state1[:, :2], e.state1[:, 2:], e.state2[:, :2], e.state2[:, 2:])
    assert np.allclose(cpa.t_cpa_s, 240.0, rtol=1e-9)
    assert np.allclose(cpa.d_cpa_m, e.d_cpa_m, atol=1e-6)
    if conflict:
        assert np.all(cpa.d_cpa_m < NM_M)
    else:
        assert np.all(cpa.d_cpa_m > 5 * NM_M)
    for st in (e.state1, e.state2):
        spd = np.hypot(st[:, 2], st[:, 3])
        assert np.all((spd >= 100 * KNOT_M_S) & (spd <= 600 * KNOT_M_S))
    cross = np.abs(e.crossing_angle_rad)
    assert np.all(cross >= np.deg2rad(15) - 1e-12) and np.any(e.crossing_angle_rad < 0)
    h1 = np.arctan2(e.state1[:, 2], e.state1[:, 3])
    h2 = np.arctan2(e.state2[:, 2], e.state2[:, 3])
    assert np.allclose(np.angle(np.exp(1j * (h2 - h1 - e.crossing_angle_rad))), 0.0, atol=1e-9)
    w = ap.conflict_warning(e.state1[:, :2], e.state1[:, 2:], e.state2[:, :2], e.state2[:, 2:], NM_M, 300.0)
    assert np.all(w.warning == conflict)


def test_two_aircraft_encounter_seeded_and_validated():
    a = ap.two_aircraft_encounter(np.random.default_rng(9), True, n=3)
    b = ap.two_aircraft_encounter(np.random.default_rng(9), True, n=3)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
    with pytest.raises(TypeError):
        ap.two_aircraft_encounter(9, True)
    with pytest.raises(ValueError):
        ap.two_aircraft_encounter(np.random.default_rng(0), True, crossing_angle_range_rad=(0.0, 1.0))


def test_simulate_intercept_miss_is_min_over_simulated_interval_only():
    # head-on, closing at 500 m/s from 10 km, but only 10 s simulated: the gap at the end is 5 km
    t = np.arange(11) * 1.0
    truth = np.stack([np.zeros(11), 10000.0 - 100.0 * t], -1)
    states = np.concatenate([truth, np.tile([0.0, -100.0], (11, 1))], -1)
    r = ap.simulate_intercept(truth, states, t, [0.0, 0.0], 400.0, 10.0)
    assert r.miss_distance_m == pytest.approx(5000.0) and np.isinf(r.capture_time_s)


def test_simulate_intercept_matches_dense_sampling():
    rng = np.random.default_rng(10)
    t, truth, states = _straight_target(20, 40, 5.0, rng)
    noisy = states + rng.normal(0, 1, states.shape) * np.array([300.0, 300.0, 30.0, 30.0])
    r_cap = 100.0
    r = ap.simulate_intercept(truth, noisy, t, [0.0, 0.0], 400.0, r_cap)
    tg = np.linspace(t[0], t[-1], 39 * 2000 + 1)
    step = tg[1] - tg[0]
    d = np.empty((20, tg.size))
    for b in range(20):
        ix = np.interp(tg, t, r.interceptor_xy_m[b, :, 0]) - np.interp(tg, t, truth[b, :, 0])
        iy = np.interp(tg, t, r.interceptor_xy_m[b, :, 1]) - np.interp(tg, t, truth[b, :, 1])
        d[b] = np.hypot(ix, iy)
    dmin = d.min(1)
    assert np.all(dmin >= r.miss_distance_m - 1e-6)
    assert np.all(dmin - r.miss_distance_m <= 600.0 * step + 1e-6)
    hit = d <= r_cap
    first = np.where(hit.any(1), tg[np.argmax(hit, 1)], np.inf)
    fin = np.isfinite(first)
    assert fin.sum() > 5 and (~fin).sum() > 0
    assert np.all(np.isfinite(r.capture_time_s[fin]))
    assert np.all(np.abs(first[fin] - r.capture_time_s[fin]) <= step + 1e-9)
    # captures the grid missed can only be grazing ones
    grazing = np.isfinite(r.capture_time_s) & ~fin
    assert np.all(dmin[grazing] - r_cap < 600.0 * step)
