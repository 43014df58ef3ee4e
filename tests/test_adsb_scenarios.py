"""ADS-B flights as scenarios in the env and the evaluation suite."""

import gymnasium as gym
import numpy as np
import pytest

import radar_env  # noqa: F401
from agents.evaluation.suites import draw_suite
from radar_env.sim.adsb import list_flights
from radar_env.sim.adsb_scenarios import AdsbPool, resolve_adsb
from radar_env.sim.radar import polar_from_cartesian


def test_named_flight_is_a_setup_with_the_radar_in_range():
    s = resolve_adsb("adsb:bornholm")
    t = np.arange(0, s.scenario.duration_s, 10.0)
    r, _, _ = polar_from_cartesian(s.scenario.states_at(t), s.radar.sites[0].position_m)
    assert r.min() >= 20e3 - 1 and np.all(np.isfinite(r))
    assert s.scenario.name == "adsb:bornholm"
    with pytest.raises(ValueError, match="unknown ADS-B flight"):
        resolve_adsb("adsb:atlantis")
    with pytest.raises(ValueError, match="adsb:<flight>"):
        resolve_adsb("adsb:")


def test_env_runs_on_a_flight_and_on_the_pool():
    env = gym.make("RadarTrack-v0", scenario="adsb:bornholm")
    obs, info = env.reset(seed=0)
    for _ in range(50):
        obs, r, term, trunc, info = env.step(6)
    assert np.all(np.isfinite(obs)) and np.isfinite(r)
    pool_env = gym.make("RadarTrack-v0", scenario="adsb_calibration")
    seen = set()
    for seed in range(6):
        pool_env.reset(seed=seed)
        seen.add(pool_env.unwrapped._core.tracker.names[0])
    assert len(seen) >= 2 and all(n.startswith("adsb:") for n in seen)


def test_suite_flies_every_flight_once():
    n = len(list_flights())
    eps = draw_suite("adsb_calibration", n, seed=5)
    assert sorted(e.name for e in eps) == sorted(f"adsb:{f}" for f in list_flights())
    assert len(AdsbPool().flights) == n
