"""The main job: compare learned policies and classical trackers on identical measurement streams.

``radar-track evaluate`` (or ``python -m agents.evaluate``) draws each suite's episodes once (held-out evaluation
seeds, see :mod:`agents.suites`), runs every tracker on the same episodes, batched over runs, and prints a table,
writes plots (PNG) and optionally a JSON file with every metric (:mod:`agents.metrics`).

Defaults: the bundled learned policy if one exists (``agents/bundled/``), the tuned 2-mode IMM (``imm2``), Bizup's
IMM, the tuned constant-q KF, the c_min tracker and the clairvoyant bound, on the default suite (random scenarios
and the papers' named scenarios).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

import numpy as np

from baselines.registry import TRACKER_NAMES, run_tracker
from baselines.trackers import run_q_policy
from radar_env.catalog import SCENARIO_NAMES
from radar_env.env import EnvConfig, actions_to_q_m_s2
from radar_env.radar import atc_radar
from radar_env.episode import stack_episodes
from radar_env.units import G0_M_S2

from .downstream import intercept_metrics, warning_metrics
from .metrics import evaluate_run, ratio_ci
from .suites import DEFAULT_RADAR_RANGE_M, DEFAULT_SUITES, EVAL_SEED_BASE, draw_suite, suite_key, trajectory_suite_names

__all__ = ["evaluate", "load_policy", "main", "DEFAULT_TRACKERS", "BUNDLED_POLICY"]

BUNDLED_POLICY = Path(__file__).with_name("bundled") / "policy.zip"
DEFAULT_TRACKERS = ("policy", "imm2", "imm2_bizup", "kf_tuned", "cmin", "clairvoyant")
DEFAULT_RUNS = {"random": 200, "random_radars": 100, "adrian_flower": 10, "adsb_calibration": 24, "encounters": 100}
"""Runs per suite when ``--runs`` is not given (the flower has 1561 looks per run, random radars up to ~1500;
the ADS-B suite flies each of its 24 flights once); others: 50 (``adsb:<flight>``: 10)."""


# ------------------------------------------------------------------------------------------------ policies
def load_policy(path):
    """Load a saved stable-baselines3 model (PPO, DQN, SAC, A2C or TD3 zip) and the env config it was trained
    with (``env_config.json`` beside it, else the defaults with the model's action type).

    Returns ``(choose_q, cfg)`` where ``choose_q(obs (n, F)) -> q (n,)`` in m/s^2. Raises ``ValueError`` for a file
    that is not such a model, or a model whose observation or action space does not match its env config (the
    message says which env kwargs it needs)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"policy file {str(path)!r} does not exist (or is not a file)")
    try:
        import stable_baselines3 as sb3
    except ImportError as e:  # pragma: no cover - depends on the install
        raise ValueError("loading a policy needs stable-baselines3: pip install -e '.[train]'") from e
    model, errors = None, []
    for algo in ("PPO", "DQN", "SAC", "A2C", "TD3"):
        try:
            model = getattr(sb3, algo).load(str(path), device="cpu")
            break
        except Exception as e:  # noqa: BLE001 - try the next algorithm class
            errors.append(f"{algo}: {type(e).__name__}")
    if model is None:
        raise ValueError(f"{path}: not a stable-baselines3 model this version can load ({'; '.join(errors)})")
    kw = {}
    cfg_file = path.with_name("env_config.json")
    if cfg_file.is_file():
        try:
            kw = json.loads(cfg_file.read_text())
        except json.JSONDecodeError as e:
            raise ValueError(f"{cfg_file}: not JSON ({e})") from None
        if not isinstance(kw, dict):
            raise ValueError(f"{cfg_file}: must hold a JSON object of RadarTrack-v0 arguments")
        kw = {k: tuple(v) if isinstance(v, list) else v for k, v in kw.items()}
    from gymnasium import spaces
    discrete = isinstance(model.action_space, spaces.Discrete)
    kw.setdefault("action_type", "discrete" if discrete else "continuous")
    try:
        cfg = EnvConfig.from_kwargs(**kw)
    except (TypeError, ValueError) as e:
        raise ValueError(f"{cfg_file}: {e}") from None
    where = str(cfg_file) if cfg_file.is_file() else f"the defaults (no {cfg_file.name} beside {path.name})"
    n_obs = int(np.prod(model.observation_space.shape))
    if n_obs != len(cfg.features):
        raise ValueError(f"{path}: the model takes {n_obs} observation entries but the env config from {where} has "
                         f"{len(cfg.features)} features; it was trained with other env kwargs: it needs 'features' "
                         f"(a list of the {n_obs} feature names it was trained with, e.g. from its run's "
                         f"env_config.json) in {cfg_file}")
    if discrete != (cfg.action_type == "discrete"):
        raise ValueError(f"{path}: the model has {model.action_space} actions but the env config from {where} has "
                         f"action_type={cfg.action_type!r}; it needs action_type="
                         f"{'discrete' if discrete else 'continuous'!r}")
    if discrete and int(model.action_space.n) != len(cfg.q_levels_g):
        raise ValueError(f"{path}: the model has {model.action_space} actions but the env config from {where} has "
                         f"{len(cfg.q_levels_g)} q levels; it needs 'q_levels_g' (the {model.action_space.n} levels "
                         f"it was trained with) in {cfg_file}")
    choose_q = model_choose_q(model, cfg)
    return choose_q, cfg


def model_choose_q(model, cfg: EnvConfig):
    """``choose_q(obs (n, F)) -> q (n,)`` in m/s^2 for a stable-baselines3 model (deterministic actions), through
    the env's action map :func:`radar_env.env.actions_to_q_m_s2`."""
    levels = np.asarray(cfg.q_levels_g) * G0_M_S2

    def choose_q(obs):
        act, _ = model.predict(obs.astype(np.float32), deterministic=True)
        return actions_to_q_m_s2(np.asarray(act).reshape(obs.shape[0], -1), cfg.action_type, levels)

    return choose_q


# ------------------------------------------------------------------------------------------------ evaluation
def evaluate(suites, trackers, policy_path=None, reference="imm2", progress=True):
    """Run ``trackers`` on every suite.

    Args:
        suites: list of ``(name, episodes)``.
        trackers: tracker names (``TRACKER_NAMES``); ``policy`` needs ``policy_path``.
        reference: tracker the ratio column is taken against (if present).
    Returns:
        ``(results, runs)``: ``results[suite]["trackers"][tracker]`` = metrics dict, ``results[suite]
        ["ratio_vs_" + reference][tracker]`` = ``[ratio, [lo, hi]]``; ``runs[suite]`` = ``(batch, {name: TrackRun})``.
    """
    choose_q = pol_cfg = None
    if "policy" in trackers:
        if policy_path is None:
            raise ValueError("tracker 'policy' needs a policy file (--policy PATH); none bundled")
        choose_q, pol_cfg = load_policy(policy_path)
    jobs = [(s, t) for s, _ in suites for t in trackers]
    bar = _progress(len(jobs), progress)
    results, runs = {}, {}
    for suite, episodes in suites:
        batch = stack_episodes(episodes)
        suite_runs = {}
        for t in trackers:
            t0 = time.time()
            if t == "policy":
                suite_runs[t] = run_q_policy(episodes, choose_q, "policy", pol_cfg)
            else:
                suite_runs[t] = run_tracker(t, episodes)
            bar(f"{suite}: {t} ({time.time() - t0:.1f} s)")
        res = {"runs": len(episodes), "looks_per_run_mean": float(batch.n_looks.mean()), "trackers": {}}
        for t, r in suite_runs.items():
            res["trackers"][t] = evaluate_run(batch, r)
            if suite == "encounters":
                res["trackers"][t].update(warning_metrics(batch, r))
            else:
                res["trackers"][t].update(intercept_metrics(batch, r))
        if reference in suite_runs:
            res[f"ratio_vs_{reference}"] = {
                t: list(_pair(ratio_ci(batch, r, suite_runs[reference]))) for t, r in suite_runs.items()}
        results[suite] = res
        runs[suite] = (batch, suite_runs)
    bar(None)
    return results, runs


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
    """Plain-text table: one block per suite, one row per tracker."""
    lines = []
    cols = ("pos RMSE m [95% CI]", "maneuver", "after", "straight", "vel m/s", "peak m", "ANEES", "in95",
            "lost", f"/{reference} [95% CI]")
    for suite, res in results.items():
        lines.append(f"\n== {suite}: {res['runs']} runs, {res['looks_per_run_mean']:.0f} looks/run ==")
        lines.append(f"{'tracker':20s} {cols[0]:>24s} {cols[1]:>9s} {cols[2]:>8s} {cols[3]:>9s} {cols[4]:>8s} "
                     f"{cols[5]:>8s} {cols[6]:>6s} {cols[7]:>5s} {cols[8]:>5s} {cols[9]:>22s}")
        ratios = res.get(f"ratio_vs_{reference}", {})
        for t, m in res["trackers"].items():
            lo, hi = m["pos_rmse_m_ci95"]
            rr = ratios.get(t)
            rtxt = f"{rr[0]:.3f} [{rr[1][0]:.3f},{rr[1][1]:.3f}]" if rr else ""
            lines.append(
                f"{t:20s} {m['pos_rmse_m']:9.1f} [{lo:6.1f},{hi:6.1f}] {_f(m['pos_rmse_m_maneuver'], 9)} "
                f"{_f(m['pos_rmse_m_after'], 8)} {_f(m['pos_rmse_m_straight'], 9)} {m['vel_rmse_m_s']:8.2f} "
                f"{m['peak_pos_err_m']:8.0f} {m['anees']:6.2f} {m['nees_in_95']:5.2f} {m['track_loss_rate']:5.2f} "
                f"{rtxt:>22s}")
    return "\n".join(lines)


def _f(v, w):
    return f"{v:{w}.1f}" if v is not None and np.isfinite(v) else f"{'-':>{w}s}"


def write_plots(runs, out_dir):
    """PNG figures per suite; returns the list of files written."""
    import matplotlib
    matplotlib.use("Agg")
    from . import plots
    out_dir = Path(out_dir)
    out_dir.mkdir(parents=True, exist_ok=True)
    files = []
    for suite, (batch, suite_runs) in runs.items():
        files += plots.suite_figures(suite, batch, suite_runs, out_dir)
    return files


def _jsonable(o):
    if isinstance(o, dict):
        return {k: _jsonable(v) for k, v in o.items()}
    if isinstance(o, (list, tuple)):
        return [_jsonable(v) for v in o]
    if isinstance(o, (float, np.floating)):
        return float(o) if np.isfinite(o) else None
    if isinstance(o, np.integer):
        return int(o)
    return o


# ------------------------------------------------------------------------------------------------ CLI
def build_parser(prog="radar-track evaluate"):
    ap = argparse.ArgumentParser(prog=prog, description="Compare trackers and learned policies on identical "
                                 "measurement streams (common random numbers).")
    ap.add_argument("--scenario", action="append", metavar="NAME",
                    help=f"suite to run, repeatable; one of {list(SCENARIO_NAMES)}, encounters (conflict warnings), "
                         "adsb_calibration or adsb:<flight> "
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
    ap.add_argument("--runs", type=int, help="Monte Carlo runs per suite (default: 200 random, 10 adrian_flower, "
                                             "100 encounter pairs, 24 adsb_calibration (each flight once), 10 "
                                             "adsb:<flight>, 50 otherwise)")
    ap.add_argument("--seed", type=int, default=EVAL_SEED_BASE,
                    help=f"base seed of the runs, >= 0 (default {EVAL_SEED_BASE}: held out from training and tuning)")
    ap.add_argument("--trackers", help=f"comma-separated tracker names from {list(TRACKER_NAMES)} "
                                       f"(default: {','.join(DEFAULT_TRACKERS)}; 'policy' only if a policy exists)")
    ap.add_argument("--policy", help="saved stable-baselines3 model (.zip) for the 'policy' tracker "
                                     f"(default: {BUNDLED_POLICY.relative_to(Path(__file__).parents[1])} if present)")
    ap.add_argument("--out", default="results", help="directory for the plots (default ./results)")
    ap.add_argument("--json", help="write every metric per tracker per suite to this JSON file (its folder must exist)")
    ap.add_argument("--no-plots", action="store_true", help="skip the plots")
    ap.add_argument("--quiet", action="store_true", help="no progress bar")
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
    if args.seed < 0:
        raise SystemExit(f"error: --seed must be an integer >= 0, got {args.seed}")
    if args.runs is not None and args.runs < 1:
        raise SystemExit(f"error: --runs must be >= 1, got {args.runs}")
    policy = args.policy
    if policy is not None and not Path(policy).is_file():
        raise SystemExit(f"error: --policy: file {policy!r} does not exist (or is not a file)")
    if policy is None and BUNDLED_POLICY.is_file():
        policy = str(BUNDLED_POLICY)
    if args.trackers is not None:
        trackers = [t.strip() for t in args.trackers.split(",") if t.strip()]
        if not trackers:
            raise SystemExit(f"error: --trackers: no tracker named in {args.trackers!r}; give comma-separated names "
                             f"from {list(TRACKER_NAMES)}")
        bad = [t for t in trackers if t not in TRACKER_NAMES]
        if bad:
            raise SystemExit(f"error: --trackers: unknown tracker(s) {bad}; valid: {list(TRACKER_NAMES)}")
        if "policy" in trackers and policy is None:
            raise SystemExit("error: tracker 'policy' needs --policy PATH (no bundled policy found)")
        if len(set(trackers)) != len(trackers):
            raise SystemExit(f"error: --trackers: a tracker is named twice in {args.trackers!r}")
    else:
        trackers = [t for t in DEFAULT_TRACKERS if t != "policy" or policy is not None]
    if "policy" in trackers:        # load once now: a file that is not a usable policy is a user error
        try:
            load_policy(policy)
        except ValueError as e:
            raise SystemExit(f"error: --policy: {e}") from None
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
    results, runs = evaluate(suites, trackers, policy, progress=not args.quiet)
    print(format_table(results))
    print(f"\n({time.time() - t0:.0f} s; seeds {args.seed}+i per suite; every tracker saw the same plots)")
    if not args.no_plots:
        files = write_plots(runs, args.out)
        print(f"plots: {len(files)} files in {args.out}/")
    if args.json:
        meta = {"seed": args.seed, "trackers": trackers, "policy": policy, "suites": [s for s, _ in suites],
                "trajectories": {n: {"file": f, "key": suite_key(f)} for n, f in
                                 zip(file_names, args.trajectory or [])},
                "radar_site_km": None if radar is None else [x_km, y_km],
                "radar_range_km": (None if radar is not None or not files else
                                   [v / 1e3 for v in (radar_range_m or DEFAULT_RADAR_RANGE_M)]),
                "command": " ".join(["radar-track", "evaluate", *(sys.argv[2:] if argv is None else argv)])}
        Path(args.json).write_text(json.dumps(_jsonable({"meta": meta, "suites": results}), indent=1))
        print(f"metrics: {args.json}")
    return results


if __name__ == "__main__":
    main(prog="python -m agents.evaluate")
