"""Generated blocks in the Markdown pages (README.md and docs/*.md), between ``<!-- name:start -->`` and
``<!-- name:end -->`` markers. A block name is unique across the pages, so a generator names only the block and the
block may move between pages.

Every block has a renderer (:data:`RENDERERS`: its text from the committed JSON or from the code alone) and the
command that makes what it shows (:data:`COMMANDS`), which the paragraph above the block names;
``tests/test_readme_blocks.py`` checks both. ``python -m agents.reports.readme_blocks`` re-renders every block (the
results' blocks from ``docs/*.json``, without running anything; the counts and lists from the code), ``--check``
only lists the blocks that differ.
"""

from __future__ import annotations

import argparse
import json
import sys

from agents.reports.blocks import ROOT, block_names, read_block, replace_block


# ------------------------------------------------------------------------------------------------ renderers

def _json(name):
    return json.loads((ROOT / "docs" / name).read_text())


def _has_policy(results):
    return any("policy" in r["trackers"] for r in results.values())


def _headline(name="results.json"):
    def f():
        from agents.reports.report import headline
        res = _json(name)
        return headline(res, _has_policy(res))
    return f


def _downstream():
    from agents.policies.bundle import BUNDLED_POLICIES
    from agents.reports.report import REPORT_TRACKERS, downstream_tables
    res = _json("results.json")
    # every bundled learned tracker the results hold, in the report's order (python -m agents.reports.report)
    learned = [t for t in BUNDLED_POLICIES if any(t in r["trackers"] for r in res.values())]
    return downstream_tables(res, learned + list(REPORT_TRACKERS))


def _adsb_flights():
    from agents.reports.report import per_flight_table
    return per_flight_table(_json("results.json")["adsb_calibration"]["per_flight"])


def _scores(headline_only=False):
    def f():
        from agents.reports.report import HEADLINE_TRACKERS, scores_table
        return scores_table(_json("results.json"), HEADLINE_TRACKERS if headline_only else None)
    return f


def _generalisation(render):
    def f():
        from agents.reports import generalisation
        return getattr(generalisation, render)(_json("generalisation.json"))
    return f


def _range_rate(render):
    def f():
        from agents.reports import range_rate
        return getattr(range_rate, render)(_json("range_rate.json"))
    return f


def evaluation_defaults():
    """``radar-track evaluate``'s defaults, from the code: its trackers, suites with their runs, figures per suite."""
    from agents.evaluation.evaluate import default_runs
    from agents.evaluation.options import DEFAULT_SUITES, DEFAULT_TRACKERS
    from agents.evaluation.plots import FIGURE_KINDS
    from agents.policies.bundle import BUNDLED_POLICIES
    learned = [t for t in DEFAULT_TRACKERS if t in BUNDLED_POLICIES]
    runs = {s: default_runs(s) for s in DEFAULT_SUITES}
    return "\n".join([
        f"* **trackers** ({len(DEFAULT_TRACKERS)}; the {len(learned)} learned ones only when bundled or given): "
        + ", ".join(f"`{t}`" for t in DEFAULT_TRACKERS),
        f"* **suites** ({len(runs)}, {sum(runs.values())} runs): "
        + ", ".join(f"`{s}` ({n} runs)" for s, n in runs.items()),
        f"* **figures** (up to {len(FIGURE_KINDS)} per suite, PNG in `--out`): "
        + ", ".join(f"`<suite>_{k}.png`" for k in FIGURE_KINDS)])


def evaluation_first_line():
    """The line ``radar-track evaluate`` prints first with its defaults (this checkout's bundled trackers)."""
    from agents.evaluation.options import build_parser, first_line
    return "```\n" + first_line(build_parser().parse_args([])) + "\n```"


def evaluation_more_suites():
    """The other suites by name with their default runs, from the code."""
    from agents.evaluation.evaluate import default_runs
    from agents.evaluation.suites import EXTRA_SUITES, HELDOUT_FAMILY_SUITES
    names = list(dict.fromkeys(EXTRA_SUITES + ("adsb:<flight>",) + HELDOUT_FAMILY_SUITES))
    return (", ".join(f"`{s}` {default_runs(s)}" for s in names)
            + f", a `--trajectory` file {default_runs('', trajectory=True)}")


RENDERERS = {"bounds": _headline("bounds.json"), "headline": _headline(), "downstream": _downstream,
             "scores": _scores(), "headline-scores": _scores(headline_only=True), "adsb-flights": _adsb_flights,
             "families": _generalisation("families_table"), "seed-spread": _generalisation("spread_table"),
             "targets": _generalisation("targets_table"), "track-start": _generalisation("track_start_table"),
             "imm-targets": _generalisation("imm_targets_readme"), "evaluation-defaults": evaluation_defaults,
             "evaluation-first-line": evaluation_first_line, "evaluation-more-suites": evaluation_more_suites,
             "range-rate": _range_rate("table"), "range-rate-targets": _range_rate("targets_table")}
"""Block name -> function returning its text (from ``docs/results.json``, ``bounds.json``, ``generalisation.json``,
``range_rate.json`` or the code)."""

REPORT, GENERALISATION, BLOCKS = ("python -m agents.reports.report", "python -m agents.reports.generalisation",
                                  "python -m agents.reports.readme_blocks")
RANGE_RATE = "python -m agents.reports.range_rate"
COMMANDS = {**{n: REPORT for n in ("bounds", "headline", "downstream", "scores", "headline-scores", "adsb-flights")},
            **{n: GENERALISATION for n in ("families", "seed-spread", "targets", "track-start", "imm-targets")},
            **{n: BLOCKS for n in ("evaluation-defaults", "evaluation-first-line", "evaluation-more-suites")},
            **{n: RANGE_RATE for n in ("range-rate", "range-rate-targets")}}
"""Block name -> the command that makes what it shows (the report and the generalisation run the evaluation and
write the JSON and their blocks; this module's command renders the blocks taken from the code)."""


def main(argv=None):
    ap = argparse.ArgumentParser(prog=BLOCKS, description="Re-render every generated block of README.md and "
                                 "docs/*.md from the committed JSON and the code (runs no evaluation: the results' "
                                 f"numbers come from `{REPORT}` and `{GENERALISATION}`).")
    ap.add_argument("names", nargs="*", metavar="BLOCK", help="blocks to render (default: every block on the pages)")
    ap.add_argument("--check", action="store_true", help="write nothing; list the blocks that differ, exit 1 if any")
    args = ap.parse_args(argv)
    names = args.names or block_names()
    unknown = sorted(set(names) - set(RENDERERS))
    if unknown:
        raise SystemExit(f"error: no renderer for block(s) {unknown}; known: {', '.join(sorted(RENDERERS))}")
    differ = []
    for name in names:
        text = RENDERERS[name]().strip()
        if read_block(name) != text:
            differ.append(name)
            if not args.check:
                replace_block(name, text)
    verb = "differ" if args.check else "rewritten"
    print(f"{len(differ)} of {len(names)} block(s) {verb}" + (f": {', '.join(differ)}" if differ else ""))
    if args.check and differ:
        sys.exit(1)


if __name__ == "__main__":
    main()
