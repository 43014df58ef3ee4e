"""Scenario suites and the seed ranges that keep training, tuning and evaluation apart.

Seeds (each run of a suite draws its whole episode, truth and noise, from ``numpy.random.default_rng(seed)``):

* training (RL) uses seeds in ``[0, 1_000_000)`` (:data:`TRAIN_SEEDS`);
* tuning of the classical baselines uses ``[1_000_000, 2_000_000)`` (:data:`TUNING_SEEDS`), also training data;
* evaluation uses ``EVAL_SEED_BASE + i`` with ``EVAL_SEED_BASE = 10_000_000`` and above (held out).

Run ``i`` of suite ``s`` with base seed ``S`` uses ``default_rng([S + i, crc32(s)])``, so every suite gets its own
stream and every tracker in one evaluation sees the same episodes (common random numbers).
"""

from __future__ import annotations

import zlib

import numpy as np

from radar_env.env import draw_setup_and_episode, resolve_scenario

__all__ = ["TRAIN_SEEDS", "TUNING_SEEDS", "EVAL_SEED_BASE", "DEFAULT_SUITES", "draw_suite", "suite_rng"]

TRAIN_SEEDS = range(0, 1_000_000)
TUNING_SEEDS = range(1_000_000, 2_000_000)
EVAL_SEED_BASE = 10_000_000
DEFAULT_SUITES = ("random", "random_radars", "bizup2002", "adrian_flower", "kim_lee_accel",
                  "seed002_course_changes", "seed002_two_radars")
EXTRA_SUITES = ("encounters", "adsb_calibration")
"""Also available: ``encounters`` (pairs of aircraft, conflict warnings; ``runs`` = pairs) and the real flights."""


def suite_rng(suite_name, seed):
    return np.random.default_rng([int(seed), zlib.crc32(str(suite_name).encode())])


def draw_suite(scenario, runs, seed=EVAL_SEED_BASE, radar=None, random_config=None):
    """``runs`` episodes of ``scenario`` (a name in ``SCENARIO_NAMES``, a CSV path, a Setup or scenario object)."""
    if int(runs) < 1:
        raise ValueError(f"runs must be >= 1, got {runs!r}")
    key = scenario if isinstance(scenario, str) else getattr(scenario, "name", "custom")
    if scenario == "encounters":     # pairs of aircraft for the conflict-warning test (agents.downstream)
        from .downstream import draw_encounters
        return draw_encounters(runs, lambda i: suite_rng(key, seed + i))
    resolved = resolve_scenario(scenario)
    if hasattr(resolved, "setup"):   # a pool (adsb_calibration): run i flies member i mod n, every member once
        return [draw_setup_and_episode(resolved.setup(i), radar, None, suite_rng(key, seed + i))
                for i in range(int(runs))]
    return [draw_setup_and_episode(resolved, radar, random_config, suite_rng(key, seed + i)) for i in range(int(runs))]


