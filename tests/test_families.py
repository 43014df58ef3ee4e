"""Held-out family suites (radar_env.sim.catalog.FAMILIES, the ADS-B split) and the RandomScenarioConfig fields they
use: every drawn flight is of its family's kind, the kernel and the per-episode drawer agree in distribution, the
default stream is untouched by the new fields, and misuse is refused."""

import numpy as np
import pytest
from scipy.stats import ks_2samp

from agents.evaluation.suites import HELDOUT_FAMILY_SUITES, draw_suite
from radar_env.sim.adsb import list_flights
from radar_env.sim.adsb_scenarios import split_flights
from radar_env.sim.catalog import FAMILIES, SCENARIO_NAMES, family_config, make_setup
from radar_env.sim.draws import draw_episodes, random_scenarios
from radar_env.sim.episode import _ARRAY_FIELDS
from radar_env.sim.scenario import RandomScenarioConfig
from radar_env.common.units import DEG, G0_M_S2, KNOT_M_S

from test_draws import _old_draw, _rngs, _same, _stats

N = 60


def _flights(name, n=N):
    out = random_scenarios(name, _rngs(range(n)))
    assert all(status == 0 for _, _, _, status in out)
    return [sc for sc, _, _, _ in out]


def _maneuvers(sc):
    """(turn segments, speed-change segments) of a flight."""
    turns = [s for s in sc.segments if s.turn_rate_rad_s != 0]
    changes = [s for s in sc.segments if s.accel_m_s2 != 0]
    return turns, changes


def test_families_are_names_of_the_catalog_and_held_out_suites():
    assert set(FAMILIES) <= set(SCENARIO_NAMES)
    assert set(HELDOUT_FAMILY_SUITES) == set(FAMILIES) | {"adsb_heldout"}


def test_start_maneuver_begins_during_the_track_start():
    for sc in _flights("start_maneuver"):
        first, second = sc.segments[:2]
        assert first.turn_rate_rad_s == 0 and first.accel_m_s2 == 0 and 5.0 <= first.duration_s <= 45.0
        assert second.turn_rate_rad_s != 0 and abs(second.turn_rate_rad_s) * second.duration_s >= 30 * DEG - 1e-9
    for e in draw_suite("start_maneuver", 30):   # the track start (2 hits + 12 looks) lasts past the turn's onset
        assert e.t_s[13] - e.t_s[0] > 45.0


def test_short_tracks_have_under_40_looks():
    eps = draw_suite("short_tracks", 80)
    n = np.array([e.n_looks for e in eps])
    assert n.max() < 40 and n.min() >= 15
    assert all(sc.duration_s <= 190.0 + 1e-9 for sc in _flights("short_tracks"))


def test_sharp_turns_are_above_6_g():
    for sc in _flights("sharp_turns"):
        turns, _ = _maneuvers(sc)
        v = np.hypot(*sc.states_at(np.array([0.0]))[0, 2:])
        assert turns and v >= 350 * KNOT_M_S - 1e-6
        for s in turns:   # speed is constant (speed changes keep the 350-600 kt range) -> |w| v is the g load
            t_mid = sum(x.duration_s for x in sc.segments[:sc.segments.index(s)]) + 0.5 * s.duration_s
            speed = np.hypot(*sc.states_at(np.array([t_mid]))[0, 2:])
            assert 6.0 - 1e-9 <= abs(s.turn_rate_rad_s) * speed / G0_M_S2 <= 9.0 + 1e-9


def test_slow_orbits_and_speed_changes():
    for sc in _flights("slow_orbits"):
        turns, changes = _maneuvers(sc)
        assert not changes and turns
        v = np.hypot(*sc.states_at(np.array([0.0]))[0, 2:])
        assert v <= 180 * KNOT_M_S + 1e-6
        # every full turn 360-720 deg (the last one may be cut where the flight leaves the radar's range)
        assert all(359.999 <= abs(s.turn_rate_rad_s) * s.duration_s / DEG <= 720.0 + 1e-6 for s in turns[:-1])
    n_changes = 0
    for sc in _flights("speed_changes"):
        turns, changes = _maneuvers(sc)
        assert not turns
        n_changes += len(changes)
        assert all(0.1 * G0_M_S2 - 1e-9 <= abs(s.accel_m_s2) <= 1.0 * G0_M_S2 + 1e-9 for s in changes)
    assert n_changes >= N   # at least one speed change per flight on average (2-5 maneuvers each)


@pytest.mark.parametrize("name", ["start_maneuver", "speed_changes", "short_tracks"])
def test_family_kernel_equals_the_per_episode_drawer_in_distribution(name):
    """Two-sample KS tests (300 episodes each, fixed seeds): the batched kernel and scenario.random_scenario
    (through make_setup) draw the same family."""
    n = 300
    new = [_stats(e) for e in (draw_episodes(name, None, None, _rngs(range(n))).episode(i) for i in range(n))]
    old = [_stats(_old_draw(name, np.random.default_rng(10_000 + i))) for i in range(n)]
    for k in [k for k in new[0] if k not in ("pd_realised", "period_s", "sites", "range_noise_m")]:
        a, b = np.array([s[k] for s in new], float), np.array([s[k] for s in old], float)
        if np.ptp(a) == 0 and np.ptp(b) == 0:
            assert a[0] == b[0], k
            continue
        assert ks_2samp(a, b).pvalue > 1e-3, (k, a.mean(), b.mean())


def test_new_fields_at_their_defaults_keep_the_random_stream():
    """first_leg_s = leg_duration_s, turn_probability = 1 and a non-binding max_duration_s draw exactly the
    default episodes (the extra draw of a skippable turn is only made when turns can be skipped)."""
    seeds = range(20)
    base = draw_episodes("random", None, None, _rngs(seeds))
    cfg = RandomScenarioConfig(first_leg_s=(30.0, 300.0), turn_probability=1.0, max_duration_s=1e5)
    same = draw_episodes("random", None, cfg, _rngs(seeds))
    for f in _ARRAY_FIELDS + ["valid", "n_looks"]:
        assert _same(getattr(base, f), getattr(same, f)), f
    other = draw_episodes("random", None, RandomScenarioConfig(turn_probability=0.5), _rngs(seeds))
    assert not _same(base.t_s, other.t_s) or not _same(base.truth, other.truth)


def test_family_draws_are_reproducible_and_named():
    a, b = draw_suite("sharp_turns", 5), draw_suite("sharp_turns", 5)
    assert all(np.array_equal(x.z_m, y.z_m, equal_nan=True) for x, y in zip(a, b))
    assert {e.name for e in a} == {"sharp_turns"}
    c = draw_suite("slow_orbits", 5)   # every family its own stream
    assert not np.array_equal(a[0].truth[:3], c[0].truth[:3])
    s = make_setup("sharp_turns", np.random.default_rng(0))
    assert s.name == "sharp_turns" and s.radar.sites[0].scan_period_s == 5.0


def test_family_refuses_a_random_config():
    with pytest.raises(ValueError, match="random_config.*'sharp_turns' is a held-out family"):
        draw_episodes("sharp_turns", None, RandomScenarioConfig(), _rngs([0]))
    import gymnasium as gym
    import radar_env  # noqa: F401
    with pytest.raises(ValueError, match="random_config"):
        gym.make("RadarTrack-v0", scenario="slow_orbits", random_config={"speed_kt": [100, 200]})
    env = gym.make("RadarTrack-v0", scenario="short_tracks")
    obs, info = env.reset(seed=3)
    assert np.all(np.isfinite(obs))
    env.close()


@pytest.mark.parametrize("kw, msg", [
    ({"first_leg_s": (0.0, 10.0)}, "first_leg_s"),
    ({"first_leg_s": (50.0, 10.0)}, "first_leg_s"),
    ({"first_leg_s": "long"}, "first_leg_s"),
    ({"turn_probability": 1.5}, "turn_probability"),
    ({"turn_probability": -0.1}, "turn_probability"),
    ({"max_duration_s": 0.5}, "max_duration_s"),
    ({"max_duration_s": 100.0}, "max_duration_s must be >= min_duration_s"),
])
def test_new_config_fields_are_checked(kw, msg):
    with pytest.raises(ValueError, match=msg):
        RandomScenarioConfig(**kw)


def test_family_configs_are_valid_and_documented():
    import radar_env.sim.catalog as catalog
    for name in FAMILIES:
        assert isinstance(family_config(name), RandomScenarioConfig)
        assert f"``{name}``" in catalog.__doc__


def test_adsb_split_is_a_partition_and_each_suite_flies_its_flights_once():
    dev, held = split_flights("adsb_dev"), split_flights("adsb_heldout")
    assert sorted(dev + held) == sorted(list_flights()) and not set(dev) & set(held)
    assert len(dev) == len(held) == len(list_flights()) // 2
    eps = draw_suite("adsb_heldout", len(held))
    assert sorted(e.name for e in eps) == sorted(f"adsb:{f}" for f in held)


def test_cli_runs_a_family_by_name(capsys):
    from agents.evaluation.evaluate import main
    main(["--scenario", "speed_changes", "--runs", "3", "--trackers", "imm2,kf_tuned", "--no-plots"])
    out = capsys.readouterr().out
    assert "speed_changes: 3 runs" in out
