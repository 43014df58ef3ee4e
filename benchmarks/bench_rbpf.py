"""The particle filter's convergence in its particle count and its cost per look beside imm_cv_ct's, in one run.

For each N: the pooled position RMSE of ``rbpf`` (and, with ``--ref``, ``rbpf_ref``) over episodes of a suite, its
ratio to ``imm_cv_ct`` on the same episodes with the paired 95 % bootstrap interval (the evaluation's
:func:`agents.evaluation.metrics.ratio_ci`), the ratio to the next-smaller N, and the wall time per track-look against
``imm_cv_ct``'s measured in the same process (the machine is shared: the load average is printed; compare runs made
under the same load). The first call of each kernel (compilation) is not timed.

Run from the repository root: ``python benchmarks/bench_rbpf.py [--suite random] [--runs 100] [--seed 1000000]
[--particles 1024 4096 16384 65536] [--ref]``. The default seed is the tuning range's start: settings are chosen
there; ``--seed 10000000`` gives the held-out evaluation episodes.
"""

from __future__ import annotations

import argparse
import os
import time
from dataclasses import replace

import numpy as np

from agents.evaluation.metrics import ratio_ci, score_run
from agents.evaluation.suites import draw_suite
from baselines.rbpf import DEFAULT_RBPF, RBPF_REF, run_rbpf
from baselines.registry import run_tracker
from radar_env.sim.episode import stack_episodes


def _pooled(batch, score):
    m = score.masks["used"]
    return float(np.sqrt(np.mean(score.pos_err_m[m] ** 2)))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="random")
    ap.add_argument("--runs", type=int, default=100)
    ap.add_argument("--seed", type=int, default=1_000_000)
    ap.add_argument("--particles", type=int, nargs="+", default=[1024, 4096, 16384, 65536])
    ap.add_argument("--ref", action="store_true", help="also rbpf_ref (the flight's start known)")
    args = ap.parse_args(argv)
    print(f"load average at start: {os.getloadavg()}")
    eps = draw_suite(args.suite, args.runs, seed=args.seed)
    batch = stack_episodes(eps)
    looks = int(sum(e.n_looks for e in eps))
    run_tracker("imm_cv_ct", eps[:1])
    t0 = time.perf_counter()
    imm = run_tracker("imm_cv_ct", eps)
    t_imm = (time.perf_counter() - t0) / looks
    s_imm = score_run(batch, imm)
    print(f"{args.suite}: {args.runs} runs from seed {args.seed}, {looks} looks; imm_cv_ct {_pooled(batch, s_imm):.1f} m,"
          f" {t_imm * 1e6:.1f} us per track-look")
    print("| tracker | N | RMSE m | / imm_cv_ct [95% CI] | / N/4 | lost | ANEES | us per look | / imm_cv_ct's time |")
    print("|---|---|---|---|---|---|---|---|---|")
    for base, name in [(DEFAULT_RBPF, "rbpf")] + ([(RBPF_REF, "rbpf_ref")] if args.ref else []):
        prev = None
        run_rbpf(eps[:1], replace(base, n_particles=16), name=name)      # compile
        for n in args.particles:
            t0 = time.perf_counter()
            run = run_rbpf(eps, replace(base, n_particles=n), name=name)
            t = (time.perf_counter() - t0) / looks
            s = score_run(batch, run)
            r, (lo, hi) = ratio_ci(batch, run, imm, scores=(s, s_imm))[:2]
            rm = _pooled(batch, s)
            m = s.masks["used"] & ~s.lost[:, None]
            d = (batch.truth - run.x)[m]
            Pi = np.linalg.inv(run.P[m])
            anees = float(np.mean(np.einsum("ni,nij,nj->n", d, Pi, d)) / 4.0)
            print(f"| {name} | {n} | {rm:.1f} | {r:.3f} [{lo:.3f}, {hi:.3f}] | "
                  f"{'-' if prev is None else f'{rm / prev:.3f}'} | {int(s.lost.sum())} | {anees:.2f} | "
                  f"{t * 1e6:.0f} | {t / t_imm:.0f}x |", flush=True)
            prev = rm
    print(f"load average at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
