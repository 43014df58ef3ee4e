"""Downstream tests of a tracker (seed 002's applications): conflict warnings and intercepts driven by its tracks.

* **Encounters** (suite ``encounters``): pairs of aircraft from :func:`radar_env.applications.two_aircraft_encounter`
  (half in conflict: closest approach < 1 NM; half safe: 5-10 NM), where aircraft B reaches its encounter course by
  a coordinated turn (30-120 deg at 3 deg/s) that ends ``lead_after_turn_s`` (150 s) before the closest approach,
  so a tracker that lags in the turn predicts the conflict late. Both aircraft are seen by one ATC radar 30-60 km
  from the encounter. At every look after the track start the tracker's two estimates feed
  :func:`radar_env.applications.conflict_warning` (threshold 3 NM, look-ahead 300 s), and is judged against the
  same warning computed from the true states (see :func:`warning_metrics`).
* **Intercepts** (every suite): from the first look after the track start, an interceptor starting 40 km from the
  target on the radar's side, at twice the target's speed, re-aims each look at the tracker's estimate
  (:func:`radar_env.applications.simulate_intercept`) for 300 s; metrics: median miss distance and capture rate
  (capture radius 100 m).
"""

from __future__ import annotations

import math

import numpy as np

from radar_env.applications import closest_approach, conflict_warning, simulate_intercept, two_aircraft_encounter
from radar_env.sim.episode import draw_episode
from radar_env.filters.kalman import transition_ct
from radar_env.sim.radar import atc_radar
from radar_env.sim.scenario import Segment, SegmentScenario
from radar_env.common.units import DEG, NM_M

__all__ = ["draw_encounters", "true_encounter", "warning_metrics", "intercept_metrics"]

WARNING_THRESHOLD_M = 3 * NM_M
LOOKAHEAD_S = 300.0
T_CPA_S = 420.0
LEAD_AFTER_TURN_S = 150.0
CONFLICT_M = 1 * NM_M


def _encounter_scenarios(rng, conflict, i):
    enc = two_aircraft_encounter(rng, conflict, 1, t_cpa_s=T_CPA_S)
    s1, s2 = enc.state1[0], enc.state2[0]
    turn_deg = rng.uniform(30.0, 120.0) * (1 if rng.uniform() < 0.5 else -1)
    w = math.copysign(3.0 * DEG, turn_deg)
    T_turn = abs(turn_deg) / 3.0
    t1 = T_CPA_S - LEAD_AFTER_TURN_S                       # turn ends here, on the encounter course
    s2_t1 = s2.copy()
    s2_t1[:2] += s2[2:] * t1
    s2_t0 = transition_ct(np.array([-T_turn]), np.array([w]))[0] @ s2_t1   # exact reverse of the turn
    t0 = t1 - T_turn
    x0 = s2_t0.copy()
    x0[:2] -= s2_t0[2:] * t0
    dur = T_CPA_S + 60.0
    a = SegmentScenario(s1, [Segment(dur)], name=f"encounter{i}:a")
    b = SegmentScenario(x0, [Segment(t0), Segment(T_turn, w), Segment(dur - t1)], name=f"encounter{i}:b")
    return a, b


def draw_encounters(runs, rng_for):
    """``runs`` encounter pairs -> list of 2*runs episodes ``[a0, b0, a1, b1, ...]``; run i uses ``rng_for(i)``."""
    eps = []
    for i in range(int(runs)):
        rng = rng_for(i)
        conflict = i % 2 == 0
        a, b = _encounter_scenarios(rng, conflict, i)
        d_site = rng.uniform(30e3, 60e3)
        ang = rng.uniform(0, 2 * np.pi)
        radar = atc_radar(position_m=(d_site * np.sin(ang), d_site * np.cos(ang)))
        eps += [draw_episode(a, radar, rng), draw_episode(b, radar, rng)]
    return eps


def true_encounter(truth_a, truth_b, t_s):
    """``(conflict, t_cpa_s, d_cpa_m)`` of an encounter pair from its true states ``(K, 4)`` at look times
    ``t_s (K,)``: the closest approach of the straight courses flown after B's turn (first look after
    ``T_CPA_S - LEAD_AFTER_TURN_S``); conflict = closer than 1 NM."""
    k = int(np.searchsorted(t_s, T_CPA_S - LEAD_AFTER_TURN_S + 1.0))
    ca = closest_approach(truth_a[k, :2], truth_a[k, 2:], truth_b[k, :2], truth_b[k, 2:])
    d = float(ca.d_cpa_m)
    return d < CONFLICT_M, float(t_s[k] + ca.t_cpa_s), d


def _warn(x1, x2, t, t_cpa):
    w = conflict_warning(x1[:, :2], x1[:, 2:], x2[:, :2], x2[:, 2:], WARNING_THRESHOLD_M, LOOKAHEAD_S).warning
    return np.asarray(w) & (t < t_cpa)


def warning_metrics(batch, run):
    """Conflict-warning quality of a run on an ``encounters`` batch, judged against the warning computed from the
    TRUE states at the same looks (the best any tracker could do: before B's turn its course may itself be a
    conflict course, and a warning then is right):

    * ``warning_lead_time_s``: mean over conflict pairs of (true closest-approach time - first warning);
      ``ideal_lead_time_s`` the same from the true states;
    * ``missed_warnings``: fraction of conflict pairs never warned before the closest approach;
    * ``false_warning_rate`` / ``missed_warning_rate``: fraction of looks (after the track start, before the
      closest approach) where the tracker warns and the truth does not / the truth warns and the tracker does not.
    """
    leads, ideal, missed, n_conf = [], [], 0, 0
    fa = miss = n_looks = 0
    for j in range(0, batch.valid.shape[0], 2):
        n = int(min(batch.n_looks[j], batch.n_looks[j + 1]))
        if not np.array_equal(batch.t_s[j, :n], batch.t_s[j + 1, :n]):
            raise ValueError("encounter pairs must share look times")
        conflict, t_cpa, _ = true_encounter(batch.truth[j, :n], batch.truth[j + 1, :n], batch.t_s[j, :n])
        k0 = int(max(run.start_index[j], run.start_index[j + 1]))
        t = batch.t_s[j, k0:n]
        w = _warn(run.x[j, k0:n], run.x[j + 1, k0:n], t, t_cpa)
        wt = _warn(batch.truth[j, k0:n], batch.truth[j + 1, k0:n], t, t_cpa)
        before = t < t_cpa
        fa += int(np.sum(w & ~wt & before))
        miss += int(np.sum(~w & wt & before))
        n_looks += int(before.sum())
        if conflict:
            n_conf += 1
            if w.any():
                leads.append(float(t_cpa - t[np.argmax(w)]))
            else:
                missed += 1
            if wt.any():
                ideal.append(float(t_cpa - t[np.argmax(wt)]))
    return {"warning_lead_time_s": float(np.mean(leads)) if leads else np.nan,
            "ideal_lead_time_s": float(np.mean(ideal)) if ideal else np.nan,
            "missed_warnings": missed / n_conf if n_conf else np.nan,
            "false_warning_rate": fa / n_looks if n_looks else np.nan,
            "missed_warning_rate": miss / n_looks if n_looks else np.nan}


def intercept_metrics(batch, run, horizon_s=300.0, start_distance_m=40e3, speed_factor=2.0, capture_radius_m=100.0):
    """Median miss distance (m) and capture rate of an interceptor aimed with the run's estimates."""
    misses, caught, members = [], [], []
    for b in range(batch.valid.shape[0]):
        k0 = int(run.start_index[b])
        t = batch.t_s[b, k0:int(batch.n_looks[b])]
        t = t[t <= t[0] + horizon_s] if t.size else t
        if t.size < 3 or t[-1] - t[0] < 0.5 * horizon_s or np.any(np.diff(t) <= 0):
            continue
        members.append((b, k0, t.size))
    if members:
        # every run flown in one call, padded to the longest (a padded row stops at its own last look)
        rows, k0s, ns = (np.array(c) for c in zip(*members))
        K = int(ns.max())
        j = np.arange(K)
        idx = k0s[:, None] + np.minimum(j, ns[:, None] - 1)     # pad by repeating the last look ...
        times = batch.t_s[rows[:, None], idx] + np.maximum(j - (ns[:, None] - 1), 0)   # ... 1 s apart
        truth = batch.truth[rows[:, None], idx]
        est = run.x[rows[:, None], idx]
        site = batch.site_xy_m[rows, k0s]
        u = truth[:, 0, :2] - site
        u /= np.linalg.norm(u, axis=1, keepdims=True)
        start = truth[:, 0, :2] - start_distance_m * u
        speed = speed_factor * np.hypot(truth[:, 0, 2], truth[:, 0, 3])
        res = simulate_intercept(truth[..., :2], est, times, start, speed, capture_radius_m, n_looks=ns)
        misses.append(np.asarray(res.miss_distance_m))
        caught.append(np.isfinite(np.asarray(res.capture_time_s)))
    if not misses:
        return {"intercept_miss_m_median": np.nan, "intercept_capture_rate": np.nan}
    m, c = np.concatenate(misses), np.concatenate(caught)
    return {"intercept_miss_m_median": float(np.median(m)), "intercept_capture_rate": float(c.mean())}
