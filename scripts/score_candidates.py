"""Score candidate policies for the choice of the bundle, on TRAINING-range seeds only (issue 20's rule, recorded in
agents/bundled/policy/choice.json):

    python scripts/score_candidates.py NAME=path/to/policy.zip [NAME=...] [--out scores.json]

Suites (seeds SELECTION_SEED_BASE + i = 900_000 + i, inside the training range; never the held-out evaluation seeds
or the held-out families): random 400 runs, random_radars 200, each named scenario 20 (adrian_flower 4), adsb_dev
(12 flights, each once). Prints per candidate the ratio to imm2 with its paired 95 % interval on every suite, the
geometric mean of the random / random_radars ratios, the worst ratio over the named scenarios and adsb_dev, and
whether it is eligible (worst <= 1.05 and the random upper end < 1).
"""

from __future__ import annotations

import argparse
import json
import sys

import numpy as np

from agents.training.callbacks import SELECTION_SEED_BASE
from agents.policies.loading import load_policy
from agents.evaluation.metrics import ratio_ci
from agents.evaluation.suites import draw_suite
from baselines.registry import run_tracker
from baselines.trackers import run_q_policy
from radar_env.sim.episode import stack_episodes

SUITES = {"random": 400, "random_radars": 200, "bizup2002": 20, "adrian_flower": 4, "kim_lee_accel": 20,
          "seed002_course_changes": 20, "seed002_two_radars": 20, "adsb_dev": 12}
GATED = ("bizup2002", "adrian_flower", "kim_lee_accel", "seed002_course_changes", "seed002_two_radars", "adsb_dev")


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("candidates", nargs="+", metavar="NAME=PATH")
    ap.add_argument("--out")
    args = ap.parse_args(argv)
    cands = dict(c.split("=", 1) for c in args.candidates)
    pols = {n: load_policy(p) for n, p in cands.items()}
    scores = {n: {} for n in cands}
    for suite, runs in SUITES.items():
        eps = draw_suite(suite, runs, seed=SELECTION_SEED_BASE)
        batch = stack_episodes(eps)
        ref = run_tracker("imm2", eps)
        for n, (choose_q, cfg) in pols.items():
            r, ci = ratio_ci(batch, run_q_policy(eps, choose_q, n, cfg), ref)
            scores[n][suite] = [r, list(ci)]
        print(suite, {n: round(scores[n][suite][0], 3) for n in cands}, file=sys.stderr, flush=True)
    for n, s in scores.items():
        worst = max(GATED, key=lambda k: s[k][0])
        s["geomean_random_random_radars"] = float(np.sqrt(s["random"][0] * s["random_radars"][0]))
        s["worst_gated"] = [worst, s[worst][0]]
        s["eligible"] = bool(s[worst][0] <= 1.05 and s["random"][1][1] < 1.0)
        print(f"{n}: geomean {s['geomean_random_random_radars']:.3f}, worst {worst} {s[worst][0]:.3f}, random "
              f"{s['random'][0]:.3f} [{s['random'][1][0]:.3f}, {s['random'][1][1]:.3f}], eligible {s['eligible']}")
    if args.out:
        with open(args.out, "w") as f:
            json.dump(scores, f, indent=1)


if __name__ == "__main__":
    main()
