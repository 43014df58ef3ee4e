"""The seed plan that keeps training, tuning and evaluation apart, and the per-suite random streams.

Defined here, in the lowest layer that needs it (the baselines' tuning draws its episodes from
:data:`TUNING_SEEDS`), and re-exported by :mod:`agents.evaluation.suites`, which documents the plan:

* training (RL): ``[0, 1_000_000)`` (:data:`TRAIN_SEEDS`);
* tuning of the classical baselines: ``[1_000_000, 2_000_000)`` (:data:`TUNING_SEEDS`);
* evaluation: ``EVAL_SEED_BASE + i``, ``EVAL_SEED_BASE = 10_000_000`` and above (held out).

Run ``i`` of suite ``s`` with base seed ``S`` draws from ``default_rng([S + i, crc32(s)])`` (:func:`suite_rng`).
"""

from __future__ import annotations

import zlib

__all__ = ["TRAIN_SEEDS", "TUNING_SEEDS", "EVAL_SEED_BASE", "suite_rng", "draw_random_episodes"]

TRAIN_SEEDS = range(0, 1_000_000)
TUNING_SEEDS = range(1_000_000, 2_000_000)
EVAL_SEED_BASE = 10_000_000


def suite_rng(suite_name, seed):
    """The generator of run ``seed`` of the suite keyed ``suite_name`` (a name or ``"sha256:<hex>"``, see
    :func:`agents.evaluation.suites.suite_key`)."""
    import numpy as np   # here, not at import: the seed ranges above are read by the commands' --help
    key = str(suite_name)
    if key.startswith("sha256:"):
        digest = bytes.fromhex(key[len("sha256:"):])
        words = [int.from_bytes(digest[i:i + 4], "little") for i in range(0, len(digest), 4)]
    else:
        words = [zlib.crc32(key.encode())]
    return np.random.default_rng([int(seed), *words])


def draw_random_episodes(runs, seed=TUNING_SEEDS.start):
    """``runs`` episodes of the ``random`` scenario, run ``i`` from ``suite_rng("random", seed + i)``: the same
    episodes, bit for bit, as ``agents.evaluation.suites.draw_suite("random", runs, seed=seed)`` (a test checks it).

    Args:
        runs: number of episodes, an integer >= 1.
        seed: base seed, an integer >= 0 (default: the start of :data:`TUNING_SEEDS`).
    """
    import numpy as np

    from radar_env.envs.config import resolve_scenario
    from radar_env.envs.core import draw_setup_and_episode
    if isinstance(runs, bool) or not isinstance(runs, (int, np.integer)) or int(runs) < 1:
        raise ValueError(f"runs must be an integer >= 1, got {runs!r}")
    if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or int(seed) < 0:
        raise ValueError(f"seed must be an integer >= 0, got {seed!r}")
    sc = resolve_scenario("random")
    return [draw_setup_and_episode(sc, None, None, suite_rng("random", int(seed) + i)) for i in range(int(runs))]
