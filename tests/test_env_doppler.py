"""RadarTrackDoppler-v0: RadarTrack-v0 whose filter also updates on the radial velocity (issue 39). Registered with
its argument, passing Gymnasium's and stable-baselines3's checkers, the same as ``RadarTrack-v0`` with
``radial_velocity=True`` bit for bit and different from v0 on the same seed and actions; its native vector env row
equals the single env; the IMM env with range rate stays finite under random actions; a non-boolean value is refused
when the env is built."""

import warnings

import gymnasium as gym
import numpy as np
import pytest

import radar_env
from test_env import _bytes_equal, _compare_vector_row_to_single, _rollout

ENV_ID = "RadarTrackDoppler-v0"


def test_registered_with_its_argument():
    assert radar_env.ENV_VARIANTS[ENV_ID] == {"radial_velocity": True}
    assert gym.spec(ENV_ID).kwargs == {"radial_velocity": True}
    assert gym.make(ENV_ID).unwrapped.config.radial_velocity is True


@pytest.mark.parametrize("action_type", ["discrete", "continuous"])
def test_env_checkers(action_type):
    from gymnasium.utils.env_checker import check_env
    from stable_baselines3.common.env_checker import check_env as sb3_check_env
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(gym.make(ENV_ID, action_type=action_type, scenario="kim_lee_accel").unwrapped,
                  skip_render_check=True)
        sb3_check_env(gym.make(ENV_ID, action_type=action_type, scenario="kim_lee_accel"), warn=True)


def test_equals_v0_with_the_argument_and_differs_from_v0():
    a = _rollout(gym.make(ENV_ID), seed=5, n_episodes=1)
    b = _rollout(gym.make("RadarTrack-v0", radial_velocity=True), seed=5, n_episodes=1)
    c = _rollout(gym.make("RadarTrack-v0"), seed=5, n_episodes=1)
    assert len(a) == len(b)
    for sa, sb in zip(a, b):
        for x, y in zip(sa, sb):
            assert _bytes_equal(x, y)
    assert _bytes_equal(a[0][4]["truth"], c[0][4]["truth"])        # same flight and plots ...
    assert not _bytes_equal(a[3][4]["estimate"], c[3][4]["estimate"])   # ... another filter


def test_vector_row_equals_single_env():
    _compare_vector_row_to_single(seed=30, row=1, num_envs=3, n_steps=120, radial_velocity=True)


def test_imm_env_with_range_rate_stays_finite_under_random_actions():
    env = gym.make(ENV_ID, tracker="imm_cv_ct", action_type="continuous", scenario="random_radars")
    rng = np.random.default_rng(0)
    env.reset(seed=3)
    for _ in range(300):
        _, r, te, tr, info = env.step(rng.choice([-1.0, 1.0, 0.0], size=7).astype(np.float32))
        P = info["covariance"]
        assert np.isfinite(r) and np.isfinite(info["estimate"]).all() and np.isfinite(P).all()
        assert np.allclose(P, P.T) and np.linalg.eigvalsh(P).min() > 0
        if te or tr:
            env.reset()


def test_non_boolean_radial_velocity_is_refused():
    with pytest.raises(ValueError, match="radial_velocity must be True or False"):
        gym.make("RadarTrack-v0", radial_velocity="yes")
