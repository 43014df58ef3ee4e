"""The env's one kernel (radar_env.envs.env_kernels) and what came with it: the closed-form refusal at build is a true
bound (it never refuses a configuration that can run), the cold-cache line, and the env's draws straight into the
tracker equal draw_episodes + Tracker.load."""

import numpy as np
import pytest
from gymnasium.utils import seeding

from radar_env.envs import env_kernels as ek
from radar_env.sim.catalog import FAMILIES, family_config
from radar_env.sim.draws import LookDrawer, _DEFAULT_CONFIG, draw_episodes, max_random_looks
from radar_env.sim.scenario import RandomScenarioConfig
from radar_env.filters.tracking import Tracker


@pytest.mark.parametrize("name, cfg", [("random", None), ("random_radars", None),
                                       ("random", RandomScenarioConfig(leg_duration_s=(30, 60), n_legs=(1, 2))),
                                       ("sharp_turns", None), ("short_tracks", None)])
def test_longest_flight_bound_holds_for_every_draw(name, cfg):
    """max_random_looks (the build-time refusal's closed form) is at least the looks of every drawn episode."""
    rc = family_config(name) if name in FAMILIES else (cfg or _DEFAULT_CONFIG)
    bound = max_random_looks(name, rc, None)
    batch = draw_episodes(name, None, cfg, [seeding.np_random(s)[0] for s in range(96)], warmup_scans=1)
    assert batch.n_looks.max() <= bound
    with pytest.raises(ValueError, match=f"warmup_scans={bound - 2}"):
        LookDrawer(name, None, cfg, bound - 2)   # needs bound + 1 looks: refused without drawing
    LookDrawer(name, None, cfg, bound - 3)       # needs exactly the bound: accepted


@pytest.mark.parametrize("scenario", ["random", "random_radars", "kim_lee_accel", "short_tracks"])
def test_drawing_into_the_tracker_equals_draw_episodes_and_load(scenario):
    rows = np.array([3, 0, 2], dtype=np.int64)
    rng_a = [seeding.np_random(s)[0] for s in (5, 6, 7)]
    rng_b = [seeding.np_random(s)[0] for s in (5, 6, 7)]
    a, b = Tracker(4), Tracker(4)
    LookDrawer.of(scenario, None, None, 12).draw(np.array([r.bit_generator.random_raw() for r in rng_a],
                                                          dtype=np.uint64), rows, a)
    batch = draw_episodes(scenario, None, None, rng_b, 12)
    b._put(rows, [batch.episode(i) for i in range(3)])
    n = b.n_looks[rows]
    np.testing.assert_array_equal(a.n_looks[rows], n)
    for j, r in enumerate(rows):
        la, lb = a._looks[r, :n[j]], b._looks[r, :n[j]]
        assert la.tobytes() == lb.tobytes()   # NaN plots included, bit for bit
        assert a.names[r] == b.names[r]


class _FakeCache:
    def __init__(self, index):
        self._cache_file = type("F", (), {"_load_index": lambda _self: index})()


class _FakeDispatcher:
    def __init__(self, index, overloads=None):
        self._cache, self.overloads = _FakeCache(index), overloads or {}


def test_cold_cache_line_is_printed_once_and_only_when_cold(monkeypatch, capsys):
    warm = {"sig": "file"}
    for d in (ek.k_env,):
        monkeypatch.setattr(d, "_cache", _FakeCache(warm), raising=False)
    from radar_env.sim import draws
    for d in (draws._random_rows, draws.k_fill_random_looks):
        monkeypatch.setattr(d, "_cache", _FakeCache(warm), raising=False)
    monkeypatch.setattr(ek, "_announced", False)
    ek.announce_compilation(_FakeDispatcher(warm))
    assert capsys.readouterr().err == ""          # warm: silent
    monkeypatch.setattr(ek, "_announced", False)
    ek.announce_compilation(_FakeDispatcher({}))
    err = capsys.readouterr().err
    assert "compiling the filter kernels (first run only" in err and err.count("\n") == 1
    ek.announce_compilation(_FakeDispatcher({}))
    assert capsys.readouterr().err == ""          # once per process
    monkeypatch.setattr(ek, "_announced", False)
    ek.announce_compilation(_FakeDispatcher({}, overloads={"sig": object()}))
    assert capsys.readouterr().err == ""          # compiled in this process already: nothing to compile
