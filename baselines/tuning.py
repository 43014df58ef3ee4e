"""Tune the classical baselines on the training scenario distribution (never on evaluation seeds).

``python -m baselines.tuning [--runs N]`` draws ``N`` random-scenario episodes with tuning seeds
(``agents.suites.TUNING_SEEDS``, disjoint from the evaluation's held-out seeds), then

* ``kf``: grid search of the constant q (25 values log-spaced over 0.01-10 g, then a finer grid of 21 around the
  best) minimising the pooled position RMSE after the track start;
* ``imm2``: grid search of the 2-mode IMM's low and high mode noises and its two stay probabilities
  (``IMM2_GRID``: 5 x 6 x 5 x 5 values) on the same criterion,

and writes ``baselines/tuned.json`` with the chosen values, the criterion values on the grid, the seeds and the
command. Runtime on the 2-core reference machine with the default 200 runs: a few minutes.
"""

from __future__ import annotations

import argparse
import itertools
import json
import sys
import time

import numpy as np

from radar_env.env import EnvConfig
from radar_env.episode import stack_episodes
from radar_env.units import G0_M_S2

from . import trackers as T
from .tuned_params import TUNED_PATH

__all__ = ["tune_kf", "tune_imm2", "main"]


def _pooled_rmse(batch, run):
    K = run.x.shape[1]
    used = batch.valid & (np.arange(K)[None, :] >= run.start_index[:, None])
    e2 = np.sum((run.x[..., :2] - batch.truth[..., :2]) ** 2, axis=-1)
    return float(np.sqrt(np.mean(e2[used])))


def tune_kf(episodes, batch, cfg):
    def rmse(q_g):
        run = T.run_q_policy(episodes, lambda o: np.full(o.shape[0], q_g * G0_M_S2), "kf", cfg)
        return _pooled_rmse(batch, run)

    coarse = np.logspace(-2, 1, 25)
    c_vals = [rmse(q) for q in coarse]
    i = int(np.argmin(c_vals))
    lo, hi = coarse[max(i - 1, 0)], coarse[min(i + 1, len(coarse) - 1)]
    fine = np.logspace(np.log10(lo), np.log10(hi), 21)
    f_vals = [rmse(q) for q in fine]
    j = int(np.argmin(f_vals))
    return {"q_g": float(fine[j]), "pos_rmse_m": f_vals[j],
            "grid_g": [float(v) for v in np.r_[coarse, fine]], "grid_pos_rmse_m": c_vals + f_vals}


IMM2_GRID = ([0.001, 0.003, 0.01, 0.03, 0.1], [1.0, 2.0, 4.0, 8.0, 16.0, 32.0], [0.9, 0.95, 0.98, 0.99, 0.995],
             [0.7, 0.8, 0.9, 0.95, 0.98])
"""q_low (g), q_high (g), P(stay low), P(stay high): a first grid with the 0.01-0.3 g / 0.5-8 g / 0.8-0.98 /
0.5-0.9 ranges put the optimum on its upper edges, so the grid was widened to this one."""


def tune_imm2(episodes, batch, cfg, progress=None):
    grid = list(itertools.product(*IMM2_GRID))
    vals = []
    for n, (ql, qh, sl, sh) in enumerate(grid):
        spec = T.IMMSpec((ql * G0_M_S2, qh * G0_M_S2), (0.0, 0.0), ((sl, 1 - sl), (1 - sh, sh)), (0.9, 0.1), (1,))
        vals.append(_pooled_rmse(batch, T.run_imm(episodes, spec, "imm2", cfg)))
        if progress:
            progress(n + 1, len(grid))
    i = int(np.argmin(vals))
    ql, qh, sl, sh = grid[i]
    return {"q_low_g": ql, "q_high_g": qh, "p_stay_low": sl, "p_stay_high": sh, "pos_rmse_m": vals[i],
            "grid": [list(g) for g in grid], "grid_pos_rmse_m": vals}


def main(argv=None):
    from agents.suites import TUNING_SEEDS, draw_suite

    ap = argparse.ArgumentParser(prog="python -m baselines.tuning", description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200, help="random-scenario episodes (default 200)")
    ap.add_argument("--out", default=str(TUNED_PATH), help="output JSON (default baselines/tuned.json)")
    args = ap.parse_args(argv)
    cfg = EnvConfig()
    t0 = time.time()
    episodes = draw_suite("random", args.runs, seed=TUNING_SEEDS.start)
    batch = stack_episodes(episodes)
    kf = tune_kf(episodes, batch, cfg)
    print(f"kf: q = {kf['q_g']:.4g} g, pos RMSE {kf['pos_rmse_m']:.1f} m ({time.time() - t0:.0f} s)", flush=True)

    def progress(n, total):
        if n % 40 == 0 or n == total:
            print(f"  imm2 grid {n}/{total} ({time.time() - t0:.0f} s)", flush=True)

    imm = tune_imm2(episodes, batch, cfg, progress)
    print(f"imm2: q_low {imm['q_low_g']} g, q_high {imm['q_high_g']} g, stay low {imm['p_stay_low']}, "
          f"stay high {imm['p_stay_high']}, pos RMSE {imm['pos_rmse_m']:.1f} m", flush=True)
    out = {"kf": kf, "imm2": imm,
           "tuning": {"suite": "random", "runs": args.runs, "seed_start": TUNING_SEEDS.start,
                      "criterion": "pooled position RMSE after the track start",
                      "command": "python -m baselines.tuning " + " ".join(sys.argv[1:] if argv is None else argv),
                      "seconds": round(time.time() - t0, 1)}}
    with open(args.out, "w") as f:
        json.dump(out, f, indent=1)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
