"""Generate the results the README shows: ``python -m agents.report``.

Runs the evaluation (:func:`agents.evaluate.evaluate`) on the default suites with every comparison tracker (and
the bundled policy if present), then writes ``docs/results.md`` (tables), ``docs/results.json`` (every metric) and
``docs/figures/*.png``. Nothing in those files is typed by hand.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from .evaluate import BUNDLED_POLICY, DEFAULT_RUNS, _jsonable, evaluate
from .suites import DEFAULT_SUITES, EVAL_SEED_BASE, draw_suite

__all__ = ["main", "markdown_tables"]

REPORT_TRACKERS = ("imm2", "imm2_bizup", "imm3_ct", "kf_tuned", "kf_low", "kf_high", "kf_blair", "cmin", "ckf",
                   "reinit", "kim_lee", "alpha_beta", "alpha_beta_adaptive", "adrian1", "adrian2", "konle",
                   "oracle_q", "clairvoyant")
FIGURE_TRACKERS = ("policy", "imm2", "imm2_bizup", "kf_tuned", "cmin", "clairvoyant")


def _fmt(v, nd=1):
    return "-" if v is None or not np.isfinite(v) else f"{v:.{nd}f}"


def markdown_tables(results, reference="imm2"):
    out = []
    for suite, res in results.items():
        out += [f"### {suite} ({res['runs']} runs, {res['looks_per_run_mean']:.0f} looks per run)", "",
                "| tracker | pos RMSE m [95% CI] | maneuver | after | straight | vel RMSE m/s | peak m | ANEES | "
                f"NEES in 95% | lost | RMSE / {reference} [95% CI] | delay (looks) | false alarms / look |",
                "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
        ratios = res.get(f"ratio_vs_{reference}", {})
        for t, m in res["trackers"].items():
            r = ratios.get(t)
            rt = f"{r[0]:.3f} [{r[1][0]:.3f}, {r[1][1]:.3f}]" if r else "-"
            out.append(
                f"| {t} | {m['pos_rmse_m']:.1f} [{m['pos_rmse_m_ci95'][0]:.1f}, {m['pos_rmse_m_ci95'][1]:.1f}] | "
                f"{_fmt(m['pos_rmse_m_maneuver'])} | {_fmt(m['pos_rmse_m_after'])} | {_fmt(m['pos_rmse_m_straight'])} | "
                f"{m['vel_rmse_m_s']:.2f} | {m['peak_pos_err_m']:.0f} | {m['anees']:.2f} | {m['nees_in_95']:.2f} | "
                f"{m['track_loss_rate']:.2f} | {rt} | {_fmt(m.get('detection_delay_looks'), 2)} | "
                f"{_fmt(m.get('false_alarm_rate'), 3)} |")
        out.append("")
    return "\n".join(out)


HEADLINE_TRACKERS = ("policy", "imm2", "imm2_bizup", "kf_tuned", "cmin", "oracle_q", "clairvoyant")


def headline(results, has_policy):
    """Compact table for the README: position RMSE (m) and ratio to imm2 with 95% CIs, per suite."""
    names = [t for t in HEADLINE_TRACKERS if t != "policy" or has_policy]
    lines = ["| suite | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    for suite, res in results.items():
        cells = []
        for t in names:
            m = res["trackers"].get(t)
            r = res.get("ratio_vs_imm2", {}).get(t)
            if m is None:
                cells.append("-")
            elif t == "imm2" or r is None:
                cells.append(f"{m['pos_rmse_m']:.0f}")
            else:
                cells.append(f"{m['pos_rmse_m']:.0f} ({r[0]:.2f} [{r[1][0]:.2f}, {r[1][1]:.2f}])")
        lines.append(f"| {suite} ({res['runs']} runs) | " + " | ".join(cells) + " |")
    return "\n".join(lines)


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
                out.append(f"| {t} | {_fmt(m['warning_lead_time_s'])} ({_fmt(m['ideal_lead_time_s'])}) | "
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
            cells.append(f"{_fmt(m.get('intercept_miss_m_median'))} ({_fmt(m.get('intercept_capture_rate'), 2)})")
        out.append(f"| {t} | " + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


def per_flight_table(batch, suite_runs, trackers, reference="imm2"):
    """Markdown: position RMSE per ADS-B flight, ratio to the reference, and where each loses most."""
    from .metrics import errors, region_masks
    names = [t for t in trackers if t in suite_runs]
    out = ["| flight | looks | maneuvering % | " + " | ".join(f"{t} m" for t in names) + " |",
           "|---" * (len(names) + 3) + "|"]
    for b, flight in enumerate(batch.names):
        cells = []
        for t in names:
            run = suite_runs[t]
            used = region_masks(batch, run.start_index)["used"][b]
            e, _ = errors(batch, run)
            cells.append(f"{np.sqrt(np.mean(e[b][used] ** 2)):.0f}")
        used0 = region_masks(batch, suite_runs[names[0]].start_index)["used"][b]
        out.append(f"| {flight} | {int(used0.sum())} | {100 * batch.maneuvering[b][used0].mean():.0f} | "
                   + " | ".join(cells) + " |")
    return "\n".join(out) + "\n"


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
    ap = argparse.ArgumentParser(prog="python -m agents.report", description=__doc__.split("\n\n")[0])
    ap.add_argument("--docs", default="docs")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE)
    ap.add_argument("--no-readme", dest="readme", action="store_false", help="do not update README.md")
    args = ap.parse_args(argv)
    docs = Path(args.docs)
    t0 = time.time()
    policy = str(BUNDLED_POLICY) if BUNDLED_POLICY.is_file() else None
    trackers = (["policy"] if policy else []) + list(REPORT_TRACKERS)
    suites = [(n, draw_suite(n, DEFAULT_RUNS.get(n, 50), seed=args.seed))
              for n in DEFAULT_SUITES + ("encounters", "adsb_calibration")]
    results, runs = evaluate(suites, trackers, policy)
    seconds = time.time() - t0
    import matplotlib
    matplotlib.use("Agg")
    from . import plots
    fig_dir = docs / "figures"
    fig_dir.mkdir(parents=True, exist_ok=True)
    for suite in ("random", "bizup2002", "kim_lee_accel", "adsb_calibration"):
        batch, suite_runs = runs[suite]
        plots.suite_figures(suite, batch, {k: v for k, v in suite_runs.items() if k in FIGURE_TRACKERS}, fig_dir)
    scope_figure(fig_dir / "scope_frame.png", args.seed)
    warning_figure(fig_dir / "warning_lead_time.png", results, trackers)
    adsb_batch, adsb_runs = runs["adsb_calibration"]
    flights = per_flight_table(adsb_batch, adsb_runs, [t for t in FIGURE_TRACKERS if t != "cmin"] + ["kf_low"])
    down = downstream_tables(results, trackers)
    text = [
        "# Evaluation results (generated by `python -m agents.report`)",
        "",
        f"Seeds {args.seed}+i per suite (held out from training and tuning); every tracker saw the same plots in run i. "
        f"Position RMSE pooled over runs and looks after the track start; 95% intervals from 2000 bootstrap "
        f"resamples of runs (paired for the ratio column). Regions: maneuver = the truth turns or changes speed, "
        f"after = within 60 s after a maneuver, straight = the rest. Policy: "
        f"{'the bundled policy `agents/bundled/policy.zip`' if policy else 'none bundled'}. "
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
    (docs / "results.md").write_text("\n".join(text))
    if args.readme:
        from .readme_blocks import replace_block
        replace_block("headline", headline(results, policy is not None))
        replace_block("downstream", down)
        replace_block("adsb-flights", flights)
    (docs / "results.json").write_text(json.dumps(_jsonable(results), indent=1))
    print("\n".join(text))


if __name__ == "__main__":
    main()
