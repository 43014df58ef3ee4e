"""The default env's optional detector features (radar_env.envs.detectors): off by default, equal to what the imm_cv_ct
and imm2 trackers compute on the same episode (imm2 against the independent 4-state IMM), independent of the
actions, the same in the evaluation's lockstep (run_q_policy) and the vector env, refused where unsupported."""

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding
from gymnasium.utils.env_checker import check_env

import radar_env  # noqa: F401  (registers RadarTrack-v0)
from baselines.imm_cv_ct_runner import _start_state, common_start, imm_cv_ct_filter, tuned_imm_cv_ct_spec
from baselines.registry import run_tracker
from baselines.trackers import run_q_policy
from baselines.tuned_params import tuned_parameters
from radar_env.envs.detectors import DetectorBank, detector_imm2_parameters
from radar_env.sim.draws import draw_episodes
from radar_env.envs.observation import DEFAULT_FEATURES, DETECTOR_FEATURES, FEATURE_SPECS, ObservationLayout

WITH = DEFAULT_FEATURES + DETECTOR_FEATURES


def _episode(seed, scenario="random"):
    """The episode a single env reset with ``seed`` draws (tests/test_env_imm.py)."""
    return draw_episodes(scenario, None, None, [seeding.np_random(seed)[0]], 12).episode(0)


def _rollout(env, seed, action):
    """Reset with ``seed`` and step with ``action(i)`` to the end: observations and the detectors' values."""
    obs, _ = env.reset(seed=seed)
    det = env.unwrapped._core.detectors
    out, vals = [obs], [det.values[0].copy()]
    i = 0
    while True:
        obs, _, term, trunc, _ = env.step(action(i))
        out.append(obs)
        vals.append(det.values[0].copy())
        i += 1
        if term or trunc:
            return np.array(out), np.array(vals)


def test_off_by_default_and_the_copy_of_imm2_is_the_tuned_one():
    assert len(DEFAULT_FEATURES) == 27 and not set(DEFAULT_FEATURES) & set(DETECTOR_FEATURES)
    assert set(FEATURE_SPECS) == set(DEFAULT_FEATURES) | set(DETECTOR_FEATURES)
    env = gym.make("RadarTrack-v0")
    assert env.observation_space.shape == (27,) and env.unwrapped._core.detectors is None
    t = tuned_parameters()["imm2"]
    assert detector_imm2_parameters() == {k: t[k] for k in ("q_low_g", "q_high_g", "p_stay_low", "p_stay_high")}
    assert json.loads(json.dumps(detector_imm2_parameters()))


@pytest.mark.parametrize("seed,scenario", [(0, "random"), (7, "random"), (3, "bizup2002")])
def test_the_features_are_imm_cv_ct_and_imm2_on_the_same_episode(seed, scenario):
    """Every look: the CT probability and turn rate are imm_cv_ct_filter's from the common start (1e-9), the
    high-noise probability is the imm2 tracker's (the independent 4-state IMM of radar_env.filters.kalman, 1e-9); the
    observation holds them scaled as FEATURE_SPECS says. At the reset: the initial values."""
    env = gym.make("RadarTrack-v0", features=WITH, scenario=scenario)
    obs, vals = _rollout(env, seed, lambda i: 4)
    ep = _episode(seed, scenario)
    spec = tuned_imm_cv_ct_spec()
    batch, k0, x4, P4 = common_start([ep])
    x5, P5 = _start_state(spec, x4, P4)
    res = imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec)
    imm2 = run_tracker("imm2", [ep]).extra["maneuver_probability"][0]
    k0 = int(k0[0])
    n = len(vals) - 1
    assert n == int(batch.n_looks[0]) - k0 - 1     # every look after the start
    np.testing.assert_allclose(vals[0], [(1 - spec.mu0_cv) / 2, 0.0, 0.1], rtol=1e-15, atol=0)
    ks = k0 + 1 + np.arange(n)
    np.testing.assert_allclose(vals[1:, 0], res.mu[0, ks, 1], rtol=0, atol=1e-9)
    np.testing.assert_allclose(vals[1:, 1], np.degrees(res.omega_rad_s[0, ks]), rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(vals[1:, 2], imm2[ks], rtol=0, atol=1e-9)
    assert vals[:, 0].max() > 0.5 and vals[:, 2].max() > 0.5     # both detect a maneuver of these flights
    lay = env.unwrapped.layout
    np.testing.assert_array_equal(obs[:, -3:], lay.encode_physical(np.concatenate(
        [np.zeros((len(vals), 27)), vals], 1))[:, -3:])
    for j, name in enumerate(DETECTOR_FEATURES):
        np.testing.assert_allclose(lay.decode(obs, name), np.clip(vals[:, j], -20, 20), rtol=1e-6, atol=1e-6)


def test_the_other_features_and_the_estimate_are_unchanged_and_the_actions_do_not_move_the_detectors():
    seed = 5
    acts = np.random.default_rng(1).integers(0, 13, 500)
    plain, _ = _rollout_plain(seed, acts)
    obs, vals = _rollout(gym.make("RadarTrack-v0", features=WITH), seed, lambda i: acts[i])
    np.testing.assert_array_equal(obs[:, :27], plain)
    _, vals_other = _rollout(gym.make("RadarTrack-v0", features=WITH), seed, lambda i: 12 - acts[i])
    np.testing.assert_array_equal(vals, vals_other)


def _rollout_plain(seed, acts):
    env = gym.make("RadarTrack-v0")
    obs, info = env.reset(seed=seed)
    out, est = [obs], [info["estimate"]]
    for a in acts:
        obs, _, term, trunc, info = env.step(a)
        out.append(obs)
        est.append(info["estimate"])
        if term or trunc:
            break
    return np.array(out), np.array(est)


def test_a_refused_action_leaves_the_detectors_where_they_were():
    seed = 2
    good, vals = _rollout(gym.make("RadarTrack-v0", features=WITH), seed, lambda i: 4)
    env = gym.make("RadarTrack-v0", features=WITH)
    env.reset(seed=seed)
    det = env.unwrapped._core.detectors
    for _ in range(3):
        env.step(4)
    before = det.values.copy(), det.xa.copy(), det.lmb.copy()
    for bad in (13, -1, 2.5):
        with pytest.raises(ValueError, match="action"):
            env.step(bad)
    np.testing.assert_array_equal(det.values, before[0])
    np.testing.assert_array_equal(det.xa, before[1])
    np.testing.assert_array_equal(det.lmb, before[2])
    obs, *_ = env.step(4)
    np.testing.assert_array_equal(obs, good[4])


def test_the_evaluation_lockstep_hands_a_policy_the_envs_observations():
    """run_q_policy with the env's config (detector features, frame_stack 2) gives a rule reading the detectors the
    env's observations bit for bit, and the same estimates."""
    seed = 2024
    env = gym.make("RadarTrack-v0", features=WITH, frame_stack=2)
    levels = env.unwrapped.q_levels_m_s2
    F = len(WITH)
    rule = lambda o: np.where(o[:, 27] + o[:, 29] > 0.5, 10, 3)   # noqa: E731  CT or high-noise mode: high q
    obs, info = env.reset(seed=seed)
    seen_env, est = [obs], [info["estimate"]]
    while True:
        obs, _, term, trunc, info = env.step(int(rule(obs[None])[0]))
        seen_env.append(obs)
        est.append(info["estimate"])
        if term or trunc:
            break
    seen = []

    def choose(o):
        seen.append(o[0].copy())
        return levels[rule(o)]
    run = run_q_policy([_episode(seed)], choose, "rule", env.unwrapped.config)
    np.testing.assert_array_equal(np.array(seen), np.array(seen_env[:-1]))
    assert np.array(seen).shape[1] == 2 * F and len({int(rule(s[None])[0]) for s in seen}) == 2
    k0 = int(run.start_index[0]) - 1
    np.testing.assert_array_equal(run.x[0, k0:k0 + len(est)], np.array(est))


def test_vector_env_rows_are_single_envs_through_autoreset():
    """Row i of the native vector env is the single env with seed s + i, its first episode and, after the
    autoreset, its second (the step that ends an episode returns the next one's first observation)."""
    n, seed, kw = 3, 11, dict(features=WITH, scenario="kim_lee_accel")
    venv = gym.make_vec("RadarTrack-v0", num_envs=n, vectorization_mode="vector_entry_point", **kw)
    obs, _ = venv.reset(seed=seed)
    expected = []
    for i in range(n):
        env = gym.make("RadarTrack-v0", **kw)
        first, _ = _rollout(env, seed + i, lambda t: 4)
        env.unwrapped._core.detectors.values[:] = np.nan      # the next reset must set them again
        o, _ = env.reset()
        second = [o]
        for _ in range(20):
            second.append(env.step(4)[0])
        expected.append(np.concatenate([first[:-1], np.array(second)]))
    got = [obs]
    for _ in range(len(expected[0]) - 1):
        obs, _, term, trunc, info = venv.step(np.full(n, 4))
        got.append(obs)
    got = np.array(got)
    for i in range(n):
        np.testing.assert_array_equal(got[:, i], expected[i][:len(got)])


def test_refusals():
    with pytest.raises(ValueError, match=r"features \['imm_ct_prob'\] apply only with tracker='cv'"):
        gym.make("RadarTrack-v0", tracker="imm_cv_ct", features=DEFAULT_FEATURES + ("imm_ct_prob",))
    lay = ObservationLayout(WITH)
    assert lay.uses_detectors and not ObservationLayout(DEFAULT_FEATURES).uses_detectors
    tr = radar_env.envs.config.EnvConfig().track_start.tracker(1)
    out = tr.load([0], [_episode(0)])
    with pytest.raises(ValueError, match="detectors must be the"):
        lay.encode(out, np.zeros(1))
    bank = DetectorBank(1)
    bank.start(np.arange(1), tr._st)
    assert lay.encode(out, np.zeros(1), bank.values).shape == (1, len(WITH))


def test_gymnasium_env_checker_and_finite_spd_soak():
    env = gym.make("RadarTrack-v0", features=WITH, action_type="continuous", scenario="random_radars")
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)
    env.action_space.seed(0)
    obs, _ = env.reset(seed=0)
    for _ in range(600):
        obs, r, term, trunc, info = env.step(env.action_space.sample())
        det = env.unwrapped._core.detectors
        assert np.isfinite(det.values).all() and np.isfinite(det.Pa).all() and np.isfinite(det.Pb).all()
        assert env.observation_space.contains(obs)
        if term or trunc:
            obs, _ = env.reset()
