"""Generate the results the README shows: ``python -m agents.reports.report``.

Runs the evaluation (:func:`agents.evaluation.evaluate.evaluate`) on the default suites with every comparison tracker (and
the bundled policy if present), then writes ``docs/results_tables.md`` (tables), ``docs/results.json`` (every metric) and
``docs/figures/*.png``. Nothing in those files is typed by hand.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from agents.evaluation.evaluate import default_runs, evaluate, table_notes
from agents.evaluation.metrics import jsonable
from agents.policies.bundle import BUNDLED_POLICIES, BUNDLED_POLICY
from agents.evaluation.metrics import FEW_RUNS, comparable_rmse
from agents.evaluation.scores import MIN_REFERENCE_GAP, normalised_score, reference_constants
from baselines.registry import BOUND_TRACKERS
from agents.evaluation.suites import DEFAULT_SUITES, EVAL_SEED_BASE, draw_suite, run_scenario

__all__ = ["main", "markdown_tables"]

REPORT_TRACKERS = ("imm2", "imm2_grid", "imm_cv_ct", "imm_ct_bank", "rbpf", "imm2_bizup", "imm3_ct", "kf_tuned", "kf_low", "kf_high", "kf_blair", "cmin", "ckf",
                   "reinit", "kim_lee", "alpha_beta", "alpha_beta_adaptive", "adrian1", "adrian2", "konle",
                   "kf_tuned_rdot", "imm2_rdot", "imm_cv_ct_rdot", "imm_ct_bank_rdot", "oracle_q",
                   "clairvoyant")
FIGURE_TRACKERS = ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo", "imm2", "imm_cv_ct", "rbpf", "imm2_bizup", "kf_tuned", "cmin", "clairvoyant")
"""The trackers of the figures: the main job's (the strongest classical tracker, imm_cv_ct, included)."""
PER_FLIGHT_TRACKERS = ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo", "imm2", "imm2_bizup", "kf_tuned", "clairvoyant", "kf_low")
"""The columns of the ADS-B per-flight table."""


def _fmt(v, nd=1):
    return "-" if v is None or not np.isfinite(v) else f"{v:.{nd}f}"


def _ci(est, ci, n, nd=1):
    """``est [lo, hi]``, with ``(n<20)`` if the interval comes from fewer than ``FEW_RUNS`` runs; '-' if undefined."""
    if est is None or not np.isfinite(est):
        return "-"
    few = f" (n<{FEW_RUNS})" if n is not None and n < FEW_RUNS else ""
    return f"{est:.{nd}f} [{_fmt(ci[0], nd)}, {_fmt(ci[1], nd)}]{few}"


def markdown_tables(results, reference="imm2"):
    """Markdown: one table per suite, one row per tracker (every metric of :mod:`agents.evaluation.metrics` the README shows)."""
    out = [f"Columns: *pos RMSE* pooled over the runs the tracker did not fail (its lost runs included); *lost* = "
           f"fraction of runs whose error passed the 30-sigma gate or went non-finite; *failed* = runs with a "
           f"non-finite estimate or covariance (left out of that tracker's other metrics); *common RMSE* over the "
           f"suite's common runs (no tracker of the table lost or failed them), the same runs for every tracker; "
           f"*RMSE / {reference}, all* paired over the runs neither failed, *common* over the common runs. "
           f"(n<{FEW_RUNS}) marks an interval from fewer than {FEW_RUNS} runs: no evidence either way.", ""]
    for suite, res in results.items():
        n_common = res.get("common_runs")
        out += [f"### {suite} ({res['runs']} runs, {res['looks_per_run_mean']:.0f} looks per run"
                + ("" if n_common is None else f", {n_common} common runs") + ")", "",
                "| tracker | pos RMSE m [95% CI] | maneuver | after | straight | vel RMSE m/s | peak m | ANEES | "
                f"NEES in 95% | lost | failed | common RMSE m [95% CI] | RMSE / {reference}, all [95% CI] | "
                f"RMSE / {reference}, common [95% CI] | delay (looks) | false alarms / look |",
                "|---" * 16 + "|"]
        ratios = res.get(f"ratio_vs_{reference}", {})
        ratio_runs = res.get(f"ratio_vs_{reference}_runs", {})
        ratios_c = res.get(f"ratio_vs_{reference}_common", {})
        for t, m in res["trackers"].items():
            r, rc = ratios.get(t), ratios_c.get(t)
            out.append(
                f"| {t} | {_ci(m['pos_rmse_m'], m['pos_rmse_m_ci95'], m.get('runs_scored', res['runs']))} | "
                f"{_fmt(m['pos_rmse_m_maneuver'])} | {_fmt(m['pos_rmse_m_after'])} | {_fmt(m['pos_rmse_m_straight'])} | "
                f"{_fmt(m['vel_rmse_m_s'], 2)} | {_fmt(m['peak_pos_err_m'], 0)} | {_fmt(m['anees'], 2)} | "
                f"{_fmt(m['nees_in_95'], 2)} | {_fmt(m['track_loss_rate'], 2)} | {m.get('failed_runs', '-')} | "
                f"{_ci(m.get('pos_rmse_m_common'), m.get('pos_rmse_m_common_ci95'), n_common)} | "
                f"{_ci(r[0], r[1], ratio_runs.get(t, res['runs']), 3) if r else '-'} | "
                f"{_ci(rc[0], rc[1], n_common, 3) if rc else '-'} | {_fmt(m.get('detection_delay_looks'), 2)} | "
                f"{_fmt(m.get('false_alarm_rate'), 3)} |")
        notes = table_notes(res)
        out += [""] + [f"* {n}" for n in notes] if notes else []
        out.append("")
    return "\n".join(out)


LEARNED_WHAT = {"policy_bp": "trained by backpropagation", "policy_imm_bp": "the learned IMM",
                "policy_imm_ppo": "the learned IMM, PPO",
                "policy_bp_rdot": "policy_bp's recipe on the range-rate filter",
                "policy_imm_bp_rdot": "policy_imm_bp's recipe on the range-rate filter",
                "policy_imm_bp_prior": "policy_imm_bp's recipe trained on the random suites' own flights",
                "policy_bp_prior": "policy_bp's recipe, GRU 128 + tanh 64, trained on the random suites' own flights",
                "policy_window": "policy_bp_prior with a learned window correction (three MLPs averaged, over its "
                                 "last 24 plots, quadratic fits through them and its base's last 12 q)"}
"""What each bundled learned tracker is, for the results page's header."""
ROOT = Path(__file__).resolve().parents[2]

HEADLINE_TRACKERS = ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo", "imm2", "imm2_grid", "imm_cv_ct", "imm_ct_bank", "rbpf",
                     "kf_tuned", "cmin", "policy_bp_rdot", "policy_imm_bp_rdot", "imm_cv_ct_rdot", "imm_ct_bank_rdot", "hindsight_q",
                     "hindsight_q_turn", "clairvoyant")


BOUNDS_SUITES = ("random", "bizup2002", "kim_lee_accel")
BOUNDS_RUNS = 30
BOUNDS_TRACKERS = ("imm2", "imm_cv_ct", "rbpf", "kf_tuned", "cmin", "hindsight_q", "hindsight_q_turn", "clairvoyant")
"""The hindsight bounds cost about a CPU-second per episode each (baselines/hindsight.py), so they are computed on the
first ``BOUNDS_RUNS`` runs of these suites only (the same episodes as runs 0..29 of the full tables, seeds
``seed + i``), beside the trackers they bound; written to ``docs/bounds.json`` and the README's ``bounds`` block."""


def headroom_share(res, tracker="policy", low="imm2", ceiling="hindsight_q"):
    """Share of the headroom between ``low`` and the ``ceiling`` bound that ``tracker`` captures, on pooled RMSE:
    ``(rmse_low - rmse_tracker) / (rmse_low - rmse_ceiling)`` (1 = at the ceiling, 0 = no better than ``low``,
    negative = worse). ``None`` where a tracker is missing, non-finite, failed a run (its pooled RMSE would cover
    other runs than the others'), or the headroom is not positive."""
    ms = [res["trackers"].get(t) for t in (tracker, low, ceiling)]
    if any(m is None or not comparable_rmse(m) for m in ms):
        return None
    a, b, c = (m["pos_rmse_m"] for m in ms)
    return None if b - c <= 0 else (b - a) / (b - c)


def scores_table(results, names=None):
    """Markdown: the normalised score (0 = ``kf_tuned``, 100 = ``rbpf``; :mod:`agents.evaluation.scores`) of each
    tracker of ``names`` (default: every tracker of the results, bounds last) per suite, the references taken from
    ``results`` themselves (:func:`~agents.evaluation.scores.reference_constants`)."""
    refs = reference_constants(results)
    present = [t for res in results.values() for t in res["trackers"]]
    names = [t for t in dict.fromkeys(present) if names is None or t in names]
    names = [t for t in names if t not in BOUND_TRACKERS] + [t for t in names if t in BOUND_TRACKERS]
    lines = ["| suite | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for suite, res in results.items():
        if suite not in refs:
            continue
        cells = []
        for t in names:
            m = res["trackers"].get(t)      # none for a tracker that failed runs (the references pool every run)
            v = normalised_score(suite, m["pos_rmse_m"], refs) if m is not None and comparable_rmse(m) else None
            cells.append("-" if v is None else str(int(round(v))))
        lines.append(f"| {suite} | " + " | ".join(cells) + " |")
    unscored = [s for s in results if s not in refs]
    if unscored:
        lines += ["", f"No score on {', '.join(unscored)}: there `rbpf` is not {MIN_REFERENCE_GAP:.0%} better than "
                      "`kf_tuned` (its prior does not hold), so the scale is undefined."]
    return "\n".join(lines)


def headline(results, has_policy):
    """Compact table for the README: position RMSE (m) pooled over the runs each tracker did not fail, and its ratio
    to imm2 paired over the runs neither failed, with 95% CIs, per suite; ``(n<20)`` beside an interval from fewer
    than 20 runs, ``lost x%`` where the tracker lost (or failed) runs."""
    present = {t for res in results.values() for t in res["trackers"]}
    names = [t for t in HEADLINE_TRACKERS if t in present and (t != "policy" or has_policy)]
    share = has_policy and "hindsight_q" in names
    lines = ["| suite | " + " | ".join(names) + (" | policy's share of the imm2 -> hindsight_q headroom |" if share
                                                 else " |"),
             "|---" * (len(names) + 1 + share) + "|"]
    for suite, res in results.items():
        cells = []
        for t in names:
            m = res["trackers"].get(t)
            r = res.get("ratio_vs_imm2", {}).get(t)
            if m is None:
                cells.append("-")
                continue
            cell = _fmt(m["pos_rmse_m"], 0)
            if t != "imm2" and r is not None:
                cell += f" ({_ci(r[0], r[1], res.get('ratio_vs_imm2_runs', {}).get(t, res['runs']), 2)})"
            if m["track_loss_rate"]:
                cell += f", lost {100 * m['track_loss_rate']:.0f}%"
            cells.append(cell)
        if share:
            h = headroom_share(res)
            cells.append("-" if h is None else f"{100 * h:.0f}%")
        lines.append(f"| {suite} ({res['runs']} runs) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def _fewer(m, suite_result):
    """' (n=k of N)' where a downstream metric comes from fewer runs than the suite has (failed runs left out)."""
    k = m.get("downstream_runs")
    return "" if k is None or k >= suite_result["runs"] else f" (n={k} of {suite_result['runs']})"


def downstream_tables(results, trackers):
    """Markdown: conflict warnings on the encounters suite, intercept miss distance per suite."""
    out = []
    enc = results.get("encounters")
    if enc:
        out += ["| tracker | warning lead time s (ideal) | conflicts never warned | false-warning looks | "
                "missed-warning looks |", "|---|---|---|---|---|"]
        for t in trackers:
            m = enc["trackers"].get(t)
            if m:
                out.append(f"| {t}{_fewer(m, enc)} | {_fmt(m['warning_lead_time_s'])} ({_fmt(m['ideal_lead_time_s'])}) | "
                           f"{_fmt(m['missed_warnings'], 2)} | {_fmt(m['false_warning_rate'], 3)} | "
                           f"{_fmt(m['missed_warning_rate'], 3)} |")
        out.append("")
    suites = [s for s in results if s != "encounters"]
    out += ["| intercept: median miss m (capture rate) | " + " | ".join(suites) + " |",
            "|---" * (len(suites) + 1) + "|"]
    for t in trackers:
        cells = []
        for su in suites:
            m = results[su]["trackers"].get(t, {})
            cells.append(f"{_fmt(m.get('intercept_miss_m_median'))} ({_fmt(m.get('intercept_capture_rate'), 2)})"
                         f"{_fewer(m, results[su])}")
        out.append(f"| {t} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def per_flight_rmse(batch, suite_runs, trackers):
    """Position RMSE (m) per ADS-B flight and tracker, JSON-able (stored as ``results["adsb_calibration"]
    ["per_flight"]`` so the README table renders from docs/results.json alone): ``{"trackers": [...], "flights":
    [{"flight", "looks", "maneuvering_pct", "rmse_m": {tracker: m, or None where the tracker failed the flight}}]}``.
    A flight without a scored look (after a tracker's track start) is refused, naming it: its RMSE would be NaN."""
    from agents.evaluation.metrics import errors, failed_runs, region_masks
    names = [t for t in trackers if t in suite_runs]
    used0 = region_masks(batch, suite_runs[names[0]].start_index)["used"]
    per = {t: (region_masks(batch, suite_runs[t].start_index)["used"], errors(batch, suite_runs[t])[0],
               failed_runs(batch, suite_runs[t])) for t in names}
    for t, (used, _, _) in per.items():
        empty = np.flatnonzero(~used.any(axis=1))
        if empty.size:
            raise ValueError(f"per_flight_rmse: flight {batch.names[empty[0]]!r} has no scored look after "
                             f"{t}'s track start: no RMSE to report")
    flights = []
    for b, flight in enumerate(batch.names):
        rmse = {t: None if fail[b] else float(np.sqrt(np.mean(e[b][used[b]] ** 2))) for t, (used, e, fail) in
                per.items()}
        flights.append({"flight": flight, "looks": int(used0[b].sum()),
                        "maneuvering_pct": float(100 * batch.maneuvering[b][used0[b]].mean()), "rmse_m": rmse})
    return {"trackers": names, "flights": flights}


def per_flight_table(per_flight):
    """Markdown: position RMSE per ADS-B flight (from :func:`per_flight_rmse`; 'failed' where the tracker's
    estimate or covariance went non-finite on the flight)."""
    names = per_flight["trackers"]
    out = ["| flight | looks | maneuvering % | " + " | ".join(f"{t} m" for t in names) + " |",
           "|---" * (len(names) + 3) + "|"]
    for f in per_flight["flights"]:
        cells = ["failed" if f["rmse_m"][t] is None else f"{f['rmse_m'][t]:.0f}" for t in names]
        out.append(f"| {f['flight']} | {f['looks']} | {f['maneuvering_pct']:.0f} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


FIGURE_SUITES = ("random", "bizup2002", "kim_lee_accel", "adsb_calibration")
"""The suites whose figures the documentation shows."""


def suite_figures(runs, fig_dir, seed):
    """``docs/figures/<suite>_*.png`` of :data:`FIGURE_SUITES` with :data:`FIGURE_TRACKERS` from the evaluation's
    ``runs`` (suites drawn with base seed ``seed``). Returns the files written."""
    import matplotlib
    matplotlib.use("Agg")
    from agents.evaluation import plots
    Path(fig_dir).mkdir(parents=True, exist_ok=True)
    files = []
    for suite in FIGURE_SUITES:
        batch, suite_runs = runs[suite]
        files += plots.suite_figures(suite, batch, {k: v for k, v in suite_runs.items() if k in FIGURE_TRACKERS},
                                     fig_dir, scenario=run_scenario(suite, seed))
    return files


def scope_figure(path, seed):
    """One radar-scope frame (the env's rgb_array render) in bizup2002's first turn."""
    import gymnasium as gym
    import matplotlib.pyplot as plt

    import radar_env  # noqa: F401
    env = gym.make("RadarTrack-v0", scenario="bizup2002", render_mode="rgb_array")
    env.reset(seed=seed)
    for _ in range(19):                      # ~ 30 s into the first turn, q = 2 g
        env.step(10)
    plt.imsave(path, env.render())
    env.close()


def warning_figure(path, results, trackers):
    """Bar charts of the conflict-warning lead time and of the looks where the warning is wrong, per tracker."""
    import matplotlib.pyplot as plt
    enc = results["encounters"]["trackers"]
    names = [t for t in trackers if t in enc]
    lead = [enc[t]["warning_lead_time_s"] for t in names]
    fa = [enc[t]["false_warning_rate"] + enc[t]["missed_warning_rate"] for t in names]
    fig, ax = plt.subplots(1, 2, figsize=(11, 0.3 * len(names) + 2.2), sharey=True, layout="constrained")
    ax[0].barh(names, lead, color="tab:blue")
    ideal_s = enc[names[0]]["ideal_lead_time_s"]
    ax[0].axvline(ideal_s, color="k", ls="--", label=f"from the true states ({ideal_s:.0f} s)")
    ax[0].set_xlabel("mean warning lead time before\nclosest approach (s)")
    ax[0].set_ylabel("tracker")
    ax[0].legend(fontsize=8, loc="lower center", bbox_to_anchor=(0.5, 1.0), frameon=False)
    ax[1].barh(names, fa, color="tab:red")
    ax[1].set_xlabel("looks where the warning disagrees with\nthe one from the true states (fraction of looks)")
    ax[0].invert_yaxis()                     # shared y: once, tracker order top to bottom
    fig.suptitle("Conflict warnings on turning encounters (3 NM, 300 s look-ahead)")
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(prog="python -m agents.reports.report", description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", default="docs")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE)
    ap.add_argument("--no-readme", dest="readme", action="store_false", help="do not update the generated blocks of docs/*.md")
    args = ap.parse_args(argv)
    from agents.reports.blocks import check_report_options
    check_report_options(args)
    docs = Path(args.docs)
    t0 = time.time()
    policy = str(BUNDLED_POLICY) if BUNDLED_POLICY.is_file() else None
    learned = (["policy"] if policy else []) + [t for t in BUNDLED_POLICIES if t != "policy"
                                                  and BUNDLED_POLICIES[t].is_file()]
    trackers = learned + list(REPORT_TRACKERS)
    suites = [(n, draw_suite(n, default_runs(n), seed=args.seed))
              for n in DEFAULT_SUITES + ("encounters", "adsb_calibration")]
    results, runs = evaluate(suites, trackers, policy)
    seconds = time.time() - t0
    refs = reference_constants(results)     # the scores against these results' own references (= the code's once
    for suite, res in results.items():      # agents.evaluation.scores.REFERENCE_RMSE_M is updated from them)
        for m in res["trackers"].values():
            m.pop("score", None)
            if suite in refs and comparable_rmse(m):
                m["score"] = normalised_score(suite, float(m["pos_rmse_m"]), refs)
    fig_dir = docs / "figures"
    suite_figures(runs, fig_dir, args.seed)
    scope_figure(fig_dir / "scope_frame.png", args.seed)
    warning_figure(fig_dir / "warning_lead_time.png", results, trackers)
    adsb_batch, adsb_runs = runs["adsb_calibration"]
    results["adsb_calibration"]["per_flight"] = per_flight_rmse(
        adsb_batch, adsb_runs, list(PER_FLIGHT_TRACKERS))
    flights = per_flight_table(results["adsb_calibration"]["per_flight"])
    down = downstream_tables(results, trackers)
    text = [
        "# Evaluation results (generated by `python -m agents.reports.report`)",
        "",
        f"Seeds {args.seed}+i per suite (held out from training and tuning); every tracker saw the same plots in run i. "
        f"Position RMSE pooled over runs and looks after the track start; 95% intervals from 2000 bootstrap "
        f"resamples of runs (paired for the ratio column). Regions: maneuver = the truth turns or changes speed, "
        f"after = within 60 s after a maneuver, straight = the rest. Policy: "
        f"{'the bundled policy `agents/bundled/policy/policy.zip`' if policy else 'none bundled'}"
        + "".join(f"; {t}: `{BUNDLED_POLICIES[t].relative_to(ROOT)}` ({LEARNED_WHAT[t]})" for t in learned
                  if t != "policy") + ". "
        f"Computed in {seconds:.0f} s.",
        "",
        markdown_tables(results),
        "## Downstream: conflict warnings and intercepts",
        "",
        down,
        "## ADS-B calibration flights, per flight (position RMSE, m)",
        "",
        flights,
    ]
    (docs / "results_tables.md").write_text("\n".join(text))
    if args.readme:
        from agents.reports.blocks import replace_block
        replace_block("headline", headline(results, policy is not None))
        replace_block("headline-scores", scores_table(results, HEADLINE_TRACKERS))
        replace_block("scores", scores_table(results))
        replace_block("downstream", down)
        replace_block("adsb-flights", flights)
    (docs / "results.json").write_text(json.dumps(jsonable(results), indent=1, allow_nan=False))
    t1 = time.time()
    bsuites = [(n, draw_suite(n, BOUNDS_RUNS, seed=args.seed)) for n in BOUNDS_SUITES]
    bounds, _ = evaluate(bsuites, learned + list(BOUNDS_TRACKERS), policy)
    bounds = {n: {**r, "seconds": time.time() - t1} for n, r in bounds.items()}
    (docs / "bounds.json").write_text(json.dumps(jsonable(bounds), indent=1, allow_nan=False))
    if args.readme:
        replace_block("bounds", headline(bounds, policy is not None))
    print("\n".join(text))


if __name__ == "__main__":
    main()
