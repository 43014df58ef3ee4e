"""Training callbacks: score the policy against the tuned 2-mode IMM during training and keep the best model.

:class:`ImmRatioEvalCallback` runs the current policy (deterministic) through the same tracking chain the
evaluation uses (:func:`baselines.trackers.run_q_policy`) on a fixed selection suite of random scenarios drawn
from the TRAINING seed range (``SELECTION_SEED_BASE + i``, default 900_000 + i: inside ``[0, 1_000_000)``,
disjoint from the rollout streams, which come from ``seeding.np_random(seed + row)`` generators, and never the
held-out evaluation seeds ``>= 10_000_000``). It logs ``eval/rmse_ratio_imm2`` (pooled position RMSE of the policy
/ imm2 on identical plots) to TensorBoard and saves the best model with its ``env_config.json`` beside it, so
``radar-track evaluate --policy <run>/best/policy.zip`` loads it.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np
from stable_baselines3.common.callbacks import BaseCallback

from baselines.registry import run_tracker
from baselines.trackers import run_q_policy
from radar_env.env import EnvConfig
from radar_env.episode import stack_episodes
from radar_env.units import G0_M_S2

from agents.evaluation.metrics import jsonable
from agents.policies.bundle import embed_env_config
from agents.policies.loading import model_choose_q
from agents.evaluation.metrics import errors, failed_runs, region_masks
from agents.evaluation.suites import EVAL_SEED_BASE, TRAIN_SEEDS, draw_suite

__all__ = ["ImmRatioEvalCallback", "SELECTION_SEED_BASE", "pooled_rmse", "model_choose_q", "EnvTimeCallback"]

SELECTION_SEED_BASE = 900_000


def pooled_rmse(batch, run):
    """Pooled position RMSE (m) over runs and looks after the track start (as :func:`agents.evaluation.metrics.evaluate_run`);
    ``inf`` if the run's estimate or covariance is non-finite at any of those looks (:func:`agents.evaluation.metrics.failed_runs`),
    so a policy whose estimate went NaN never scores better than one that tracked."""
    used = region_masks(batch, run.start_index)["used"]
    if failed_runs(batch, run, used).any():
        return np.inf
    ep, _ = errors(batch, run)
    return float(np.sqrt(np.mean(ep[used] ** 2)))


class ImmRatioEvalCallback(BaseCallback):
    """Every ``eval_freq`` env steps (summed over the vector env's rows), score the policy / imm2 RMSE ratio.

    Args:
        env_kwargs: the env's keyword arguments (JSON-able; ``env_config.json`` of the saved model).
        eval_freq: env steps between evaluations.
        scenarios: ``{suite name: runs}``; all are scored and logged.
        seed: base seed of the selection suites (training range, disjoint from the rollouts).
        best_dir: where the best model goes (``policy.zip`` + ``env_config.json``); None: do not save.
        select_on: suite names whose ratios' geometric mean selects the best model (default: ``"random"`` if
            scored, else the first suite).
        on_row: called with each evaluation's row (as kept in ``history``) right after it is made (e.g. a sweep
            reporting ``selection_ratio`` to Ray Tune, :mod:`agents.training.sweep`).
    """

    def __init__(self, env_kwargs, eval_freq=50_000, scenarios=None, seed=SELECTION_SEED_BASE, best_dir=None,
                 verbose=1, select_on=None, on_row=None):
        super().__init__(verbose)
        self.on_row = on_row
        scenarios = dict(scenarios or {"random": 100})
        last = int(seed) + max(scenarios.values())
        if int(seed) < TRAIN_SEEDS.start or last > TRAIN_SEEDS.stop or last > EVAL_SEED_BASE:
            raise ValueError(f"selection seeds must lie in the training range {TRAIN_SEEDS}, got {seed}..{last}")
        self.env_kwargs = dict(env_kwargs)
        self.cfg = EnvConfig.from_kwargs(**{k: tuple(v) if isinstance(v, list) else v
                                            for k, v in self.env_kwargs.items()})
        self.eval_freq = int(eval_freq)
        self.best_dir = None if best_dir is None else Path(best_dir)
        self.primary = "random" if "random" in scenarios else next(iter(scenarios))
        self.select_on = tuple(select_on) if select_on else (self.primary,)
        bad = [n for n in self.select_on if n not in scenarios]
        if bad:
            raise ValueError(f"select_on names {bad}, which are not among the scored suites {list(scenarios)}")
        self.suites = {}
        for name, runs in scenarios.items():
            # the suites as the evaluation draws them (default generator settings), whatever the training used
            eps = draw_suite(name, runs, seed=int(seed))
            batch = stack_episodes(eps)
            self.suites[name] = (eps, batch, pooled_rmse(batch, run_tracker("imm2", eps)))
        self.best_ratio = np.inf
        self.history = []
        self._next = self.eval_freq

    def _on_step(self):
        if self.num_timesteps >= self._next:
            self._next += self.eval_freq
            self.evaluate_now()
        return True

    def _on_training_end(self):
        if not self.history or self.history[-1]["timesteps"] != self.num_timesteps:
            self.evaluate_now()
        # SB3 writes the logger only at its own log points, none after the last rollout: write the final scores
        # now, so TensorBoard gets them (also for a run shorter than eval_freq, whose only evaluation is this one)
        if self.logger.name_to_value:
            self.logger.dump(self.num_timesteps)

    def evaluate_now(self):
        t0 = time.time()
        choose_q = model_choose_q(self.model, self.cfg)
        row = {"timesteps": int(self.num_timesteps)}
        for name, (eps, batch, imm_rmse) in self.suites.items():
            run = run_q_policy(eps, choose_q, "policy", self.cfg)
            rmse = pooled_rmse(batch, run)
            # inf if the policy (or imm2) failed on a run: never the best (rmse / inf would read as 0)
            ratio = rmse / imm_rmse if np.isfinite(rmse) and np.isfinite(imm_rmse) else np.inf
            row[f"{name}_failed_runs"] = int(failed_runs(batch, run).sum())
            row[f"{name}_rmse_m"], row[f"{name}_ratio_imm2"] = rmse, ratio
            tag = "" if name == self.primary else f"_{name}"
            self.logger.record(f"eval/rmse_ratio_imm2{tag}", ratio)
            if name == self.primary:
                self.logger.record("eval/pos_rmse_m", rmse)
                self.logger.record("eval/imm2_pos_rmse_m", imm_rmse)
                q = run.q_m_s2[np.isfinite(run.q_m_s2)] / G0_M_S2
                if q.size:
                    self.logger.record("eval/median_q_g", float(np.median(q)))
        ratio = float(np.exp(np.mean([np.log(row[f"{n}_ratio_imm2"]) for n in self.select_on])))
        row["selection_ratio"] = ratio
        row["eval_s"] = time.time() - t0
        improved = ratio < self.best_ratio
        if improved:
            self.best_ratio = ratio
            if self.best_dir is not None:
                self.best_dir.mkdir(parents=True, exist_ok=True)
                self.model.save(self.best_dir / "policy.zip")
                embed_env_config(self.best_dir / "policy.zip", self.env_kwargs)
                (self.best_dir / "env_config.json").write_text(json.dumps(self.env_kwargs, indent=1))
                (self.best_dir / "selection.json").write_text(json.dumps(jsonable(row), indent=1))
        row["best"] = bool(improved)
        self.history.append(row)
        if self.on_row is not None:
            self.on_row(dict(row))
        self.logger.record("eval/best_rmse_ratio_imm2", self.best_ratio)
        if self.verbose:
            others = " ".join(f"{k}={v:.3f}" for k, v in row.items() if k.endswith("_ratio_imm2"))
            print(f"[eval @ {self.num_timesteps}] policy/imm2 {others} ({row['eval_s']:.1f} s)"
                  f"{' *best*' if improved else ''}", flush=True)
        return row


class EnvTimeCallback(BaseCallback):
    """Logs the share of wall time spent inside the env (``adapter.env_time_s``) to TensorBoard."""

    def __init__(self, adapter, log_every=10_000):
        super().__init__(0)
        self.adapter, self.log_every = adapter, int(log_every)
        self.t0 = None
        self._next = self.log_every

    def _on_training_start(self):
        self.t0 = time.perf_counter()
        self.env_t0 = self.adapter.env_time_s

    def share(self):
        wall = time.perf_counter() - self.t0
        return (self.adapter.env_time_s - self.env_t0) / wall if wall > 0 else float("nan"), wall

    def _on_step(self):
        if self.num_timesteps >= self._next:
            self._next += self.log_every
            s, wall = self.share()
            self.logger.record("time/env_share", s)
            self.logger.record("time/env_steps_per_s", self.num_timesteps / max(wall, 1e-9))
        return True
