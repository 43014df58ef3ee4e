"""The native vector env's ``num_threads``: the per-row step kernel and the autoreset draws on several numba threads
give bit-identical outputs to ``num_threads=1`` (radar_env.common.parallel), and the keyword is validated."""

import gymnasium as gym
import numba
import numpy as np
import pytest

import radar_env  # noqa: F401  (registers the ids)

CONFIGS = {
    "default": {},
    "continuous": {"action_type": "continuous"},
    "random_radars": {"scenario": "random_radars"},
    "radial_velocity": {"radial_velocity": True},
    "frame_stack": {"frame_stack": 3},
}


def _flat(info, prefix=""):
    """Every array of a (nested) vector-env info as ``(key, array)``; object arrays element by element."""
    out = []
    for k, v in sorted(info.items()):
        if isinstance(v, dict):
            out += _flat(v, prefix + k + "/")
        elif isinstance(v, np.ndarray) and v.dtype == object:   # final_obs: None except for the rows that ended
            have = np.array([e is not None for e in v])
            out += [(prefix + k + "/rows", have), (prefix + k, np.stack([e for e in v if e is not None]))]
        else:
            out.append((prefix + k, np.asarray(v)))
    return out


def _trajectory(num_threads, n, steps, kwargs):
    env = gym.make_vec("RadarTrack-v0", num_envs=n, vectorization_mode="vector_entry_point",
                       num_threads=num_threads, **kwargs)
    rng = np.random.default_rng(7)
    obs, info = env.reset(seed=11)
    out = [("reset/obs", obs.copy())] + [("reset/" + k, v.copy()) for k, v in _flat(info)]
    ends = 0
    for s in range(steps):
        a = env.action_space.sample() if kwargs.get("action_type") == "continuous" else None
        a = rng.uniform(-1, 1, a.shape) if a is not None else rng.integers(0, env.single_action_space.n, n)
        obs, rew, term, trunc, info = env.step(a)
        ends += int(np.sum(term | trunc))
        out += [(f"{s}/obs", obs.copy()), (f"{s}/rew", rew.copy()), (f"{s}/term", term.copy()),
                (f"{s}/trunc", trunc.copy())]
        out += [(f"{s}/{k}", v.copy()) for k, v in _flat(info)]
    env.close()
    return out, ends


def _assert_same(a, b):
    assert [k for k, _ in a] == [k for k, _ in b]
    for (k, x), (_, y) in zip(a, b):
        assert x.dtype == y.dtype and np.array_equal(x, y, equal_nan=x.dtype.kind in "fc"), k


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
@pytest.mark.parametrize("name", list(CONFIGS))
def test_threads_bit_identical_48_rows(name):
    one, ends = _trajectory(1, 48, 300, CONFIGS[name])
    two, ends2 = _trajectory(2, 48, 300, CONFIGS[name])
    assert ends == ends2 and ends > 0      # autoresets (the parallel draws) are in the comparison
    _assert_same(one, two)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
@pytest.mark.parametrize("name", ["default", "random_radars"])
def test_threads_bit_identical_1024_rows(name):
    one, ends = _trajectory(1, 1024, 120, CONFIGS[name])
    two, _ = _trajectory(2, 1024, 120, CONFIGS[name])
    assert ends > 0
    _assert_same(one, two)


def test_num_threads_validated():
    top = numba.config.NUMBA_NUM_THREADS
    for bad in (0, -1, top + 1, 1.0, "2", True, None):
        with pytest.raises(ValueError, match=rf"num_threads must be an integer in \[1, {top}\]"):
            gym.make_vec("RadarTrack-v0", num_envs=2, vectorization_mode="vector_entry_point", num_threads=bad)


def test_num_threads_leaves_numba_setting():
    before = numba.get_num_threads()
    env = gym.make_vec("RadarTrack-v0", num_envs=4, vectorization_mode="vector_entry_point",
                       num_threads=numba.config.NUMBA_NUM_THREADS)
    env.reset(seed=0)
    env.step(np.zeros(4, dtype=np.int64))
    assert numba.get_num_threads() == before


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="numba has one thread")
@pytest.mark.parametrize("env_id, kwargs", [
    ("RadarTrackIMM-v0", {}),                                               # the IMM tracker (its kernels serial)
    ("RadarTrack-v0", {"features": "detectors"}),                           # detector features (ext columns)
    ("RadarTrack-v0", {"scenario": "bizup2002"}),                           # a fixed scenario's draws
    ("RadarTrack-v0", {"reward_nees_weight": 0.5, "max_episode_steps": 50}),
])
def test_threads_bit_identical_other_envs(env_id, kwargs):
    if kwargs.get("features") == "detectors":
        from radar_env.envs.config import EnvConfig
        from radar_env.envs.observation import DETECTOR_FEATURES
        kwargs = {"features": tuple(EnvConfig().features) + DETECTOR_FEATURES}
    runs = []
    for num_threads in (1, 2):
        env = gym.make_vec(env_id, num_envs=48, vectorization_mode="vector_entry_point", num_threads=num_threads,
                           **kwargs)
        env.action_space.seed(5)
        obs, info = env.reset(seed=11)
        out = [("reset/obs", obs.copy())] + _flat(info)
        for s in range(200):
            obs, rew, term, trunc, info = env.step(env.action_space.sample())
            out += [(f"{s}/obs", obs.copy()), (f"{s}/rew", rew.copy()), (f"{s}/end", term | trunc)]
            out += [(f"{s}/{k}", v.copy()) for k, v in _flat(info)]
        runs.append(out)
    _assert_same(*runs)
