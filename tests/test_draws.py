"""radar_env.sim.draws: batched == per-row, reproducibility, the padding of stack_episodes, the kernels' truth and
placement against the reference code, plot statistics, and the random distributions against the per-episode
drawer (two-sample KS tests, fixed seeds)."""

import numpy as np
import pytest
from scipy.stats import ks_2samp

from radar_env.sim import draws
from radar_env.sim.catalog import Setup, make_setup
from radar_env.sim.draws import draw_episodes, random_scenarios
from radar_env.sim.episode import _ARRAY_FIELDS, draw_episode, stack_episodes
from radar_env.sim.radar import atc_radar, converted_covariance, polar_from_cartesian
from radar_env.sim.scenario import RandomScenarioConfig, ScenarioBuilder, place_radar_site
from radar_env.filters.tracking import looks_for_track_start
from radar_env.common.units import G0_M_S2

MEASURED = ("range_m", "bearing_rad", "radial_velocity_m_s", "z_m", "R_m2")


def _rngs(seeds):
    return [np.random.default_rng(s) for s in seeds]


def _same(a, b):
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _trajectory():
    return (ScenarioBuilder(position_m=(0, 0), speed_kt=300, heading_deg=80).straight(200).turn(90, accel_g=2)
            .straight(150).build("traj"))


class _Pool:
    """A pool like adsb_calibration: draw_setup picks a member with the generator."""
    name = "pool"

    def __init__(self):
        self.members = [make_setup("bizup2002"), make_setup("seed002_two_radars")]

    def draw_setup(self, rng):
        return self.members[int(rng.integers(2))]


SCENARIOS = ["random", "random_radars", "bizup2002", "seed002_two_radars", "traj", "pool"]


def _scenario(name):
    return {"traj": _trajectory, "pool": _Pool}.get(name, lambda: name)()


@pytest.mark.parametrize("name", SCENARIOS)
def test_row_of_a_batch_equals_the_draw_alone_and_is_reproducible(name):
    sc = _scenario(name)
    seeds = [3, 17, 5, 400, 22, 9]
    b = draw_episodes(sc, None, None, _rngs(seeds))
    again = draw_episodes(sc, None, None, _rngs(seeds))
    for f in _ARRAY_FIELDS + ["valid", "n_looks"]:
        assert _same(getattr(b, f), getattr(again, f)), f
    for i, s in enumerate(seeds):
        one = draw_episodes(sc, None, None, _rngs([s])).episode(0)
        row = b.episode(i)
        for f in _ARRAY_FIELDS:
            assert _same(getattr(row, f), getattr(one, f)), (s, f)
    assert len({b.episode(i).z_m.tobytes() for i in range(len(seeds))}) == len(seeds)   # seeds differ


@pytest.mark.parametrize("name", SCENARIOS)
def test_batch_is_padded_as_stack_episodes_and_finite(name):
    b = draw_episodes(_scenario(name), None, None, _rngs(range(40)))
    eps = [b.episode(i) for i in range(b.batch_size)]
    ref = stack_episodes(eps)
    for f in _ARRAY_FIELDS + ["valid", "n_looks"]:
        assert _same(getattr(b, f), getattr(ref, f)), f
    for e in eps:
        need = looks_for_track_start(e.detected, e.t_s, 12)
        assert need is not None and e.n_looks >= need
        for f in _ARRAY_FIELDS:
            a = getattr(e, f)
            if f in MEASURED:
                det = e.detected.reshape((-1,) + (1,) * (a.ndim - 1))
                assert np.all(np.isfinite(a[np.broadcast_to(det, a.shape)]))
                assert np.all(np.isnan(a[~np.broadcast_to(det, a.shape)]))
            elif a.dtype.kind == "f":
                assert np.all(np.isfinite(a)), f
        assert np.all(np.diff(e.t_s) >= 0)


def test_rngs_are_checked():
    with pytest.raises(ValueError, match="Generator"):
        draw_episodes("random", None, None, [0])
    with pytest.raises(ValueError, match="at least one generator"):
        draw_episodes("random", None, None, [])


@pytest.mark.parametrize("name", ["random", "random_radars"])
def test_random_truth_and_schedule_equal_the_reference_code(name):
    """The kernel's flight, rebuilt as a SegmentScenario, gives the kernel's truth; the looks are
    scan_schedule's; the whole flight stays in the placement annulus."""
    seeds = range(30)
    b = draw_episodes(name, None, None, _rngs(seeds))
    for i, (sc, sites, K, status) in enumerate(random_scenarios(name, _rngs(seeds))):
        e = b.episode(i)
        assert status == 0 and K == e.n_looks
        np.testing.assert_allclose(e.truth, sc.states_at(e.t_s), rtol=1e-12, atol=1e-6)
        np.testing.assert_allclose(e.truth_accel_m_s2, sc.accelerations_at(e.t_s), rtol=1e-9, atol=1e-9)
        assert np.array_equal(e.truth_turn_rate_rad_s, sc.turn_rates_at(e.t_s))
        assert np.array_equal(e.maneuvering, sc.maneuvering_at(e.t_s))
        from radar_env.sim.radar import Radar, RadarSite
        radar = Radar(tuple(RadarSite(position_m=(s[0], s[1]), scan_period_s=s[2], range_noise_std_m=s[3],
                                      bearing_noise_std_rad=s[4], radial_velocity_noise_std_m_s=s[5],
                                      detection_probability=s[6], first_scan_s=s[9]) for s in sites))
        from radar_env.sim.radar import scan_schedule
        t, idx = scan_schedule(radar, sc.duration_s)
        assert np.array_equal(t, e.t_s) and np.array_equal(idx, e.site_index)
        tg = np.arange(0.0, sc.duration_s, 1.0)
        r, _, _ = polar_from_cartesian(sc.states_at(tg), sites[0, :2])
        assert r.min() >= 10e3 - 1e-6 and r.max() <= 150e3 + 1e-6 and sc.duration_s >= 120.0


@pytest.mark.parametrize("seed", range(6))
def test_placement_skipping_equals_the_whole_grid(seed):
    """The placement skips grid points a margin proves inside; the result equals testing every point, and equals
    place_radar_site's rule for the same candidates."""
    sc, _, _, _ = random_scenarios("random", _rngs([seed]))[0]
    dur = sc.duration_s
    n_grid, extra = draws._grid_size(dur)
    tg = np.arange(n_grid) * 2.0
    tg = np.append(tg, dur) if extra else tg
    grid = np.ascontiguousarray(sc.states_at(tg)[:, :2])
    vmax = np.hypot(*sc.states_at(np.linspace(0, dur, 2001))[:, 2:].T).max() * 1.01
    key = np.uint64(12345 + seed)
    fast = draws._place_on_grid(key, 0, 64, 10e3, 150e3, grid, n_grid, extra, dur, np.empty((64, 2)), vmax * 2.0)
    slow = draws._place_on_grid(key, 0, 64, 10e3, 150e3, grid, n_grid, extra, dur, np.empty((64, 2)), 0.0)
    assert fast == slow
    # place_radar_site's rule (first exit on the grid, longest wins, first drawn on ties) for these candidates
    u = draws.uniforms(key, 0, 128).reshape(64, 2)
    d, a = 10e3 + 140e3 * u[:, 0], 2 * np.pi * u[:, 1]
    cand = grid[0] + np.stack([d * np.sin(a), d * np.cos(a)], axis=-1)
    r = np.hypot(grid[None, :, 0] - cand[:, None, 0], grid[None, :, 1] - cand[:, None, 1])
    out = (r < 10e3) | (r > 150e3)
    first = np.where(out.any(axis=1), out.argmax(axis=1), grid.shape[0])
    best = int(np.argmax(first))
    assert (fast[0], fast[1]) == (cand[best, 0], cand[best, 1])
    assert fast[2] == (dur if first[best] == grid.shape[0] else tg[max(first[best] - 1, 0)])


def test_plot_noise_statistics_and_converted_covariance():
    """Box-Muller normals with the site's sigmas; the converted R matches the plots' empirical covariance."""
    s = make_setup("bizup2002")
    site = s.radar.sites[0]
    n = 3000
    b = draw_episodes("bizup2002", None, None, _rngs(range(n)))
    k = 40
    r, br, rd = polar_from_cartesian(b.truth[:, k], site.position_m)
    for err, sig in ((b.range_m[:, k] - r, site.range_noise_std_m), (b.bearing_rad[:, k] - br,
                     site.bearing_noise_std_rad), (b.radial_velocity_m_s[:, k] - rd,
                                                   site.radial_velocity_noise_std_m_s)):
        assert abs(err.mean()) < 4 * sig / np.sqrt(n)
        assert abs(err.std() / sig - 1) < 4 / np.sqrt(2 * n)
        assert ks_2samp(err / sig, np.random.default_rng(0).standard_normal(n)).pvalue > 1e-3
    emp = np.cov(b.z_m[:, k].T)
    R = converted_covariance(r[0], br[0], site.range_noise_std_m, site.bearing_noise_std_rad)
    np.testing.assert_allclose(emp, R, rtol=0.1, atol=0.1 * np.sqrt(R[0, 0] * R[1, 1]))
    np.testing.assert_allclose(b.R_m2[:, k], converted_covariance(b.range_m[:, k], b.bearing_rad[:, k],
                                                                  site.range_noise_std_m,
                                                                  site.bearing_noise_std_rad), rtol=1e-12)


def test_detection_probability_and_user_radar():
    radar = atc_radar(detection_probability=0.7)
    b = draw_episodes("bizup2002", radar, None, _rngs(range(300)))
    assert abs(b.detected.mean() - 0.7) < 0.01
    br = draw_episodes("random", radar, None, _rngs(range(300)))
    assert abs(br.detected[br.valid].mean() - 0.7) < 0.01
    assert np.all(br.range_noise_std_m[br.valid] == radar.sites[0].range_noise_std_m)


# ---------------------------------------------------------------------------------------------------- distributions
def _old_draw(name, rng, cfg=None, warmup_scans=12):
    """The per-episode drawer of the previous version (make_setup + draw_episode, redrawn until long enough)."""
    for _ in range(draws.MAX_EPISODE_DRAWS):
        s = make_setup(name, rng, cfg)
        e = draw_episode(s.scenario, s.radar, rng)
        need = looks_for_track_start(e.detected, e.t_s, warmup_scans)
        if need is not None and e.n_looks >= need:
            return e
    raise AssertionError("no draw long enough")


def _stats(e):
    speed = np.hypot(e.truth[:, 2], e.truth[:, 3])
    turning = e.truth_turn_rate_rad_s != 0
    starts = np.flatnonzero(turning[1:] & ~turning[:-1]).size + int(turning[0])
    g = np.abs(e.truth_turn_rate_rad_s) * speed / G0_M_S2
    rng_m = np.hypot(*(e.truth[:, :2] - e.site_xy_m).T)
    s0 = e.site_index == 0
    return {"duration_s": e.t_s[-1], "n_looks": e.n_looks, "turns": starts,
            "turn_g_max": g.max(), "range_mean_m": rng_m.mean(), "range_first_m": rng_m[0],
            "speed_first_m_s": speed[0], "speed_change_m_s": np.ptp(speed), "pd_realised": e.detected.mean(),
            "period_s": np.median(np.diff(e.t_s[s0])), "sites": e.site_index.max() + 1,
            "range_noise_m": e.range_noise_std_m[0]}


@pytest.mark.parametrize("name", ["random", "random_radars"])
def test_random_distributions_equal_the_per_episode_drawer(name):
    """Two-sample KS tests, 300 episodes each, fixed seeds: the new stream draws the same distributions."""
    n = 300
    new = [_stats(e) for e in (draw_episodes(name, None, None, _rngs(range(n))).episode(i) for i in range(n))]
    old = [_stats(_old_draw(name, np.random.default_rng(10_000 + i))) for i in range(n)]
    keys = list(new[0])
    if name == "random":
        keys = [k for k in keys if k not in ("pd_realised", "period_s", "sites", "range_noise_m")]  # constant
    for k in keys:
        a, b = np.array([s[k] for s in new], float), np.array([s[k] for s in old], float)
        p = ks_2samp(a, b).pvalue
        assert p > 1e-3, (k, p, a.mean(), b.mean())


def test_short_draws_are_redrawn_and_refused_like_before():
    """Slow radar far away: many first attempts are too short; the redraws keep the too-short share at zero, and
    an impossible config is refused with the old message."""
    radar = atc_radar(scan_period_s=30.0)
    rc = RandomScenarioConfig(range_km=(250.0, 300.0))
    b = draw_episodes("random", radar, rc, _rngs(range(40)))
    first = draw_episodes("random", radar, rc, _rngs(range(40)), warmup_scans=0)
    assert all(b.n_looks >= 15)
    assert np.sum(first.n_looks < 15) > 0
    with pytest.raises(ValueError, match="warmup_scans=1000"):
        draw_episodes("random", None, RandomScenarioConfig(leg_duration_s=(30, 60)), _rngs([0]), 1000)
    with pytest.raises(ValueError, match=r"warmup_scans=99.*<= 98"):
        draw_episodes("kim_lee_accel", None, None, _rngs([0]), 99)
    with pytest.raises(ValueError, match="range_km"):
        draw_episodes("random", None, RandomScenarioConfig(range_km=(10.0, 10.5)), _rngs([0]))


def test_fixed_setup_and_trajectory_placement():
    """A Setup keeps its radar; a trajectory without radar gets the ATC radar placed in the annulus per row."""
    s = make_setup("seed002_course_changes")
    b = draw_episodes(Setup(s.scenario, s.radar), None, None, _rngs(range(5)))
    assert np.all(b.site_xy_m == np.asarray(s.radar.sites[0].position_m))
    np.testing.assert_array_equal(b.truth[0], s.scenario.states_at(b.t_s[0]))
    tr = _trajectory()
    bt = draw_episodes(tr, None, None, _rngs(range(50)), radar_range_m=(20e3, 60e3))
    r = np.hypot(*(bt.truth[:, 0, :2] - bt.site_xy_m[:, 0]).T)
    assert np.all((r >= 20e3) & (r <= 60e3)) and len(np.unique(bt.site_xy_m[:, 0, 0])) == 50
    ref_site, _ = place_radar_site(np.random.default_rng(0), tr)   # same annulus rule (default 10-150 km)
    assert 10e3 <= np.hypot(*ref_site) <= 150e3


@pytest.mark.parametrize("name", ["random", "bizup2002"])
def test_look_drawer_pads_only_what_the_previous_episode_left(name):
    """LookDrawer rewrites a row's looks up to its previous episode's end and one look beyond (not the whole store):
    every look past n_looks is not detected, look n_looks repeats the last look, and the looks themselves equal
    Tracker.load's of the same episodes (which pads the whole store)."""
    from radar_env.filters.tracking import Tracker
    from radar_env.sim.looks import L_DET
    drawer = draws.LookDrawer.of(name, None, None, 12)
    B = 6
    tr, ref = Tracker(B), Tracker(B)
    rows = np.arange(B, dtype=np.int64)
    for rep in range(5):      # successive episodes of different lengths in the same rows
        rngs = _rngs(range(100 * rep, 100 * rep + B))
        keys = draws._keys(rngs)
        drawer.draw(keys, rows, tr)
        batch = draw_episodes(name, None, None, _rngs(range(100 * rep, 100 * rep + B)))
        ref.load(rows, [batch.episode(i) for i in range(B)])
        n = tr._it[:, 1]
        assert np.array_equal(n, ref.n_looks)
        for r in range(B):
            k = int(n[r])
            assert _same(tr._looks[r, :k], ref._looks[r, :k])
            assert not tr._looks[r, k:, L_DET].any()
            if k < tr._looks.shape[1]:
                want = tr._looks[r, k - 1].copy()
                want[L_DET] = 0.0
                assert _same(tr._looks[r, k], want)
