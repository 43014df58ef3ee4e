"""Scenario suites and the seed ranges that keep training, tuning and evaluation apart.

Seeds (each run of a suite draws its whole episode, truth and noise, from ``numpy.random.default_rng(seed)``):

* training (RL) uses seeds in ``[0, 1_000_000)`` (:data:`TRAIN_SEEDS`);
* tuning of the classical baselines uses ``[1_000_000, 2_000_000)`` (:data:`TUNING_SEEDS`), also training data;
* evaluation uses ``EVAL_SEED_BASE + i`` with ``EVAL_SEED_BASE = 10_000_000`` and above (held out).

Run ``i`` of suite ``s`` with base seed ``S`` uses ``default_rng([S + i, crc32(s)])``, so every suite gets its own
stream and every tracker in one evaluation sees the same episodes (common random numbers).

A user trajectory (CSV file) is keyed by its content, not its path: run ``i`` uses ``default_rng([S + i, w0, ...,
w7])`` with ``w0..w7`` the SHA-256 digest of the file's bytes read as eight little-endian 32-bit words
(:func:`suite_key`). ``a.csv``, ``./a.csv``, an absolute path or a renamed copy give the same episodes; any edit of
the file (even whitespace) gives new ones. Its suite is named after the file's stem (``flight.csv`` -> ``flight``);
two files with the same stem, or a stem that is a built-in suite's name, are refused
(:func:`trajectory_suite_names`). Its radar is Adrian's ATC radar, placed per run by
:func:`radar_env.sim.scenario.place_radar_site` at 10-150 km (``radar_range_m``), or a fixed site (``radar``).
"""

from __future__ import annotations

import hashlib
from pathlib import Path

import numpy as np

from baselines.seeds import EVAL_SEED_BASE, TRAIN_SEEDS, TUNING_SEEDS, suite_rng
from radar_env.sim.catalog import FAMILIES, SCENARIO_NAMES, make_setup
from radar_env.sim.draws import draw_episodes, random_scenarios
from radar_env.envs.env import draw_setup_and_episode, resolve_scenario
from radar_env.sim.scenario import RADAR_PLACEMENT_RANGE_M, SegmentScenario, TrajectoryScenario

from agents.evaluation.options import DEFAULT_SUITES

__all__ = ["TRAIN_SEEDS", "TUNING_SEEDS", "EVAL_SEED_BASE", "DEFAULT_SUITES", "HELDOUT_FAMILY_SUITES",
           "DEFAULT_RADAR_RANGE_M", "draw_suite", "run_scenario", "suite_rng", "suite_key", "trajectory_suite_names"]

# TRAIN_SEEDS, TUNING_SEEDS, EVAL_SEED_BASE and suite_rng live in baselines.seeds (the tuning draws from them and
# baselines never import agents); re-exported here, where the seed plan is documented. DEFAULT_SUITES lives with
# the command's options (agents.evaluation.options, read by --help without loading the simulation).
EXTRA_SUITES = ("encounters", "adsb_calibration", "adsb_dev", "adsb_heldout")
"""Also available: ``encounters`` (pairs of aircraft, conflict warnings; ``runs`` = pairs) and the real flights
(all, and the two halves of :data:`radar_env.sim.adsb_scenarios.ADSB_SPLIT`)."""

HELDOUT_FAMILY_SUITES = tuple(FAMILIES) + ("adsb_heldout",)
"""The held-out families of issue 20 (:data:`radar_env.sim.catalog.FAMILIES` and the held-out half of the real
flights): evaluated with held-out seeds only, never used for training, tuning or choosing a policy."""


DEFAULT_RADAR_RANGE_M = RADAR_PLACEMENT_RANGE_M
"""Range annulus (m) of the ATC radar placement for a trajectory suite (:func:`radar_env.sim.scenario.place_radar_site`)."""


def _is_csv(scenario):
    return isinstance(scenario, Path) or (isinstance(scenario, str) and scenario.endswith(".csv")
                                          and not scenario.startswith("adsb:"))


def suite_key(scenario):
    """The stream key of a suite: its name, or ``"sha256:<hex>"`` of a CSV file's bytes (path-independent)."""
    if _is_csv(scenario):
        path = Path(scenario)
        if not path.is_file():
            raise ValueError(f"trajectory file {str(path)!r} does not exist")
        return "sha256:" + hashlib.sha256(path.read_bytes()).hexdigest()
    return scenario if isinstance(scenario, str) else getattr(scenario, "name", "custom")


def trajectory_suite_names(paths, taken=()):
    """Suite names of trajectory CSV files: each file's stem. Raises ``ValueError`` (naming ``--trajectory``) if two
    files share a stem, or a stem is the name of a built-in suite or of one in ``taken``, so that no suite's
    results, plots or JSON entry overwrite another's."""
    builtin = set(SCENARIO_NAMES) | set(EXTRA_SUITES) | set(DEFAULT_SUITES)
    seen, names = {}, []
    for p in paths:
        name = Path(p).stem
        if name in seen:
            raise ValueError(f"--trajectory: {str(seen[name])!r} and {str(p)!r} would both be suite {name!r} (suites "
                             "are named after the file name); rename one")
        if name in builtin or name in taken or name.startswith("adsb:"):
            raise ValueError(f"--trajectory: {str(p)!r} would be suite {name!r}, the name of a built-in suite; "
                             "rename the file")
        seen[name] = p
        names.append(name)
    return names


def draw_suite(scenario, runs, seed=EVAL_SEED_BASE, radar=None, random_config=None, radar_range_m=None):
    """``runs`` episodes of ``scenario`` (a name in ``SCENARIO_NAMES``, a CSV path, a Setup or scenario object).

    Args:
        seed: base seed (an integer >= 0); run ``i`` uses ``suite_rng(suite_key(scenario), seed + i)``.
        radar: a :class:`radar_env.sim.radar.Radar` replacing the scenario's (for a trajectory: a fixed site).
        radar_range_m: ``(lo, hi)`` in m, ``0 < lo < hi``: range annulus of the ATC radar placement for a trajectory
            without ``radar`` (default :data:`DEFAULT_RADAR_RANGE_M`); trajectories only.
    """
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or int(runs) < 1:
        raise ValueError(f"runs must be an integer >= 1, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    from radar_env.sim.radar import Radar
    from radar_env.sim.scenario import RandomScenarioConfig
    if radar is not None and not isinstance(radar, Radar):
        raise ValueError(f"radar must be a radar_env.sim.radar.Radar (e.g. atc_radar(...)) or None, got "
                         f"{type(radar).__name__}")
    if random_config is not None and not isinstance(random_config, RandomScenarioConfig):
        raise ValueError(f"random_config must be a radar_env.sim.scenario.RandomScenarioConfig or None, got "
                         f"{type(random_config).__name__}")
    key = suite_key(scenario)
    if scenario == "encounters":     # pairs of aircraft for the conflict-warning test (agents.evaluation.downstream)
        from agents.evaluation.downstream import draw_encounters
        return draw_encounters(runs, lambda i: suite_rng(key, seed + i))
    resolved = resolve_scenario(scenario)
    trajectory = isinstance(resolved, (TrajectoryScenario, SegmentScenario))   # radar placed per run
    if radar_range_m is not None:
        if not trajectory:
            raise ValueError(f"radar_range_m applies to trajectory suites only, not {key!r}")
        lo, hi = _check_range_m(radar_range_m)
        radar_range_m = (lo, hi)
    rr = radar_range_m or DEFAULT_RADAR_RANGE_M
    if hasattr(resolved, "setup"):   # a pool (adsb_*): run i flies member i mod n, every member once
        return [draw_setup_and_episode(resolved.setup(i), radar, None, suite_rng(key, seed + i))
                for i in range(int(runs))]
    # all runs in one batched draw; run i's episode comes from its own generator only, as a draw alone would
    batch = draw_episodes(resolved, radar, random_config, [suite_rng(key, seed + i) for i in range(int(runs))],
                          radar_range_m=rr)
    return [batch.episode(i) for i in range(int(runs))]


def run_scenario(scenario, seed=EVAL_SEED_BASE, run=0):
    """The truth model of run ``run`` of the suite :func:`draw_suite` draws from ``scenario`` with base seed
    ``seed``: a :class:`~radar_env.sim.scenario.SegmentScenario` (named scenarios, the random flights and families,
    re-drawn from the run's generator) or a :class:`~radar_env.sim.scenario.TrajectoryScenario` (ADS-B flights, CSV
    trajectories); None for ``encounters`` (two aircraft per run). The figures draw its exact path and maneuver
    times (and check them against the episode's truth first)."""
    if scenario == "encounters":
        return None
    resolved = resolve_scenario(scenario)
    if hasattr(resolved, "setup"):                       # a pool: run i flies member i mod n
        return resolved.setup(int(run)).scenario
    if isinstance(resolved, (SegmentScenario, TrajectoryScenario)):
        return resolved
    if hasattr(resolved, "scenario"):                    # a Setup
        return resolved.scenario
    if resolved in ("random", "random_radars") or resolved in FAMILIES:
        return random_scenarios(resolved, [suite_rng(suite_key(scenario), int(seed) + int(run))])[0][0]
    return make_setup(resolved).scenario


def _check_range_m(r):
    try:
        lo, hi = (float(v) for v in r)
    except (TypeError, ValueError):
        raise ValueError(f"radar_range_m must be two numbers (lo, hi) in m, got {r!r}") from None
    if not (np.isfinite(lo) and np.isfinite(hi) and 0.0 < lo < hi):
        raise ValueError(f"radar_range_m must be finite with 0 < lo < hi (m), got {r!r}")
    return lo, hi
