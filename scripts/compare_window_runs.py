"""A window-correction run beside another (a bundled seed, say) on the broad flights and on the held-out suites:
what agents/bundled/window/CHOICE.md reports for the ninth recipe's seed 300000.

    python scripts/compare_window_runs.py RUN/best agents/bundled/window/seeds/window_s300000 [--heldout] [--out F.json]

Broad flights (training-range seeds): 200 ``random`` and 200 ``random_radars`` flights with the broad laws
(:func:`agents.training.window.broad_config`) from seeds 900,000 + 40,000 + i, pooled RMSE of both and of
``imm_ct_bank``; the broad score is the geometric mean of the two ratios. With ``--heldout`` (only after a choice:
these are the held-out seeds), every suite of docs/generalisation.json's seed spread on its own episodes (its seed,
10,000,000, and runs): both, and the suite's strongest classical tracker there, paired ratios with 95 % bootstrap
intervals; the second folder's RMSE and the classical tracker's are checked against the JSON's when it holds them
(the same episodes).
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from agents.evaluation.metrics import evaluate_run, ratio_ci  # noqa: E402
from agents.evaluation.runner import run_policy  # noqa: E402
from agents.evaluation.suites import draw_suite  # noqa: E402
from agents.policies.loading import load_policy  # noqa: E402
from agents.training.selection import SELECTION_SEED_BASE, pooled_rmse  # noqa: E402
from agents.training.window import broad_config  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.sim.episode import stack_episodes  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("run", help="a window correction's folder (a run's best/)")
    ap.add_argument("other", help="the folder it is compared with")
    ap.add_argument("--heldout", action="store_true", help="also the held-out suites (after a choice only)")
    ap.add_argument("--out", help="write the numbers as JSON")
    args = ap.parse_args(argv)
    pols = {n: load_policy(Path(f) / "policy.npz") for n, f in (("run", args.run), ("other", args.other))}
    other_name = Path(args.other).name
    out = {"broad": {}, "heldout": {}}
    for gen in ("random", "random_radars"):
        eps = draw_suite(gen, 200, seed=SELECTION_SEED_BASE + 40_000, random_config=broad_config())
        b = stack_episodes(eps)
        m = {n: pooled_rmse(b, run_policy(n, eps, *p)) for n, p in pols.items()}
        m["imm_ct_bank"] = pooled_rmse(b, run_tracker("imm_ct_bank", eps))
        out["broad"][gen] = m
        print(f"broad {gen}: run {m['run']:.1f} m, other {m['other']:.1f} m, imm_ct_bank {m['imm_ct_bank']:.1f} m",
              flush=True)
    out["broad_score"] = math.exp(sum(math.log(v["run"] / v["other"]) for v in out["broad"].values()) / 2)
    print(f"broad score (run / other): {out['broad_score']:.4f}")
    if args.heldout:
        data = json.loads((REPO / "docs" / "generalisation.json").read_text())
        t0 = time.time()
        for suite, old in data["spread"].items():
            eps = draw_suite(suite, old["runs"], seed=data["seed"])
            b = stack_episodes(eps)
            strongest = old["strongest_classical"]
            runs = {n: run_policy(n, eps, *p) for n, p in pols.items()}
            runs[strongest] = run_tracker(strongest, eps)
            rmse = {n: evaluate_run(b, r)["pos_rmse_m"] for n, r in runs.items()}
            same = {"classical": rmse[strongest] == old["trackers"][strongest]["pos_rmse_m"]}
            if other_name in old["policies"]:
                same["other"] = rmse["other"] == old["policies"][other_name]["pos_rmse_m"]
            ratios = {f"{a}/{c}": ratio_ci(b, runs[a], runs[c])
                      for a, c in (("run", "other"), ("run", strongest), ("other", strongest))}
            out["heldout"][suite] = {"runs": len(eps), "strongest": strongest, "rmse_m": rmse,
                                     "ratios": {k: [v[0], *v[1]] for k, v in ratios.items()}, "same_as_json": same}
            print(f"{suite} ({len(eps)}): " + ", ".join(f"{k} {v[0]:.3f} [{v[1][0]:.3f}, {v[1][1]:.3f}]"
                                                         for k, v in ratios.items())
                  + f"; equal to the JSON: {same} ({time.time() - t0:.0f} s)", flush=True)
    if args.out:
        Path(args.out).write_text(json.dumps(out, indent=1))


if __name__ == "__main__":
    main()
