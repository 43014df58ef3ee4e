"""Held-out numbers of the backprop recipe's seeds for issue 25's targets: ``python scripts/heldout_backprop.py
[--seeds-dir agents/bundled/backprop/seeds] --chosen NAME [--suites A,B,...] [--out FILE.json]``.

Every seed (``<dir>/<name>/policy.npz``) and the bundled PPO policy (``policy``) on every suite of the
generalisation report's seed-spread table (``agents.reports.generalisation``: the default suites and the held-out
families with ``adsb_heldout``, held-out seeds ``10_000_000 + i``, the same runs per suite), scored by
:func:`agents.reports.generalisation.evaluate_suite` against the classical field; ``--chosen`` (the seed the rule in
``agents/bundled/backprop/CHOICE.md`` chose) is also reported as ``policy_bp``. Prints
:func:`agents.reports.generalisation.bp_targets` and writes the per-suite results. Run it once, after the choice.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from agents.evaluation.metrics import jsonable  # noqa: E402
from agents.evaluation.suites import DEFAULT_SUITES, EVAL_SEED_BASE, HELDOUT_FAMILY_SUITES, draw_suite  # noqa: E402
from agents.policies.bundle import BUNDLED_POLICY  # noqa: E402
from agents.policies.loading import load_policy  # noqa: E402
from agents.reports import generalisation as g  # noqa: E402


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds-dir", default=str(g.BP_RECIPE_DIR))
    ap.add_argument("--chosen", required=True, help="the seed's folder name the choice rule picked (policy_bp)")
    ap.add_argument("--out", default=str(g.BUNDLED_BP_POLICY.with_name("heldout_eval.json")))
    ap.add_argument("--suites", default=",".join(DEFAULT_SUITES + HELDOUT_FAMILY_SUITES))
    a = ap.parse_args(argv)
    seeds = g.recipe_policies(a.seeds_dir)
    if a.chosen not in seeds:
        ap.error(f"--chosen {a.chosen!r} is not among the seeds {list(seeds)}")
    policies = {"policy": load_policy(BUNDLED_POLICY), **{n: load_policy(p) for n, p in seeds.items()}}
    t0 = time.time()
    spread = {}
    for suite in a.suites.split(","):
        eps = draw_suite(suite, g._runs(suite, 200), seed=EVAL_SEED_BASE)
        res = g.evaluate_suite(suite, eps, policies)
        res["policies"]["policy_bp"] = res["policies"][a.chosen]
        spread[suite] = res
        print(f"{suite}: {time.time() - t0:.0f} s", file=sys.stderr, flush=True)
    data = {"seed": EVAL_SEED_BASE, "chosen": a.chosen, "seeds": list(seeds), "seconds": time.time() - t0,
            "spread": spread}
    Path(a.out).write_text(json.dumps(jsonable(data), indent=1, allow_nan=False))
    rows = g.bp_targets(spread, "policy_bp", list(seeds))
    print("| target (policy_bp and its recipe's seeds, held-out seeds) | reached | numbers |\n|---|---|---|")
    for name, ok, nums in rows:
        print(f"| {name} | {'-' if ok is None else ('yes' if ok else '**no**')} | {nums} |")
    print("\n| suite (runs) | strongest | " + " | ".join(f"{n} / strongest" for n in [*seeds, "policy"]) + " |")
    for s, res in spread.items():
        print(f"| {s} ({res['runs']}) | {res['strongest_classical']} | " + " | ".join(
            g._f3(res["policies"][n]["ratio_vs_strongest"]) for n in [*seeds, "policy"]) + " |")
    return data


if __name__ == "__main__":
    main()
