"""One tracker on one suite's episodes, as the serial and the Ray evaluations both run it.

A tracker that raises does not stop the evaluation: :func:`run_one` turns the exception into a failed
:class:`baselines.trackers.TrackRun` (:func:`failed_track_run`), scored as failed on every run.
"""

from __future__ import annotations

import sys

import numpy as np

from baselines.registry import POLICY_TRACKERS, run_tracker
from baselines.trackers import TrackRun, run_q_policy

__all__ = ["run_one", "run_policy", "failed_track_run"]


def run_one(tracker, episodes, choose_q=None, policy_cfg=None):
    """Run one tracker (a learned one, bundled or a user's folder under its label: through ``choose_q`` with its env
    config ``policy_cfg``, or, for a learned IMM, ``choose_q.run``) on a suite's episodes. A tracker that raises does not stop the evaluation: it gets a
    :class:`TrackRun` of NaN (so every run counts as failed) with the exception in ``error``, reported in its metrics
    and on stderr; the other trackers are scored as usual."""
    try:
        if tracker in POLICY_TRACKERS or choose_q is not None:     # a learned tracker under any name
            return run_policy(tracker, episodes, choose_q, policy_cfg)
        return run_tracker(tracker, episodes)
    except (ArithmeticError, ValueError, np.linalg.LinAlgError, FloatingPointError, RuntimeWarning) as e:
        return failed_track_run(tracker, episodes, f"{type(e).__name__}: {e}")


def run_policy(name, episodes, choose_q, cfg):
    """A loaded policy (:func:`agents.policies.loading.load_policy`'s ``(choose_q, cfg)``) on ``episodes`` as the
    tracker ``name``: a q-policy through :func:`baselines.trackers.run_q_policy`, a learned IMM (``is_tracker``) by its
    own ``run``."""
    if getattr(choose_q, "is_tracker", False):
        return choose_q.run(episodes, name)
    return run_q_policy(episodes, choose_q, name, cfg)


def failed_track_run(tracker, episodes, msg):
    """The :class:`TrackRun` of a tracker that raised ``msg`` on a suite: NaN on every run and look (so every run
    counts as failed), ``error=msg``; the warning goes to stderr. Shared by the serial and the Ray evaluations
    (:mod:`agents.evaluation.parallel`: a failure in any chunk fails the whole suite, as serially)."""
    print(f"warning: tracker {tracker!r} failed on this suite ({msg}); every run counted as failed", file=sys.stderr)
    B, K = len(episodes), max(len(ep.t_s) for ep in episodes)
    return TrackRun(tracker, np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan), np.zeros(B, np.int64),
                    np.full((B, K), np.nan), error=msg)
