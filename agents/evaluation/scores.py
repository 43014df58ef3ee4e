"""The normalised score of a tracker on a suite, as RL benchmarks publish one (D4RL's ``100 (score - random) /
(expert - random)``): **0 = ``kf_tuned``** (the tuned constant-q Kalman filter), **100 = ``rbpf``** (the particle filter
over the random flights' regimes, the causal reference on its own prior), from the pooled position RMSE:

    score = 100 (RMSE_kf_tuned - RMSE) / (RMSE_kf_tuned - RMSE_rbpf)

Above 100 beats the particle filter; below 0 is worse than the constant-q filter. The reference RMSEs are constants
here (:data:`REFERENCE_RMSE_M`): the main job's on its default suites, runs and held-out seeds, as
``docs/results.json`` has them (a test checks they agree; ``python -m agents.evaluation.scores`` prints them from that
file after a regeneration). A suite without references has no score: a trajectory file (its own ``kf_tuned`` and
``rbpf`` rows are the references there), and a suite where ``rbpf`` is not clearly better than ``kf_tuned``
(:data:`MIN_REFERENCE_GAP`: the real ADS-B flights, where the particle filter's prior does not hold).
"""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

__all__ = ["REFERENCE_RMSE_M", "REFERENCE_TRACKERS", "normalised_score", "reference_constants"]

REFERENCE_TRACKERS = ("kf_tuned", "rbpf")
"""(score 0, score 100)."""

MIN_REFERENCE_GAP = 0.05
"""A suite is scored only where ``rbpf`` beats ``kf_tuned`` by at least this fraction of ``kf_tuned``'s RMSE: where the
particle filter's prior is so far off that it is no better than a constant-q filter (the real flights), the scale
from one to the other is undefined, and a score would only magnify noise."""

REFERENCE_RMSE_M = {
    'random': (115.817, 66.79),
    'random_radars': (171.952, 84.099),
    'bizup2002': (291.9, 136.661),
    'adrian_flower': (76.337, 39.123),
    'kim_lee_accel': (344.127, 158.155),
    'seed002_course_changes': (84.799, 54.5),
    'seed002_two_radars': (64.512, 34.299),
    'encounters': (91.323, 48.686),
}
"""Per suite: ``(RMSE of kf_tuned, RMSE of rbpf)`` in m, the main job's (default runs, seed 10,000,000)."""


def normalised_score(suite, rmse_m, references=None):
    """The score of a pooled position RMSE ``rmse_m`` (m) on ``suite``: 0 at ``kf_tuned``'s, 100 at ``rbpf``'s.

    Args:
        suite: a suite name of :data:`REFERENCE_RMSE_M` (or of ``references``).
        rmse_m: a finite RMSE >= 0.
        references: ``{suite: (kf_tuned m, rbpf m)}`` replacing the constants (e.g. computed on other episodes).
    Returns the score, or None for a suite without references. ``ValueError`` for a non-finite or negative RMSE."""
    refs = REFERENCE_RMSE_M if references is None else references
    if isinstance(rmse_m, bool) or not isinstance(rmse_m, (int, float)) or not math.isfinite(rmse_m) or rmse_m < 0:
        raise ValueError(f"normalised_score: rmse_m must be a finite number >= 0, got {rmse_m!r}")
    if suite not in refs:
        return None
    lo, hi = refs[suite]
    return 100.0 * (lo - float(rmse_m)) / (lo - hi)


def reference_constants(results):
    """``{suite: (kf_tuned m, rbpf m)}`` from an evaluation's results (``docs/results.json``'s ``suites``): the
    suites where both references ran and ``rbpf`` beat ``kf_tuned`` by :data:`MIN_REFERENCE_GAP` or more."""
    out = {}
    for suite, res in results.items():
        t = res.get("trackers", {})
        vals = [t.get(n, {}).get("pos_rmse_m") for n in REFERENCE_TRACKERS]
        if all(isinstance(v, (int, float)) and math.isfinite(v) for v in vals) and \
                vals[0] - vals[1] >= MIN_REFERENCE_GAP * vals[0]:
            out[suite] = tuple(round(v, 3) for v in vals)
    return out


def main(argv=None):
    """Print :data:`REFERENCE_RMSE_M` as computed from a results JSON (default ``docs/results.json``)."""
    path = Path((argv or sys.argv[1:] or ["docs/results.json"])[0])
    data = json.loads(path.read_text())
    consts = reference_constants(data.get("suites", data))
    print("REFERENCE_RMSE_M = {")
    for s, (a, b) in consts.items():
        print(f"    {s!r}: ({a}, {b}),")
    print("}")


if __name__ == "__main__":
    main()
