"""The normalised score: its definition at the references, its refusals, and the reference constants in code equal
to the committed results' (so they cannot go stale)."""

import json
import math
from pathlib import Path

import pytest

from agents.evaluation.scores import REFERENCE_RMSE_M, normalised_score, reference_constants

ROOT = Path(__file__).resolve().parents[1]


def test_zero_at_kf_tuned_hundred_at_rbpf_linear_between():
    refs = {"s": (120.0, 60.0)}
    assert normalised_score("s", 120.0, refs) == 0.0
    assert normalised_score("s", 60.0, refs) == 100.0
    assert normalised_score("s", 90.0, refs) == 50.0
    assert normalised_score("s", 30.0, refs) == 150.0
    assert normalised_score("other", 30.0, refs) is None


@pytest.mark.parametrize("bad", [math.nan, math.inf, -1.0, True, "3"])
def test_refuses_a_non_finite_or_negative_rmse(bad):
    with pytest.raises(ValueError, match="rmse_m"):
        normalised_score("random", bad, {"random": (1.0, 0.5)})


def test_the_constants_are_the_committed_results_references():
    results = json.loads((ROOT / "docs" / "results.json").read_text())
    consts = reference_constants(results)
    assert set(consts) >= {"random", "bizup2002"}          # the references ran on the main suites
    assert REFERENCE_RMSE_M == consts, "run python -m agents.evaluation.scores and update REFERENCE_RMSE_M"
    for suite, res in results.items():   # and the results' scores are these references' scores
        for t, m in res["trackers"].items():
            if suite in consts and m.get("pos_rmse_m") is not None:
                assert m["score"] == pytest.approx(normalised_score(suite, m["pos_rmse_m"]), abs=0.05), (suite, t)
