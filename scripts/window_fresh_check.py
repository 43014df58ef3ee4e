"""Window corrections against a reference correction on fresh TRAINING-range flights: S4 (the geometric mean over the
four selection suites of the correction / imm2 pooled-RMSE ratio, as the trainer selects on) and the broad score
(the geometric mean of the pooled-RMSE ratios to the reference on ``random`` and ``random_radars`` flights with the
broad laws, :func:`agents.training.window.broad_config`), each with a paired bootstrap interval over flights (2,000
draws; issue 38; agents/bundled/window/CHOICE.md, the eleventh recipe's rule).

    python scripts/window_fresh_check.py REFERENCE CANDIDATE [CANDIDATE ...] [--runs 200] [--seed 965000]
        [--broad-seed 975000]

The selection suites are drawn as the trainer draws them (:func:`agents.training.selection.draw_selection_suite`)
from ``--seed``, the broad pair from ``--broad-seed`` (the defaults are the eleventh window recipe's rule's, 966,000
and 976,000 the twelfth's: a new rule should take seeds no earlier rule or check used, as
agents/bundled/window/CHOICE.md records them, below the held-out 10,000,000); every correction must share its base,
which runs once per suite. A non-finite estimate stops the script with a one-line error naming the tracker (a failure
is never pooled).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path
from types import SimpleNamespace

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from agents.evaluation.metrics import errors, failed_runs, region_masks  # noqa: E402
from agents.evaluation.suites import draw_suite  # noqa: E402
from agents.training.selection import START_UNKNOWN_SUITES, draw_selection_suite  # noqa: E402
from agents.training.window import broad_config  # noqa: E402
from baselines.registry import run_tracker  # noqa: E402
from radar_env.sim.episode import stack_episodes, stack_fields  # noqa: E402

SELECTION = ("random", "random_radars", *START_UNKNOWN_SUITES)
BROAD = ("random", "random_radars")


def suite_sums(eps, pols, names, partner):
    """Per-flight squared position-error sums of the corrections ``pols`` (sharing their base, which runs once per
    precision of its GRU) and of the classical tracker ``partner`` on the episodes ``eps``, over the looks each
    scores: ``(sums (corrections, runs), looks (runs), partner's sums (runs), partner's looks (runs))``. A non-finite
    estimate stops the script with a one-line error naming the tracker (a failure is never pooled)."""
    b = stack_episodes(eps)
    bases = {}          # one run of the base per precision of its GRU (an ensemble's may be float32)
    for p in pols:
        bp = getattr(p, "base_precision", "float64")
        if bp not in bases:
            bases[bp] = p.base_run(eps)
    base = next(iter(bases.values()))      # its track start (start_index) is every base's: the GRU acts after it
    looks = SimpleNamespace(**stack_fields(eps, ("t_s", "z_m", "R_m2", "detected")))
    runs = [p.correct(looks, bases[getattr(p, "base_precision", "float64")], n) for p, n in zip(pols, names)]
    other = run_tracker(partner, eps)
    bad = [r.name for r in (*runs, other) if failed_runs(b, r).any()]
    if bad:
        raise SystemExit(f"error: {bad} failed on some runs (non-finite estimate or covariance)")
    used = region_masks(b, base.start_index)["used"]
    o_used = region_masks(b, other.start_index)["used"]
    return (np.array([np.where(used, errors(b, r)[0] ** 2, 0.0).sum(1) for r in runs]), used.sum(1),
            np.where(o_used, errors(b, other)[0] ** 2, 0.0).sum(1), o_used.sum(1))


def _rmse(s, n, i):
    return np.sqrt(s[..., i].sum(-1) / n[i].sum())


def s4(sel, idx):
    """S4 of each correction, ``(corrections,)``: the geometric mean over the suites of ``sel`` (``{suite:
    suite_sums(...)}``, imm2 as the partner) of its pooled RMSE over imm2's on the flights ``idx[suite]``."""
    return np.exp(np.mean([np.log(_rmse(s, n, idx[u]) / np.sqrt(so[idx[u]].sum() / no[idx[u]].sum()))
                           for u, (s, n, so, no) in sel.items()], 0))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("folders", nargs="+", help="the reference correction's folder, then the candidates'")
    ap.add_argument("--runs", type=int, default=200, help="flights per suite (at least 2)")
    ap.add_argument("--seed", type=int, default=965_000, help="the selection suites' base seed")
    ap.add_argument("--broad-seed", type=int, default=975_000, help="the broad pair's base seed")
    args = ap.parse_args(argv)
    if args.runs < 2:
        raise SystemExit(f"error: --runs must be at least 2, got {args.runs}")
    if len(args.folders) < 2:
        raise SystemExit(f"error: a reference and at least one candidate, got {len(args.folders)} folder(s)")
    from agents.evaluation.suites import EVAL_SEED_BASE
    from agents.training.selection import START_UNKNOWN_SEED_OFFSET
    for option, first, last in (("--seed", args.seed, args.seed + START_UNKNOWN_SEED_OFFSET + args.runs - 1),
                                ("--broad-seed", args.broad_seed, args.broad_seed + args.runs - 1)):
        if first < 0 or last >= EVAL_SEED_BASE:
            raise SystemExit(f"error: {option}: the flights' seeds {first}..{last} must lie in [0, "
                             f"{EVAL_SEED_BASE:,}) (the held-out evaluation's seeds start there)")
    names = [Path(f).name for f in args.folders]
    from agents.policies.layout import CORRECTION_KINDS
    from agents.policies.learned import load_learned
    try:
        pols = [load_learned(f, kinds=CORRECTION_KINDS).policy for f in args.folders]
    except ValueError as e:
        raise SystemExit(f"error: {str(e).splitlines()[0]}"[:500]) from None
    if len({str(p.config.get("base")) for p in pols}) > 1:
        raise SystemExit(f"error: the corrections must share their base, got "
                         f"{sorted({str(p.config.get('base')) for p in pols})}")
    sel = {u: suite_sums(draw_selection_suite(u, args.runs, args.seed), pols, names, "imm2") for u in SELECTION}
    broad = {u: suite_sums(draw_suite(u, args.runs, seed=args.broad_seed, random_config=broad_config()), pols, names,
                      "imm_ct_bank") for u in BROAD}

    def broad_rmse(idx):   # (suites, corrections)
        return np.array([_rmse(s, n, idx[u]) for u, (s, n, _, _) in broad.items()])

    full = {u: np.arange(args.runs) for u in (*SELECTION, *BROAD)}
    rng = np.random.default_rng(0)
    draws = [{u: rng.integers(0, args.runs, args.runs) for u in full} for _ in range(2000)]
    S = s4(sel, full)
    Br = broad_rmse(full)
    s4_d = np.array([s4(sel, i) for i in draws])
    br_d = np.array([broad_rmse(i) for i in draws])
    print(f"{args.runs} flights per suite: selection suites from seed {args.seed}, broad pair from "
          f"{args.broad_seed}; reference {names[0]}")
    print("| correction | S4 | S4 / reference | broad random (m) | broad random_radars (m) | broad score |")
    print("|---|---:|---|---:|---:|---|")
    for k, n in enumerate(names):
        r = s4_d[:, k] / s4_d[:, 0]
        b = np.exp(np.log(br_d[:, :, k] / br_d[:, :, 0]).mean(1))
        score = float(np.exp(np.log(Br[:, k] / Br[:, 0]).mean()))
        print(f"| {n} | {S[k]:.4f} | {S[k] / S[0]:.4f} [{np.percentile(r, 2.5):.4f}, {np.percentile(r, 97.5):.4f}] "
              f"| {Br[0, k]:.1f} | {Br[1, k]:.1f} | {score:.4f} [{np.percentile(b, 2.5):.4f}, "
              f"{np.percentile(b, 97.5):.4f}] |")
    print("per suite, correction / imm2 (selection) and imm_ct_bank's RMSE (broad, m):")
    for u, (s, n, so, no) in sel.items():
        print(f"  {u}: " + ", ".join(f"{nm} {v:.4f}" for nm, v in
                                     zip(names, _rmse(s, n, full[u]) / np.sqrt(so.sum() / no.sum()))))
    for u, (_, _, so, no) in broad.items():
        print(f"  broad {u}: imm_ct_bank {np.sqrt(so.sum() / no.sum()):.1f} m")


if __name__ == "__main__":
    main()
