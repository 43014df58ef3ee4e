"""Downstream applications in the evaluation: encounter construction, warnings judged against the truth,
intercepts driven by track estimates."""

import numpy as np

from agents.evaluation.downstream import LEAD_AFTER_TURN_S, T_CPA_S, intercept_metrics, true_encounter, warning_metrics
from agents.evaluation.suites import draw_suite
from baselines.registry import run_tracker
from baselines.trackers import TrackRun
from radar_env.sim.episode import stack_episodes
from radar_env.common.units import NM_M


def test_encounters_have_prescribed_closest_approach_after_the_turn():
    eps = draw_suite("encounters", 6, seed=3)
    for j in range(0, len(eps), 2):
        a, b = eps[j], eps[j + 1]
        conflict, t_cpa, d = true_encounter(a.truth, b.truth, a.t_s)
        assert np.array_equal(a.t_s, b.t_s)
        assert abs(t_cpa - T_CPA_S) < 1e-6                              # the prescribed closest-approach time
        assert conflict == (j // 2 % 2 == 0)                             # pairs alternate conflict / safe
        assert d < 1 * NM_M if conflict else 5 * NM_M <= d <= 10 * NM_M
        # the true tracks do come that close, at that time (sampled truth, 1 s before and after)
        k = np.searchsorted(a.t_s, T_CPA_S - LEAD_AFTER_TURN_S + 1.0)   # first look after B's turn
        sep = [np.hypot(*((a.truth[k, :2] - b.truth[k, :2]) + (a.truth[k, 2:] - b.truth[k, 2:]) * (t_cpa + dt - a.t_s[k])))
               for dt in (-1.0, 0.0, 1.0)]
        assert abs(sep[1] - d) < 1e-6 * max(d, 1.0) and min(sep[0], sep[2]) > d
        assert np.any(np.abs(b.truth_turn_rate_rad_s) > 0)              # B does turn onto its course


def _perfect(batch):
    return TrackRun("truth", batch.truth.copy(), np.tile(np.eye(4), batch.truth.shape[:2] + (1, 1)),
                    np.full(batch.valid.shape[0], 14), np.full(batch.valid.shape, np.nan))


def test_warning_metrics_perfect_track_is_ideal_and_trackers_are_judged_against_it():
    eps = draw_suite("encounters", 10, seed=4)
    batch = stack_episodes(eps)
    m = warning_metrics(batch, _perfect(batch))
    assert m["false_warning_rate"] == 0 and m["missed_warning_rate"] == 0 and m["missed_warnings"] == 0
    assert m["warning_lead_time_s"] == m["ideal_lead_time_s"] > 0
    low = warning_metrics(batch, run_tracker("kf_low", eps))
    clair = warning_metrics(batch, run_tracker("clairvoyant", eps))
    assert clair["missed_warning_rate"] + clair["false_warning_rate"] <= low["missed_warning_rate"] + \
        low["false_warning_rate"]


def test_intercept_metrics_perfect_track_captures_and_noisy_track_misses_more():
    eps = draw_suite("bizup2002", 6, seed=5)
    batch = stack_episodes(eps)
    perfect = intercept_metrics(batch, _perfect(batch))
    assert perfect["intercept_capture_rate"] == 1.0 and perfect["intercept_miss_m_median"] < 1e-6
    low = intercept_metrics(batch, run_tracker("kf_low", eps))
    assert low["intercept_miss_m_median"] > perfect["intercept_miss_m_median"]
