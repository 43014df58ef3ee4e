"""The main job's figures drawn by one process and by forked processes (issue 35 item 4), on the main job's own runs.

Run from the repository root: ``python benchmarks/bench_figures.py [--rounds 3] [--processes 2]``. It runs
``radar-track evaluate`` with its defaults once (without writing figures: its runs are kept), then draws the 35
figures with ``write_plots(..., processes=1)`` and ``processes=N`` in turn, each round into a fresh temporary folder,
and prints the seconds of each and their ratio with the 1-minute load average (docs/speed.md, "The figures in
parallel"). The figures are the same files either way (tests/test_cli_feedback.py).
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time

from agents.evaluation import evaluate as E


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=3, help="rounds of (one process, N processes), >= 1")
    ap.add_argument("--processes", type=int, default=2, help="N, the forked processes to compare, >= 2")
    args = ap.parse_args(argv)
    if args.rounds < 1 or args.processes < 2:
        raise SystemExit("error: --rounds must be >= 1 and --processes >= 2")
    draw, kept = E.write_plots, {}

    def keep(runs, out_dir, scenarios=None, progress=False, inputs=(), processes=None):
        kept.update(runs=runs, scenarios=scenarios)
        return []
    E.write_plots = keep
    with tempfile.TemporaryDirectory() as out:
        E.main(["--quiet", "--out", out])
    E.write_plots = draw
    print(f"| round | 1 process s | {args.processes} processes s | ratio | load (1 min) |\n|---:|---:|---:|---:|---:|")
    for r in range(args.rounds):
        times = []
        for n in (1, args.processes):
            with tempfile.TemporaryDirectory() as out:
                t0 = time.perf_counter()
                files = draw(kept["runs"], out, kept["scenarios"], processes=n)
                times.append(time.perf_counter() - t0)
        print(f"| {r} | {times[0]:.2f} | {times[1]:.2f} | {times[0] / times[1]:.2f} | {os.getloadavg()[0]:.2f} |"
              f"  ({len(files)} figures)", flush=True)


if __name__ == "__main__":
    main()
