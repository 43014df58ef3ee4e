"""Issue 15 (env side): valid configurations never crash mid-run, bad inputs are refused naming the parameter,
units and documented behaviour (info keys, docstring, vector wrappers, the bundled policy's env)."""

import math
import re

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import radar_env  # noqa: F401
from radar_env.sim.draws import draw_episodes
from radar_env.envs.env import DEFAULT_Q_LEVELS_G, EnvConfig, RadarTrackEnv, RadarTrackVectorEnv, draw_setup_and_episode
from radar_env.envs.observation import DEFAULT_FEATURES, PAST_FEATURES
from radar_env.sim.radar import Radar, RadarSite, atc_radar
from radar_env.sim.scenario import RandomScenarioConfig
from radar_env.common.units import G0_M_S2

ENV_ID = "RadarTrack-v0"


def _run_episode(env, action):
    obs, info = env.reset(seed=0)
    done, n = False, 0
    while not done:
        obs, r, te, tr, info = env.step(action)
        done, n = te or tr, n + 1
    return n


# ------------------------------------------------------------------------------------------------ never crash mid-run
def test_vector_env_with_long_warmup_never_crashes():
    """Main crashed after 258 steps: an autoreset drew a flight with fewer looks than 60 warm-up looks need."""
    venv = gym.make_vec(ENV_ID, num_envs=16, vectorization_mode="vector_entry_point", warmup_scans=60)
    venv.reset(seed=0)
    ends = 0
    for _ in range(270):
        obs, rew, te, tr, info = venv.step(np.zeros(16, dtype=np.int64))
        ends += int((te | tr).sum())
        assert np.all(np.isfinite(obs)) and np.all(np.isfinite(rew))
    assert ends > 0   # autoresets happened


def test_slow_radar_far_ranges_never_crash():
    """A 30 s radar with flights at 250-300 km: main crashed for 23 of 300 seeds, those whose first draw (the
    episode main ran) has fewer than 15 looks: 12 at reset (< 14 looks), 11 at the first step (14 looks: the
    warm-up used the last look)."""
    radar = atc_radar(scan_period_s=30.0)
    rc = RandomScenarioConfig(range_km=(250.0, 300.0))
    env = gym.make(ENV_ID, radar=radar, random_config={"range_km": (250, 300)})
    short = [s for s in range(80)
             if _draw_once("random", radar, rc, seeding.np_random(s)[0]).n_looks < 15]   # reset(seed=s)
    assert short
    for seed in short:
        env.reset(seed=seed)
        _, _, te, tr, _ = env.step(4)   # at least one look to act on after the warm-up
        assert isinstance(te, bool) and isinstance(tr, bool)


def test_named_scenario_too_short_for_warmup_is_refused_at_build():
    """kim_lee_accel has 101 looks (T = 1 s): warm-up 98 leaves one look to act on, 99 leaves none (main built
    the env and crashed at the first step)."""
    assert _run_episode(gym.make(ENV_ID, scenario="kim_lee_accel", warmup_scans=98), 4) == 1
    for env_cls in (RadarTrackEnv, lambda **kw: RadarTrackVectorEnv(num_envs=2, **kw)):
        with pytest.raises(ValueError, match=r"warmup_scans=99.*<= 98"):
            env_cls(scenario="kim_lee_accel", warmup_scans=99)


def test_impossible_random_config_is_refused_at_build():
    """Flights of at most 6 legs of 60 s (and their turns) never give the 1003 looks a warm-up of 1000 needs."""
    with pytest.raises(ValueError, match="warmup_scans=1000"):
        gym.make(ENV_ID, warmup_scans=1000, random_config={"leg_duration_s": (30, 60)})


@pytest.mark.parametrize("random_config, words", [
    ({"range_km": (1, 6)}, r"flights did not stay in range_km=\(1.0, 6.0\).*widen range_km"),
    ({"range_km": (1000, 1000)}, r"256 of 256 flights did not stay in range_km"),
    ({"min_duration_s": 1e5}, r"min_duration_s=100000 s"),
    ({"max_turn_rate_deg_s": 1e-8}, r"longest flight can last 1.35e\+11 s.*raise max_turn_rate_deg_s"),
])
def test_random_config_the_placement_cannot_serve_is_refused_at_build(random_config, words):
    """Main built these and failed at a reset: range (1, 6) km at 22 of 3,000 seeds (after hundreds of episodes in a
    vector env), the others at the first; a 1e-8 deg/s turn rate asked the placement for a 216 GB grid."""
    for env_cls in (RadarTrackEnv, lambda **kw: RadarTrackVectorEnv(num_envs=2, **kw)):
        with pytest.raises(ValueError, match=words):
            env_cls(random_config=random_config)


def test_a_narrow_range_that_is_accepted_draws_every_episode():
    """range_km (1, 10): about two flights in three cannot be placed, so a draw tries up to 200 (0.65^200: never all
    fail); 64 rows run through their autoresets."""
    venv = RadarTrackVectorEnv(num_envs=64, random_config={"range_km": (1, 10)})
    venv.reset(seed=3)
    ends = 0
    for _ in range(300):
        _, _, te, tr, _ = venv.step(np.full(64, 4))
        ends += int(np.sum(te | tr))
    assert ends > 64


def _draw_once(scenario, radar, random_config, rng):
    """The first attempt of a draw (warmup_scans=0 accepts every attempt with two hits, and the warm-up does not
    change what an attempt draws)."""
    return draw_episodes(scenario, radar, random_config, [rng], warmup_scans=0).episode(0)


def test_redraw_only_replaces_draws_that_could_not_run():
    """Every episode that runs is the first draw of its generator (the default streams are unchanged); the only
    draws replaced are those too short for the track start."""
    radar = atc_radar(scan_period_s=30.0)
    rc = RandomScenarioConfig(range_km=(250.0, 300.0))
    replaced = 0
    for seed in range(60):
        first = _draw_once("random", radar, rc, np.random.default_rng(seed))
        got = draw_setup_and_episode("random", radar, rc, np.random.default_rng(seed), 12)
        same = first.truth.shape == got.truth.shape and first.truth.tobytes() == got.truth.tobytes()
        replaced += not same
        assert same == (first.n_looks >= 15), seed   # 15 = two hits + 12 warm-up looks + one to act on
        assert got.n_looks >= 15
    assert replaced > 0
    for seed in range(20):   # default config: nothing replaced
        a = _draw_once("random", None, None, np.random.default_rng(seed))
        b = draw_setup_and_episode("random", None, None, np.random.default_rng(seed))
        assert a.truth.tobytes() == b.truth.tobytes() and a.z_m.tobytes() == b.z_m.tobytes()


# ------------------------------------------------------------------------------------------------ actions
@pytest.mark.parametrize("action_type, bad", [
    ("discrete", np.zeros((2, 2), dtype=np.int64)),          # 4 values for 4 rows, wrong shape (main accepted)
    ("discrete", np.zeros((4, 1), dtype=np.int64)),
    ("continuous", np.zeros((1, 4), dtype=np.float32)),      # (main accepted)
    ("continuous", np.zeros((2, 2), dtype=np.float32)),
    ("continuous", np.zeros((4, 2), dtype=np.float32)),
])
def test_vector_env_refuses_wrong_action_shape(action_type, bad):
    venv = RadarTrackVectorEnv(num_envs=4, action_type=action_type)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape"):
        venv.step(bad)
    ok = np.zeros(4, np.int64) if action_type == "discrete" else np.zeros((4, 1), np.float32)
    venv.step(ok)   # the right shape still works after the refusal


@pytest.mark.parametrize("action_type, good, bad", [("discrete", (4, np.int64(4), np.array(4)),
                                                     (np.array([4]), np.array([[4]]))),
                                                    ("continuous", (0.1, np.array([0.1])), (np.array([[0.1]]),))])
def test_single_env_takes_its_spaces_shape_or_one_number(action_type, good, bad):
    """Main took any array with the right number of elements ([[4]] as 4); now the space's shape or a scalar."""
    env = RadarTrackEnv(action_type=action_type)
    env.reset(seed=0)
    for a in good:
        env.step(a)
    for a in bad:
        with pytest.raises(ValueError, match=rf"got shape \({a.shape[0]},"):
            env.step(a)


BAD_KINDS = {"str": "3", "complex": 3 + 0j, "bool": True, "none": None}


@pytest.mark.parametrize("kind", sorted(BAD_KINDS))
@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_wrong_action_types_are_refused_in_both_envs(kind, action_type):
    """Main took True as action 1 (and as q = the top level for continuous), '3' and 3+0j as 3."""
    v = BAD_KINDS[kind]
    env = RadarTrackEnv(action_type=action_type)
    env.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        env.step(v if action_type == "discrete" else [v])
    venv = RadarTrackVectorEnv(num_envs=2, action_type=action_type)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match="action"):
        venv.step(np.array([v, v], dtype=object) if kind == "none" else np.array([v, v]))


# ------------------------------------------------------------------------------------------------ wrong types
WRONG = ["5", None, True, 1j, [1]]


@pytest.mark.parametrize("value", WRONG, ids=repr)
@pytest.mark.parametrize("name", ["scan_period_s", "range_noise_std_m", "bearing_noise_std_rad",
                                  "radial_velocity_noise_std_m_s", "detection_probability", "range_bias_m",
                                  "bearing_bias_rad", "first_scan_s", "position_m", "name"])
def test_radar_site_wrong_types_name_the_attribute(name, value):
    """Main stored scan_period_s='5' and failed steps later; None raised a bare TypeError."""
    if name == "position_m" and value == [1]:
        value = ["1", "2"]
    if name == "name" and value == "5":
        value = 5
    with pytest.raises(ValueError, match=f"RadarSite.{name}"):
        RadarSite(**{name: value})


@pytest.mark.parametrize("name, value", [("num_envs", True), ("num_envs", 2.0), ("num_envs", "2"),
                                         ("max_episode_steps", True), ("max_episode_steps", 7.0)])
def test_vector_env_size_arguments_wrong_types(name, value):
    """Main took num_envs=True (and max_episode_steps=True) as 1."""
    kw = {"num_envs": 2, name: value}
    with pytest.raises(ValueError, match=name):
        RadarTrackVectorEnv(**kw)


@pytest.mark.parametrize("seed", [True, "12", 1.5, ["a", "b"], [True, 1]])
def test_vector_env_reset_seed_wrong_types(seed):
    """Main seeded the rows with 1, 2 for seed=True and with a list of characters for '12'."""
    venv = RadarTrackVectorEnv(num_envs=2)
    with pytest.raises(ValueError, match="seed"):
        venv.reset(seed=seed)
    if not isinstance(seed, list):
        with pytest.raises(ValueError, match="seed"):
            RadarTrackEnv().reset(seed=seed)


def test_radar_wrong_sites():
    for bad in ("atc", None, (), (1, 2)):
        with pytest.raises(ValueError, match="Radar.sites"):
            Radar(bad)


ENV_FIELDS_NUMERIC = ["warmup_scans", "warmup_q_g", "reward_clip", "track_loss_gate_sigma", "n_adrian",
                      "window_kim_lee", "fma_weight"]


@pytest.mark.parametrize("value", WRONG, ids=repr)
@pytest.mark.parametrize("name", ENV_FIELDS_NUMERIC)
def test_env_numeric_arguments_wrong_types(name, value):
    with pytest.raises(ValueError, match=name):
        EnvConfig.from_kwargs(**{name: value})


@pytest.mark.parametrize("name, value", [
    ("q_levels_g", ["a"]), ("q_levels_g", ("0.1", "1")), ("q_levels_g", None), ("q_levels_g", "0.1,1"),
    ("q_levels_g", (0.1, True)), ("q_levels_g", 5.0), ("features", "nis"), ("features", None),
    ("features", ("nis", 3)), ("features", ("nope",)), ("features", ("nis", "nis")), ("action_type", None), ("action_type", ["discrete"]), ("reward_type", 1),
    ("render_mode", 0), ("radar", "atc"), ("random_config", "fast"), ("random_config", [("speed_kt", (1, 2))]),
    ("scenario", None), ("scenario", 3),
])
def test_env_arguments_wrong_types(name, value):
    with pytest.raises(ValueError, match=name):
        EnvConfig.from_kwargs(**{name: value})


PAIR_KEYS = ["speed_kt", "n_legs", "leg_duration_s", "turn_accel_g", "turn_heading_change_deg",
             "speed_change_accel_g", "range_km"]
SCALAR_KEYS = ["first_leg_min_s", "max_turn_rate_deg_s", "speed_change_probability", "site_candidates",
               "min_duration_s", "random_radar_probability"]


@pytest.mark.parametrize("key", PAIR_KEYS + SCALAR_KEYS)
def test_random_config_wrong_types_name_the_key(key):
    """Every RandomScenarioConfig key, given through the env: strings, None, booleans and complex numbers."""
    bads = ([("5", "6"), None, (True, 2), (1j, 2), "56", (1, 2, 3)] if key in PAIR_KEYS
            else ["5", None, True, 1j, (1, 2)])
    for bad in bads:
        with pytest.raises(ValueError, match=f"RandomScenarioConfig.{key}"):
            gym.make(ENV_ID, random_config={key: bad})


def test_random_config_unknown_key_and_list_pairs():
    with pytest.raises(ValueError, match=r"unknown RandomScenarioConfig key\(s\) \['speed'\]"):
        RandomScenarioConfig.from_dict({"speed": (1, 2)})
    assert RandomScenarioConfig.from_dict({"speed_kt": [150, 300]}) == RandomScenarioConfig(speed_kt=(150.0, 300.0))
    with pytest.raises(ValueError, match=r"unknown RadarTrack-v0 argument\(s\) \['q_level_g'\]"):
        gym.make(ENV_ID, q_level_g=(0.1, 1.0))


# ------------------------------------------------------------------------------------------------ units and docs
def test_info_q_carries_its_unit_and_keeps_the_deprecated_alias():
    env = RadarTrackEnv()
    _, info = env.reset(seed=0)
    assert info["q_m_s2"] == pytest.approx(0.03 * G0_M_S2)
    _, _, _, _, info = env.step(10)
    assert info["q_m_s2"] == DEFAULT_Q_LEVELS_G[10] * G0_M_S2 == info["q"]   # m/s^2, not g
    venv = RadarTrackVectorEnv(num_envs=2)
    venv.reset(seed=0)
    _, _, _, _, vinfo = venv.step(np.array([10, 2]))
    np.testing.assert_array_equal(vinfo["q_m_s2"], np.array(DEFAULT_Q_LEVELS_G)[[10, 2]] * G0_M_S2)
    assert vinfo["_q_m_s2"].all()


def test_environment_page_names_info_q_with_its_unit():
    from pathlib import Path
    text = (Path(__file__).resolve().parents[1] / "docs" / "environment.md").read_text()
    assert 'info["q_m_s2"]' in text
    for m in re.finditer(re.escape('info["q"]'), text):   # only as the documented deprecated alias
        assert "deprecated" in text[m.start(): m.start() + 80], text[m.start() - 80: m.start() + 80]


def test_docstring_preview_indices_and_render_mode():
    doc = RadarTrackEnv.__doc__
    first = DEFAULT_FEATURES.index(next(f for f in DEFAULT_FEATURES if f not in PAST_FEATURES))
    last = len(DEFAULT_FEATURES) - 1
    history = doc[doc.index("## Version History"):]
    assert f"{first}-{last}" in history
    assert f"Entries 0-{first - 1} describe" in " ".join(doc.split())
    arguments = doc[doc.index("## Arguments"):doc.index("## Version History")]
    assert "``render_mode``" in arguments and "human" in arguments


def test_human_render_mode_without_a_window_is_refused_at_build():
    """Main built the env and rendered into nothing (matplotlib's Agg backend draws no window)."""
    pytest.importorskip("matplotlib")
    import matplotlib.pyplot as plt
    before = plt.get_backend()
    plt.switch_backend("agg")
    try:
        with pytest.raises(ValueError, match=r"render_mode='human'.*'agg'.*rgb_array"):
            gym.make(ENV_ID, render_mode="human")
    finally:
        plt.switch_backend(before)


def test_close_releases_the_human_window_and_pyplots_mode(monkeypatch):
    """The human window is pyplot's (interactive mode switched on for it): close() closes it and puts the mode back.
    Drawn with the Agg backend, the display check bypassed (no window on a test machine)."""
    pytest.importorskip("matplotlib")
    import warnings
    import matplotlib.pyplot as plt
    from radar_env import render
    before = plt.get_backend()
    plt.switch_backend("agg")
    monkeypatch.setattr(render, "human_display_problem", lambda: None)
    plt.ioff()
    try:
        env = gym.make(ENV_ID, render_mode="human")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")      # Agg: "cannot be shown"
            env.reset(seed=0)
            env.step(3)
        fig = env.unwrapped._human_fig
        assert plt.fignum_exists(fig.number) and plt.isinteractive()
        env.close()
        assert not plt.fignum_exists(fig.number) and not plt.isinteractive()
        assert env.unwrapped._fig is None
        env.close()                                # twice: nothing left to close
    finally:
        plt.ioff()
        plt.switch_backend(before)


# ------------------------------------------------------------------------------------------------ vector wrappers
def _rollout(venv, n_steps=150):
    obs, _ = venv.reset(seed=5)
    rows = [obs.copy()]
    for t in range(n_steps):
        obs, rew, te, tr, _ = venv.step(np.full(venv.num_envs, 3 + t % 5))
        rows.append(obs.copy())
    return np.array(rows)


def test_readme_vector_env_combinations():
    """The README's table: sync with SAME_STEP autoreset equals the native env row for row; sync with its default
    NEXT_STEP autoreset diverges after the first episode end; gymnasium's vector observation wrappers refuse
    the same-step native env and accept the next-step sync env; reward/statistics wrappers take the native env."""
    from gymnasium.wrappers import vector as vw
    kw = dict(num_envs=2, scenario="kim_lee_accel")     # 86 steps per episode: ends inside the rollout
    native = gym.make_vec(ENV_ID, vectorization_mode="vector_entry_point", **kw)
    same = gym.make_vec(ENV_ID, vectorization_mode="sync", vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP},
                        **kw)
    nxt = gym.make_vec(ENV_ID, vectorization_mode="sync", **kw)
    assert nxt.metadata["autoreset_mode"] == AutoresetMode.NEXT_STEP
    a, b, c = _rollout(native), _rollout(same), _rollout(nxt)
    assert a.tobytes() == b.tobytes()
    differs = np.flatnonzero(np.any(a != c, axis=(1, 2)))
    assert differs.size and a[: differs[0]].tobytes() == c[: differs[0]].tobytes()
    for wrapper in (vw.NormalizeObservation, vw.FlattenObservation):
        with pytest.raises(ValueError, match="autoreset_mode"):
            wrapper(gym.make_vec(ENV_ID, vectorization_mode="vector_entry_point", **kw))
        w = wrapper(gym.make_vec(ENV_ID, vectorization_mode="sync", **kw))
        w.reset(seed=0)
        w.step(np.array([3, 3]))
    for wrapper in (vw.NormalizeReward, vw.RecordEpisodeStatistics):
        w = wrapper(gym.make_vec(ENV_ID, vectorization_mode="vector_entry_point", **kw))
        w.reset(seed=0)
        w.step(np.array([3, 3]))
    # per-env observation normalisation with same-step autoreset: the single-env wrapper inside sync
    w = gym.make_vec(ENV_ID, vectorization_mode="sync", wrappers=[gym.wrappers.NormalizeObservation],
                     vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}, **kw)
    w.reset(seed=0)
    w.step(np.array([3, 3]))


@pytest.mark.parametrize("second_seed, options", [(None, None), ([None, 7, None], None),
                                                  (None, {"scenario": "kim_lee_accel"}),
                                                  (None, {"scenario": "adsb_dev"})])    # a pool (AdsbPool)
def test_unseeded_reset_after_autoresets_keeps_each_row_the_single_envs(second_seed, options):
    """An explicit reset() without a seed (or with None for a row) after some rows ended: each such row continues its
    generator from where a single env's would be (an autoreset's prepared draw is put back), so the native env
    equals sync with same-step autoreset row for row, and row 0 does not depend on the batch."""
    def run(mode, n=3):
        kw = {} if mode == "vector_entry_point" else {"vector_kwargs": {"autoreset_mode": AutoresetMode.SAME_STEP}}
        v = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode=mode, **kw)
        v.reset(seed=5)
        for _ in range(150):
            v.step(np.full(n, 4))
        if mode == "vector_entry_point" and n == 3:
            core = v.unwrapped._core
            assert core._ready.any() and not core._ready.all()      # rows ended at different steps
        out = [v.reset(seed=second_seed if n == 3 else None, options=options)[0]]
        for _ in range(30):
            out.append(v.step(np.full(n, 4))[0])
        return np.stack(out)
    native = run("vector_entry_point")
    assert native.tobytes() == run("sync").tobytes()
    if second_seed is None:
        assert native[:, :1].tobytes() == run("vector_entry_point", n=1).tobytes()


# ------------------------------------------------------------------------------------------------ bundled policy
def test_bundled_policy_runs_in_make_policy_env():
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from agents.policies.bundle import BUNDLED_POLICY, make_policy_env, policy_env_kwargs
    model = PPO.load(BUNDLED_POLICY, device="cpu")
    env = make_policy_env()
    assert env.observation_space == model.observation_space and env.action_space == model.action_space
    assert env.action_space.n == len(policy_env_kwargs()["q_levels_g"]) != len(DEFAULT_Q_LEVELS_G)
    obs, _ = env.reset(seed=0)
    action, _ = model.predict(obs, deterministic=True)
    env.step(action)
    venv = make_policy_env(num_envs=3, scenario="bizup2002")
    assert venv.single_action_space == model.action_space and venv.config.scenario == "bizup2002"
    obs, _ = venv.reset(seed=0)
    venv.step(model.predict(obs, deterministic=True)[0])
    assert isinstance(policy_env_kwargs()["random_config"]["range_km"], tuple)
    with pytest.raises(ValueError, match="env_config.json"):
        policy_env_kwargs("/nonexistent/policy.zip")


# ------------------------------------------------------------------------------------------------ fuzz
SHORT = {"n_legs": (2, 3), "leg_duration_s": (30.0, 60.0), "first_leg_min_s": 60.0, "min_duration_s": 100.0}
"""Short random flights (100-250 s, 20-50 looks at 5 s) that always leave looks after a warm-up of <= 12."""

BAD_NUMBERS = st.sampled_from(["5", None, True, 1j, math.nan, math.inf, -1e12, 1e12, [1.0]])

ENV_VALUES = {
    "action_type": (st.sampled_from(["discrete", "continuous"]), st.sampled_from(["Discrete", None, 0, ""])),
    "q_levels_g": (st.lists(st.floats(1e-3, 50.0), min_size=2, max_size=6, unique=True).map(lambda v: tuple(sorted(v)))
                   .filter(lambda v: min(np.diff(v)) > 0),
                   st.sampled_from([["a"], (1.0,), (2.0, 1.0), (0.0, 1.0), (1.0, 200.0), "1,2", None, (1.0, math.nan)])),
    "features": (st.lists(st.sampled_from(DEFAULT_FEATURES), min_size=1, max_size=6, unique=True).map(tuple),
                 st.sampled_from(["nis", None, ("nis", "nis"), ("nope",), (1,)])),
    "warmup_scans": (st.integers(1, 12), st.one_of(BAD_NUMBERS, st.sampled_from([0, 2.5, 1001]))),
    "warmup_q_g": (st.floats(0.0, 100.0), st.one_of(BAD_NUMBERS, st.sampled_from([-0.1, 100.5]))),
    "reward_type": (st.sampled_from(["squared", "absolute", "squared_m"]), st.sampled_from(["mse", None, 1])),
    "reward_clip": (st.floats(1e-3, 1e9), BAD_NUMBERS),
    "track_loss_gate_sigma": (st.floats(1.0, 1e6), st.one_of(BAD_NUMBERS, st.just(0.5))),
    "n_adrian": (st.integers(1, 50), st.one_of(BAD_NUMBERS, st.sampled_from([0, 51, 2.5]))),
    "window_kim_lee": (st.integers(1, 1000), st.one_of(BAD_NUMBERS, st.sampled_from([0, 3.5]))),
    "fma_weight": (st.floats(1e-6, 1.0), st.one_of(BAD_NUMBERS, st.just(0.0))),
}
RC_VALUES = {
    "speed_kt": (st.tuples(st.floats(100, 400), st.floats(400, 900)), st.sampled_from([("1", "2"), (600, 100), (1, 2)])),
    "turn_accel_g": (st.tuples(st.floats(0.01, 3), st.floats(3, 20)), st.sampled_from([None, (0, 1), (True, 2)])),
    "turn_heading_change_deg": (st.tuples(st.floats(1, 90), st.floats(90, 720)), st.sampled_from([(1j, 2), (0, 5)])),
    "speed_change_probability": (st.floats(0, 1), st.one_of(BAD_NUMBERS, st.just(1.5))),
    "speed_change_accel_g": (st.tuples(st.floats(0.05, 1), st.floats(1, 5)), st.sampled_from([(0, 1), "0.1"])),
    "max_turn_rate_deg_s": (st.floats(1, 180), st.one_of(BAD_NUMBERS, st.just(0.0))),
    "site_candidates": (st.integers(1, 128), st.one_of(BAD_NUMBERS, st.sampled_from([0, 2.5]))),
    "random_radar_probability": (st.floats(0, 1), st.one_of(BAD_NUMBERS, st.just(-0.5))),
}


@st.composite
def configs(draw):
    """(kwargs, names given an invalid value, action strategy name)."""
    kwargs, bad = {"scenario": draw(st.sampled_from(["random", "random_radars"]))}, set()
    for name in draw(st.lists(st.sampled_from(sorted(ENV_VALUES)), max_size=4, unique=True)):
        valid, invalid = ENV_VALUES[name]
        is_valid = draw(st.booleans())
        kwargs[name] = draw(valid if is_valid else invalid)
        if not is_valid:
            bad.add(name)
    rc = dict(SHORT)
    for key in draw(st.lists(st.sampled_from(sorted(RC_VALUES)), max_size=3, unique=True)):
        valid, invalid = RC_VALUES[key]
        is_valid = draw(st.booleans())
        rc[key] = draw(valid if is_valid else invalid)
        if not is_valid:
            bad.add(key)
    kwargs["random_config"] = rc
    return kwargs, bad, draw(st.sampled_from(["valid", "valid", "valid", "out_of_range", "str", "bool", "complex"]))


def _action(env, kind):
    space = env.action_space
    if kind == "valid":
        return space.sample()
    if kind == "out_of_range":
        return space.n if isinstance(space, gym.spaces.Discrete) else np.array([1.5], np.float32)
    return {"str": "1", "bool": True, "complex": 1 + 0j}[kind]


@settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(configs(), st.integers(0, 2**31 - 1))
def test_fuzz_env_configurations_and_actions(cfg, seed):
    """Either a ValueError naming an invalid parameter (at build or step), or a whole episode whose every
    observation, reward and info array is finite."""
    kwargs, bad, action_kind = cfg
    try:
        env = RadarTrackEnv(**kwargs)
    except ValueError as e:
        assert bad, f"valid configuration refused: {kwargs}: {e}"
        assert any(re.search(rf"\b{n}\b", str(e)) for n in bad), (str(e), bad)
        return
    assert not bad, f"invalid {sorted(bad)} accepted: {kwargs}"
    env.action_space.seed(seed)
    obs, info = env.reset(seed=seed)
    assert np.all(np.isfinite(obs))
    done = False
    while not done:
        a = _action(env, action_kind)
        if action_kind != "valid":
            with pytest.raises(ValueError, match="action"):
                env.step(a)
            return
        obs, rew, te, tr, info = env.step(a)
        done = te or tr
        assert env.observation_space.contains(obs) and np.all(np.isfinite(obs)) and math.isfinite(rew)
        for k in ("truth", "estimate", "covariance", "q_m_s2", "dt", "time_s"):
            assert np.all(np.isfinite(info[k])), k
        for k in ("measurement", "measurement_covariance", "polar"):   # NaN only at a missed look (documented)
            assert np.all(np.isfinite(info[k])) == info["detected"], k
        assert all(math.isfinite(v) for v in info["reward_terms"].values())


# ------------------------------------------------------------------------------------------------ radar placement
def _place_radar_site_whole_grid(rng, scenario, range_m, n_candidates, grid_dt_s=2.0):
    """The previous implementation (every candidate against the whole grid at once), as an oracle."""
    lo, hi = range_m
    t = np.arange(0.0, scenario.duration_s + 1e-9, grid_dt_s)
    if t[-1] < scenario.duration_s:
        t = np.append(t, scenario.duration_s)
    p = scenario.states_at(t)[:, :2]
    d = rng.uniform(lo, hi, size=n_candidates)
    a = rng.uniform(0.0, 2 * np.pi, size=n_candidates)
    sites = p[0] + np.stack([d * np.sin(a), d * np.cos(a)], axis=-1)
    r = np.hypot(p[None, :, 0] - sites[:, None, 0], p[None, :, 1] - sites[:, None, 1])
    out = (r < lo) | (r > hi)
    first_out = np.where(out.any(axis=1), out.argmax(axis=1), t.size)
    best = int(np.argmax(first_out))
    until = scenario.duration_s if first_out[best] == t.size else float(t[max(first_out[best] - 1, 0)])
    return sites[best], until


@pytest.mark.parametrize("segments", [
    [(9001.0, 0.01), (3000.0, 0.0)],     # circles for 9 ks (several blocks), then flies out in a later block
    [(20001.3, 0.008)],                  # stays in range to the end; the duration is off the grid
    [(300.0, 0.0), (40.0, 0.05), (500.0, 0.0)],
])
def test_radar_placement_in_blocks_equals_the_whole_grid(segments):
    from radar_env.sim.scenario import Segment, SegmentScenario, place_radar_site
    sc = SegmentScenario([0.0, 0.0, 100.0, 0.0], [Segment(d, w) for d, w in segments])
    for seed in range(5):
        for range_m in ((10e3, 150e3), (5e3, 20e3)):
            a = place_radar_site(np.random.default_rng(seed), sc, range_m, 64)
            b = _place_radar_site_whole_grid(np.random.default_rng(seed), sc, range_m, 64)
            assert a[0].tobytes() == b[0].tobytes() and a[1] == b[1]


def test_radar_placement_memory_does_not_grow_with_the_flight():
    """A 200 000 s flight (slow turns and long legs are valid): main held the whole (64, 100 001) grid (tens of
    MB; with max_turn_rate_deg_s=1e-6 a 270 deg turn lasts 2.7e8 s and main ran out of memory). Slow turns run
    (1e-4 deg/s); 1e-6 deg/s, whose flights' placement grid could need 10.8 GB, is refused when built."""
    import tracemalloc

    from radar_env.sim.scenario import Segment, SegmentScenario, place_radar_site
    sc = SegmentScenario([0.0, 0.0, 200.0, 0.0], [Segment(200_000.0)])
    tracemalloc.start()
    try:
        place_radar_site(np.random.default_rng(0), sc, (10e3, 150e3), 64)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 64 * 100_001 * 8 / 4   # a quarter of one (64, K) float64 array
    env = RadarTrackEnv(random_config={"max_turn_rate_deg_s": 1e-4})
    env.reset(seed=0)
    env.step(4)
    with pytest.raises(ValueError, match="raise max_turn_rate_deg_s"):    # its flights' grid: up to 10.8 GB
        RadarTrackEnv(random_config={"max_turn_rate_deg_s": 1e-6})
