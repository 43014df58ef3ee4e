"""The generated blocks of README.md and docs/*.md equal what their generators render from the committed JSON alone, so the text
and the numbers cannot drift apart.

Generators called, by name: ``agents.reports.report.headline(results, has_policy)`` and
``agents.reports.report.downstream_tables(results, trackers)`` on ``docs/results.json`` and ``headline`` on
``docs/bounds.json`` for ``bounds`` (the hindsight bounds, on the first runs of three suites), and
``agents.reports.report.downstream_tables(results, trackers)`` on ``docs/results.json`` (trackers as ``agents.reports.report.main``
passes them: ``policy`` if evaluated, then ``REPORT_TRACKERS``), and ``agents.reports.paper_checks.readme_block(data)`` on
``docs/paper_checks.json``, and ``agents.reports.report.per_flight_table(results["adsb_calibration"]["per_flight"])``
for ``adsb-flights``, ``agents.reports.report.scores_table(results[, HEADLINE_TRACKERS])`` for ``scores`` and
``headline-scores``, and ``agents.reports.generalisation``'s ``families_table``, ``spread_table``, ``targets_table`` and
``track_start_table`` on ``docs/generalisation.json`` for ``families``, ``seed-spread``, ``targets`` and
``track-start``.
"""

import json
from pathlib import Path

import pytest

from agents.reports import report
from agents.reports.readme_blocks import block_file, block_names, read_block, replace_block

ROOT = Path(__file__).resolve().parents[1]
README = ROOT / "README.md"


def _results():
    return json.loads((ROOT / "docs" / "results.json").read_text())


def _has_policy(results):
    return any("policy" in r["trackers"] for r in results.values())


def _headline():
    res = _results()
    return report.headline(res, _has_policy(res))


def _downstream():
    res = _results()
    learned = [t for t in ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo")
               if any(t in r["trackers"] for r in res.values())]
    return report.downstream_tables(res, learned + list(report.REPORT_TRACKERS))


def _adsb_flights():
    return report.per_flight_table(_results()["adsb_calibration"]["per_flight"])


def _scores(names=None):
    return lambda: report.scores_table(_results(), names)


def _bounds():
    res = json.loads((ROOT / "docs" / "bounds.json").read_text())
    return report.headline(res, _has_policy(res))


def _generalisation(render):
    def f():
        from agents.reports import generalisation
        return getattr(generalisation, render)(json.loads((ROOT / "docs" / "generalisation.json").read_text()))
    return f


RENDERERS = {"bounds": _bounds, "headline": _headline, "downstream": _downstream, "scores": _scores(),
             "headline-scores": _scores(report.HEADLINE_TRACKERS),
             "adsb-flights": _adsb_flights, "families": _generalisation("families_table"),
             "seed-spread": _generalisation("spread_table"), "targets": _generalisation("targets_table"),
             "track-start": _generalisation("track_start_table"), "imm-targets": _generalisation("imm_targets_readme")}


def test_every_generated_block_has_a_generator():
    names = block_names()      # README.md and every docs/*.md
    assert len(names) == len(set(names)), f"duplicate blocks: {names}"
    assert set(names) == set(RENDERERS)


@pytest.mark.parametrize("name", sorted(RENDERERS))
def test_generated_block_equals_generator_output(name):
    assert read_block(name) == RENDERERS[name]().strip(), (
        f"block {name!r} ({block_file(name).name}) differs from its generator's output on the committed JSON; regenerate it")


def test_read_and_replace_block_round_trip(tmp_path):
    p = tmp_path / "R.md"
    p.write_text("a\n<!-- x:start -->\nold\n<!-- x:end -->\nb\n")
    replace_block("x", "  new text\n", p)
    assert read_block("x", p) == "new text"
    assert p.read_text() == "a\n<!-- x:start -->\nnew text\n<!-- x:end -->\nb\n"
    assert block_names(p) == ["x"]
    with pytest.raises(ValueError, match="y:start"):
        read_block("y", p)
    with pytest.raises(ValueError, match="y:start"):
        replace_block("y", "t", p)
