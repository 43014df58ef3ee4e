"""Range rate in the trackers: every tracker that also updates on the radial velocity beside its position-only self,
on held-out seeds: ``python -m agents.reports.range_rate``.

Per suite (the main job's, the held-out families and ``adsb_heldout``; evaluation seeds ``EVAL_SEED_BASE + i``):
each range-rate tracker's pooled position RMSE, its ratio to its position-only self and to ``imm_cv_ct`` (paired 95 %
bootstrap intervals, :func:`agents.evaluation.metrics.ratio_ci`), ANEES and track loss; the learned range-rate
trackers (every bundled learned tracker whose env config has ``radial_velocity``) against the strongest classical
range-rate tracker of the suite (:data:`CLASSICAL_RDOT`, chosen on the same runs, which favours it). Writes
``docs/range_rate.json`` and the blocks ``range-rate`` and ``range-rate-targets`` (docs/results.md). Every number is
computed here.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from agents.evaluation.evaluate import default_runs
from agents.evaluation.metrics import FEW_RUNS, evaluate_run, jsonable, ratio_ci
from agents.evaluation.runner import run_policy
from agents.evaluation.suites import DEFAULT_SUITES, EVAL_SEED_BASE, HELDOUT_FAMILY_SUITES, draw_suite
from agents.policies.learned import BUNDLED_LEARNED, load_learned
from baselines.registry import RANGE_RATE_TRACKERS, run_tracker
from radar_env.sim.episode import stack_episodes

__all__ = ["PAIRS", "CLASSICAL_RDOT", "VS_IMM_CV_CT", "SUITES", "learned_rdot", "learned_seeds", "evaluate_suite",
           "table", "seeds_table", "targets_table", "main"]

PAIRS = {t: t.removesuffix("_rdot") for t in RANGE_RATE_TRACKERS}
"""Each range-rate tracker and its position-only self."""
CLASSICAL_RDOT = tuple(PAIRS)
"""The classical field of the range-rate trackers (the learned range-rate trackers are compared with its best)."""
VS_IMM_CV_CT = ("imm_cv_ct_rdot", "imm_ct_bank_rdot", "rbpf_rdot")
"""The classical range-rate trackers whose ratio to imm_cv_ct (position only) the table shows."""
SUITES = DEFAULT_SUITES + HELDOUT_FAMILY_SUITES
FAMILY_RUNS = 60
"""Runs of a held-out family (as the generalisation report's family table); the main job's suites run their
default runs."""


def learned_rdot():
    """The bundled learned trackers that update on the radial velocity: ``{name: LearnedTracker}``."""
    out = {}
    for name in BUNDLED_LEARNED:
        lt = load_learned(name)
        if getattr(lt.env_config, "radial_velocity", False):
            out[name] = lt
    return out


def learned_seeds(learned):
    """Every training seed of each bundled range-rate tracker's recipe (its ``seeds/`` folder): ``{name: {seed run:
    LearnedTracker}}``, with ``None`` for the seed the bundle is (its ``choice.json``'s ``chosen``: the bundle's own
    run stands for it, not a second run of the same weights)."""
    out = {}
    for n in learned:
        folder = BUNDLED_LEARNED[n]
        if (folder / "seeds").is_dir():
            chosen = json.loads((folder / "choice.json").read_text()).get("chosen")
            out[n] = {d.name: None if d.name == chosen else load_learned(str(d))
                      for d in sorted((folder / "seeds").iterdir()) if d.is_dir()}
    return out


def _runs(suite, family_runs):
    return family_runs if suite in HELDOUT_FAMILY_SUITES and suite != "adsb_heldout" else default_runs(suite)


def _ratio(batch, a, b):
    r, (lo, hi) = ratio_ci(batch, a, b)[:2]
    return [float(r), [float(lo), float(hi)]]


def evaluate_suite(episodes, learned, seeds=None):
    """Every range-rate tracker, its position-only self, imm_cv_ct and the ``learned`` range-rate trackers
    (``{name: LearnedTracker}``) on ``episodes``, and each learned tracker's recipe on its training ``seeds``
    (:func:`learned_seeds`; their ratios to imm_cv_ct and to the strongest classical range-rate tracker); the
    suite's JSON-able result."""
    batch = stack_episodes(episodes)
    names = list(dict.fromkeys(list(PAIRS) + list(PAIRS.values()) + ["imm_cv_ct"]))
    runs = {t: run_tracker(t, episodes) for t in names}
    for n, lt in learned.items():
        runs[n] = run_policy(n, episodes, lt.policy, lt.env_config)
    metrics = {t: evaluate_run(batch, r) for t, r in runs.items()}
    ok = {t: metrics[t]["pos_rmse_m"] for t in CLASSICAL_RDOT if np.isfinite(metrics[t]["pos_rmse_m"])}
    strongest = min(ok, key=ok.get)
    res = {"runs": len(episodes), "few_runs": len(episodes) < FEW_RUNS, "strongest_classical_rdot": strongest,
           "trackers": {t: {k: metrics[t][k] for k in ("pos_rmse_m", "pos_rmse_m_ci95", "track_loss_rate",
                                                     "failed_runs", "anees")} for t in runs},
           "ratio_vs_self": {t: _ratio(batch, runs[t], runs[s]) for t, s in PAIRS.items()},
           "ratio_vs_imm_cv_ct": {t: _ratio(batch, runs[t], runs["imm_cv_ct"]) for t in runs},
           "ratio_vs_strongest_rdot": {n: _ratio(batch, runs[n], runs[strongest]) for n in learned}, "seeds": {}}
    for n, by_seed in (seeds or {}).items():
        res["seeds"][n] = {}
        for run_name, lt in by_seed.items():
            r = runs[n] if lt is None else run_policy(n, episodes, lt.policy, lt.env_config)
            m = metrics[n] if lt is None else evaluate_run(batch, r)
            res["seeds"][n][run_name] = {"pos_rmse_m": m["pos_rmse_m"], "anees": m["anees"],
                                         "track_loss_rate": m["track_loss_rate"],
                                         "ratio_vs_imm_cv_ct": _ratio(batch, r, runs["imm_cv_ct"]),
                                         "ratio_vs_strongest_rdot": _ratio(batch, r, runs[strongest])}
    return res


def _r(r):
    return "-" if r is None or not np.isfinite(r[0]) else f"{r[0]:.3f} [{r[1][0]:.3f}, {r[1][1]:.3f}]"


def table(data):
    """Markdown: per suite, each range-rate tracker's RMSE, its ratio to its position-only self and to imm_cv_ct."""
    learned = data["learned"]
    cols = list(PAIRS) + learned
    out = ["Made by `python -m agents.reports.range_rate` (held-out seeds; docs/range_rate.json). Per suite: RMSE m "
           "(ANEES) of each range-rate tracker; / self: over its position-only self; / imm_cv_ct: over imm_cv_ct "
           "(position only); paired 95 % intervals" + (f"; (n<{FEW_RUNS}): fewer runs than that" if any(
               s["few_runs"] for s in data["suites"].values()) else "") + ".", "",
           "| suite (runs) | " + " | ".join(f"{c} m (ANEES)" for c in cols) + " | "
           + " | ".join(f"{t} / self" for t in PAIRS) + " | "
           + " | ".join(f"{c} / imm_cv_ct" for c in (*VS_IMM_CV_CT, *learned)) + " |",
           "|---" * (1 + len(cols) + len(PAIRS) + len(VS_IMM_CV_CT) + len(learned)) + "|"]
    for suite, s in data["suites"].items():
        tr = s["trackers"]
        few = f" (n<{FEW_RUNS})" if s["few_runs"] else ""
        cells = [f"{tr[c]['pos_rmse_m']:.1f} ({tr[c]['anees']:.2f})" + (
            f", lost {tr[c]['track_loss_rate']:.2f}" if tr[c]["track_loss_rate"] > 0 else "") for c in cols]
        cells += [_r(s["ratio_vs_self"][t]) for t in PAIRS]
        cells += [_r(s["ratio_vs_imm_cv_ct"][c]) for c in (*VS_IMM_CV_CT, *learned)]
        out.append(f"| {suite} ({s['runs']}){few} | " + " | ".join(cells) + " |")
    return "\n".join(out + seeds_table(data))


def seeds_table(data):
    """Markdown lines: the spread of each learned range-rate recipe over its training seeds, per suite (the mean and
    the worst of the seeds' ratios to the strongest classical range-rate tracker); none without seed runs."""
    S = data["suites"]
    names = [n for n in data["learned"] if any(s.get("seeds", {}).get(n) for s in S.values())]
    if not names:
        return []
    counts = {n: max(len(s["seeds"].get(n, {})) for s in S.values()) for n in names}
    out = ["", "Over the training seeds of each learned recipe (" + ", ".join(
        f"{n}: {k} seed{'s' if k != 1 else ''}" for n, k in counts.items()) + "; the bundled one is the seed with the "
           "best validation score, chosen before any of these numbers): the mean and the worst (highest) of the "
           "seeds' ratios to the suite's strongest classical range-rate tracker.", "",
           "| suite | " + " | ".join(f"{n} mean / worst" for n in names) + " |", "|---" * (1 + len(names)) + "|"]
    for suite, s in S.items():
        cells = []
        for n in names:
            r = [v["ratio_vs_strongest_rdot"][0] for v in s["seeds"].get(n, {}).values()]
            cells.append(f"{np.mean(r):.3f} / {max(r):.3f}" if r and np.all(np.isfinite(r)) else "-")
        out.append(f"| {suite} | " + " | ".join(cells) + " |")
    return out


def _row(target, value, reached):
    return f"| {target} | {value} | {'reached' if reached else '**not reached**'} |"


def targets_table(data):
    """Markdown: the range-rate targets of issue 39, reached or not, with the numbers."""
    S = data["suites"]
    rnd = S["random"]
    r = rnd["ratio_vs_imm_cv_ct"]["imm_cv_ct_rdot"]
    worse = {t: [k for k, s in S.items() if s["ratio_vs_self"][t][1][0] > 1.0] for t in PAIRS}
    anees = {t: rnd["trackers"][t]["anees"] for t in list(PAIRS) + data["learned"]}
    out = ["Made by `python -m agents.reports.range_rate` (the same runs as the table above).", "",
           "| target | measured | |", "|---|---|---|",
           _row("imm_cv_ct_rdot at most 0.85x imm_cv_ct on random (stretch 0.75x)", _r(r), r[0] <= 0.85),
           _row("no suite where a range-rate tracker is worse than its position-only self (interval above 1)",
                "; ".join(f"{t}: {', '.join(v) or 'none'}" for t, v in worse.items()),
                not any(worse.values())),
           _row("ANEES of every range-rate tracker on random within [0.7, 2]",
                ", ".join(f"{t} {v:.2f}" for t, v in anees.items()),
                all(0.7 <= v <= 2.0 for v in anees.values()))]
    if data["learned"]:
        for n in data["learned"]:
            bad = [k for k, s in S.items() if s["ratio_vs_strongest_rdot"][n][1][1] > 1.02]
            rr = rnd["ratio_vs_strongest_rdot"][n]
            out.append(_row(f"{n} at most 1.0x the strongest classical range-rate tracker on every suite (upper "
                            "end at most 1.02)", "above on: " + (", ".join(bad) or "none"), not bad))
            out.append(_row(f"{n} at most 0.95x it on random ({rnd['strongest_classical_rdot']})", _r(rr),
                            rr[0] <= 0.95))
            sd = rnd.get("seeds", {}).get(n, {})
            if sd:
                ok = [k for k, v in sd.items() if v["ratio_vs_strongest_rdot"][0] <= 0.95]
                out.append(_row(f"{n}'s recipe: at most 0.95x it on random on at least 2 of {len(sd)} training seeds",
                                ", ".join(f"{k} {v['ratio_vs_strongest_rdot'][0]:.3f}" for k, v in sd.items()),
                                len(ok) >= 2))
    else:
        out.append("| the learned range-rate trackers' targets | no learned range-rate tracker is bundled | "
                   "**not reached** |")
    return "\n".join(out)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m agents.reports.range_rate", description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", default="docs")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE)
    ap.add_argument("--family-runs", type=int, default=FAMILY_RUNS)
    ap.add_argument("--suites", default=",".join(SUITES), help="comma-separated suites (default: all)")
    ap.add_argument("--no-readme", dest="readme", action="store_false",
                    help="do not update the generated blocks of docs/*.md")
    args = ap.parse_args(argv)
    from agents.reports.blocks import check_report_options
    check_report_options(args, SUITES)
    t0 = time.time()
    learned = learned_rdot()
    seeds = learned_seeds(learned)
    data = {"seed": args.seed, "learned": list(learned), "suites": {}}
    for suite in [s.strip() for s in args.suites.split(",") if s.strip()]:
        eps = draw_suite(suite, _runs(suite, args.family_runs), seed=args.seed)
        data["suites"][suite] = evaluate_suite(eps, learned, seeds)
        print(f"{suite} ({time.time() - t0:.0f} s)", flush=True)
    data["seconds"] = time.time() - t0
    docs = Path(args.docs)
    (docs / "range_rate.json").write_text(json.dumps(jsonable(data), indent=1, allow_nan=False))
    blocks = {"range-rate": table(data), "range-rate-targets": targets_table(data)}
    if args.readme:
        from agents.reports.blocks import replace_block
        for name, text in blocks.items():
            replace_block(name, text)
    print("\n\n".join(blocks.values()))


if __name__ == "__main__":
    main()
