"""Each learned tracker's time per track-look beside imm_cv_ct's, in one process (issue 38's cap: at most 5x).

    python benchmarks/bench_learned_cost.py [--runs 100] [--rounds 3] [--trackers policy_bp,policy_bp_prior,...]

On ``random`` episodes of training-range seeds (900_000 + i), one numba thread, every tracker run once to compile
and start, then ``--rounds`` rounds in turn; the CPU time (``time.process_time``) of the best round of each, per
track-look (the looks after the common track start), and its ratio to imm_cv_ct's. CPU time and rounds taken in
turn make the ratio robust to the machine's load; the absolute numbers are not.
"""

from __future__ import annotations

import argparse
import os
import time


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--trackers", default="policy_bp,policy_bp_prior,policy_window,policy_imm_bp,policy_imm_bp_prior",
                    help="comma-separated bundled learned trackers (default: %(default)s)")
    args = ap.parse_args(argv)
    import numba
    numba.set_num_threads(1)
    from agents.evaluation.runner import run_one
    from agents.evaluation.suites import draw_suite
    from agents.policies.learned import load_learned
    from baselines.imm_cv_ct_runner import common_start
    from baselines.registry import run_tracker

    eps = draw_suite("random", args.runs, seed=900_000)
    batch, k0 = common_start(eps)[:2]
    looks = int(sum(int(batch.n_looks[i]) - int(k0[i]) - 1 for i in range(len(eps))))
    runs = {"imm_cv_ct": lambda: run_tracker("imm_cv_ct", eps)}
    for name in args.trackers.split(","):
        lt = load_learned(name)
        runs[name] = lambda lt=lt, name=name: run_one(name, eps, lt.policy, lt.env_config)
    for f in runs.values():
        f()
    best = {n: float("inf") for n in runs}
    for _ in range(args.rounds):
        for n, f in runs.items():
            t = time.process_time()
            f()
            best[n] = min(best[n], time.process_time() - t)
    print(f"{args.runs} random episodes, {looks} track-looks, best of {args.rounds} rounds, load "
          f"{os.getloadavg()[0]:.2f}")
    print("| tracker | CPU s | us per track-look | / imm_cv_ct |\n|---|---:|---:|---:|")
    for n, v in best.items():
        print(f"| {n} | {v:.3f} | {1e6 * v / looks:.1f} | {v / best['imm_cv_ct']:.2f} |")


if __name__ == "__main__":
    main()
