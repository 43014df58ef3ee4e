"""The printed evaluation table: compact within TABLE_WIDTH characters for the default trackers, every column
with --wide (issue 36). Measured on the committed main-job numbers (docs/results.json, the default suites and
trackers), so the test sees the real tracker names and magnitudes."""

import copy
import json
from pathlib import Path

import pytest

from agents.evaluation.evaluate import TABLE_WIDTH, compact_legend, format_table, main as evaluate_main
from agents.evaluation.metrics import FEW_RUNS
from agents.evaluation.options import DEFAULT_SUITES, DEFAULT_TRACKERS

ROOT = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def default_results():
    d = json.loads((ROOT / "docs" / "results.json").read_text())
    out = {}
    for s in DEFAULT_SUITES:
        r = copy.deepcopy(d[s])
        r["trackers"] = {t: m for t, m in r["trackers"].items() if t in DEFAULT_TRACKERS}
        out[s] = r
    assert {t for r in out.values() for t in r["trackers"]} == set(DEFAULT_TRACKERS)
    return out


def _width(text):
    return max(len(line) for line in text.splitlines())


def test_default_table_fits_and_wide_has_every_column(default_results):
    compact = format_table(default_results)
    assert _width(compact) <= TABLE_WIDTH == 120
    for t in DEFAULT_TRACKERS:            # every tracker of every suite has its row
        assert sum(line.startswith(t + " ") for line in compact.splitlines()) == len(DEFAULT_SUITES)
    assert default_results["adrian_flower"]["runs"] < FEW_RUNS       # the default's one few-runs suite
    assert all(line in compact for line in compact_legend(few_runs=True))
    wide = format_table(default_results, wide=True)
    assert _width(wide) > TABLE_WIDTH     # why the compact one is the default
    for col in ("vel m/s", "peak m", "in95", "common RMSE m [95% CI]", "/imm2 common [95% CI]"):
        assert col in wide and col not in compact
    # the compact cells are the wide table's: the random suite's policy_bp row
    row = next(line for line in compact.splitlines() if line.startswith("policy_bp "))
    m = default_results["random"]["trackers"]["policy_bp"]
    assert f"{m['pos_rmse_m']:.1f} [{m['pos_rmse_m_ci95'][0]:.1f},{m['pos_rmse_m_ci95'][1]:.1f}]" in row
    assert f"{m['pos_rmse_m_maneuver']:.1f}" in row and f"{m['anees']:.2f}" in row


def test_compact_table_fits_with_few_runs_marked(default_results):
    """Every interval then carries (n<20), and the header its warning: still within the width."""
    few = copy.deepcopy(default_results)
    for r in few.values():
        r["runs"] = 5
        for m in r["trackers"].values():
            m["runs_scored"] = 5
        r["ratio_vs_imm2_runs"] = {t: 5 for t in r["ratio_vs_imm2_runs"]}
    text = format_table(few)
    assert f"(n<{FEW_RUNS})" in text and _width(text) <= TABLE_WIDTH
    assert all(line in text for line in compact_legend(few_runs=True))
    assert f"(n<{FEW_RUNS})" not in "".join(compact_legend())


def test_command_prints_compact_by_default_and_wide_on_request(capsys):
    args = ["--scenario", "bizup2002", "--runs", "2", "--trackers", "imm2,kf_tuned", "--no-plots", "--quiet"]
    evaluate_main(args)
    out = capsys.readouterr().out
    assert compact_legend()[0] in out and "common RMSE" not in out
    evaluate_main(args + ["--wide"])
    out = capsys.readouterr().out
    assert "common RMSE m [95% CI]" in out and compact_legend()[0] not in out
