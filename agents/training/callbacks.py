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

from radar_env.envs.env import EnvConfig

from agents.evaluation.metrics import jsonable
from agents.policies.bundle import embed_env_config
from agents.policies.checks import env_kwargs_from_json
from agents.policies.loading import model_choose_q, model_run_imm
from agents.policies.numpy_policy import export_saved
from agents.training.selection import SELECTION_SEED_BASE, SelectionSuites, pooled_rmse

__all__ = ["ImmRatioEvalCallback", "SELECTION_SEED_BASE", "pooled_rmse", "model_choose_q", "EnvTimeCallback"]


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
        self.env_kwargs = dict(env_kwargs)
        self.cfg = EnvConfig.from_kwargs(**env_kwargs_from_json(self.env_kwargs))
        self.eval_freq = int(eval_freq)
        self.best_dir = None if best_dir is None else Path(best_dir)
        # the suites as the evaluation draws them (default generator settings), whatever the training used
        self.selection = SelectionSuites(scenarios, seed, select_on)
        self.primary, self.select_on = self.selection.primary, self.selection.select_on
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
        if self.cfg.tracker == "imm_cv_ct":     # the IMM's parameters as the action: the model runs the IMM
            scored, _ = self.selection.score_runs(model_run_imm(self.model, self.cfg))
        else:
            scored, _ = self.selection.score(model_choose_q(self.model, self.cfg), self.cfg)
        row = {"timesteps": int(self.num_timesteps)}
        for name in self.selection.suites:
            for key in (f"{name}_failed_runs", f"{name}_rmse_m", f"{name}_ratio_imm2"):
                row[key] = scored[key]
            tag = "" if name == self.primary else f"_{name}"
            self.logger.record(f"eval/rmse_ratio_imm2{tag}", row[f"{name}_ratio_imm2"])
            if name == self.primary:
                self.logger.record("eval/pos_rmse_m", row[f"{name}_rmse_m"])
                self.logger.record("eval/imm2_pos_rmse_m", scored[f"imm2_rmse_m_{name}"])
                if np.isfinite(scored["median_q_g"]):
                    self.logger.record("eval/median_q_g", scored["median_q_g"])
        ratio = row["selection_ratio"] = scored["selection_ratio"]
        row["eval_s"] = scored["eval_s"]
        improved = ratio < self.best_ratio
        if improved:
            self.best_ratio = ratio
            if self.best_dir is not None:
                self.best_dir.mkdir(parents=True, exist_ok=True)
                self.model.save(self.best_dir / "policy.zip")
                embed_env_config(self.best_dir / "policy.zip", self.env_kwargs)
                export_saved(self.best_dir / "policy.zip", self.model)    # arrays beside the pickle
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
