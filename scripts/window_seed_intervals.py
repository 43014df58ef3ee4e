"""How far apart the window recipe's seeds really are: S4 (the geometric mean over the four selection suites of the
policy / imm2 pooled-RMSE ratio, as the trainer selects on) of each shipped seed on fresh TRAINING-range flights,
with paired bootstrap intervals (over flights, 2,000 draws) of each pair's ratio, at half of ``--runs`` and at
``--runs`` flights per suite (default 100 and 200; issue 38; agents/bundled/window/CHOICE.md).

    python scripts/window_seed_intervals.py [--runs 200] [--seed 960000] [--folders FOLDER ...]

The flights are drawn as the selection suites (:func:`agents.training.selection.draw_selection_suite`) from
``--seed`` (default 960_000: used by no training draw, selection or broad check of the shipped recipes); the base
runs once and each seed's correction is applied to it.
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from agents.evaluation.metrics import errors, failed_runs, region_masks  # noqa: E402
from agents.policies.loading import load_policy  # noqa: E402
from agents.training.selection import START_UNKNOWN_SUITES, draw_selection_suite  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.sim.episode import stack_episodes, stack_fields  # noqa: E402

SUITES = ("random", "random_radars", *START_UNKNOWN_SUITES)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200, help="flights per suite (even, at least 2)")
    ap.add_argument("--seed", type=int, default=960_000)
    ap.add_argument("--folders", nargs="+", default=sorted(glob.glob(str(REPO / "agents/bundled/window/seeds/*"))))
    args = ap.parse_args(argv)
    if args.runs < 2 or args.runs % 2:
        raise SystemExit(f"error: --runs must be an even number of at least 2, got {args.runs}")
    if len(args.folders) < 2:
        raise SystemExit(f"error: --folders: at least two window corrections to compare, got {len(args.folders)}")
    names = [Path(f).name for f in args.folders]
    pols = [load_policy(Path(f) / "policy.npz")[0] for f in args.folders]
    bases = {str(p.config.get("base")) for p in pols}
    if len(bases) > 1:      # the base runs once for all of them
        raise SystemExit(f"error: --folders: the corrections must share their base, got {sorted(bases)}")
    per_run = {}        # suite -> (squared-error sums (seeds, runs), looks (runs), imm2's sums, imm2's looks)
    for suite in SUITES:
        eps = draw_selection_suite(suite, args.runs, args.seed)
        b = stack_episodes(eps)
        base = pols[0].base_run(eps)
        looks = SimpleNamespace(**stack_fields(eps, ("t_s", "z_m", "R_m2", "detected")))
        used = region_masks(b, base.start_index)["used"]
        corrected = [p.correct(looks, base, n) for p, n in zip(pols, names)]
        imm = run_tracker("imm2", eps)
        bad = [r.name for r in (*corrected, imm) if failed_runs(b, r).any()]
        if bad:             # a non-finite estimate is a failure, not an error to pool
            raise SystemExit(f"error: {suite}: {bad} failed on some runs (non-finite estimate or covariance)")
        sums = [np.where(used, errors(b, r)[0] ** 2, 0.0).sum(1) for r in corrected]
        imm_used = region_masks(b, imm.start_index)["used"]
        per_run[suite] = (np.array(sums), used.sum(1), np.where(imm_used, errors(b, imm)[0] ** 2, 0.0).sum(1),
                          imm_used.sum(1))

    def s4(idx, k):
        return float(np.exp(np.mean([np.log(np.sqrt(s[k][i].sum() / n[i].sum()) / np.sqrt(si[i].sum() / ni[i].sum()))
                                     for (s, n, si, ni), i in ((per_run[u], idx[u]) for u in SUITES)])))

    rng = np.random.default_rng(0)
    for runs in (args.runs // 2, args.runs):
        full = {u: np.arange(runs) for u in SUITES}
        print(f"\n{runs} flights per suite (seeds {args.seed}+): S4 " + ", ".join(
            f"{n} {s4(full, k):.4f}" for k, n in enumerate(names)))
        draws = [{u: rng.integers(0, runs, runs) for u in SUITES} for _ in range(2000)]
        for a in range(len(pols)):
            for c in range(a + 1, len(pols)):
                d = [s4(idx, a) / s4(idx, c) for idx in draws]
                lo, hi = np.percentile(d, [2.5, 97.5])
                print(f"  {names[a]} / {names[c]}: {s4(full, a) / s4(full, c):.4f} [{lo:.4f}, {hi:.4f}]")


if __name__ == "__main__":
    main()
