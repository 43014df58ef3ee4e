"""frame_stack: the env's observation is the last k observations, newest first; the evaluation chain
(run_q_policy) stacks them the same way; a policy fine-tuned from a single-frame one starts as exactly it."""

import numpy as np
import pytest
import gymnasium as gym
from gymnasium.utils import seeding

import radar_env  # noqa: F401
from baselines.trackers import run_q_policy
from radar_env.envs.env import EnvConfig, RadarTrackVectorEnv, draw_setup_and_episode
from radar_env.envs.observation import FrameStack


def _rollout(k, seed, actions):
    env = gym.make("RadarTrack-v0", frame_stack=k)
    obs, _ = env.reset(seed=seed)
    out = [obs]
    for a in actions:
        obs, _, term, trunc, _ = env.step(a)
        out.append(obs)
        if term or trunc:
            break
    return np.array(out), env


def test_stack_is_the_last_k_single_observations_newest_first():
    acts = [3, 7, 0, 12, 5, 5]
    single, _ = _rollout(1, 11, acts)
    stacked, env = _rollout(3, 11, acts)
    F = single.shape[1]
    assert stacked.shape == (len(single), 3 * F) and env.observation_space.shape == (3 * F,)
    for t in range(len(single)):
        for j in range(3):   # frame j is look t - j; before the first look, the first observation repeats
            assert np.array_equal(stacked[t, j * F:(j + 1) * F], single[max(t - j, 0)]), (t, j)
    assert env.observation_space.contains(stacked[-1])
    # the current look's features decode from a stacked observation as from a single one
    lay = env.unwrapped.layout
    assert lay.decode(stacked[-1], "nis") == lay.decode(single[-1], "nis")


def test_vector_env_resets_the_stack_of_a_finished_row():
    v = RadarTrackVectorEnv(num_envs=3, frame_stack=2, scenario="kim_lee_accel")
    obs, _ = v.reset(seed=0)
    F = obs.shape[1] // 2
    assert np.array_equal(obs[:, :F], obs[:, F:])
    for _ in range(200):   # kim_lee_accel: 100 looks -> every row finishes and starts again
        prev = obs
        obs, _, term, trunc, _ = v.step(np.full(3, 4))
        done = term | trunc
        if done.any():
            # a new episode's stack repeats its first observation (nothing of the old episode leaks into it)
            assert np.array_equal(obs[done, :F], obs[done, F:])
            assert not np.array_equal(obs[done, F:], prev[done, :F])
            break
    else:
        raise AssertionError("no row finished")
    alive = ~done
    assert np.array_equal(obs[alive, F:], prev[alive, :F])


def test_evaluation_chain_stacks_as_the_env_does():
    """run_q_policy with frame_stack = 4 hands the policy exactly the env's observations (bit for bit)."""
    k, seed = 4, 2024
    env = gym.make("RadarTrack-v0", frame_stack=k)
    levels = env.unwrapped.q_levels_m_s2
    obs, _ = env.reset(seed=seed)
    seen_env = [obs]
    rule = lambda o: int(np.argmin(np.abs(o[..., 2] - 0.1 * np.arange(levels.size)[:, None]), axis=0)[0]) % 13
    for _ in range(60):
        obs, _, term, trunc, _ = env.step(rule(obs[None]))
        seen_env.append(obs)
        if term or trunc:
            break
    ep = draw_setup_and_episode("random", None, None, seeding.np_random(seed)[0])
    seen = []

    def choose(o):
        seen.append(o[0].copy())
        return np.array([levels[rule(o)]])

    run_q_policy([ep], choose, "stacked", EnvConfig.from_kwargs(frame_stack=k))
    n = min(len(seen), len(seen_env))
    assert n >= 40 and all(np.array_equal(a, b) for a, b in zip(seen[:n], seen_env[:n]))


def test_frame_stack_is_checked():
    for bad in (0, 65, 2.5, "2", None, True):
        with pytest.raises(ValueError, match="frame_stack"):
            gym.make("RadarTrack-v0", frame_stack=bad)
    # an integral float is taken as its integer (it used to pass the check and fail at reset)
    cfg = EnvConfig.from_kwargs(frame_stack=2.0, warmup_scans=12.0, n_adrian=4.0, window_kim_lee=12.0)
    assert all(type(getattr(cfg, n)) is int for n in ("frame_stack", "warmup_scans", "n_adrian", "window_kim_lee"))
    env = gym.make("RadarTrack-v0", frame_stack=2.0)
    obs, _ = env.reset(seed=0)
    assert obs.shape == env.observation_space.shape and env.observation_space.contains(obs)


def test_frame_stack_push_returns_copies():
    fs = FrameStack(2, 3, 2)
    a = fs.reset(np.arange(2), np.ones((2, 2)))
    b = fs.push(slice(None), np.full((2, 2), 2.0))
    c = fs.push(slice(None), np.full((2, 2), 3.0))
    assert np.array_equal(b[0], [2, 2, 1, 1, 1, 1]) and np.array_equal(c[0], [3, 3, 2, 2, 1, 1])
    assert np.array_equal(a[0], [1] * 6)


def test_fine_tune_into_a_stacked_observation_starts_as_the_source_policy(tmp_path):
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from agents.training.sb3_vec import make_sb3_vec_env
    from agents.training.train import _expanded_state, _stack_factor

    def model(k):
        env, _ = make_sb3_vec_env(2, {"frame_stack": k}, seed=0)
        return PPO("MlpPolicy", env, seed=k, device="cpu", n_steps=8, batch_size=16,
                   policy_kwargs={"net_arch": [16, 16]}), env

    src, _ = model(1)
    new, env = model(3)
    k = _stack_factor(src.observation_space, new.observation_space)
    assert k == 3 and _stack_factor(new.observation_space, src.observation_space) is None
    new.policy.load_state_dict(_expanded_state(src.policy.state_dict(), new.policy.state_dict(), k))
    obs = env.reset()
    F = obs.shape[1] // 3
    rng = np.random.default_rng(0)
    obs[:, F:] = rng.uniform(-1, 1, size=obs[:, F:].shape)   # whatever the older frames hold
    import torch
    with torch.no_grad():
        a = src.policy.get_distribution(torch.as_tensor(obs[:, :F])).distribution.logits
        b = new.policy.get_distribution(torch.as_tensor(obs)).distribution.logits
        va, vb = src.policy.predict_values(torch.as_tensor(obs[:, :F])), new.policy.predict_values(torch.as_tensor(obs))
    # equal up to float32 summation order (the zero columns join the matrix product)
    assert torch.allclose(a, b, rtol=0, atol=1e-6) and torch.allclose(va, vb, rtol=0, atol=1e-6)
    assert torch.equal(a.argmax(dim=1), b.argmax(dim=1))
