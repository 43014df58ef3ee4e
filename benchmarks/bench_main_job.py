"""The main job's time without and with its figures, beside CartPole-v1 steps/s measured in the same process.

The main job is ``radar-track evaluate`` with its defaults (issue 35 item 4: at most 10 s warm without the figures,
20 s with them, on the idle 2-core machine). One run with the figures gives both numbers: the time of the figures
(drawing and writing them, and the suites' truth models they draw) is measured inside it, and the time without
them is the rest. The per-tracker seconds (summed over the suites) say where the time goes.

The machine is shared, so wall times move with the load: the 1-minute load average is printed at the start and the
end, and CartPole-v1's ``gym.make`` steps/s is measured in this process before the job, so that the ratio
``main job s x CartPole steps/s`` (CartPole steps the job costs) can be compared between runs under different loads
more fairly than the seconds alone. Run it warm (the numba cache filled by an earlier run): the first call of each
kernel otherwise compiles.

Run from the repository root: ``python benchmarks/bench_main_job.py [--seconds 2] [evaluate options ...]``; any
other option goes to ``radar-track evaluate`` (e.g. ``--runs 2 --scenario bizup2002`` for a quick check), whose
figures go to a temporary folder.
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from collections import defaultdict

import gymnasium as gym

from agents.evaluation import evaluate as E


def cartpole_steps_per_s(seconds):
    """CartPole-v1 (``gym.make``, its wrappers included) random-action steps/s over at least ``seconds``."""
    env = gym.make("CartPole-v1")
    env.reset(seed=0)
    env.action_space.seed(0)
    steps, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for _ in range(1000):
            _, _, term, trunc, _ = env.step(env.action_space.sample())
            if term or trunc:
                env.reset()
        steps += 1000
    rate = steps / (time.perf_counter() - t0)
    env.close()
    return rate


def time_main_job(eval_args):
    """Run ``radar-track evaluate eval_args`` with its figures (in a temporary folder) and return ``(seconds without
    figures, seconds of the figures, {tracker: seconds})``: the figures' part is timed by wrapping the functions
    only the figures call (``write_plots`` and ``run_scenario``)."""
    per_tracker, plots_s = defaultdict(float), [0.0]

    def timed(fn, add):
        def wrapper(*a, **kw):
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                add(a, time.perf_counter() - t0)
        return wrapper

    saved = E.run_one, E.write_plots, E.run_scenario
    E.run_one = timed(E.run_one, lambda a, s: per_tracker.__setitem__(a[0], per_tracker[a[0]] + s))
    E.write_plots = timed(E.write_plots, lambda a, s: plots_s.__setitem__(0, plots_s[0] + s))
    E.run_scenario = timed(E.run_scenario, lambda a, s: plots_s.__setitem__(0, plots_s[0] + s))
    try:
        with tempfile.TemporaryDirectory(prefix="bench-main-job-") as out:
            t0 = time.perf_counter()
            E.main(["--quiet", "--out", out, *eval_args])
            total = time.perf_counter() - t0
    finally:
        E.run_one, E.write_plots, E.run_scenario = saved
    return total - plots_s[0], plots_s[0], dict(per_tracker)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seconds", type=float, default=2.0, help="CartPole-v1 window (s) (default 2)")
    args, eval_args = ap.parse_known_args(argv)
    load0 = os.getloadavg()[0]
    cartpole = cartpole_steps_per_s(args.seconds)
    stdout, sys.stdout = sys.stdout, open(os.devnull, "w")       # the evaluation's table: not part of this report
    try:
        no_plots, plots, per_tracker = time_main_job(eval_args)
    finally:
        sys.stdout.close()
        sys.stdout = stdout
    load1 = os.getloadavg()[0]
    with_plots = no_plots + plots
    print(f"load average (1 min, {os.cpu_count()} CPUs): {load0:.2f} at the start, {load1:.2f} at the end")
    print(f"CartPole-v1 (gym.make): {cartpole:,.0f} steps/s")
    print("| main job | s | CartPole steps in that time | target | |")
    print("|---|---:|---:|---:|---|")
    for case, s, target in (("without figures", no_plots, 10.0), ("with figures", with_plots, 20.0)):
        print(f"| {case} | {s:.1f} | {s * cartpole:,.0f} | <= {target:g} s | "
              f"{'reached' if s <= target else 'NOT reached'} |")
    print(f"figures alone: {plots:.1f} s")
    print("per tracker (s, summed over the suites): " + ", ".join(
        f"{t} {s:.2f}" for t, s in sorted(per_tracker.items(), key=lambda kv: -kv[1])))
    return {"load_start": load0, "load_end": load1, "cartpole_steps_per_s": cartpole, "no_plots_s": no_plots,
            "with_plots_s": with_plots, "plots_s": plots, "per_tracker_s": per_tracker}


if __name__ == "__main__":
    main()
