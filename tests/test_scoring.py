"""Scoring: a NaN or Inf estimate is a failed run, never a zero error; losses, common runs, few-run flags, no NaN
in tables or JSON; the training callback never prefers a policy whose estimate went NaN (issue 15, scoring)."""

import copy
import json

import numpy as np
import pytest

import agents.evaluation.evaluate as ev
import agents.evaluation.runner as runner
from agents.training.callbacks import pooled_rmse
from agents.evaluation.evaluate import evaluate, format_table
from agents.evaluation.metrics import (FEW_RUNS, NEES_95_4DOF, evaluate_run, failed_runs, jsonable, lost_runs, ratio_ci,
                                      region_masks)
from agents.reports.report import headline, markdown_tables
from agents.evaluation.suites import draw_suite
from baselines.registry import run_tracker
from radar_env.sim.episode import stack_episodes

TRACKERS = ("imm2", "kf_tuned", "cmin")


@pytest.fixture(scope="module")
def suite():
    eps = draw_suite("bizup2002", 3)
    batch = stack_episodes(eps)
    return eps, batch, {t: run_tracker(t, eps) for t in TRACKERS}


def _corrupt(run, row, fn):
    """A deep copy of ``run`` with ``fn(copy, row, k)`` applied at the used looks k >= the middle of run ``row``."""
    bad = copy.deepcopy(run)
    k0 = int(run.start_index[row])
    k = np.arange(k0 + 10, bad.x.shape[1])
    fn(bad, row, k)
    return bad


def _subset(batch, run, rows):
    """The batch and the run restricted to ``rows`` (same padding: bizup2002 runs all have the same length)."""
    sub = type(batch)(**{f: (getattr(batch, f)[rows] if isinstance(getattr(batch, f), np.ndarray)
                             else tuple(np.asarray(getattr(batch, f))[rows]))
                         for f in batch.__dataclass_fields__})
    r = copy.deepcopy(run)
    r.x, r.P, r.start_index, r.q_m_s2 = run.x[rows], run.P[rows], run.start_index[rows], run.q_m_s2[rows]
    r.declared = None if run.declared is None else run.declared[rows]
    return sub, r


def _rmse_over(batch, run, rows):
    used = region_masks(batch, run.start_index)["used"]
    d = run.x - batch.truth
    e2 = d[..., 0] ** 2 + d[..., 1] ** 2
    return float(np.sqrt(e2[rows][used[rows]].mean()))


def _with(monkeypatch, corrupted):
    """Make :func:`agents.evaluation.evaluate.evaluate` run the given (corrupted) TrackRuns instead of the real trackers."""
    real = runner.run_tracker
    monkeypatch.setattr(runner, "run_tracker", lambda name, eps: corrupted.get(name) or real(name, eps))


def test_nan_estimate_is_a_failed_run_excluded_not_zero_error(suite, monkeypatch):
    eps, batch, runs = suite
    bad = _corrupt(runs["kf_tuned"], 1, lambda r, b, k: r.x.__setitem__((b, k), np.nan))
    m = evaluate_run(batch, bad, n_boot=200)
    assert m["failed_runs"] == 1 and m["runs_scored"] == 2 and m["failed_rate"] == pytest.approx(1 / 3)
    assert m["lost_runs"] >= 1 and m["track_loss_rate"] >= 1 / 3       # a NaN estimate is a lost track
    # the pooled metrics are those of the two other runs alone (not the NaN looks counted as zero error)
    sub_b, sub_r = _subset(batch, bad, [0, 2])
    ref = evaluate_run(sub_b, sub_r, n_boot=200)
    for key in ("pos_rmse_m", "pos_rmse_m_maneuver", "vel_rmse_m_s", "peak_pos_err_m", "anees", "npe"):
        assert m[key] == ref[key], key
    assert m["pos_rmse_m"] == pytest.approx(_rmse_over(batch, bad, [0, 2]))
    # in the suite, the other trackers are scored as if nothing happened
    _with(monkeypatch, {"kf_tuned": bad})
    results, _ = evaluate([("bizup2002", eps)], list(TRACKERS), progress=False)
    res = results["bizup2002"]
    assert res["trackers"]["kf_tuned"]["failed_runs"] == 1
    for t in ("imm2", "cmin"):
        clean = evaluate_run(batch, runs[t])
        got = res["trackers"][t]
        assert got["failed_runs"] == 0
        for key in ("pos_rmse_m", "pos_rmse_m_ci95", "anees", "track_loss_rate"):
            assert got[key] == clean[key], (t, key)
    assert res["ratio_vs_imm2_runs"]["kf_tuned"] == 2 and res["ratio_vs_imm2_runs"]["cmin"] == 3


def test_nan_before_the_track_start_does_not_fail_the_run(suite):
    _, batch, runs = suite
    run = copy.deepcopy(runs["imm2"])
    run.x[0, int(run.start_index[0]) - 1] = np.nan         # a look the metrics do not use
    assert not failed_runs(batch, run).any()


def test_singular_or_inf_covariance_does_not_abort_evaluate_run(suite):
    _, batch, runs = suite
    run = runs["imm2"]
    k = int(run.start_index[0]) + 5
    bad = copy.deepcopy(run)
    bad.P[0, k] = 0.0                                       # finite but singular: no NEES at this look
    bad.P[2, k + 1] = np.inf                                # non-finite: run 2 failed
    m = evaluate_run(batch, bad, n_boot=100)
    assert m["failed_runs"] == 1 and m["nees_invalid_looks"] == 1
    assert np.isfinite(m["anees"]) and np.isfinite(m["pos_rmse_m"])
    # the singular look counts as outside the 95 % bound, over the looks of the two scored runs
    used = region_masks(batch, run.start_index)["used"]
    inside = [_nees(batch, run, b, j) <= NEES_95_4DOF for b in (0, 1) for j in np.flatnonzero(used[b])
              if (b, j) != (0, k)]
    assert m["nees_in_95"] == pytest.approx(sum(inside) / used[[0, 1]].sum())


def _nees(batch, run, b, k):
    d = run.x[b, k] - batch.truth[b, k]
    return float(d @ np.linalg.solve(run.P[b, k], d))


def test_divergence_counts_as_loss_and_the_common_runs_exclude_it_for_all(suite, monkeypatch):
    eps, batch, runs = suite
    div = _corrupt(runs["kf_tuned"], 0, lambda r, b, k: r.x.__setitem__((b, k, 0), r.x[b, k, 0] + 1e7))
    assert lost_runs(batch, div).tolist() == [True, False, False]
    assert not any(lost_runs(batch, runs[t]).any() for t in TRACKERS)      # the clean trackers hold every run
    _with(monkeypatch, {"kf_tuned": div})
    results, _ = evaluate([("bizup2002", eps)], list(TRACKERS), progress=False)
    res = results["bizup2002"]
    assert res["common_runs"] == 2 and res["common_trackers"] == list(TRACKERS)
    kf = res["trackers"]["kf_tuned"]
    assert kf["failed_runs"] == 0 and kf["lost_runs"] == 1 and kf["track_loss_rate"] == pytest.approx(1 / 3)
    assert kf["pos_rmse_m"] > 1e6                          # the pooled all-runs RMSE keeps the divergence ...
    for t, r in (("imm2", runs["imm2"]), ("kf_tuned", div), ("cmin", runs["cmin"])):
        m = res["trackers"][t]                             # ... the common-run RMSE leaves run 0 out for everyone
        assert m["common_runs"] == 2
        assert m["pos_rmse_m_common"] == pytest.approx(_rmse_over(batch, r, [1, 2]))
    ratio_c = res["ratio_vs_imm2_common"]["kf_tuned"][0]
    assert ratio_c == pytest.approx(_rmse_over(batch, div, [1, 2]) / _rmse_over(batch, runs["imm2"], [1, 2]))
    assert ratio_c == pytest.approx(ratio_ci(batch, runs["kf_tuned"], runs["imm2"], runs=[False, True, True])[0])
    assert res["ratio_vs_imm2"]["kf_tuned"][0] > 100        # all-runs ratio: the divergence, labelled as such


def test_fewer_than_20_runs_are_flagged_beside_every_interval(suite, monkeypatch):
    eps, _, _ = suite
    results, _ = evaluate([("bizup2002", eps)], ["imm2", "kf_tuned"], progress=False)
    res = results["bizup2002"]
    assert res["few_runs"] and res["few_common_runs"]
    assert all(m["few_runs"] and m["few_common_runs"] for m in res["trackers"].values())
    d = json.loads(json.dumps(jsonable(results), allow_nan=False))
    assert d["bizup2002"]["trackers"]["imm2"]["few_runs"] is True
    # two intervals per row in the compact table, four with --wide and in the Markdown tables
    for text, n_min in ((format_table(results), 4), (format_table(results, wide=True), 8),
                        (markdown_tables(results), 8)):
        rows = [line for line in text.splitlines() if line.startswith(("imm2", "kf_tuned", "| imm2", "| kf_tuned"))]
        n_ci = sum(line.count("[") for line in rows)
        assert n_ci >= n_min and sum(line.count(f"(n<{FEW_RUNS})") for line in rows) == n_ci
    assert headline(results, False).count(f"(n<{FEW_RUNS})") == 1             # kf_tuned's ratio to imm2
    many = draw_suite("bizup2002", FEW_RUNS)
    results, _ = evaluate([("bizup2002", many)], ["imm2", "kf_tuned"], progress=False)
    assert not results["bizup2002"]["few_runs"] and not results["bizup2002"]["trackers"]["imm2"]["few_runs"]
    for text in (format_table(results), format_table(results, wide=True), markdown_tables(results).split("\n", 1)[1],
                 headline(results, False)):
        assert f"(n<{FEW_RUNS})" not in text


def test_no_nan_or_inf_in_json_or_tables_when_a_tracker_fails_everywhere(suite, monkeypatch):
    eps, batch, runs = suite
    dead = copy.deepcopy(runs["cmin"])
    dead.x[:] = np.nan
    dead.P[:] = np.nan
    _with(monkeypatch, {"cmin": dead})
    results, _ = evaluate([("bizup2002", eps)], list(TRACKERS), progress=False)
    res = results["bizup2002"]
    m = res["trackers"]["cmin"]
    # a tracker that failed every run is left out of the common set (named), not allowed to empty it
    assert m["failed_runs"] == 3 and m["track_loss_rate"] == 1.0 and res["common_runs"] == 3
    assert res["common_excluded_failed_everywhere"] == ["cmin"]
    assert "all 3 runs failed" in m["undefined"]["pos_rmse_m"]
    assert np.isfinite(res["trackers"]["imm2"]["pos_rmse_m_common"])
    # asked for explicitly, the common set over every tracker is empty, and says why
    strict = evaluate([("bizup2002", eps)], list(TRACKERS), progress=False, common_over=list(TRACKERS))[0]
    assert strict["bizup2002"]["common_runs"] == 0
    assert "no common run" in strict["bizup2002"]["trackers"]["imm2"]["undefined"]["pos_rmse_m_common"]
    json.dumps(jsonable(strict), allow_nan=False)
    text = json.dumps(jsonable({"meta": {}, "suites": results}), allow_nan=False)      # raises on NaN / Inf
    d = json.loads(text)["suites"]["bizup2002"]
    assert d["trackers"]["cmin"]["pos_rmse_m"] is None and d["trackers"]["cmin"]["pos_rmse_m_ci95"] == [None, None]
    assert set(d["trackers"]["cmin"]["undefined"]) >= {k for k, v in d["trackers"]["cmin"].items() if v is None}
    assert d["ratio_vs_imm2"]["cmin"][0] is None and d["ratio_vs_imm2_runs"]["cmin"] == 0
    for table in (format_table(results), markdown_tables(results), headline(results, False)):
        low = table.lower()
        assert "nan" not in low and "inf" not in low
    assert "cmin" in format_table(json.loads(text)["suites"])     # the table also reads the JSON back (nulls)


def test_callback_score_is_inf_for_a_nan_estimate(suite):
    _, batch, runs = suite
    run = runs["kf_tuned"]
    assert np.isfinite(pooled_rmse(batch, run))
    bad = _corrupt(run, 2, lambda r, b, k: r.x.__setitem__((b, k[:1]), np.nan))
    assert pooled_rmse(batch, bad) == np.inf
    bad = _corrupt(run, 0, lambda r, b, k: r.P.__setitem__((b, k[:1]), np.inf))
    assert pooled_rmse(batch, bad) == np.inf


def test_downstream_metrics_leave_the_failed_runs_out(suite, monkeypatch):
    from agents.evaluation.downstream import intercept_metrics
    eps, batch, runs = suite
    bad = _corrupt(runs["cmin"], 1, lambda r, b, k: r.x.__setitem__((b, k), np.nan))
    _with(monkeypatch, {"cmin": bad})
    results, _ = evaluate([("bizup2002", eps)], ["imm2", "cmin"], progress=False)
    m = results["bizup2002"]["trackers"]["cmin"]
    assert m["downstream_runs"] == 2 and results["bizup2002"]["trackers"]["imm2"]["downstream_runs"] == 3
    want = intercept_metrics(*_subset(batch, bad, [0, 2]))
    assert np.isfinite(want["intercept_miss_m_median"])
    assert m["intercept_miss_m_median"] == want["intercept_miss_m_median"]
    assert m["intercept_capture_rate"] == want["intercept_capture_rate"]


def test_a_tracker_that_raises_is_reported_failed_and_the_others_still_scored(monkeypatch):
    """One tracker's singular matrix (here: a LinAlgError raised by its runner) must not abort the evaluation."""
    import json

    from agents.evaluation.suites import draw_suite
    from baselines import registry

    def boom(episodes, cfg):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setitem(registry._RUNNERS, "kf_low", boom)
    suites = [("bizup2002", draw_suite("bizup2002", 3, seed=5000))]
    results, _ = ev.evaluate(suites, ["imm2", "kf_low", "kf_tuned"], progress=False)
    res = results["bizup2002"]
    bad = res["trackers"]["kf_low"]
    assert bad["failed_runs"] == 3 and bad["error"].startswith("LinAlgError")
    assert res["trackers"]["imm2"]["failed_runs"] == 0 and np.isfinite(res["trackers"]["imm2"]["pos_rmse_m"])
    assert np.isfinite(res["trackers"]["kf_tuned"]["pos_rmse_m"])
    json.dumps(jsonable(results), allow_nan=False)
    assert "kf_low" in ev.format_table(results)


def test_tracker_failing_everywhere_does_not_empty_the_common_set_and_is_noted(monkeypatch):
    from agents.evaluation.suites import draw_suite
    from baselines import registry

    def boom(episodes, cfg):
        raise np.linalg.LinAlgError("Singular matrix")

    monkeypatch.setitem(registry._RUNNERS, "kf_low", boom)
    suites = [("bizup2002", draw_suite("bizup2002", 3, seed=5000))]
    res = ev.evaluate(suites, ["imm2", "kf_low", "konle"], progress=False)[0]["bizup2002"]
    assert res["common_excluded_failed_everywhere"] == ["kf_low"] and res["common_runs"] == 3
    assert np.isfinite(res["trackers"]["imm2"]["pos_rmse_m_common"])
    table = ev.format_table({"bizup2002": res})
    assert "kf_low: failed on every run: LinAlgError" in table and "konle: design envelope:" in table


def test_downstream_cells_say_when_they_come_from_fewer_runs():
    from agents.reports.report import downstream_tables
    res = {"bizup2002": {"runs": 8, "trackers": {"a": {"intercept_miss_m_median": 5.0, "intercept_capture_rate": 1.0,
                                                       "downstream_runs": 6},
                                                 "b": {"intercept_miss_m_median": 4.0, "intercept_capture_rate": 1.0,
                                                       "downstream_runs": 8}}}}
    text = downstream_tables(res, ["a", "b"])
    assert "(n=6 of 8)" in text and text.count("(n=") == 1


# ------------------------------------------------------------------------------------ the vectorised metrics
def _detection_stats_loop(batch, declared, masks, after_window_s=60.0):
    """The per-run, per-maneuver loop detection_stats replaced (frozen here as the reference)."""
    used = masks["used"]
    man = batch.maneuvering & used
    delays, missed = [], 0
    B, K = man.shape
    for b in range(B):
        m = man[b]
        for k0 in np.flatnonzero(m & ~np.r_[False, m[:-1]]):
            end = k0 + np.argmax(~m[k0:]) if np.any(~m[k0:]) else K
            t_end = batch.t_s[b, end - 1] + after_window_s
            win = np.flatnonzero((np.arange(K) >= k0) & (batch.t_s[b] <= t_end) & batch.valid[b])
            hits = win[declared[b, win]]
            if hits.size:
                delays.append(int(hits[0] - k0))
            else:
                missed += 1
    n_man = len(delays) + missed
    return (float(np.mean(delays)) if delays else np.nan, float(missed / n_man) if n_man else np.nan)


@pytest.mark.parametrize("suite_name", ["random", "random_radars", "seed002_two_radars"])
def test_detection_stats_equal_the_per_maneuver_loop(suite_name):
    from agents.evaluation.metrics import detection_stats
    eps = draw_suite(suite_name, 12, seed=777)
    batch = stack_episodes(eps)
    rng = np.random.default_rng(3)
    for t in ("imm2", "cmin"):
        run = run_tracker(t, eps)
        masks = region_masks(batch, run.start_index)
        for declared in (run.declared, rng.uniform(size=run.declared.shape) < 0.02, np.zeros_like(run.declared)):
            got = detection_stats(batch, declared, masks)
            ref = _detection_stats_loop(batch, declared, masks)
            np.testing.assert_equal((got["detection_delay_looks"], got["missed_maneuvers"]), ref)


def test_positive_definite_is_eigvalsh_exactly_on_hard_cases():
    from agents.evaluation.metrics import positive_definite
    rng = np.random.default_rng(0)
    A = rng.standard_normal((4000, 4, 4))
    P = A @ A.transpose(0, 2, 1)
    lam, V = np.linalg.eigh(P)
    cases = [P]
    for lo in (0.0, 1e-18, -1e-18, 1e-14, -1e-14, 1e-12, 1e-9, 1e-6, -1e-3):   # smallest eigenvalue near 0
        lam2 = lam.copy()
        lam2[:, 0] = lo * lam[:, -1]
        cases.append(np.einsum("nij,nj,nkj->nik", V, lam2, V))
    S = np.diag([1e6, 1e6, 1.0, 1.0]) * (1.0 + 1e-3 * rng.standard_normal((500, 1, 1)))   # scales far apart
    cases += [S, np.tile(np.eye(4), (3, 1, 1)) * [[[1.0]], [[0.0]], [[-1.0]]], np.zeros((0, 4, 4))]
    U = P.copy()
    U[:, 0, 3] += 1e9            # the upper triangle is not read (as eigvalsh)
    cases.append(U)
    for c in cases:
        np.testing.assert_array_equal(positive_definite(c), np.linalg.eigvalsh(c)[:, 0] > 0 if len(c) else
                                      np.zeros(0, bool))


def test_score_run_is_what_the_separate_functions_give(suite):
    from agents.evaluation.metrics import errors, score_run
    eps, batch, runs = suite
    for run in runs.values():
        sc = score_run(batch, run)
        ep, ev_ = errors(batch, run)
        np.testing.assert_array_equal(sc.pos_err_m, ep)
        np.testing.assert_array_equal(sc.vel_err_m_s, ev_)
        np.testing.assert_array_equal(sc.failed, failed_runs(batch, run))
        np.testing.assert_array_equal(sc.lost, lost_runs(batch, run))
        assert evaluate_run(batch, run, score=sc) == evaluate_run(batch, run)
