"""First use of every registered id with an empty numba cache (issue 35: make + reset + step of each env, at most
20 s): a fresh interpreter per run, ``NUMBA_CACHE_DIR`` pointed at an empty temporary folder; for each id in
``radar_env.ENV_VARIANTS`` order, ``gym.make(id)`` + reset + one step, then a 4-row native vector env of the same
id + reset + one step. Prints the seconds per id, the total, and the machine's 1-minute load before and after, and
CartPole-v1's steps/s measured for a second in the same interpreter afterwards: the same code's first use took 18 s
on the machine of 2026-12-04 and 25-31 s on that of 2026-12-06 (docs/speed.md), so the envs' time is also given in
CartPole steps (seconds x CartPole steps/s), a rough reference for the machine's state, as the main job's bench
does (its :func:`bench_main_job.cartpole_steps_per_s`; the interpreter's wall and CPU time include that second).

    python benchmarks/bench_first_use.py [--runs N] [--warm] [--repo CHECKOUT]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent

_CODE = r"""
import json, time
t0 = time.perf_counter()
import gymnasium as gym
import numpy as np
import radar_env
from radar_env.envs.env import RadarTrackVectorEnv
t1 = time.perf_counter()
out = {"import_s": t1 - t0, "ids": {}}
for env_id in radar_env.ENV_VARIANTS:
    a = time.perf_counter()
    env = gym.make(env_id)
    env.reset(seed=0)
    env.step(env.action_space.sample())
    venv = RadarTrackVectorEnv(num_envs=4, **radar_env.ENV_VARIANTS[env_id])
    venv.reset(seed=0)
    venv.step(venv.action_space.sample())
    out["ids"][env_id] = time.perf_counter() - a
out["envs_s"] = time.perf_counter() - t1
from bench_main_job import cartpole_steps_per_s     # this benchmarks folder's (run_once puts it on the path)
out["cartpole_steps_s"] = cartpole_steps_per_s(1.0)  # the machine's speed in the same interpreter, afterwards
print(json.dumps(out))
"""


def load1():
    return os.getloadavg()[0]


def run_once(cache_dir, repo=REPO):
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache_dir), PYTHONPATH=str(repo))
    l0 = load1()
    w0 = time.perf_counter()
    c0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    code = f"import sys; sys.path.insert(0, {str(Path(__file__).resolve().parent)!r})\n" + _CODE
    p = subprocess.run([sys.executable, "-c", code], cwd=repo, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - w0
    c1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    cpu = (c1.ru_utime - c0.ru_utime) + (c1.ru_stime - c0.ru_stime)
    if p.returncode != 0:
        raise RuntimeError(p.stderr[-3000:])
    res = json.loads(p.stdout.strip().splitlines()[-1])
    return dict(res, wall_s=wall, cpu_s=cpu, load_before=l0, load_after=load1())


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=1)
    ap.add_argument("--warm", action="store_true", help="also a run with the cache the cold run filled")
    ap.add_argument("--repo", default=str(REPO), help="the checkout whose radar_env is measured (default: this one)")
    a = ap.parse_args(argv)
    for _ in range(a.runs):
        with tempfile.TemporaryDirectory(prefix="first_use_cache_") as cache:
            kinds = ("cold", "warm") if a.warm else ("cold",)
            for kind in kinds:
                r = run_once(cache, a.repo)
                ids = ", ".join(f"{k} {v:.1f}" for k, v in r["ids"].items())
                cp = r["cartpole_steps_s"]
                print(f"{kind}: envs {r['envs_s']:.1f} s (import {r['import_s']:.1f} s, interpreter "
                      f"{r['wall_s']:.1f} s wall, {r['cpu_s']:.1f} s CPU; load {r['load_before']:.2f} -> "
                      f"{r['load_after']:.2f}): {ids}; "
                      f"CartPole-v1 {cp:,.0f} steps/s in the same interpreter afterwards, so the envs took the time of "
                      f"{r['envs_s'] * cp / 1e6:.2f} M CartPole steps", flush=True)


if __name__ == "__main__":
    main()
