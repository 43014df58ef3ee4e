"""The registered env ids (radar_env/envs/variants.py): each passes Gymnasium's check_env, each bundled learned
tracker's env_config.json is exactly its id's kwargs (so the two cannot drift), and gym.make keeps Gymnasium's
behaviour (overrides accepted, unknown keys refused in one line)."""

import json
import math
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.envs.registration import registry

import radar_env
from radar_env.envs.variants import ENV_VARIANTS, PINNED_FEATURES
from agents.policies.checks import env_kwargs_from_json
from agents.policies.bundle import (BUNDLED_ENV_IDS, BUNDLED_POLICIES, bundled_env_kwargs,
                                    policy_env_kwargs)

IDS = list(ENV_VARIANTS)


def test_every_variant_is_registered_with_its_kwargs_and_no_time_limit():
    assert radar_env.ENV_VARIANTS is ENV_VARIANTS
    for env_id, kwargs in ENV_VARIANTS.items():
        spec = registry[env_id]
        assert spec.kwargs == kwargs and spec.kwargs is not kwargs   # a copy: gym.make cannot change the table
        assert spec.max_episode_steps is None    # the flight ends the episode (variants.py says why)
        assert spec.entry_point == "radar_env.envs.env:RadarTrackEnv"
        assert spec.vector_entry_point == "radar_env.envs.env:RadarTrackVectorEnv"


def test_variant_kwargs_are_json_like():
    """What env_kwargs_from_json gives for the JSON of the kwargs is the kwargs: tuples for lists and ranges."""
    for kwargs in ENV_VARIANTS.values():
        assert env_kwargs_from_json(json.loads(json.dumps(kwargs))) == kwargs


@pytest.mark.parametrize("env_id", IDS)
def test_check_env(env_id):
    from gymnasium.utils.env_checker import check_env
    env = gym.make(env_id, disable_env_checker=True).unwrapped
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env, skip_render_check=True)


@pytest.mark.parametrize("name", sorted(BUNDLED_ENV_IDS))
def test_bundled_env_config_is_its_ids_kwargs(name):
    env_id = BUNDLED_ENV_IDS[name]
    assert bundled_env_kwargs(name) == registry[env_id].kwargs
    # and gym.make(id) gives the observation (and action range) the checkpoint was trained on
    meta = json.loads(BUNDLED_POLICIES[name].with_name("policy.json").read_text())
    env = gym.make(env_id).unwrapped
    assert env.observation_space.shape == (meta["architecture"]["input_size"],)
    assert tuple(meta["input_features"]) == env.config.features == PINNED_FEATURES
    if "q_range_m_s2" in meta:        # the q-policy's action map is the env's continuous one
        assert np.allclose(meta["q_range_m_s2"], [env.q_levels_m_s2[0], env.q_levels_m_s2[-1]], rtol=1e-9)
        assert env.config.tracker == meta["model"] == "cv"
    else:                             # the learned IMM: the env's filter and its feature chain's q
        from radar_env.envs.imm_env import imm_env_defaults
        assert env.config.tracker == meta["model"] == "imm_cv_ct"
        assert math.isclose(imm_env_defaults()["feature_q_g"], meta["feature_q_g"], rel_tol=1e-12)


def test_the_other_bundles_are_one_override_away():
    """What BUNDLED_ENV_IDS's docstring says of the PPO bundles."""
    cont, imm = registry["RadarTrackContinuous-v0"].kwargs, registry["RadarTrackIMM-v0"].kwargs
    assert policy_env_kwargs(BUNDLED_POLICIES["policy"]) == {**cont, "action_type": "discrete",
                                                             "reward_type": "squared", "frame_stack": 4}
    ppo = policy_env_kwargs(BUNDLED_POLICIES["policy_imm_ppo"])
    assert {k: v for k, v in ppo.items() if k not in ("random_config", "reward_type")} == {
        k: v for k, v in imm.items() if k != "random_config"}
    assert ppo["random_config"] != imm["random_config"]     # the earlier flights
    assert ppo["reward_type"] == "squared" == radar_env.envs.config.EnvConfig.reward_type   # the default
    prior = bundled_env_kwargs("policy_imm_bp_prior")      # the random suites' own flights
    assert prior == {**imm, "random_config": {"random_radar_probability": 0.7}}
    cv_prior = bundled_env_kwargs("policy_bp_prior")
    assert cv_prior == {**cont, "random_config": {"random_radar_probability": 0.7}}
    assert bundled_env_kwargs("policy_window") == cv_prior         # its base acts
    assert set(BUNDLED_ENV_IDS) | {"policy", "policy_imm_ppo", "policy_imm_bp_prior", "policy_bp_prior",
                                   "policy_window"} == set(BUNDLED_POLICIES)
    with pytest.raises(ValueError, match="unknown bundled policy 'policy_x'.*policy_bp"):
        bundled_env_kwargs("policy_x")


def test_make_accepts_overrides_and_refuses_unknown_keys():
    env = gym.make("RadarTrackIMM-v0", scenario="bizup2002", feature_q_g=0.5).unwrapped
    assert env.config.scenario == "bizup2002" and env.config.feature_q_g == 0.5
    assert env.config.tracker == "imm_cv_ct"                     # the id's other kwargs stay
    assert registry["RadarTrackIMM-v0"].kwargs == ENV_VARIANTS["RadarTrackIMM-v0"]   # the override did not stick
    env = gym.make("RadarTrackContinuous-v0", random_config={"speed_kt": [100, 200]}).unwrapped
    assert env.config.random_scenario_config.speed_kt == (100.0, 200.0)
    with pytest.raises(ValueError) as e:
        gym.make("RadarTrackContinuousDoppler-v0", framestack=2)
    assert "framestack" in str(e.value) and "\n" not in str(e.value)
    with pytest.raises(ValueError, match=r"frame_stack.*\[1, 64\]|frame_stack.*1.*64"):
        gym.make("RadarTrackContinuous-v0", frame_stack=0)


def test_vector_make_of_each_new_id():
    for env_id in ("RadarTrackContinuous-v0", "RadarTrackIMMDoppler-v0"):
        venv = gym.make_vec(env_id, num_envs=2, vectorization_mode="vector_entry_point")
        obs, _ = venv.reset(seed=0)
        assert obs.shape == (2,) + gym.make(env_id).observation_space.shape
        obs, r, term, trunc, _ = venv.step(np.zeros((2,) + venv.single_action_space.shape, dtype=np.float32))
        assert np.all(np.isfinite(r))
