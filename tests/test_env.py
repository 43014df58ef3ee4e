"""RadarTrack-v0: registration, env checkers, seeding, the info contract, configuration errors, track loss,
the native vector env against the single env, and robustness under random/extreme actions."""

import importlib
import subprocess
import sys
import warnings

import gymnasium as gym
import numpy as np
import pytest

import radar_env
from radar_env.sim.draws import LookDrawer
from radar_env.sim.looks import L_MAN, L_TACC, L_TRUTH, L_TTURN
from radar_env.sim.catalog import make_setup
from radar_env.sim.radar import atc_radar
from radar_env.envs.env import DEFAULT_Q_LEVELS_G, RadarTrackEnv, RadarTrackVectorEnv
from radar_env.envs.observation import DEFAULT_FEATURES
from radar_env.common.units import G0_M_S2

ENV_ID = "RadarTrack-v0"
INFO_KEYS = {"truth", "estimate", "covariance", "measurement", "measurement_covariance", "polar", "q_m_s2", "dt",
             "detected", "maneuvering", "reward_terms", "track_lost"}
# The env also reports the look time (not in the lead's list; documented here so an addition/removal is seen) and
# the deprecated alias "q" of "q_m_s2" (kept for one version).
EXTRA_INFO_KEYS = {"time_s", "q"}


def _bytes_equal(a, b):
    """Bit-for-bit equality of nested info values (NaN == NaN when the bits agree)."""
    if isinstance(a, dict):
        return isinstance(b, dict) and a.keys() == b.keys() and all(_bytes_equal(a[k], b[k]) for k in a)
    a, b = np.asarray(a), np.asarray(b)
    return a.dtype == b.dtype and a.shape == b.shape and a.tobytes() == b.tobytes()


def _rollout(env, seed, n_episodes=2, action_seed=123, options=None):
    """Whole episodes with actions from a seeded generator; returns a list of (obs, reward, term, trunc, info)."""
    rng = np.random.default_rng(action_seed)
    out = []
    obs, info = env.reset(seed=seed, options=options)
    out.append((obs, 0.0, False, False, info))
    for _ in range(n_episodes):
        done = False
        while not done:
            if isinstance(env.action_space, gym.spaces.Discrete):
                a = int(rng.integers(env.action_space.n))
            else:
                a = rng.uniform(-1, 1, size=(1,)).astype(np.float32)
            obs, r, te, tr, info = env.step(a)
            out.append((obs, r, te, tr, info))
            done = te or tr
        obs, info = env.reset()
        out.append((obs, 0.0, False, False, info))
    return out


# ------------------------------------------------------------------------------------------------ registration
def test_make_after_import():
    env = gym.make(ENV_ID)
    assert isinstance(env.unwrapped, RadarTrackEnv)
    assert env.spec.vector_entry_point == "radar_env.envs.env:RadarTrackVectorEnv"
    obs, _ = env.reset(seed=0)
    assert env.observation_space.contains(obs)


def test_make_with_module_prefix_in_fresh_process():
    code = ("import sys, gymnasium as gym\n"
            "assert 'radar_env' not in sys.modules\n"
            "env = gym.make('radar_env:RadarTrack-v0')\n"
            "obs, info = env.reset(seed=1)\n"
            "assert env.observation_space.contains(obs)\n"
            "print(type(env.unwrapped).__name__)\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=60)
    assert res.returncode == 0, res.stderr
    assert res.stdout.strip() == "RadarTrackEnv"


def test_registration_idempotent():
    from gymnasium.envs.registration import registry
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # a re-registration would warn "Overriding environment"
        radar_env._register()
        radar_env._register()
        importlib.reload(radar_env)
    assert [k for k in registry if "RadarTrack" in k] == list(radar_env.ENV_VARIANTS)
    gym.make(ENV_ID).reset(seed=0)


# ------------------------------------------------------------------------------------------------ checkers
@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_gymnasium_env_checker(action_type):
    from gymnasium.utils.env_checker import check_env
    env = gym.make(ENV_ID, action_type=action_type, scenario="kim_lee_accel").unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, skip_render_check=True)


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_sb3_env_checker(action_type):
    from stable_baselines3.common.env_checker import check_env
    env = gym.make(ENV_ID, action_type=action_type, scenario="kim_lee_accel")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, warn=True)


# ------------------------------------------------------------------------------------------------ determinism
@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_same_seed_same_episodes_bit_for_bit(action_type):
    radar = atc_radar(detection_probability=0.8)  # missed looks: NaN plots must compare equal bit for bit
    a = _rollout(gym.make(ENV_ID, action_type=action_type, radar=radar), seed=7)
    b = _rollout(gym.make(ENV_ID, action_type=action_type, radar=radar), seed=7)
    assert len(a) == len(b)
    saw_nan = False
    for sa, sb in zip(a, b):
        for x, y in zip(sa, sb):
            assert _bytes_equal(x, y)
        saw_nan |= bool(np.isnan(sa[4]["measurement"]).any())
    assert saw_nan, "no missed look in the rollout: the NaN comparison was not exercised"


def test_different_seeds_differ():
    a = _rollout(gym.make(ENV_ID), seed=1, n_episodes=1)
    b = _rollout(gym.make(ENV_ID), seed=2, n_episodes=1)
    assert not np.array_equal(a[0][0], b[0][0])
    assert not np.array_equal(a[0][4]["truth"], b[0][4]["truth"])


def test_reset_option_scenario_applies_to_that_reset_only():
    env = gym.make(ENV_ID)
    bizup = make_setup("bizup2002").scenario
    env.reset(seed=3, options={"scenario": "bizup2002"})
    ep = env.unwrapped.episode()
    np.testing.assert_array_equal(ep["truth"], bizup.states_at(ep["t_s"]))
    env.reset()
    ep2 = env.unwrapped.episode()
    assert ep2["t_s"].shape != ep["t_s"].shape or not np.array_equal(ep2["truth"], ep["truth"])
    # and the constructor's default comes back with the same draws as a fresh env that never saw the option
    ref = gym.make(ENV_ID)
    ref.reset(seed=3)
    ref_ep = ref.unwrapped.episode()
    assert not np.array_equal(ref_ep["truth"][:1], bizup.states_at(ref_ep["t_s"][:1]))


# ------------------------------------------------------------------------------------------------ info contract
def test_default_q_levels():
    j = np.arange(-4, 9)
    np.testing.assert_allclose(DEFAULT_Q_LEVELS_G, 0.03 * (2 / 0.03) ** (j / 6), rtol=1e-14)
    lv = np.asarray(DEFAULT_Q_LEVELS_G)
    assert len(lv) == 13 and np.all(np.diff(lv) > 0)
    assert np.isclose(lv, 0.03, rtol=1e-12).sum() == 1 and np.isclose(lv, 2.0, rtol=1e-12).sum() == 1
    assert lv[0] <= 0.003 and lv[-1] >= 8.0


def test_info_keys_shapes_q_and_reward_terms():
    env = gym.make(ENV_ID)
    obs, info = env.reset(seed=11)
    assert set(info) == INFO_KEYS | EXTRA_INFO_KEYS
    assert obs.dtype == np.float32 and obs.shape == env.observation_space.shape
    levels = np.asarray(DEFAULT_Q_LEVELS_G) * G0_M_S2
    assert info["q_m_s2"] == pytest.approx(0.03 * G0_M_S2)  # warm-up level
    for a in [0, 4, 10, 12, 6, 0]:
        obs, r, te, tr, info = env.step(a)
        assert set(info) == INFO_KEYS | EXTRA_INFO_KEYS
        shapes = {"truth": (4,), "estimate": (4,), "covariance": (4, 4), "measurement": (2,),
                  "measurement_covariance": (2, 2), "polar": (3,)}
        for k, s in shapes.items():
            assert np.shape(info[k]) == s, k
        for k in ("q_m_s2", "dt"):
            assert isinstance(info[k], float) and np.isfinite(info[k])
        for k in ("detected", "maneuvering", "track_lost"):
            assert isinstance(info[k], bool)
        assert info["q_m_s2"] == levels[a]  # exactly the chosen level, m/s^2
        assert info["dt"] > 0
        assert set(info["reward_terms"]) == {"position_error", "track_lost"}
        assert r == pytest.approx(sum(info["reward_terms"].values()), rel=0, abs=1e-12)
        assert isinstance(r, float)
        assert np.isnan(info["measurement"]).all() == (not info["detected"])


@pytest.mark.parametrize("a, end", [(-1.0, 0), (1.0, -1)])
def test_continuous_action_maps_to_range_ends(a, end):
    env = gym.make(ENV_ID, action_type="continuous")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([a], dtype=np.float32))
    assert info["q_m_s2"] == pytest.approx(DEFAULT_Q_LEVELS_G[end] * G0_M_S2, rel=1e-12)


def test_continuous_midpoint_is_geometric_mean():
    env = gym.make(ENV_ID, action_type="continuous")
    env.reset(seed=0)
    _, _, _, _, info = env.step(np.array([0.0], dtype=np.float32))
    lo, hi = DEFAULT_Q_LEVELS_G[0] * G0_M_S2, DEFAULT_Q_LEVELS_G[-1] * G0_M_S2
    assert info["q_m_s2"] == pytest.approx(np.sqrt(lo * hi), rel=1e-12)


def test_observation_does_not_depend_on_truth(monkeypatch):
    """Same plots, different truth: the observations must be identical (only rewards/infos may differ)."""
    def run():
        env = gym.make(ENV_ID, track_loss_gate_sigma=1e6)
        out = [env.reset(seed=5)]
        for a in [0, 12, 4, 8] * 30:
            o, r, te, tr, i = env.step(a)
            out.append((o, r, i))
            if te or tr:
                break
        return out

    ref = run()
    orig = LookDrawer.draw   # the core draws its episodes straight into the tracker's looks (radar_env.sim.draws)

    def perturbed(self, keys, rows, tracker, num_threads=1):
        orig(self, keys, rows, tracker, num_threads)
        L = tracker._looks
        L[rows, :, L_TRUTH:L_TRUTH + 4] += np.array([300.0, -200.0, 5.0, -3.0])
        L[rows, :, L_TACC:L_TACC + 2] += 20.0
        L[rows, :, L_TTURN] += 0.1
        L[rows, :, L_MAN] = 1.0 - L[rows, :, L_MAN]

    monkeypatch.setattr(LookDrawer, "draw", perturbed)   # the core draws the episodes
    alt = run()
    assert len(ref) == len(alt)
    for a, b in zip(ref, alt):
        assert a[0].tobytes() == b[0].tobytes()
    assert any(a[1] != b[1] for a, b in zip(ref[1:], alt[1:])), "truth perturbation did not reach the reward"


# ------------------------------------------------------------------------------------------------ config errors
@pytest.mark.parametrize("kwargs, name", [
    ({"bogus": 1}, "bogus"),
    ({"action_type": "multi"}, "action_type"),
    ({"q_levels_g": (1.0,)}, "q_levels_g"),
    ({"q_levels_g": (1.0, 0.5)}, "q_levels_g"),
    ({"q_levels_g": (0.0, 1.0)}, "q_levels_g"),
    ({"q_levels_g": (0.1, float("nan"))}, "q_levels_g"),
    ({"features": ("nis", "truth_x")}, "truth_x"),
    ({"features": ()}, "features"),
    ({"warmup_scans": -1}, "warmup_scans"),
    ({"warmup_scans": 2.5}, "warmup_scans"),
    ({"scenario": "nowhere"}, "scenario"),
    ({"reward_type": "cubic"}, "reward_type"),
    ({"reward_clip": 0}, "reward_clip"),
    ({"track_loss_gate_sigma": float("inf")}, "track_loss_gate_sigma"),
])
def test_config_errors_name_the_parameter(kwargs, name):
    with pytest.raises(ValueError, match=name):
        RadarTrackEnv(**kwargs)
    with pytest.raises(ValueError, match=name):
        gym.make(ENV_ID, **kwargs)


def test_bad_reset_option():
    env = gym.make(ENV_ID)
    with pytest.raises(ValueError, match="sceanrio"):
        env.reset(seed=0, options={"sceanrio": "bizup2002"})
    with pytest.raises(ValueError, match="scenario"):
        env.reset(seed=0, options={"scenario": "nowhere"})
    with pytest.raises(ValueError, match="reset: options must be a dict"):
        env.reset(seed=0, options="bizup2002")
    with pytest.raises(ValueError, match="reset: seed must be >= 0, got -1"):
        env.reset(seed=-1)
    a, _ = env.reset(seed=np.int64(7))          # a numpy integer seeds as the same Python integer
    b, _ = env.reset(seed=7)
    np.testing.assert_array_equal(a, b)


def test_vector_reset_seeds_and_options_are_checked():
    venv = RadarTrackVectorEnv(num_envs=3)
    a, _ = venv.reset(seed=np.array([1, 2, 3]))
    b, _ = venv.reset(seed=[1, 2, 3])
    np.testing.assert_array_equal(a, b)
    for bad, match in ((dict(seed=-1), "seed must be >= 0"), (dict(seed=[1, -2, 3]), "seed must be >= 0"),
                       (dict(options="x"), "reset: options must be a dict")):
        with pytest.raises(ValueError, match=match):
            venv.reset(**bad)
    with pytest.raises(ValueError, match=r"num_envs=1,000,000,000: the rows' arrays do not fit"):
        RadarTrackVectorEnv(num_envs=10**9)


@pytest.mark.parametrize("action_type, bad", [
    ("discrete", 13), ("discrete", -1), ("discrete", np.nan), ("discrete", 1.5), ("discrete", [1, 2]),
    ("continuous", np.array([1.5], np.float32)), ("continuous", np.array([np.nan], np.float32)),
    ("continuous", np.array([-np.inf])), ("continuous", np.zeros(2, np.float32)),
])
def test_bad_actions(action_type, bad):
    env = RadarTrackEnv(action_type=action_type)
    env.reset(seed=0)
    with pytest.raises(ValueError):
        env.step(bad)


def test_step_before_reset_and_after_end():
    with pytest.raises(RuntimeError, match="reset"):
        RadarTrackEnv().step(0)
    with pytest.raises(gym.error.ResetNeeded):
        gym.make(ENV_ID).step(0)
    env = RadarTrackEnv(scenario="kim_lee_accel")
    env.reset(seed=0)
    done = False
    while not done:
        _, _, te, tr, _ = env.step(4)
        done = te or tr
    with pytest.raises(RuntimeError, match="reset"):
        env.step(4)


# ------------------------------------------------------------------------------------------------ track loss
HIGH_G = {"turn_accel_g": (5.0, 7.0), "turn_heading_change_deg": (120.0, 270.0), "speed_kt": (400.0, 600.0)}


def _steps_to_end(env, seed, action):
    env.reset(seed=seed)
    n, done = 0, False
    while not done:
        _, _, te, tr, info = env.step(action)
        n += 1
        done = te or tr
    return n, te, info


@pytest.mark.parametrize("kwargs, action", [
    ({"random_config": HIGH_G}, 0),                # 0.0018 g against 5-7 g turns
    ({"track_loss_gate_sigma": 1.0}, 12),          # tight gate
])
def test_track_loss_terminates_with_penalty(kwargs, action):
    clip = 50.0
    n_total, te_ok, _ = _steps_to_end(RadarTrackEnv(track_loss_gate_sigma=1e6, reward_clip=clip,
                                                    **{k: v for k, v in kwargs.items() if k == "random_config"}),
                                      seed=4, action=action)
    assert not te_ok
    env = RadarTrackEnv(reward_clip=clip, **kwargs)
    env.reset(seed=4)
    n, done, rewards = 0, False, []
    while not done:
        _, r, te, tr, info = env.step(action)
        rewards.append(r)
        n += 1
        done = te or tr
        assert info["track_lost"] == te
    assert te and not tr and info["track_lost"]
    assert n < n_total
    assert info["reward_terms"]["track_lost"] == pytest.approx(-clip * (n_total - n))
    assert -clip <= info["reward_terms"]["position_error"] < 0
    assert rewards[-1] == pytest.approx(sum(info["reward_terms"].values()))
    assert all(r >= -clip for r in rewards[:-1])


# ------------------------------------------------------------------------------------------------ vector env
def test_make_vec_native():
    from gymnasium.vector import AutoresetMode
    venv = gym.make_vec(ENV_ID, num_envs=3, vectorization_mode="vector_entry_point", scenario="kim_lee_accel")
    assert isinstance(venv.unwrapped, RadarTrackVectorEnv)
    assert venv.metadata["autoreset_mode"] == AutoresetMode.SAME_STEP
    obs, info = venv.reset(seed=0)
    assert obs.shape == (3, len(DEFAULT_FEATURES)) and venv.observation_space.contains(obs)
    obs, rew, te, tr, info = venv.step(venv.action_space.sample())
    assert rew.shape == te.shape == tr.shape == (3,)
    for k in INFO_KEYS - {"reward_terms"}:
        assert np.shape(info[k])[0] == 3, k
        assert info["_" + k].dtype == bool and info["_" + k].all(), k
    assert info["covariance"].shape == (3, 4, 4)
    assert info["reward_terms"]["position_error"].shape == (3,) and info["_reward_terms"].all()
    np.testing.assert_allclose(rew, info["reward_terms"]["position_error"] + info["reward_terms"]["track_lost"])


def _compare_vector_row_to_single(seed, row, num_envs, n_steps, action_type="discrete", scenario="kim_lee_accel",
                                  **kwargs):
    venv = RadarTrackVectorEnv(num_envs=num_envs, scenario=scenario, action_type=action_type, **kwargs)
    env = RadarTrackEnv(scenario=scenario, action_type=action_type, **kwargs)
    vo, vi = venv.reset(seed=seed)
    so, si = env.reset(seed=seed + row)
    assert vo[row].tobytes() == so.tobytes()
    assert _bytes_equal(vi["truth"][row], si["truth"])
    rng = np.random.default_rng(0)
    boundaries = 0
    for _ in range(n_steps):
        if action_type == "discrete":
            acts = rng.integers(0, 13, size=num_envs)
            a_single = int(acts[row])
        else:
            acts = rng.uniform(-1, 1, size=(num_envs, 1)).astype(np.float32)
            a_single = acts[row]
        vo, vr, vte, vtr, vi = venv.step(acts)
        so, sr, ste, strn, si = env.step(a_single)
        assert vr[row] == sr and vte[row] == ste and vtr[row] == strn
        if ste or strn:
            boundaries += 1
            assert vi["_final_obs"][row] and vi["final_obs"][row].tobytes() == so.tobytes()
            fi = vi["final_info"]
            assert fi["_truth"][row]
            assert _bytes_equal(fi["truth"][row], si["truth"]) and _bytes_equal(fi["estimate"][row], si["estimate"])
            so, si = env.reset()  # continues the env's generator, as the vector row does
        else:
            assert not vi.get("_final_obs", np.zeros(num_envs, bool))[row]
        assert vo[row].tobytes() == so.tobytes()
        for k in ("truth", "estimate", "covariance", "measurement", "q_m_s2", "dt"):
            assert _bytes_equal(np.asarray(vi[k][row]), np.asarray(si[k])), k
    return boundaries


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_vector_one_env_equals_single_env_across_boundary(action_type):
    assert _compare_vector_row_to_single(seed=21, row=0, num_envs=1, n_steps=200, action_type=action_type) >= 2


def test_vector_row_i_equals_single_env_seeded_s_plus_i():
    for row in (0, 2, 3):
        _compare_vector_row_to_single(seed=100, row=row, num_envs=4, n_steps=95, scenario="random",
                                      radar=atc_radar(detection_probability=0.8))


def test_vector_bad_actions_and_step_before_reset():
    venv = RadarTrackVectorEnv(num_envs=2)
    with pytest.raises(RuntimeError):
        venv.step(np.zeros(2, dtype=np.int64))
    venv.reset(seed=0)
    for bad in (np.array([0, 13]), np.array([0]), np.array([0.0, np.nan])):
        with pytest.raises(ValueError):
            venv.step(bad)


# ------------------------------------------------------------------------------------------------ robustness
@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_random_and_extreme_actions_stay_finite(action_type):
    n = 16
    venv = RadarTrackVectorEnv(num_envs=n, action_type=action_type)
    obs, info = venv.reset(seed=2024)
    rng = np.random.default_rng(1)
    ends = 0
    for t in range(350):
        mode = (t // 40) % 3  # runs of lowest, highest and random actions
        if action_type == "discrete":
            acts = {0: np.zeros(n, int), 1: np.full(n, 12), 2: rng.integers(0, 13, n)}[mode]
        else:
            acts = {0: -np.ones((n, 1)), 1: np.ones((n, 1)), 2: rng.uniform(-1, 1, (n, 1))}[mode].astype(np.float32)
        obs, rew, te, tr, info = venv.step(acts)
        ends += int((te | tr).sum())
        assert np.all(np.isfinite(obs)) and venv.observation_space.contains(obs)
        assert np.all(np.isfinite(rew))
        P = info["covariance"]
        np.testing.assert_array_equal(P, np.swapaxes(P, -1, -2))
        assert np.all(np.linalg.eigvalsh(P) > 0)
        assert np.all(np.isfinite(info["estimate"]))
    assert ends >= n  # many episodes (incl. lost tracks) went through


# ------------------------------------------------------------------------------------------------ copies
def test_pickle_and_deepcopy_continue_identically():
    import copy
    import pickle
    env = RadarTrackEnv(radar=atc_radar(detection_probability=0.9))
    env.reset(seed=9)
    for a in (3, 7, 1):
        env.step(a)
    clones = [pickle.loads(pickle.dumps(env)), copy.deepcopy(env)]
    for a in [12, 0, 5] * 20:
        ref = env.step(a)
        for c in clones:
            got = c.step(a)
            assert all(_bytes_equal(x, y) for x, y in zip(ref, got))
        if ref[2] or ref[3]:
            break


def test_vector_reset_options_and_seed_list():
    venv = RadarTrackVectorEnv(num_envs=2)
    o1, _ = venv.reset(seed=[5, 9])
    env = RadarTrackEnv()
    assert env.reset(seed=9)[0].tobytes() == o1[1].tobytes()
    _, info = venv.reset(seed=0, options={"scenario": "bizup2002"})
    bizup = make_setup("bizup2002").scenario
    np.testing.assert_array_equal(info["truth"], bizup.states_at(info["time_s"]))
    with pytest.raises(ValueError, match="sceanrio"):
        venv.reset(options={"sceanrio": "bizup2002"})
    # reset() without a seed continues each row's generator (reproducible from the first seed)
    a, b = RadarTrackVectorEnv(num_envs=2), RadarTrackVectorEnv(num_envs=2)
    a.reset(seed=4), b.reset(seed=4)
    assert a.reset()[0].tobytes() == b.reset()[0].tobytes()
    with pytest.raises(ValueError, match="num_envs"):
        venv.reset(seed=[1, 2, 3])


# ------------------------------------------------------------------------------------------------ reward formula
@pytest.mark.parametrize("reward_type", ["squared", "absolute", "squared_m"])
def test_reward_formula_against_truth(reward_type):
    """Bizup's radar sits at the origin: e = |estimate - truth| / sqrt((sr^2 + (r sb)^2) / 2), r = |truth|;
    squared_m: e = |estimate - truth| / 100 m."""
    setup = make_setup("bizup2002")
    site = setup.radar.sites[0]
    clip = 2.0 if reward_type == "absolute" else 7.0
    env = gym.make(ENV_ID, scenario="bizup2002", reward_type=reward_type, reward_clip=clip,
                   track_loss_gate_sigma=1e6)
    env.reset(seed=0)
    clipped = False
    for a in [12, 0, 6] * 20:
        _, r, te, tr, info = env.step(a)
        rng_m = np.hypot(*info["truth"][:2])
        sig = np.sqrt(0.5 * (site.range_noise_std_m ** 2 + (rng_m * site.bearing_noise_std_rad) ** 2))
        e = np.hypot(*(info["estimate"][:2] - info["truth"][:2])) / (100.0 if reward_type == "squared_m" else sig)
        expected = -min(e if reward_type == "absolute" else e * e, clip)
        assert r == pytest.approx(expected, rel=1e-9)
        assert info["reward_terms"]["track_lost"] == 0.0
        clipped |= expected == -clip
        if te or tr:
            break
    assert clipped, "the clip was never reached (action 0 in a 2 g turn should exceed it)"


# ------------------------------------------------------------------------------------------------ vs Gymnasium
def test_native_vector_env_equals_gymnasium_sync_vector_env():
    """Gymnasium's own SyncVectorEnv (same-step autoreset) over the single env gives the same rollout."""
    from gymnasium.vector import AutoresetMode
    n = 2
    native = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="vector_entry_point", scenario="kim_lee_accel")
    sync = gym.make_vec(ENV_ID, num_envs=n, vectorization_mode="sync", scenario="kim_lee_accel",
                        vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP})
    o1, _ = native.reset(seed=3)
    o2, _ = sync.reset(seed=3)
    assert o1.tobytes() == o2.tobytes()
    rng = np.random.default_rng(0)
    ends = 0
    for _ in range(190):
        acts = rng.integers(0, 13, n)
        o1, r1, te1, tr1, i1 = native.step(acts)
        o2, r2, te2, tr2, i2 = sync.step(acts)
        assert o1.tobytes() == o2.tobytes()
        np.testing.assert_array_equal(r1, r2)
        np.testing.assert_array_equal(te1, te2)
        np.testing.assert_array_equal(tr1, tr2)
        np.testing.assert_array_equal(i1["estimate"], i2["estimate"])
        if (te1 | tr1).any():
            ends += 1
            for j in np.flatnonzero(te1 | tr1):
                assert i1["final_obs"][j].tobytes() == i2["final_obs"][j].tobytes()
    assert ends >= 2


def test_max_episode_steps_truncates_like_time_limit():
    """gym.make_vec passes max_episode_steps to the vector entry point: it must truncate as gym.make's TimeLimit."""
    venv = gym.make_vec(ENV_ID, num_envs=2, vectorization_mode="vector_entry_point", max_episode_steps=7)
    env = gym.make(ENV_ID, max_episode_steps=7)
    vo, _ = venv.reset(seed=0)
    so, _ = env.reset(seed=0)
    for t in range(1, 16):
        vo, vr, vte, vtr, vi = venv.step(np.array([3, 3]))
        so, sr, ste, strn, si = env.step(3)
        assert vtr[0] == strn == (t % 7 == 0)
        assert vtr.tolist() == [strn, strn]
        if strn:
            assert vi["_final_obs"].all()
            so, _ = env.reset()
        assert vo[0].tobytes() == so.tobytes() and vr[0] == sr
    with pytest.raises(ValueError, match="max_episode_steps"):
        RadarTrackVectorEnv(num_envs=1, max_episode_steps=0)


def test_documented_observation_tables_match_the_feature_specs():
    """The observation tables users read (RadarTrackEnv's docstring, radar_env.envs.observation's module docstring) list
    every feature of FEATURE_SPECS, in order, with its index, unit range and scale."""
    import re

    import radar_env.envs.observation as obs_mod
    from radar_env.envs.observation import FEATURE_SPECS
    names = list(FEATURE_SPECS)
    rows = re.findall(r"^\s*\| (\d+) \| (\w+):.*\| ([^|]+) \| (-?\d+) \| (-?\d+) \|$", RadarTrackEnv.__doc__, re.M)
    assert [r[1] for r in rows] == names and [int(r[0]) for r in rows] == list(range(len(names)))
    for _, name, scaling, lo, hi in rows:
        s = FEATURE_SPECS[name]
        assert (int(lo), int(hi)) == (s.low, s.high), name
        if s.kind == "linear":
            assert scaling.strip() == ("x" if s.scale == 1 else f"x/{s.scale:g}"), name
    listed = re.findall(r"^``(\w+)``\s{2,}", obs_mod.__doc__, re.M)  # table rows: name, then aligned columns
    assert listed == names


def test_inconsistency_reward_term_is_the_position_nees_beyond_its_bound():
    """reward_nees_weight w: the term is -w * min(max(NEES / chi2_2(0.99) - 1, 0), reward_clip) of the position
    error against the position block of P (computed here with numpy's solve); the other terms and the episode are
    unchanged."""
    from scipy.stats import chi2
    w = 0.1
    plain, nees_env = gym.make("RadarTrack-v0"), gym.make("RadarTrack-v0", reward_nees_weight=w)
    plain.reset(seed=8)
    nees_env.reset(seed=8)
    seen_positive = False
    for a in [0] * 40 + [12] * 10:
        _, r0, t0, tr0, i0 = plain.step(a)
        _, r1, t1, tr1, i1 = nees_env.step(a)
        assert (t0, tr0) == (t1, tr1)
        d = i1["estimate"][:2] - i1["truth"][:2]
        nees = d @ np.linalg.solve(i1["covariance"][:2, :2], d)
        want = -w * min(max(nees / chi2.ppf(0.99, 2) - 1.0, 0.0), 100.0)   # reward_clip 100
        assert i1["reward_terms"]["inconsistency"] == pytest.approx(want, rel=1e-9, abs=1e-12)
        assert i1["reward_terms"]["position_error"] == i0["reward_terms"]["position_error"]
        assert r1 == pytest.approx(r0 + want, rel=0, abs=1e-12)
        seen_positive |= want < 0
        if t0 or tr0:   # the track was lost (or the flight ended): the episode is over
            break
    assert seen_positive   # q = 0.00045 g on a maneuvering flight: the covariance is too small somewhere
    with pytest.raises(ValueError, match="reward_nees_weight"):
        gym.make("RadarTrack-v0", reward_nees_weight=-1.0)
