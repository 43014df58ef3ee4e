"""The main job: compare learned policies and classical trackers on identical measurement streams.

``radar-track evaluate`` (or ``python -m agents.evaluation.evaluate``) draws each suite's episodes once (held-out evaluation
seeds, see :mod:`agents.evaluation.suites`), runs every tracker on the same episodes, batched over runs, and prints a table,
writes plots (PNG) and optionally a JSON file with every metric (:mod:`agents.evaluation.metrics`).

Defaults: the bundled learned policies if they exist (``agents/bundled/``: ``policy``, PPO, and ``policy_bp``, trained
by backpropagation), the tuned 2-mode IMM (``imm2``), the tuned
CV / CT-EKF IMM (``imm_cv_ct``, the strongest classical tracker on most suites), Bizup's IMM, the tuned constant-q
KF, the c_min tracker and the clairvoyant bound, on the default suite (random scenarios and the papers' named
scenarios).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from baselines.registry import DESIGN_ENVELOPES, POLICY_TRACKERS, TRACKER_NAMES, tracker_names
from baselines.user_trackers import import_tracker_module
from radar_env.catalog import FAMILIES, SCENARIO_NAMES
from radar_env.radar import atc_radar
from radar_env.episode import stack_episodes

from agents.policies.bundle import BUNDLED_BP_POLICY, BUNDLED_POLICY
from agents.policies.loading import load_policy
from agents.evaluation.downstream import intercept_metrics, warning_metrics
from agents.evaluation.metrics import FEW_RUNS, common_runs, evaluate_run, failed_runs, jsonable, ratio_ci
from agents.evaluation.runner import run_one
from agents.evaluation.suites import DEFAULT_RADAR_RANGE_M, DEFAULT_SUITES, EVAL_SEED_BASE, draw_suite, suite_key, trajectory_suite_names

__all__ = ["evaluate", "main", "format_table", "DEFAULT_TRACKERS", "DEFAULT_RUNS"]

DEFAULT_TRACKERS = ("policy", "policy_bp", "imm2", "imm_cv_ct", "imm2_bizup", "kf_tuned", "cmin", "clairvoyant")
DEFAULT_RUNS = {"random": 200, "random_radars": 100, "adrian_flower": 10, "adsb_calibration": 24, "adsb_dev": 12,
                "adsb_heldout": 12, "encounters": 100, **{f: 200 for f in FAMILIES}}
"""Runs per suite when ``--runs`` is not given (the flower has 1561 looks per run, random radars up to ~1500;
the ADS-B suites fly each of their flights once; the held-out families 200); others: 50 (``adsb:<flight>``: 10)."""


# ------------------------------------------------------------------------------------------------ evaluation
def evaluate(suites, trackers, policy_path=None, reference="imm2", progress=True, workers=1, address=None, seed=None,
             common_over=None, loaded_policy=None, policy_bp_path=None, loaded_policy_bp=None):
    """Run ``trackers`` on every suite.

    Args:
        suites: list of ``(name, episodes)``.
        trackers: tracker names (``TRACKER_NAMES``); ``policy`` needs ``policy_path``, ``policy_bp`` runs
            ``policy_bp_path`` (default: the bundled backprop policy, :data:`BUNDLED_BP_POLICY`). Either file may be
            an SB3 zip or a recurrent ``.npz`` (:func:`agents.policies.loading.load_policy`).
        reference: tracker the ratio column is taken against (if present).
        workers, address, seed: ``workers > 1`` runs the trackers on Ray (:func:`agents.evaluation.parallel.run_suites_ray`,
            same numbers as the serial run); ``seed``: the base seed the suites were drawn with (lets the tasks draw
            the named suites themselves).
        common_over: tracker names whose lost or failed runs are left out of every tracker's common-run metrics
            (:func:`agents.evaluation.metrics.common_runs`); default: all ``trackers`` except, per suite, those that failed
            every run (named in ``common_excluded_failed_everywhere``).
        loaded_policy, loaded_policy_bp: ``load_policy(policy_path)``'s (``policy_bp_path``'s) result if the caller
            has it already (not loaded again).
    Returns:
        ``(results, runs)``: ``results[suite]["trackers"][tracker]`` = metrics dict, ``results[suite]
        ["ratio_vs_" + reference][tracker]`` = ``[ratio, [lo, hi]]`` over the runs neither failed (their number in
        ``"ratio_vs_" + reference + "_runs"``), ``..._common`` the same over the suite's ``common_runs``;
        ``runs[suite]`` = ``(batch, {name: TrackRun})``.
    """
    if policy_bp_path is None and BUNDLED_BP_POLICY.is_file():
        policy_bp_path = BUNDLED_BP_POLICY
    paths = {"policy": policy_path, "policy_bp": policy_bp_path}
    given = {"policy": loaded_policy, "policy_bp": loaded_policy_bp}
    policies = {}                           # tracker -> (choose_q, env config)
    for t in POLICY_TRACKERS:
        if t in trackers:
            if paths[t] is None and given[t] is None:
                raise ValueError(f"tracker {t!r} needs a policy file (--{t.replace('_', '-')} PATH); none bundled")
            policies[t] = given[t] if given[t] is not None else load_policy(paths[t])
    default_common = common_over is None
    common_over = list(trackers if common_over is None else common_over)
    bad = [t for t in common_over if t not in trackers]
    if bad:
        raise ValueError(f"common_over names {bad}, which are not among the trackers {list(trackers)}")
    jobs = [(s, t) for s, _ in suites for t in trackers]
    bar = _progress(len(jobs), progress)
    results, runs = {}, {}
    ray_runs = None
    if workers > 1 or address:
        from agents.evaluation.parallel import run_suites_ray
        ray_runs = run_suites_ray(suites, trackers, {t: paths[t] for t in policies}, workers, address, seed, bar)
    for suite, episodes in suites:
        batch = stack_episodes(episodes)
        suite_runs = {} if ray_runs is None else ray_runs[suite]
        for t in trackers if ray_runs is None else ():
            t0 = time.time()
            suite_runs[t] = run_one(t, episodes, *policies.get(t, (None, None)))
            bar(f"{suite}: {t} ({time.time() - t0:.1f} s)")
        # by default a tracker that failed every run does not empty the common set for all the others
        dropped = [t for t in common_over if default_common and failed_runs(batch, suite_runs[t]).all()]
        cover = [t for t in common_over if t not in dropped]
        common = common_runs(batch, [suite_runs[t] for t in cover])
        n_common = int(common.sum())
        res = {"runs": len(episodes), "looks_per_run_mean": float(batch.n_looks.mean()),
               "few_runs": len(episodes) < FEW_RUNS, "common_runs": n_common, "few_common_runs": n_common < FEW_RUNS,
               "common_trackers": cover, "common_excluded_failed_everywhere": dropped, "trackers": {}}
        for t, r in suite_runs.items():
            m = evaluate_run(batch, r, common=common)
            if r.error is not None:
                m["error"] = r.error
            m.update(_downstream(suite, episodes, batch, r))
            _note_undefined(m)
            res["trackers"][t] = m
        if reference in suite_runs:
            ref = suite_runs[reference]
            ref_ok = ~failed_runs(batch, ref)
            res[f"ratio_vs_{reference}"] = {
                t: list(_pair(ratio_ci(batch, r, ref))) for t, r in suite_runs.items()}
            res[f"ratio_vs_{reference}_runs"] = {
                t: int((ref_ok & ~failed_runs(batch, r)).sum()) for t, r in suite_runs.items()}
            res[f"ratio_vs_{reference}_common"] = {
                t: list(_pair(ratio_ci(batch, r, ref, runs=common))) for t, r in suite_runs.items()}
        results[suite] = res
        runs[suite] = (batch, suite_runs)
    bar(None)
    return results, runs


def _downstream(suite, episodes, batch, run):
    """Conflict warnings (``encounters``) or intercepts (other suites) over the runs the tracker did not fail (an
    encounter pair goes with either of its runs); ``downstream_runs`` counts them."""
    fn = warning_metrics if suite == "encounters" else intercept_metrics
    keep = ~failed_runs(batch, run)
    if suite == "encounters":
        keep = np.repeat(keep.reshape(-1, 2).all(axis=1), 2)
    if keep.all() or not keep.any():          # nothing to leave out, or nothing left (the values are then NaN)
        return {**fn(batch, run), "downstream_runs": int(keep.sum())}
    rows = np.flatnonzero(keep)
    sub = stack_episodes([episodes[i] for i in rows])
    return {**fn(sub, _take_rows(run, rows, sub.valid.shape[1])), "downstream_runs": int(rows.size)}


def _take_rows(run, rows, K):
    """The TrackRun of the episodes ``rows`` only, padded to ``K`` looks like a batch of just those episodes."""
    return dataclasses.replace(
        run, x=run.x[rows, :K], P=run.P[rows, :K], start_index=run.start_index[rows], q_m_s2=run.q_m_s2[rows, :K],
        declared=None if run.declared is None else run.declared[rows, :K],
        extra={k: v[rows, :K] for k, v in run.extra.items()})


def _note_undefined(m):
    """Give every non-finite value of a metrics dict a reason in ``m["undefined"]`` (the JSON writes it as null)."""
    und = m.setdefault("undefined", {})
    for k, v in m.items():
        if k != "undefined" and k not in und and not _finite(v):
            und[k] = f"not finite ({v!r}; {m.get('failed_runs', 0)} failed runs)"


def _finite(v):
    if isinstance(v, (list, tuple)):
        return all(_finite(x) for x in v)
    if isinstance(v, (float, np.floating)):
        return bool(np.isfinite(v))
    return True


def _pair(rc):
    est, (lo, hi) = rc
    return est, [lo, hi]


def _progress(total, enabled):
    if not enabled:
        return lambda msg: None
    try:
        from tqdm import tqdm
    except ImportError:
        tqdm = None
    if tqdm is None:
        count = [0]

        def plain(msg):
            if msg is not None:
                count[0] += 1
                print(f"[{count[0]}/{total}] {msg}", file=sys.stderr, flush=True)
        return plain
    bar = tqdm(total=total, file=sys.stderr, leave=False)

    def tick(msg):
        if msg is None:
            bar.close()
        else:
            bar.set_description(msg)
            bar.update(1)
    return tick


# ------------------------------------------------------------------------------------------------ output
def format_table(results, reference="imm2"):
    """Plain-text table: one block per suite, one row per tracker.

    ``pos RMSE`` is pooled over the runs the tracker did not fail (lost runs included); ``common`` over the suite's
    common runs (no compared tracker lost or failed them); the ratio columns are paired over the runs neither
    tracker failed (``all``) and over the common runs. ``(n<20)`` marks an interval from fewer than 20 runs."""
    lines = []
    head = ("tracker", "pos RMSE m [95% CI]", "maneuver", "after", "straight", "vel m/s", "peak m", "ANEES",
            "in95", "lost", "failed", "common RMSE m [95% CI]", f"/{reference} all [95% CI]",
            f"/{reference} common [95% CI]")
    widths = (20, 30, 9, 8, 9, 8, 8, 6, 5, 5, 6, 30, 28, 28)
    for suite, res in results.items():
        n_common = res.get("common_runs")
        lines.append(f"\n== {suite}: {res['runs']} runs, {res['looks_per_run_mean']:.0f} looks/run"
                     + ("" if n_common is None else f"; {n_common} common runs (no tracker lost or failed them)")
                     + (f"; (n<{FEW_RUNS}): fewer than {FEW_RUNS} runs, the intervals are no evidence"
                        if res["runs"] < FEW_RUNS else "") + " ==")
        lines.append(" ".join(f"{h:{'<' if i == 0 else '>'}{w}s}" for i, (h, w) in enumerate(zip(head, widths))))
        ratios = res.get(f"ratio_vs_{reference}", {})
        ratio_runs = res.get(f"ratio_vs_{reference}_runs", {})
        ratios_c = res.get(f"ratio_vs_{reference}_common", {})
        for t, m in res["trackers"].items():
            rr, rc = ratios.get(t), ratios_c.get(t)
            cells = (
                t,
                _f_ci(m["pos_rmse_m"], m["pos_rmse_m_ci95"], m.get("runs_scored", res["runs"]), 1),
                _f(m["pos_rmse_m_maneuver"], 9), _f(m["pos_rmse_m_after"], 8), _f(m["pos_rmse_m_straight"], 9),
                _f(m["vel_rmse_m_s"], 8, 2), _f(m["peak_pos_err_m"], 8, 0), _f(m["anees"], 6, 2),
                _f(m["nees_in_95"], 5, 2), _f(m["track_loss_rate"], 5, 2), str(m.get("failed_runs", "-")),
                _f_ci(m["pos_rmse_m_common"], m["pos_rmse_m_common_ci95"], m["common_runs"], 1)
                if "pos_rmse_m_common" in m else "-",
                _f_ci(rr[0], rr[1], ratio_runs.get(t, res["runs"]), 3) if rr else "",
                _f_ci(rc[0], rc[1], n_common, 3) if rc else "")
            lines.append(" ".join(f"{c:{'<' if i == 0 else '>'}{w}s}" for i, (c, w) in enumerate(zip(cells, widths))))
        lines += [f"  {n}" for n in table_notes(res)]
    return "\n".join(lines)


def table_notes(suite_result):
    """Notes printed under a suite's table: a tracker that raised (its error), and the design envelope of each
    tracker used outside the conditions its paper assumed (:data:`baselines.registry.DESIGN_ENVELOPES`)."""
    notes = []
    for t, m in suite_result["trackers"].items():
        if m.get("error"):
            notes.append(f"{t}: failed on every run: {m['error']}")
        if t in DESIGN_ENVELOPES:
            notes.append(f"{t}: design envelope: {DESIGN_ENVELOPES[t]}")
    return notes


def _f(v, w, nd=1):
    """``v`` with ``nd`` decimals right-aligned in ``w`` characters, '-' if None or not finite."""
    return f"{v:{w}.{nd}f}" if v is not None and np.isfinite(v) else f"{'-':>{w}s}"


def _f_ci(est, ci, n, nd):
    """``est [lo,hi]`` and ``(n<20)`` if the interval comes from fewer than ``FEW_RUNS`` runs; '-' if undefined."""
    if est is None or not np.isfinite(est):
        return "-"
    lo, hi = ci
    txt = f"{est:.{nd}f} [{_f(lo, 0, nd).strip()},{_f(hi, 0, nd).strip()}]"
    return txt + (f" (n<{FEW_RUNS})" if n is not None and n < FEW_RUNS else "")


def write_plots(runs, out_dir):
    """PNG figures per suite; returns the list of files written."""
    import matplotlib
    matplotlib.use("Agg")
    from agents.evaluation import plots
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for suite, (batch, suite_runs) in runs.items():
        files += plots.suite_figures(suite, batch, suite_runs, out_dir)
    return files


# ------------------------------------------------------------------------------------------------ CLI
def build_parser(prog="radar-track evaluate"):
    ap = argparse.ArgumentParser(prog=prog, description="Compare trackers and learned policies on identical "
                                 "measurement streams (common random numbers).")
    ap.add_argument("--scenario", action="append", metavar="NAME",
                    help=f"suite to run, repeatable; one of {list(SCENARIO_NAMES)}, encounters (conflict warnings), "
                         "adsb_calibration, adsb_dev, adsb_heldout or adsb:<flight> "
                         f"(default: {', '.join(DEFAULT_SUITES)})")
    ap.add_argument("--trajectory", action="append", metavar="FILE.csv",
                    help="user trajectory CSV with columns t_s,x_m,y_m,vx_m_s,vy_m_s (repeatable); its suite is "
                         "named after the file's stem, its runs are seeded by the SHA-256 of the file's bytes "
                         "(the same file by any path gives the same episodes)")
    ap.add_argument("--radar-site", metavar="X_KM,Y_KM",
                    help="--trajectory suites: Adrian's ATC radar at this fixed site (km, the CSV's x/y frame) "
                         "instead of one placed per run")
    ap.add_argument("--radar-range-km", metavar="LO,HI",
                    help="--trajectory suites: range annulus (km) of the per-run ATC radar placement: the site is "
                         "drawn LO-HI km from the start, keeping the flight in range longest (default "
                         f"{DEFAULT_RADAR_RANGE_M[0] / 1e3:g},{DEFAULT_RADAR_RANGE_M[1] / 1e3:g})")
    ap.add_argument("--runs", type=int, help="Monte Carlo runs per suite (default: 200 random and each held-out "
                                             "family, 10 adrian_flower, 100 encounter pairs, 24 adsb_calibration "
                                             "and 12 adsb_dev / adsb_heldout (each flight once), 10 "
                                             "adsb:<flight>, 50 otherwise)")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE,
                    help=f"base seed of the runs, >= 0 (default {EVAL_SEED_BASE}: held out from training and tuning)")
    ap.add_argument("--trackers", help=f"comma-separated tracker names from {list(TRACKER_NAMES)} or registered by "
                                       f"a --tracker-module (default: {','.join(DEFAULT_TRACKERS)}; 'policy' only if "
                                       "a policy exists)")
    ap.add_argument("--tracker-module", action="append", metavar="MODULE",
                    help="import a user tracker module before the trackers are resolved: a dotted module name "
                         "(importable from the current directory) or a .py file; it registers its trackers with "
                         "baselines.registry.register_tracker (repeatable; see 'Your own tracker in the "
                         "comparison' in the README)")
    ap.add_argument("--policy", help="saved policy for the 'policy' tracker: a stable-baselines3 model (.zip) or a "
                                     "recurrent policy trained by backpropagation (policy.npz) "
                                     f"(default: {BUNDLED_POLICY.relative_to(Path(__file__).parents[2])} if present)")
    ap.add_argument("--policy-bp", help="saved policy for the 'policy_bp' tracker (.npz or .zip; default: "
                                        f"{BUNDLED_BP_POLICY.relative_to(Path(__file__).parents[2])} if present)")
    ap.add_argument("--out", default="results", help="directory for the plots (default ./results)")
    ap.add_argument("--json", help="write every metric per tracker per suite to this JSON file (its folder must exist)")
    ap.add_argument("--no-plots", action="store_true", help="skip the plots")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
    ap.add_argument("--workers", type=int, default=1, help="split the runs over N Ray workers (same numbers as "
                    "the serial run; needs the 'scale' extra; default 1: no Ray)")
    ap.add_argument("--address", help="Ray cluster to run on, e.g. 127.0.0.1:6379 (default: RAY_ADDRESS if set, else "
                                      "an embedded local Ray with --workers CPUs)")
    return ap


def _km_pair(option, text):
    """``"A,B"`` -> two finite floats (km); a one-line error naming ``option`` otherwise."""
    parts = [p.strip() for p in str(text).split(",")]
    try:
        vals = [float(p) for p in parts]
    except ValueError:
        vals = []
    if len(vals) != 2 or not all(np.isfinite(vals)):
        raise SystemExit(f"error: {option}: expected two finite numbers in km separated by a comma, got {text!r}")
    return vals


def _check_outputs(args):
    """Fail before the evaluation runs if an output cannot be written (``--out`` for plots, ``--json``)."""
    if not args.no_plots:
        out = Path(args.out)
        if out.exists() and not out.is_dir():
            raise SystemExit(f"error: --out: {args.out!r} exists and is not a directory")
        try:
            out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise SystemExit(f"error: --out: cannot create directory {args.out!r} ({e.strerror or e})") from None
        if not os.access(out, os.W_OK | os.X_OK):
            raise SystemExit(f"error: --out: directory {args.out!r} is not writable")
    if args.json:
        js = Path(args.json)
        folder = js.parent
        if js.is_dir():
            raise SystemExit(f"error: --json: {args.json!r} is a directory; give a file name")
        if not folder.is_dir():
            raise SystemExit(f"error: --json: folder {str(folder)!r} of {args.json!r} does not exist (or is not a "
                             "directory)")
        if not os.access(folder, os.W_OK | os.X_OK) or (js.exists() and not os.access(js, os.W_OK)):
            raise SystemExit(f"error: --json: {args.json!r} is not writable")


def main(argv=None, prog="radar-track evaluate"):
    """The ``radar-track evaluate`` command. Every user error (options, files, outputs) stops with a one-line
    ``error: --option: ...`` (``SystemExit``) before any evaluation runs. Returns the results dict."""
    args = build_parser(prog).parse_args(argv)
    # a CSV path given to --scenario is a trajectory suite (named by its stem, seeded by its content)
    csv_scenarios = [n for n in (args.scenario or []) if n.endswith(".csv")]
    if csv_scenarios:
        args.scenario = [n for n in args.scenario if not n.endswith(".csv")]
        args.trajectory = list(args.trajectory or []) + csv_scenarios
    if args.seed < 0:
        raise SystemExit(f"error: --seed must be an integer >= 0, got {args.seed}")
    if args.runs is not None and args.runs < 1:
        raise SystemExit(f"error: --runs must be >= 1, got {args.runs}")
    if args.workers < 1:
        raise SystemExit(f"error: --workers must be >= 1, got {args.workers}")
    policy = args.policy
    if policy is not None and not Path(policy).is_file():
        raise SystemExit(f"error: --policy: file {policy!r} does not exist (or is not a file)")
    if policy is None and BUNDLED_POLICY.is_file():
        policy = str(BUNDLED_POLICY)
    policy_bp = args.policy_bp
    if policy_bp is not None and not Path(policy_bp).is_file():
        raise SystemExit(f"error: --policy-bp: file {policy_bp!r} does not exist (or is not a file)")
    if policy_bp is None and BUNDLED_BP_POLICY.is_file():
        policy_bp = str(BUNDLED_BP_POLICY)
    policy_files = {"policy": policy, "policy_bp": policy_bp}
    for spec in args.tracker_module or []:
        try:
            import_tracker_module(spec)
        except ValueError as e:
            raise SystemExit(f"error: --tracker-module: {e}") from None
    if args.tracker_module and (args.workers > 1 or args.address):
        raise SystemExit("error: --tracker-module: user trackers are registered in this process only and cannot run "
                         f"on Ray workers; use --workers 1 without --address (got --workers {args.workers})")
    known = tracker_names()
    if args.trackers is not None:
        trackers = [t.strip() for t in args.trackers.split(",") if t.strip()]
        if not trackers:
            raise SystemExit(f"error: --trackers: no tracker named in {args.trackers!r}; give comma-separated names "
                             f"from {list(known)}")
        bad = [t for t in trackers if t not in known]
        if bad:
            raise SystemExit(f"error: --trackers: unknown tracker(s) {bad}; valid: {list(known)}"
                             + ("" if args.tracker_module else " (user trackers need --tracker-module)"))
        for t in POLICY_TRACKERS:
            if t in trackers and policy_files[t] is None:
                raise SystemExit(f"error: tracker {t!r} needs --{t.replace('_', '-')} PATH (no bundled policy found)")
        if len(set(trackers)) != len(trackers):
            raise SystemExit(f"error: --trackers: a tracker is named twice in {args.trackers!r}")
    else:
        trackers = [t for t in DEFAULT_TRACKERS if t not in POLICY_TRACKERS or policy_files[t] is not None]
    loaded = {}
    for t in POLICY_TRACKERS:       # load once, now: a file that is not a usable policy is a user error
        if t in trackers:
            try:
                loaded[t] = load_policy(policy_files[t])
            except ValueError as e:
                raise SystemExit(f"error: --{t.replace('_', '-')}: {e}") from None
    radar, radar_range_m = None, None
    if args.radar_site is not None or args.radar_range_km is not None:
        if not args.trajectory:
            opt = "--radar-site" if args.radar_site is not None else "--radar-range-km"
            raise SystemExit(f"error: {opt} applies to --trajectory suites only; no --trajectory given")
        if args.radar_site is not None and args.radar_range_km is not None:
            raise SystemExit("error: --radar-site (a fixed site) and --radar-range-km (the placement rule's range) "
                             "exclude each other; give one")
    if args.radar_site is not None:
        x_km, y_km = _km_pair("--radar-site", args.radar_site)
        radar = atc_radar(position_m=(x_km * 1e3, y_km * 1e3))
    if args.radar_range_km is not None:
        lo_km, hi_km = _km_pair("--radar-range-km", args.radar_range_km)
        if not 0.0 < lo_km < hi_km:
            raise SystemExit(f"error: --radar-range-km: expected 0 < LO < HI (km), got {args.radar_range_km!r}")
        radar_range_m = (lo_km * 1e3, hi_km * 1e3)
    _check_outputs(args)
    names = list(args.scenario or ([] if args.trajectory else DEFAULT_SUITES))
    dup = sorted({n for n in names if names.count(n) > 1})
    if dup:
        raise SystemExit(f"error: --scenario: {dup} given more than once")
    suites = []
    files = list(args.trajectory or [])
    try:
        file_names = trajectory_suite_names(files, taken=names)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    for n in names:
        runs = args.runs or DEFAULT_RUNS.get(n, 10 if n.startswith("adsb:") else 50)
        try:
            suites.append((n, draw_suite(n, runs, seed=args.seed)))
        except ValueError as e:
            raise SystemExit(f"error: --scenario: {e}") from None
    for n, f in zip(file_names, files):
        try:
            suites.append((n, draw_suite(f, args.runs or 50, seed=args.seed, radar=radar,
                                         radar_range_m=radar_range_m)))
        except ValueError as e:
            raise SystemExit(f"error: --trajectory: {e}") from None
    t0 = time.time()
    try:
        results, runs = evaluate(suites, trackers, policy, progress=not args.quiet, workers=args.workers,
                                 address=args.address, seed=args.seed, loaded_policy=loaded.get("policy"),
                                 policy_bp_path=policy_bp, loaded_policy_bp=loaded.get("policy_bp"))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    print(format_table(results))
    print(f"\n({time.time() - t0:.0f} s; seeds {args.seed}+i per suite; every tracker saw the same plots)")
    if args.json:
        meta = {"seed": args.seed, "trackers": trackers, "tracker_modules": list(args.tracker_module or []),
                "policy": policy, "policy_bp": policy_bp if "policy_bp" in trackers else None,
                "suites": [s for s, _ in suites],
                "trajectories": {n: {"file": f, "key": suite_key(f)} for n, f in
                                 zip(file_names, args.trajectory or [])},
                "radar_site_km": None if radar is None else [x_km, y_km],
                "radar_range_km": (None if radar is not None or not files else
                                   [v / 1e3 for v in (radar_range_m or DEFAULT_RADAR_RANGE_M)]),
                "command": " ".join(["radar-track", "evaluate", *(sys.argv[2:] if argv is None else argv)])}
        Path(args.json).write_text(json.dumps(jsonable({"meta": meta, "suites": results}), indent=1,
                                              allow_nan=False))
        print(f"metrics: {args.json}")
    if not args.no_plots:
        written = write_plots(runs, args.out)
        print(f"plots: {len(written)} files in {args.out}/")
    return results


if __name__ == "__main__":
    main(prog="python -m agents.evaluation.evaluate")
