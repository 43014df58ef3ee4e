"""Throughput of RadarTrack-v0 relative to CartPole-v1, measured in the same process.

Run by hand: ``python benchmarks/bench_env.py [--seconds 2] [--profile]``. Prints steps per second of

(a) gymnasium CartPole-v1, single env, random actions (the reference),
(b) RadarTrack-v0, single env (gym.make, with its wrappers), random actions, resets included,
(c) the native vector env (RadarTrackVectorEnv) at num_envs in {1, 16, 256, 1024}: row-steps per second
    (num_envs * vector steps / s), same-step autoresets included,
(d) Tracker.step alone at B = 1024 (row-steps per second; rows reloaded when they run out, load time excluded),

each also as a ratio to (a). ``--profile`` adds a cProfile of the vector env at num_envs = 256 (top 10 by
cumulative and by internal time).
"""

from __future__ import annotations

import argparse
import cProfile
import io
import pstats
import time

import gymnasium as gym
import numpy as np

import radar_env  # noqa: F401  (registers RadarTrack-v0)
from radar_env.catalog import make_setup
from radar_env.env import RadarTrackVectorEnv
from radar_env.episode import draw_episode
from radar_env.tracking import Tracker
from radar_env.units import G0_M_S2


def _timed(step, seconds):
    """Call ``step()`` (returns the number of row-steps it did) until ``seconds`` pass; return row-steps/s."""
    step()  # warm up
    n, t0 = 0, time.perf_counter()
    while True:
        n += step()
        dt = time.perf_counter() - t0
        if dt >= seconds:
            return n / dt


def bench_single(env_id, seconds, **kwargs):
    env = gym.make(env_id, **kwargs)
    env.reset(seed=0)
    env.action_space.seed(0)
    sample = env.action_space.sample

    def step():
        _, _, te, tr, _ = env.step(sample())
        if te or tr:
            env.reset()
        return 1

    return _timed(step, seconds)


def bench_vector(num_envs, seconds):
    venv = RadarTrackVectorEnv(num_envs=num_envs)
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    n_act = venv.single_action_space.n

    def step():
        venv.step(rng.integers(0, n_act, num_envs))
        return num_envs

    return _timed(step, seconds)


def bench_tracker(B, seconds):
    rng = np.random.default_rng(0)
    pool = []
    for _ in range(32):
        s = make_setup("random", rng)
        pool.append(draw_episode(s.scenario, s.radar, rng))
    tr = Tracker(B)
    tr.load(np.arange(B), [pool[i % len(pool)] for i in range(B)])
    q = np.full(B, 0.5 * G0_M_S2)
    load_time = [0.0]

    def step():
        if np.any(tr.remaining_looks() == 0):
            t0 = time.perf_counter()
            rows = np.flatnonzero(tr.remaining_looks() == 0)
            tr.load(rows, [pool[i % len(pool)] for i in rows])
            load_time[0] += time.perf_counter() - t0
        tr.step(q)
        return B

    # exclude reload time: measure it and add it back to the denominator-free count
    step()
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        n += step()
    return n / (time.perf_counter() - t0 - load_time[0])


def profile_vector(num_envs=256, steps=300):
    venv = RadarTrackVectorEnv(num_envs=num_envs)
    venv.reset(seed=0)
    rng = np.random.default_rng(0)
    acts = rng.integers(0, venv.single_action_space.n, (steps, num_envs))
    pr = cProfile.Profile()
    pr.enable()
    for a in acts:
        venv.step(a)
    pr.disable()
    for key in ("cumulative", "tottime"):
        s = io.StringIO()
        pstats.Stats(pr, stream=s).sort_stats(key).print_stats(10)
        print(f"\n--- cProfile, RadarTrackVectorEnv num_envs={num_envs}, {steps} steps, top 10 by {key} ---")
        print(s.getvalue())


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--seconds", type=float, default=2.0, help="measuring time per case (default 2)")
    ap.add_argument("--profile", action="store_true", help="also profile the vector env at num_envs=256")
    args = ap.parse_args()
    T = args.seconds

    rows = []
    cart = bench_single("CartPole-v1", T)
    rows.append(("(a) CartPole-v1 single env", cart))
    rows.append(("(b) RadarTrack-v0 single env", bench_single("RadarTrack-v0", T)))
    for n in (1, 16, 256, 1024):
        rows.append((f"(c) RadarTrackVectorEnv num_envs={n} (row-steps)", bench_vector(n, T)))
    rows.append(("(d) Tracker.step B=1024 (row-steps)", bench_tracker(1024, T)))

    w = max(len(r[0]) for r in rows)
    print(f"{'case':<{w}}  {'steps/s':>12}  {'/ CartPole':>10}")
    for name, sps in rows:
        print(f"{name:<{w}}  {sps:12,.0f}  {sps / cart:10.3f}")
    if args.profile:
        profile_vector()


if __name__ == "__main__":
    main()
