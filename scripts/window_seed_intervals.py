"""How far apart the window recipe's seeds really are: S4 (the geometric mean over the four selection suites of the
policy / imm2 pooled-RMSE ratio, as the trainer selects on) of each shipped seed on fresh TRAINING-range flights,
with paired bootstrap intervals (over flights, 2,000 draws) of each pair's ratio, at half of ``--runs`` and at
``--runs`` flights per suite (default 100 and 200; issue 38; agents/bundled/window/CHOICE.md).

    python scripts/window_seed_intervals.py [--runs 200] [--seed 960000] [--folders FOLDER ...]

The flights are drawn as the selection suites (:func:`agents.training.selection.draw_selection_suite`) from
``--seed`` (default 960_000: used by no training draw, selection or broad check of the shipped recipes); the base
runs once and each seed's correction is applied to it (`scripts/window_fresh_check.py`'s
:func:`suite_sums` and :func:`s4`).
"""

from __future__ import annotations

import argparse
import glob
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))
sys.path.insert(0, str(Path(__file__).resolve().parent))

from agents.policies.loading import load_policy  # noqa: E402
from agents.training.selection import START_UNKNOWN_SUITES, draw_selection_suite  # noqa: E402
from window_fresh_check import s4, suite_sums  # noqa: E402  (the per-flight sums and S4, one copy)

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
    per_run = {u: suite_sums(draw_selection_suite(u, args.runs, args.seed), pols, names, "imm2") for u in SUITES}

    rng = np.random.default_rng(0)
    for runs in (args.runs // 2, args.runs):
        full = {u: np.arange(runs) for u in SUITES}
        S = s4(per_run, full)
        print(f"\n{runs} flights per suite (seeds {args.seed}+): S4 " + ", ".join(
            f"{n} {S[k]:.4f}" for k, n in enumerate(names)))
        draws = [{u: rng.integers(0, runs, runs) for u in SUITES} for _ in range(2000)]
        Sd = np.array([s4(per_run, idx) for idx in draws])     # (draws, corrections)
        for a in range(len(pols)):
            for c in range(a + 1, len(pols)):
                lo, hi = np.percentile(Sd[:, a] / Sd[:, c], [2.5, 97.5])
                print(f"  {names[a]} / {names[c]}: {S[a] / S[c]:.4f} [{lo:.4f}, {hi:.4f}]")


if __name__ == "__main__":
    main()
