"""The options of ``radar-track tune`` (also ``python -m baselines.tuning``), importable at once (no numpy, scipy or
the trackers): ``--help`` and option errors answer from here before :mod:`baselines.tuning` is imported."""

from __future__ import annotations

import argparse

__all__ = ["build_parser", "check_options", "first_line", "TUNABLE", "MAX_TUNING_RUNS"]

TUNABLE = ("kf", "imm2", "imm_cv_ct", "kf_rdot", "imm2_rdot", "imm_cv_ct_rdot", "imm_ct_bank", "imm_ct_bank_rdot")
"""The tuned trackers' keys in ``tuned.json`` (:func:`baselines.tuning.tuned_tracker`)."""

MAX_TUNING_RUNS = 50_000
"""``--runs`` at most: 50,000 random flights are about 5.5 GB (measured 0.11 MB per flight), held in memory at once,
inside the tuning seeds."""


def build_parser(prog="radar-track tune"):
    """The tuning command's argument parser (every option with its default and unit)."""
    ap = argparse.ArgumentParser(prog=prog, description="Tune the classical baselines (constant-q KF, 2-mode IMM, "
                                 "CV/CT IMM) on random-scenario episodes drawn with tuning seeds, never on "
                                 "evaluation seeds; writes their tuned parameters for every tracker that reads them.")
    ap.add_argument("--runs", type=int, default=200, metavar="N",
                    help="random-scenario episodes to tune on, in [1, 50000] (default 200; kf and imm2 took about 3 min on "
                         "an idle 2-core machine, docs/trackers.md)")
    ap.add_argument("--trackers", default=",".join(TUNABLE), metavar="A,B,...",
                    help="comma-separated trackers to tune, from " + ", ".join(TUNABLE) + " (a _rdot name: the "
                         "same tracker also updating on the radial velocity, tuned on its own); the others keep "
                         "their entry in the existing file (default: all)")
    ap.add_argument("--starts", type=int, default=3, metavar="N",
                    help="optimizer starts per tracker, >= 1: the previous tuned values, then random points in "
                         "the search box (default 3)")
    ap.add_argument("--out", metavar="FILE.json",
                    help="output JSON: a new file or a regular file to replace (default: tuned.json in a new run "
                         "folder runs/tune_<time>/; never baselines/tuned.json, the file every tracker reads, "
                         "without --replace-shipped)")
    ap.add_argument("--replace-shipped", action="store_true",
                    help="write baselines/tuned.json, the shipped parameters every later evaluation reads (the "
                         "command says what it replaced) (default: off)")
    return ap


def check_options(args):
    """``--runs``, ``--starts`` and ``--trackers`` checked (a ``SystemExit`` naming the option), before the first line
    is printed and again by :func:`baselines.tuning.main`."""
    if not 1 <= args.runs <= MAX_TUNING_RUNS:
        raise SystemExit(f"error: --runs must be in [1, {MAX_TUNING_RUNS:,}] (the episodes, about 0.1 MB each, are "
                         f"held in memory at once), got {args.runs}")
    if args.starts < 1:
        raise SystemExit(f"error: --starts must be >= 1, got {args.starts}")
    names = [t.strip() for t in args.trackers.split(",") if t.strip()]
    bad = [t for t in names if t not in TUNABLE]
    if bad or not names:
        raise SystemExit(f"error: --trackers: expected names from {list(TUNABLE)}, got {args.trackers!r}")
    return names


def first_line(args):
    """What the command is about to do (printed before numpy, scipy and the trackers are imported)."""
    dest = args.out or ("baselines/tuned.json (--replace-shipped)" if args.replace_shipped else
                        "a new run folder runs/tune_<time>/")
    return (f"radar-track tune: tuning {args.trackers} on {args.runs} training-seed episodes ({args.starts} "
            f"optimizer starts each), writing {dest}; loading the trackers ...")
