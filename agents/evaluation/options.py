"""The options of ``radar-track evaluate`` and its defaults, importable at once (no numpy, numba, torch or the
trackers): ``radar-track evaluate --help`` and option errors answer from here before any slow import, and the
command says what it is about to do (:func:`first_line`) before it loads the trackers and the policy.

:mod:`agents.evaluation.evaluate` runs the parsed options; the suites and trackers themselves are resolved there
(``--list`` prints every name)."""

from __future__ import annotations

import argparse
from pathlib import Path

from agents.policies.bundle import BUNDLED_POLICIES
from agents.policies.learned import BUNDLED_LEARNED
from baselines.seeds import EVAL_SEED_BASE

__all__ = ["DEFAULT_TRACKERS", "DEFAULT_SUITES", "OLD_OPTIONS", "OLD_OPTION_KINDS", "build_parser", "check_numbers",
           "first_line"]

OLD_OPTIONS = {"policy": "--policy", "policy_bp": "--policy-bp", "policy_imm_bp": "--policy-imm-bp",
               "policy_imm_ppo": "--policy-imm-ppo"}
"""The per-tracker options before ``--learned`` (aliases for one release): tracker name -> option."""
OLD_OPTION_KINDS = {"policy": ("ppo_q_policy", "dqn_q_policy", "sac_q_policy", "gru_q_policy"),
                    "policy_bp": ("gru_q_policy", "ppo_q_policy", "dqn_q_policy", "sac_q_policy"),
                    "policy_imm_bp": ("learned_imm_gru",), "policy_imm_ppo": ("learned_imm_ppo", "learned_imm_sac")}
"""The kinds each old option accepts (the q-policy options took either q-policy before; a learned IMM given to one
of them, or a q-policy to an IMM option, is refused naming its kind)."""

DEFAULT_TRACKERS = ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo", "policy_bp_rdot", "policy_imm_bp_rdot",
                    "policy_window", "imm2", "imm_cv_ct", "imm_ct_bank", "rbpf", "imm2_bizup", "kf_tuned", "cmin",
                    "kf_tuned_rdot", "imm2_rdot", "imm_cv_ct_rdot", "imm_ct_bank_rdot", "clairvoyant")
"""The main job's trackers (the learned ones, ``policy``, PPO, ``policy_bp``, a q-policy trained by backpropagation,
``policy_imm_bp`` and ``policy_imm_ppo``, the learned IMM trained by backpropagation and by PPO, their range-rate
recipes, and ``policy_window``, the best learned tracker on the random flights, only when such a file is bundled or
given)."""

DEFAULT_SUITES = ("random", "random_radars", "bizup2002", "adrian_flower", "kim_lee_accel",
                  "seed002_course_changes", "seed002_two_radars")
"""The main job's suites: random flights, random radars and the papers' named scenarios."""

RADAR_RANGE_HELP_KM = (10, 150)
"""The default of ``--radar-range-km`` as the help states it: :data:`radar_env.sim.scenario.RADAR_PLACEMENT_RANGE_M`
in km (a test checks that they agree; the value itself is not imported here, which would load numba)."""


def build_parser(prog="radar-track evaluate"):
    """The ``radar-track evaluate`` argument parser (every option with its default and unit)."""
    lo_km, hi_km = RADAR_RANGE_HELP_KM
    ap = argparse.ArgumentParser(prog=prog, description="Compare trackers and learned policies on identical "
                                 "measurement streams (common random numbers): a table per suite, figures in --out.",
                                 epilog="Security: a policy.zip (stable-baselines3) in a --learned folder and "
                                        "--tracker-module files are code: loading them runs what their author "
                                        "wrote. Use only files you trust. A zip is unpickled only with "
                                        "--allow-pickle (otherwise its numpy export policy.npz runs, or it is "
                                        "refused).")
    ap.add_argument("--scenario", action="append", metavar="NAME",
                    help="suite to run, repeatable: random, random_radars, a paper's scenario (e.g. bizup2002), a "
                         "held-out family (e.g. sharp_turns), encounters (conflict warnings), adsb_calibration, "
                         "adsb_dev, adsb_heldout, adsb:<flight>, or a trajectory .csv (as --trajectory); --list "
                         f"prints every name (default: {', '.join(DEFAULT_SUITES)})")
    ap.add_argument("--trajectory", action="append", metavar="FILE.csv",
                    help="user trajectory CSV with columns t_s,x_m,y_m,vx_m_s,vy_m_s (s, m, m/s; repeatable); its "
                         "suite is named after the file's stem, its runs are seeded by the SHA-256 of the file's "
                         "bytes (the same file by any path gives the same episodes) (default: none)")
    ap.add_argument("--radar-site", metavar="X_KM,Y_KM",
                    help="--trajectory suites: Adrian's ATC radar at this fixed site (km, the CSV's x/y frame) "
                         "instead of one placed per run (default: placed per run, see --radar-range-km)")
    ap.add_argument("--radar-range-km", metavar="LO,HI",
                    help="--trajectory suites: range annulus (km) of the per-run ATC radar placement: the site is "
                         f"drawn LO-HI km from the start, keeping the flight in range longest (default "
                         f"{lo_km:g},{hi_km:g})")
    ap.add_argument("--runs", type=int, metavar="N",
                    help="Monte Carlo runs per suite, >= 1 (default: 200 random and each held-out family, 100 "
                         "random_radars, 10 adrian_flower, 100 encounter pairs, 24 adsb_calibration and 12 adsb_dev / "
                         "adsb_heldout (each flight once), 10 adsb:<flight>, 50 otherwise)")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE, metavar="S",
                    help=f"base seed of the runs, >= 0; run i of a suite uses seed S + i (default {EVAL_SEED_BASE}: "
                         "held out from training and tuning)")
    ap.add_argument("--trackers", metavar="A,B,...",
                    help="comma-separated tracker names, built-in or registered by a --tracker-module; --list prints "
                         f"the built-in ones (default: {','.join(DEFAULT_TRACKERS)}; 'policy' only if a policy exists)")
    ap.add_argument("--tracker-module", action="append", metavar="MODULE",
                    help="import a user tracker module before the trackers are resolved: a dotted module name "
                         "(found in the current directory, which is not left on sys.path, or installed) or a .py file; it "
                         "registers its trackers with baselines.registry.register_tracker (repeatable; see "
                         "docs/evaluation.md). It runs as code (default: none)")
    ap.add_argument("--learned", action="append", metavar="NAME|DIR",
                    help="a learned tracker to run, by bundled name (" + ", ".join(BUNDLED_LEARNED) + ") or "
                         "folder (policy.npz, policy.json naming its kind, env_config.json: as radar-track train "
                         "writes), repeatable; its kind decides how it runs; a folder is reported under its name "
                         "(a training run's best/ as <run>_best), which must not be a built-in tracker's. Added to "
                         "--trackers (or to the default list). A policy.zip in a folder is a pickle: loading it (when "
                         "its numpy export is not current) runs the code inside, so it is refused unless "
                         "--allow-pickle (default: the bundled ones present)")
    ap.add_argument("--allow-pickle", action="store_true",
                    help="let a learned tracker's stable-baselines3 policy.zip be unpickled when its numpy export "
                         "is missing or stale: this runs the code inside the file; only for files you trust "
                         "(default: refused, in one line)")
    for t, opt in OLD_OPTIONS.items():
        ap.add_argument(opt, dest=t, metavar="FILE",
                        help=f"deprecated alias (for one release) of --learned for the '{t}' tracker: a file in a "
                             f"learned tracker folder, of kind {' or '.join(OLD_OPTION_KINDS[t])} (default: the "
                             f"bundled {BUNDLED_POLICIES[t].relative_to(Path(__file__).parents[2])} if present)")
    ap.add_argument("--out", default="results", metavar="DIR",
                    help="directory for the figures (PNG; created if missing; a link inside it is replaced, never "
                         "followed) (default: ./results)")
    ap.add_argument("--json", metavar="FILE.json",
                    help="write every metric per tracker per suite to this JSON file; its folder must exist; not "
                         "a symbolic link, not one of the run's input files (default: no JSON)")
    ap.add_argument("--no-plots", action="store_true", help="skip the figures (default: draw them)")
    ap.add_argument("--wide", action="store_true",
                    help="print every column of the table (velocity RMSE, peak error, NEES in 95 %%, the common "
                         "runs' RMSE and ratio; about 220 characters wide) (default: the compact table, within 120 "
                         "characters, with a legend; --json has every metric either way)")
    ap.add_argument("--quiet", action="store_true",
                    help="no progress: no first line, no bars; the table only (default: progress on stderr)")
    ap.add_argument("--workers", type=int, default=1, metavar="N",
                    help="split the runs over N Ray workers, >= 1 (same numbers as the serial run; needs the 'scale' "
                         "extra) (default 1: no Ray)")
    ap.add_argument("--address", metavar="HOST:PORT",
                    help="Ray cluster to run on, e.g. 127.0.0.1:6379 (default: RAY_ADDRESS if set, else an embedded "
                         "local Ray with --workers CPUs)")
    ap.add_argument("--list", action="store_true",
                    help="print every suite and built-in tracker name and exit (default: evaluate)")
    return ap


def check_numbers(args):
    """The numeric options' ranges (``--seed``, ``--runs``, ``--workers``), checked before the first line is printed
    and again by :func:`agents.evaluation.evaluate.main` (a ``SystemExit`` naming the option)."""
    if args.seed < 0:
        raise SystemExit(f"error: --seed must be an integer >= 0, got {args.seed}")
    if args.runs is not None and args.runs < 1:
        raise SystemExit(f"error: --runs must be >= 1, got {args.runs}")
    if args.workers < 1:
        raise SystemExit(f"error: --workers must be >= 1, got {args.workers}")


def first_line(args):
    """What the command is about to do, in one line, from the parsed options alone (printed before the slow
    imports: the trackers, the numba kernels, torch for the policy)."""
    if args.list:
        return "radar-track evaluate: listing the suites and trackers (loading the registry) ..."
    suites = list(args.scenario or []) + list(args.trajectory or [])
    suites = suites or list(DEFAULT_SUITES)
    named = ([t.strip() for t in args.trackers.split(",") if t.strip()] if args.trackers is not None
             else DEFAULT_TRACKERS)
    trackers = (len(named) if args.trackers is not None
                else len(DEFAULT_TRACKERS) - sum(not (getattr(args, t, None) or BUNDLED_POLICIES[t].is_file())
                                                 for t in BUNDLED_POLICIES))
    # user folders add one each, and so does a bundled name not already listed (policy_bp_prior, ...)
    trackers += len([x for x in args.learned or [] if x not in BUNDLED_LEARNED or x not in named])
    shown = ", ".join(suites[:4]) + (f" and {len(suites) - 4} more" if len(suites) > 4 else "")
    return (f"radar-track evaluate: {trackers} tracker(s) on {len(suites)} suite(s) ({shown}); loading the trackers"
            + (" and the policies" if trackers and (args.trackers is None or "policy" in args.trackers
                                                     or args.learned) else "")
            + " ...")
