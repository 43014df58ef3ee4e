"""Where the bundled window correction (``policy_window``) still loses to ``rbpf``: pooled position RMSE (m) by
region and, on ``random_radars``, by scan-period tercile (issue 38; docs/training.md, "Closing the gap to rbpf").

    python scripts/window_gap_by_region.py [--runs 200] [--seed 960000]

On TRAINING-range seeds only (default 960_000 + i: used by no training draw, selection or broad check; never the
held-out seeds), ``random`` and ``random_radars`` episodes from ``rbpf``'s common track start: ``policy_window``,
its base ``policy_bp_prior``, ``rbpf`` and ``imm_cv_ct``, overall and by region (maneuver, the 60 s after one,
straight: :func:`agents.evaluation.metrics.region_masks`), with each region's share of the window's squared-error
gap to ``rbpf`` (sum over looks of window^2 - rbpf^2, over the whole).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from agents.evaluation.metrics import errors, failed_runs, region_masks  # noqa: E402
from agents.evaluation.suites import TRAIN_SEEDS, draw_suite  # noqa: E402
from agents.policies.bundle import BUNDLED_WINDOW  # noqa: E402
from agents.policies.loading import load_policy  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.sim.episode import stack_episodes, stack_fields  # noqa: E402

REGIONS = ("used", "maneuver", "after", "straight")


def rmse(e, mask):
    return float(np.sqrt(np.mean(e[mask] ** 2))) if mask.any() else float("nan")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--runs", type=int, default=200)
    ap.add_argument("--seed", type=int, default=960_000)
    args = ap.parse_args(argv)
    if not (TRAIN_SEEDS.start <= args.seed and args.seed + args.runs <= TRAIN_SEEDS.stop):
        raise SystemExit(f"error: --seed/--runs must stay in the training range {TRAIN_SEEDS}")
    window = load_policy(BUNDLED_WINDOW)[0]
    for suite in ("random", "random_radars"):
        eps = draw_suite(suite, args.runs, seed=args.seed)
        b = stack_episodes(eps)
        base = window.base_run(eps)             # once: the correction moves this run's positions (as its run())
        looks = SimpleNamespace(**stack_fields(eps, ("t_s", "z_m", "R_m2", "detected")))
        runs = {"policy_window": window.correct(looks, base, "policy_window"), "policy_bp_prior": base,
                "rbpf": run_tracker("rbpf", eps), "imm_cv_ct": run_tracker("imm_cv_ct", eps)}
        bad = [n for n, r in runs.items() if failed_runs(b, r).any()]
        if bad:             # a non-finite estimate is a failure, not an error to pool
            raise SystemExit(f"error: {suite}: {bad} failed on some runs (non-finite estimate or covariance)")
        m = region_masks(b, runs["rbpf"].start_index)
        e = {n: errors(b, r)[0] for n, r in runs.items()}
        gap = e["policy_window"] ** 2 - e["rbpf"] ** 2
        print(f"\n{suite}, {args.runs} runs from seed {args.seed}\n| region | " + " | ".join(runs)
              + " | window / rbpf | share of the squared gap |\n|---|" + "---:|" * (len(runs) + 2))
        for reg in REGIONS:
            r = {n: rmse(v, m[reg]) for n, v in e.items()}
            print(f"| {reg} | " + " | ".join(f"{v:.1f}" for v in r.values())
                  + f" | {r['policy_window'] / r['rbpf']:.3f} | {gap[m[reg]].sum() / gap[m['used']].sum():.2f} |")
        if suite == "random_radars":
            dt = np.diff(b.t_s, axis=1)
            period = np.nanmedian(np.where(np.isfinite(dt) & (dt > 0), dt, np.nan), axis=1)
            q = np.quantile(period, [0, 1 / 3, 2 / 3, 1])
            print("\n| scan period (s) | runs | " + " | ".join(f"{reg}: window / rbpf" for reg in REGIONS)
                  + " |\n|---|---:|" + "---:|" * len(REGIONS))
            for i in range(3):
                sel = ((period >= q[i]) & (period <= q[i + 1]))[:, None]
                print(f"| {q[i]:.2f}-{q[i + 1]:.2f} | {int(sel.sum())} | " + " | ".join(
                    f"{rmse(e['policy_window'], m[reg] & sel) / rmse(e['rbpf'], m[reg] & sel):.3f}" for reg in REGIONS)
                    + " |")


if __name__ == "__main__":
    main()
