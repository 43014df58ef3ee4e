"""Scenarios (truth), radar and episodes: exact kinematics, noise statistics, determinism, validation."""

import numpy as np
import pytest
from scipy.integrate import solve_ivp

from radar_env.sim.catalog import FAMILIES, SCENARIO_NAMES, make_setup
from radar_env.sim.episode import draw_episode, stack_episodes
from radar_env.sim.radar import (Radar, RadarSite, atc_radar, bizup_radar, converted_covariance,
                             polar_from_cartesian, scan_schedule)
from radar_env.sim.scenario import (RandomScenarioConfig, ScenarioBuilder, Segment, SegmentScenario,
                                TrajectoryScenario, random_scenario)
from radar_env.common.units import DEG, G0_M_S2, KNOT_M_S


def _ode_truth(sc, t_eval):
    """Integrate the segment dynamics numerically (independent of the closed form)."""
    def rhs(t, s):
        i = min(np.searchsorted(sc._t0, t, side="right") - 1, len(sc.segments) - 1)
        w, a = sc._w[i], sc._a[i]
        sp = np.hypot(s[2], s[3])
        return [s[2], s[3], w * s[3] + a * s[2] / sp, -w * s[2] + a * s[3] / sp]
    knots = list(sc._t0) + [sc.duration_s]
    out = []
    x = sc._x0[0]
    for t0, t1 in zip(knots[:-1], knots[1:]):
        te = t_eval[(t_eval >= t0) & (t_eval < t1)]
        sol = solve_ivp(rhs, (t0, t1), x, t_eval=np.r_[te, t1], rtol=1e-11, atol=1e-8, first_step=1e-3,
                        max_step=1.0)
        out.append(sol.y.T[:-1])
        x = sol.y.T[-1]
    return np.concatenate(out)


def test_segment_scenario_matches_ode_integration():
    b = ScenarioBuilder(position_m=(1e3, -2e3), speed_kt=350, heading_deg=30)
    b.straight(40).turn(120, accel_g=4).change_speed(250, 3.0).turn(-200, rate_deg_s=3).straight(20)
    sc = b.build()
    t = np.linspace(0, sc.duration_s, 157)[:-1]
    np.testing.assert_allclose(sc.states_at(t), _ode_truth(sc, t), rtol=0, atol=2e-3)


def test_turn_builder_heading_change_and_direction():
    sc = ScenarioBuilder(speed_m_s=200, heading_deg=0).turn(90, accel_g=2).build()
    end = sc.final_state
    assert np.isclose(np.degrees(np.arctan2(end[2], end[3])), 90.0)          # right turn: north -> east
    assert np.isclose(sc.duration_s, 90 * DEG / (2 * G0_M_S2 / 200))
    acc = sc.accelerations_at(np.array([1.0]))[0]
    assert np.isclose(np.hypot(*acc), 2 * G0_M_S2)
    assert sc.turn_rates_at(np.array([1.0]))[0] > 0
    left = ScenarioBuilder(speed_m_s=200, heading_deg=0).turn(-90, rate_deg_s=3).build()
    assert np.isclose(np.degrees(np.arctan2(left.final_state[2], left.final_state[3])), -90.0)


def test_states_continuous_at_segment_boundaries():
    sc = make_setup("adrian_flower").scenario
    knots = sc._t0[1:]
    a, b = sc.states_at(knots - 1e-7), sc.states_at(knots)
    np.testing.assert_allclose(a, b, atol=1e-3)


@pytest.mark.parametrize("bad", [dict(duration_s=0), dict(duration_s=1, turn_rate_rad_s=0.1, accel_m_s2=1),
                                 dict(duration_s=np.nan)])
def test_segment_validation(bad):
    with pytest.raises(ValueError):
        Segment(**bad)


def test_speed_below_minimum_rejected():
    with pytest.raises(ValueError, match="below MIN_SPEED"):
        SegmentScenario([0, 0, 0, 50], [Segment(10, accel_m_s2=-5)])


def test_trajectory_scenario_reproduces_samples_and_matches_segments():
    sc = ScenarioBuilder(speed_kt=300, heading_deg=80).straight(30).turn(90, rate_deg_s=3).straight(30).build()
    t = np.arange(0, sc.duration_s, 1.0)
    s = sc.states_at(t)
    tr = TrajectoryScenario(t + 100.0, *s.T)  # shifted start: times re-based to 0
    np.testing.assert_allclose(tr.states_at(t), s, atol=1e-9)
    tm = t[:-1] + 0.5
    np.testing.assert_allclose(tr.states_at(tm)[:, :2], sc.states_at(tm)[:, :2], atol=0.05)
    np.testing.assert_allclose(tr.turn_rates_at(np.array([45.0])), 3 * DEG, rtol=0.02)
    assert not tr.maneuvering_at(np.array([10.0]))[0] and tr.maneuvering_at(np.array([45.0]))[0]


def test_trajectory_csv_errors_name_line_and_column(tmp_path):
    p = tmp_path / "t.csv"
    p.write_text("t_s,x_m,y_m,vx_m_s,vy_m_s\n0,0,0,100,0\n1,100,0,abc,0\n")
    with pytest.raises(ValueError, match=r"line 3, column 'vx_m_s'"):
        TrajectoryScenario.from_csv(p)
    p.write_text("t_s,x_m,y_m,vx_m_s\n0,0,0,100\n")
    with pytest.raises(ValueError, match="missing column"):
        TrajectoryScenario.from_csv(p)
    p.write_text("t_s,x_m,y_m,vx_m_s,vy_m_s\n0,0,0,100,0\n2,200,0,100,0\n1,300,0,100,0\n")
    with pytest.raises(ValueError, match="strictly increasing"):
        TrajectoryScenario.from_csv(p)
    p.write_text("t_s,x_m,y_m,vx_m_s,vy_m_s\n0,0,0,100,0\n2,200,0,100,0\n")
    assert TrajectoryScenario.from_csv(p).duration_s == 2.0


def test_random_scenario_deterministic_and_in_range():
    cfg = RandomScenarioConfig()
    for seed in range(20):
        a, sa = random_scenario(np.random.default_rng(seed), cfg)
        b, sb = random_scenario(np.random.default_rng(seed), cfg)
        t = np.arange(0, a.duration_s, 1.0)
        assert np.array_equal(a.states_at(t), b.states_at(t)) and np.array_equal(sa, sb)
        r, _, _ = polar_from_cartesian(a.states_at(t), sa)
        assert r.min() >= 10e3 - 1 and r.max() <= 150e3 + 1
        sp = np.hypot(*a.states_at(t)[:, 2:].T)
        assert sp.min() >= 100 * KNOT_M_S - 1e-6 and sp.max() <= 600 * KNOT_M_S + 1e-6
        acc = np.hypot(*a.accelerations_at(t).T)
        assert acc.max() <= 7 * G0_M_S2 + 1e-6
        assert a.duration_s >= cfg.min_duration_s


def test_random_config_rejects_bad_values():
    with pytest.raises(ValueError, match="speed_kt"):
        RandomScenarioConfig(speed_kt=(600, 100))
    with pytest.raises(ValueError, match="unknown RandomScenarioConfig key"):
        RandomScenarioConfig.from_dict({"speed_knots": (1, 2)})


def test_radar_site_validation_names_parameter():
    with pytest.raises(ValueError, match="detection_probability"):
        RadarSite(detection_probability=1.5)
    with pytest.raises(ValueError, match="scan_period_s"):
        RadarSite(scan_period_s=0)
    with pytest.raises(ValueError, match="unknown RadarSite"):
        RadarSite().replace(scan_period=3)


def test_polar_conventions():
    r, b, rdot = polar_from_cartesian(np.array([[1000.0, 0.0, 100.0, 0.0], [0.0, -1000.0, 0.0, 50.0]]), (0, 0))
    assert np.allclose(r, 1000) and np.allclose(b, [np.pi / 2, np.pi]) and np.allclose(rdot, [100.0, -50.0])


def test_radar_noise_statistics_and_converted_covariance():
    """Measured polar noise has the configured sigmas; the converted R matches the empirical covariance."""
    site = RadarSite(position_m=(0, 0), range_noise_std_m=50.0, bearing_noise_std_rad=0.2 * DEG,
                     radial_velocity_noise_std_m_s=3.0, scan_period_s=1.0)
    sc = SegmentScenario([30e3, 40e3, 0.0, 150.0], [Segment(1.0)])
    eps = [draw_episode(sc, Radar((site,)), np.random.default_rng(i)) for i in range(4000)]
    e_r = np.array([e.range_m[0] for e in eps]) - 50e3
    e_b = np.array([e.bearing_rad[0] for e in eps]) - np.arctan2(30e3, 40e3)
    e_v = np.array([e.radial_velocity_m_s[0] for e in eps]) - 150.0 * 40 / 50
    n = len(eps)
    for err, sig in ((e_r, 50.0), (e_b, 0.2 * DEG), (e_v, 3.0)):
        assert abs(err.mean()) < 4 * sig / np.sqrt(n)
        assert abs(err.std() / sig - 1) < 4 / np.sqrt(2 * n)
    z = np.array([e.z_m[0] for e in eps])
    emp = np.cov(z.T)
    R = converted_covariance(50e3, np.arctan2(30e3, 40e3), 50.0, 0.2 * DEG)
    np.testing.assert_allclose(emp, R, rtol=0.1, atol=0.1 * np.sqrt(R[0, 0] * R[1, 1]))


def test_registration_bias_shifts_measurements():
    sc = SegmentScenario([0.0, 50e3, 100.0, 0.0], [Segment(50.0)])
    base = atc_radar()
    biased = Radar((base.sites[0].replace(bearing_bias_rad=0.2 * DEG, range_bias_m=100.0),))
    a = draw_episode(sc, base, np.random.default_rng(3))
    b = draw_episode(sc, biased, np.random.default_rng(3))
    np.testing.assert_allclose(b.range_m - a.range_m, 100.0, atol=1e-6)
    np.testing.assert_allclose(b.bearing_rad - a.bearing_rad, 0.2 * DEG, atol=1e-12)


def test_episode_reproducible_and_detection_probability():
    s = make_setup("seed002_two_radars")
    a = draw_episode(s.scenario, s.radar, np.random.default_rng(7))
    b = draw_episode(s.scenario, s.radar, np.random.default_rng(7))
    for f in ("z_m", "R_m2", "radial_velocity_m_s", "truth"):
        assert np.array_equal(getattr(a, f), getattr(b, f), equal_nan=True)
    assert set(np.unique(a.site_index)) == {0, 1} and np.all(np.diff(a.t_s) >= 0)
    radar = Radar((s.radar.sites[0].replace(detection_probability=0.7), s.radar.sites[1]))
    rates = []
    for i in range(100):
        e = draw_episode(s.scenario, radar, np.random.default_rng(i))
        rates.append(e.detected[e.site_index == 0].mean())
        assert np.all(np.isnan(e.z_m[~e.detected])) and np.all(np.isfinite(e.z_m[e.detected]))
    assert abs(np.mean(rates) - 0.7) < 0.03


def test_scan_schedule_two_sites():
    r = Radar((RadarSite(scan_period_s=5.0), RadarSite(scan_period_s=4.0, first_scan_s=1.5)))
    t, i = scan_schedule(r, 20.0)
    assert list(t) == [0, 1.5, 5, 5.5, 9.5, 10, 13.5, 15, 17.5, 20] and list(i) == [0, 1, 0, 1, 1, 0, 1, 0, 1, 0]


def test_named_scenarios_and_presets():
    for name in SCENARIO_NAMES:
        s = make_setup(name, np.random.default_rng(0))
        e = draw_episode(s.scenario, s.radar, np.random.default_rng(0))
        # a family's flights are random, at least min_duration_s = 120 s (24 looks at 5 s); tests/test_families.py
        assert e.n_looks >= (24 if name in FAMILIES else 90) and np.all(np.isfinite(e.truth))
    bz = make_setup("bizup2002")
    assert bz.radar.sites[0].scan_period_s == 10 and 92 <= bz.scenario.duration_s / 10 + 1 <= 95
    assert np.isclose(bizup_radar(bearing_noise_deg=0.5).sites[0].bearing_noise_std_rad, 0.5 * DEG)
    kl = make_setup("kim_lee_accel").scenario
    sp = np.hypot(*kl.states_at(np.array([0.0, 35.0, 60.0, 100.0]))[:, 2:].T)
    np.testing.assert_allclose(sp, [120, 120 + 5 * G0_M_S2 * 10, 120 + 5 * G0_M_S2 * 10, 120], atol=1e-9)
    with pytest.raises(ValueError, match="unknown scenario"):
        make_setup("bizup")


def test_stack_episodes_pads_and_roundtrips():
    rng = np.random.default_rng(5)
    eps = []
    for _ in range(3):
        s = make_setup("random", rng)
        eps.append(draw_episode(s.scenario, s.radar, rng))
    b = stack_episodes(eps)
    assert b.t_s.shape[0] == 3 and b.valid.sum() == sum(e.n_looks for e in eps)
    e1 = b.episode(1)
    assert np.array_equal(e1.z_m, eps[1].z_m, equal_nan=True)
    assert not b.detected[~b.valid].any()
    # a few fields alone: the batch's arrays, padding included
    from radar_env.sim.episode import stack_fields
    assert len({e.n_looks for e in eps}) > 1                       # some padding to compare
    part = stack_fields(eps, ("t_s", "z_m", "R_m2", "detected"))
    for f, a in part.items():
        assert np.array_equal(a, getattr(b, f), equal_nan=True), f


def test_random_radar_ranges_and_reproducible():
    from radar_env.sim.catalog import RANDOM_RADAR_RANGES as R, random_radar
    n_two = 0
    for seed in range(200):
        r = random_radar(np.random.default_rng(seed), (1e3, 2e3))
        assert r.sites[0].position_m == (1e3, 2e3) and r.sites[0].first_scan_s == 0
        n_two += len(r.sites) == 2
        for s in r.sites:
            assert R["scan_period_s"][0] <= s.scan_period_s <= R["scan_period_s"][1]
            assert R["range_noise_std_m"][0] <= s.range_noise_std_m <= R["range_noise_std_m"][1]
            lo, hi = R["bearing_noise_std_deg"]
            assert lo * DEG <= s.bearing_noise_std_rad <= hi * DEG
            assert R["detection_probability"][0] <= s.detection_probability <= 1.0
        if len(r.sites) == 2:
            d = np.hypot(*(np.subtract(r.sites[1].position_m, r.sites[0].position_m)))
            assert 20e3 <= d <= 80e3
        assert r == random_radar(np.random.default_rng(seed), (1e3, 2e3))
    assert 40 <= n_two <= 80   # 30 % of 200 draws
    # random_radars flies the same flight as random for the same generator (the radar is drawn after the site)
    a = make_setup("random", np.random.default_rng(7))
    b = make_setup("random_radars", np.random.default_rng(7))
    assert a.scenario.duration_s == b.scenario.duration_s
    np.testing.assert_array_equal(a.radar.sites[0].position_m, b.radar.sites[0].position_m)


def test_random_radars_mixture_probability():
    from radar_env.sim.scenario import RandomScenarioConfig
    atc = make_setup("random", np.random.default_rng(0)).radar.sites[0]
    n_atc = 0
    for seed in range(100):
        r = make_setup("random_radars", np.random.default_rng(seed), RandomScenarioConfig(random_radar_probability=0.5)).radar
        n_atc += len(r.sites) == 1 and r.sites[0].scan_period_s == atc.scan_period_s and \
            r.sites[0].range_noise_std_m == atc.range_noise_std_m
    assert 35 <= n_atc <= 65
    with pytest.raises(ValueError, match="random_radar_probability"):
        RandomScenarioConfig(random_radar_probability=1.5)
