"""Selection during training: score a policy against the tuned 2-mode IMM on fixed suites of TRAINING-range seeds.

One scorer for both trainers: the SB3 callback (:class:`agents.training.callbacks.ImmRatioEvalCallback`) and the
backprop trainer (:mod:`agents.training.backprop`) keep the checkpoint whose :meth:`SelectionSuites.score` is
lowest. The suites are drawn as the evaluation draws them (:func:`agents.evaluation.suites.draw_suite`, default
generator settings) from seeds ``SELECTION_SEED_BASE + i`` (default 900_000 + i: inside the training range
``[0, 1_000_000)``, disjoint from the training streams and never the held-out evaluation seeds ``>= 10_000_000``).
The policy runs through the evaluation's chain (:func:`baselines.trackers.run_q_policy`), deterministic.

Besides the evaluation's suites, two validation suites exist for selection only (:data:`START_UNKNOWN_SUITES`):
``random_any_start`` and ``random_radars_any_start``, the random generators with ``first_leg_min_s = 0`` (the first
leg drawn as every other leg, so a maneuver can begin during the track start), from seeds ``seed + 20_000 + i``.
The evaluation's random flights all start on a straight leg of at least 90 s, which a deployed tracker cannot
know; these suites score a tracker where that does not hold, from training-range seeds.
"""

from __future__ import annotations

import time

import numpy as np

from baselines.registry import run_tracker
from baselines.trackers import run_q_policy
from radar_env.sim.episode import stack_episodes
from radar_env.common.units import G0_M_S2

from agents.evaluation.metrics import errors, failed_runs, region_masks
from agents.evaluation.suites import EVAL_SEED_BASE, TRAIN_SEEDS, draw_suite

__all__ = ["SELECTION_SEED_BASE", "START_UNKNOWN_SUITES", "SelectionSuites", "draw_selection_suite", "pooled_rmse"]

SELECTION_SEED_BASE = 900_000
START_UNKNOWN_SUITES = {"random_any_start": "random", "random_radars_any_start": "random_radars"}
"""Selection-only suites: name -> the random generator drawn with ``first_leg_min_s = 0`` (module docstring)."""
START_UNKNOWN_SEED_OFFSET = 20_000


def draw_selection_suite(name, runs, seed):
    """``runs`` episodes of selection suite ``name`` from base seed ``seed``: an evaluation suite as
    :func:`agents.evaluation.suites.draw_suite` draws it, or a :data:`START_UNKNOWN_SUITES` one (its generator with
    ``first_leg_min_s = 0``, seeds ``seed + 20_000 + i``)."""
    if name in START_UNKNOWN_SUITES:
        from radar_env.sim.scenario import RandomScenarioConfig
        return draw_suite(START_UNKNOWN_SUITES[name], runs, seed=int(seed) + START_UNKNOWN_SEED_OFFSET,
                          random_config=RandomScenarioConfig(first_leg_min_s=0.0))
    return draw_suite(name, runs, seed=seed)


def pooled_rmse(batch, run):
    """Pooled position RMSE (m) over runs and looks after the track start (as
    :func:`agents.evaluation.metrics.evaluate_run`); ``inf`` if the run's estimate or covariance is non-finite at any
    of those looks (:func:`agents.evaluation.metrics.failed_runs`), so a policy whose estimate went NaN never scores
    better than one that tracked."""
    used = region_masks(batch, run.start_index)["used"]
    if failed_runs(batch, run, used).any():
        return np.inf
    ep, _ = errors(batch, run)
    return float(np.sqrt(np.mean(ep[used] ** 2)))


class SelectionSuites:
    """The selection suites and their imm2 references, drawn once.

    Args:
        scenarios: ``{suite name: runs}``; all are scored.
        seed: base seed (training range, see the module docstring).
        select_on: suite names whose ratios' geometric mean is the selection score (default ``"random"`` if scored,
            else the first suite).
    Raises ``ValueError`` for seeds outside the training range or ``select_on`` naming an unscored suite.
    """

    def __init__(self, scenarios=None, seed=SELECTION_SEED_BASE, select_on=None):
        scenarios = dict(scenarios or {"random": 100})
        last = int(seed) + max(r + START_UNKNOWN_SEED_OFFSET * (n in START_UNKNOWN_SUITES)
                               for n, r in scenarios.items())
        if int(seed) < TRAIN_SEEDS.start or last > TRAIN_SEEDS.stop or last > EVAL_SEED_BASE:
            raise ValueError(f"selection seeds must lie in the training range {TRAIN_SEEDS}, got {seed}..{last}")
        self.primary = "random" if "random" in scenarios else next(iter(scenarios))
        self.select_on = tuple(select_on) if select_on else (self.primary,)
        bad = [n for n in self.select_on if n not in scenarios]
        if bad:
            raise ValueError(f"select_on names {bad}, which are not among the scored suites {list(scenarios)}")
        self.suites = {}
        for name, runs in scenarios.items():
            eps = draw_selection_suite(name, runs, int(seed))
            batch = stack_episodes(eps)
            self.suites[name] = (eps, batch, pooled_rmse(batch, run_tracker("imm2", eps)))

    def score(self, choose_q, cfg):
        """Run ``choose_q`` (a q-policy for :func:`baselines.trackers.run_q_policy`, stateful or not) with the env
        config ``cfg`` on every suite: :meth:`score_runs` of it."""
        return self.score_runs(lambda eps: run_q_policy(eps, choose_q, "policy", cfg))

    def score_runs(self, run):
        """Score a tracker, ``run(episodes) -> TrackRun``, on every suite. Returns ``(row, primary_run)``: ``row``
        has per suite ``<name>_rmse_m``, ``<name>_ratio_imm2`` (inf if either failed a run), ``<name>_failed_runs``
        and ``imm2_rmse_m_<name>``, ``median_q_g`` (primary suite; NaN for a tracker without q), ``selection_ratio``
        (geometric mean over ``select_on``) and ``eval_s``."""
        t0 = time.time()
        row, primary = {}, None
        for name, (eps, batch, imm_rmse) in self.suites.items():
            tr = run(eps)
            rmse = pooled_rmse(batch, tr)
            # inf if the policy (or imm2) failed on a run: never the best (rmse / inf would read as 0)
            ratio = rmse / imm_rmse if np.isfinite(rmse) and np.isfinite(imm_rmse) else np.inf
            row[f"{name}_failed_runs"] = int(failed_runs(batch, tr).sum())
            row[f"{name}_rmse_m"], row[f"{name}_ratio_imm2"] = rmse, ratio
            row[f"imm2_rmse_m_{name}"] = imm_rmse
            if name == self.primary:
                primary = tr
                q = tr.q_m_s2[np.isfinite(tr.q_m_s2)] / G0_M_S2
                row["median_q_g"] = float(np.median(q)) if q.size else np.nan
        row["selection_ratio"] = float(np.exp(np.mean([np.log(row[f"{n}_ratio_imm2"]) for n in self.select_on])))
        row["eval_s"] = time.time() - t0
        return row, primary
