"""The README headline's derived numbers (agents.reports.report)."""

import math

from agents.reports.report import headline, headroom_share


def _res(**rmse):
    return {"runs": 30, "trackers": {t: {"pos_rmse_m": v, "track_loss_rate": 0.0} for t, v in rmse.items()}}


def test_headroom_share_is_the_captured_fraction():
    assert math.isclose(headroom_share(_res(policy=90.0, imm2=100.0, hindsight_q=60.0)), 0.25)
    assert math.isclose(headroom_share(_res(policy=110.0, imm2=100.0, hindsight_q=60.0)), -0.25)
    assert headroom_share(_res(policy=90.0, imm2=100.0)) is None                  # no ceiling on this suite
    assert headroom_share(_res(policy=90.0, imm2=100.0, hindsight_q=100.0)) is None   # no headroom
    assert headroom_share(_res(policy=float("nan"), imm2=100.0, hindsight_q=60.0)) is None
    failed = _res(policy=90.0, imm2=100.0, hindsight_q=60.0)
    failed["trackers"]["policy"]["failed_runs"] = 3             # its RMSE pools other runs than imm2's
    assert headroom_share(failed) is None


def test_a_bound_is_compared_only_with_trackers_that_failed_no_run():
    from agents.evaluation.evaluate import bounds_beaten
    trackers = {"clairvoyant": {"pos_rmse_m": 50.0, "failed_runs": 0},
                "cherry": {"pos_rmse_m": 40.0, "failed_runs": 23},     # scored on the two runs it did not fail
                "imm2": {"pos_rmse_m": 80.0, "failed_runs": 0}}
    assert bounds_beaten(trackers) == {}
    trackers["cherry"]["failed_runs"] = 0
    assert bounds_beaten(trackers)["clairvoyant"]["beaten_by"] == "cherry"


def test_no_normalised_score_for_a_tracker_that_failed_runs(monkeypatch):
    """The score's references pool every run: a tracker scored on fewer runs gets none (it is reported failed)."""
    import numpy as np
    from agents.evaluation.evaluate import evaluate
    from agents.evaluation.suites import draw_suite
    from baselines import registry
    eps = draw_suite("random", 4, seed=10_000_000)

    def odd_fail(episodes, cfg):
        run = registry._RUNNERS["imm2"](episodes, cfg)
        run.x[1::2] = np.nan
        return run
    monkeypatch.setitem(registry._RUNNERS, "odd_fail", odd_fail)
    res, _ = evaluate([("random", eps)], ["imm2", "odd_fail"], progress=False)
    t = res["random"]["trackers"]
    assert t["odd_fail"]["failed_runs"] == 2 and "score" not in t["odd_fail"] and "score" in t["imm2"]


def test_headline_lists_only_present_trackers_and_the_share():
    text = headline({"random": _res(policy=90.0, imm2=100.0, hindsight_q=60.0)}, has_policy=True)
    head = text.splitlines()[0]
    assert "imm_cv_ct" not in head and "hindsight_q" in head and "headroom" in head
    assert text.splitlines()[2].rstrip().endswith("| 25% |")


def test_the_scores_table_leaves_out_a_tracker_that_failed_runs():
    """(a tracker that failed every run stopped the report: normalised_score of a NaN)"""
    from agents.reports.report import scores_table
    res = {"random": {"trackers": {"kf_tuned": {"pos_rmse_m": 100.0}, "rbpf": {"pos_rmse_m": 60.0},
                                   "x": {"pos_rmse_m": float("nan"), "failed_runs": 4},
                                   "y": {"pos_rmse_m": 50.0, "failed_runs": 3}}}}
    row = scores_table(res).splitlines()[2]
    assert row == "| random | 0 | 100 | - | - |"


def test_per_flight_rmse_refuses_a_flight_without_scored_looks():
    """A flight whose looks all precede the track start would get a NaN RMSE: refused, naming it."""
    import pytest
    from agents.evaluation.suites import draw_suite
    from agents.reports.report import per_flight_rmse, per_flight_table
    from baselines.registry import run_tracker
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("random", 2, seed=10_000_000)
    batch, run = stack_episodes(eps), run_tracker("imm2", eps)
    table = per_flight_table(per_flight_rmse(batch, {"imm2": run}, ["imm2"]))
    assert table.count("\n") == 4 and "nan" not in table
    run.start_index[1] = batch.n_looks[1]           # nothing of flight 1 is scored
    with pytest.raises(ValueError, match=f"flight {batch.names[1]!r} has no scored look after imm2's"):
        per_flight_rmse(batch, {"imm2": run}, ["imm2"])
