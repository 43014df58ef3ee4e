"""Episodes per second of the batched drawer (radar_env.sim.draws) and of the per-episode drawer it replaced.

Run by hand: ``python benchmarks/bench_draws.py [--rows 1024] [--repeats 3]``. For each scenario (``random``,
``random_radars``, ``bizup2002``) it draws ``rows`` episodes (one generator per row, as the vector env's rows)
with

(a) the per-episode drawer of the previous version: ``make_setup`` + ``draw_episode``, redrawn until long enough
    for the track start (what ``draw_setup_and_episode`` did per row),
(b) ``draw_episodes`` for all rows in one call (what the vector env and the evaluation suites do now),
(c) ``draw_episodes`` one row per call (the single env's reset),

and prints the best of ``repeats`` runs as episodes/s (compilation excluded: one warm-up call first).
"""

from __future__ import annotations

import argparse
import time

import numpy as np

from radar_env.sim.catalog import make_setup
from radar_env.sim.draws import MAX_EPISODE_DRAWS, draw_episodes
from radar_env.sim.episode import draw_episode
from radar_env.filters.tracking import looks_for_track_start


def per_episode(name, rng, warmup_scans=12):
    for _ in range(MAX_EPISODE_DRAWS):
        s = make_setup(name, rng)
        e = draw_episode(s.scenario, s.radar, rng)
        need = looks_for_track_start(e.detected, e.t_s, warmup_scans)
        if need is not None and e.n_looks >= need:
            return e
    raise RuntimeError("no draw long enough")


def _best(fn, repeats):
    best = np.inf
    for r in range(repeats):
        t0 = time.perf_counter()
        fn(r)
        best = min(best, time.perf_counter() - t0)
    return best


def main():
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rows", type=int, default=1024)
    ap.add_argument("--repeats", type=int, default=3)
    args = ap.parse_args()
    n = args.rows
    rngs = lambda r: [np.random.default_rng(r * n + i) for i in range(n)]  # noqa: E731
    print(f"{'scenario':<14} {'(a) per-episode':>16} {'(b) batched':>12} {'(c) one per call':>17}  episodes/s")
    for name in ("random", "random_radars", "bizup2002"):
        draw_episodes(name, None, None, rngs(99))          # compile / load the cache
        a = _best(lambda r: [per_episode(name, g) for g in rngs(r)[: max(n // 8, 1)]], args.repeats) * 8
        b = _best(lambda r: draw_episodes(name, None, None, rngs(r)), args.repeats)
        c = _best(lambda r: [draw_episodes(name, None, None, [g]) for g in rngs(r)], args.repeats)
        print(f"{name:<14} {n / a:16,.0f} {n / b:12,.0f} {n / c:17,.0f}")


if __name__ == "__main__":
    main()
