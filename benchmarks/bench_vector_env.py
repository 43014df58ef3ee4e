"""Row-steps/s of RadarTrack-v0's native vector env beside CartPole-v1 in one process (issue 35, items 3 and 5).

Run by hand from the repository root: ``python benchmarks/bench_vector_env.py [--num-envs 64,1024,4096]
[--num-threads 1,2] [--rounds 3] [--seconds 2] [--markdown]``. Each round measures, one after the other in this process,

* CartPole-v1 through ``gym.make`` (steps/s, resets included): the reference;
* RadarTrack-v0 through ``gym.make`` (its wrappers included; the single env must keep >= 0.5 x CartPole);
* ``gym.make_vec("RadarTrack-v0", num_envs=N, vectorization_mode="vector_entry_point")`` at every N, random
  actions drawn beforehand (row-steps/s = N x vector steps / s, same-step autoresets included; a window lasts
  ``--seconds`` and until one reset per row was seen, so the autoreset draws are in it); with ``--num-threads``
  once per thread count (the env's ``num_threads``), the counts one after the other at each N (alternating);

so the reference and the env share the machine's load of that moment (interleaved). The report gives per N the
median of the rounds, its ratio to the same rounds' CartPole median, the 1-minute load average before every round,
and whether the targets were reached (1,000,000 row-steps/s at 1,024 rows; the single env at >= 0.5 x
CartPole-v1). Rates are wall-clock: compare only runs made under
the same load.
"""

from __future__ import annotations

import argparse
import datetime
import os
import statistics
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for p in (str(REPO), str(REPO / "benchmarks")):
    if p not in sys.path:      # run as a script: this checkout's radar_env and bench_env
        sys.path.insert(0, p)

import gymnasium as gym  # noqa: E402
import numpy as np  # noqa: E402

import radar_env  # noqa: E402,F401  (registers RadarTrack-v0)
from bench_env import _bench_vec, bench_single  # noqa: E402

TARGET_ROWS, TARGET_RATE = 1024, 1_000_000


def bench_make_vec(num_envs, seconds, num_threads=1):
    """Row-steps/s of the native vector env made as users make it (``gym.make_vec``)."""
    venv = gym.make_vec("RadarTrack-v0", num_envs=num_envs, vectorization_mode="vector_entry_point",
                        num_threads=num_threads)
    return _bench_vec(venv, num_envs, seconds, num_envs)


def run(num_envs, rounds, seconds, num_threads=(1,)):
    """``{"cartpole": [...], (N, threads): [...], "load": [...]}``: steps/s per round."""
    out = {"cartpole": [], "single": [], "load": []}
    out.update({(n, t): [] for n in num_envs for t in num_threads})
    for t in num_threads:   # compile the parallel builds before the first window (lazily built on first use)
        if t > 1:
            bench_make_vec(8, 0.01, t)
    for _ in range(rounds):
        out["load"].append(os.getloadavg()[0])
        out["cartpole"].append(bench_single("CartPole-v1", seconds).steps_per_s)
        out["single"].append(bench_single("RadarTrack-v0", seconds).steps_per_s)
        for n in num_envs:
            for t in num_threads:
                out[(n, t)].append(bench_make_vec(n, seconds, t).steps_per_s)
    return out


def report(res, num_envs, markdown, num_threads=(1,)):
    cp = statistics.median(res["cartpole"])
    head = ("| case | envs | (row-)steps/s (median) | rounds | ratio to CartPole-v1 single env |",
            "|---|---:|---:|---|---:|")
    rows = [f"| CartPole-v1 (gym.make) | 1 | {cp:,.0f} | {', '.join(f'{v:,.0f}' for v in res['cartpole'])} | 1 |"]
    m = statistics.median(res["single"])
    rows.append(f"| RadarTrack-v0 single env (gym.make) | 1 | {m:,.0f} | "
                f"{', '.join(f'{v:,.0f}' for v in res['single'])} | {m / cp:.2f} |")
    for n in num_envs:
        for t in num_threads:
            m = statistics.median(res[(n, t)])
            label = "RadarTrack-v0 vector env" + ("" if num_threads == (1,) else f", num_threads={t}")
            rows.append(f"| {label} | {n:,} | {m:,.0f} | {', '.join(f'{v:,.0f}' for v in res[(n, t)])} | "
                        f"{m / cp:.2f} |")
    if markdown:
        print("\n".join(head + tuple(rows)))
    else:
        for r in rows:
            print(r.strip("|").replace(" | ", "  "))
    print(f"1-minute load average before each round ({os.cpu_count()} CPUs): "
          + ", ".join(f"{v:.2f}" for v in res["load"]) + f"; after: {os.getloadavg()[0]:.2f}")
    single = statistics.median(res["single"]) / cp
    print(f"target single env >= 0.5 x CartPole-v1: {single:.2f} x ({'reached' if single >= 0.5 else 'NOT reached'})")
    for t in num_threads:
        if (TARGET_ROWS, t) in res:
            m = statistics.median(res[(TARGET_ROWS, t)])
            print(f"target >= {TARGET_RATE:,} row-steps/s at {TARGET_ROWS:,} rows, num_threads={t}: {m:,.0f} "
                  f"({'reached' if m >= TARGET_RATE else 'NOT reached'}, under the load above)")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--num-envs", default="64,1024,4096", help="comma-separated row counts")
    ap.add_argument("--num-threads", default="1", help="comma-separated thread counts of the vector env")
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--seconds", type=float, default=2.0, help="least length of one rate window")
    ap.add_argument("--markdown", action="store_true")
    a = ap.parse_args(argv)
    num_envs = [int(v) for v in a.num_envs.split(",")]
    num_threads = tuple(int(v) for v in a.num_threads.split(","))
    if a.rounds < 1 or a.seconds <= 0 or any(n < 1 for n in num_envs) or any(t < 1 for t in num_threads):
        ap.error("--rounds, --seconds, every --num-envs and every --num-threads must be positive")
    commit = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=REPO, capture_output=True,
                            text=True).stdout.strip()
    print(f"{datetime.datetime.now(datetime.timezone.utc):%Y-%m-%d %H:%M} UTC, commit {commit or '?'}, "
          f"numpy {np.__version__}, gymnasium {gym.__version__}, OMP_NUM_THREADS="
          f"{os.environ.get('OMP_NUM_THREADS', 'unset')}")
    report(run(num_envs, a.rounds, a.seconds, num_threads), num_envs, a.markdown, num_threads)


if __name__ == "__main__":
    main()
