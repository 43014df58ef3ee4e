"""Seed and hyperparameter sweeps on Ray Tune: ``radar-track sweep CONFIG.toml [--out DIR] [--address ADDR]``.

Each trial is one ``radar-track train`` run (:func:`agents.training.train.train`, or with ``method = "backprop"``
:func:`agents.training.backprop.train_backprop`) with its own run folder
``<out>/<name>/runs/<trial>/``; the selection metric (``selection_ratio``: the geometric mean of the policy/imm2
RMSE ratios on the selection suites, training-range seeds, :class:`agents.training.callbacks.ImmRatioEvalCallback`) is
reported to Tune after every selection evaluation, so an ASHA scheduler can stop weak trials early. At the end a
table (best selection ratio per trial, lower is better) is printed and written as ``results.csv`` and
``results.json`` in ``<out>/<name>/``. Running the same command again after an interruption resumes the sweep
(finished trials are kept, unfinished ones start again from scratch: training has no mid-run checkpoint resume).
Ctrl+C (SIGINT) stops the trials, saves the experiment, writes the table with the cut trials as ``unfinished``,
prints the command that resumes and exits with status 1 (a second Ctrl+C skips Tune's last save). ``name`` must be
a plain folder name (no ``/``, ``..``); Ray errors are one line naming Ray's log folder.

The config (example: ``agents/training/sweeps/example.toml``)::

    [sweep]
    name = "ppo_lr_seeds"        # experiment folder under --out (default: the config file's stem)
    method = "ppo"               # ppo (SB3, with algo) | backprop (hyperparams backprop.toml; budget n_steps)
    algo = "ppo"                 # ppo | dqn | sac
    hyperparams = "ppo.toml"     # base file (a path, or a name in agents/training/hyperparams/; default <algo>.toml)
    search = "grid"              # grid | random | optuna
    num_samples = 1              # grid: repeats of the whole grid; random / optuna: number of trials
    search_seed = 0              # seed of the random / optuna sampler (reproducible trial configs)
    cpus_per_trial = 1
    max_concurrent_trials = 2    # default: as many as the CPUs allow
    scheduler = "fifo"           # fifo | asha (early stopping on selection_ratio)
    grace_evals = 2              # asha: selection evaluations a trial always gets
    [base]                       # fixed, over the base file's values: tables merge key by key (eval_scenarios
                                 # replaces the file's), dotted keys nest
    n_timesteps = 200_000
    [space]                      # searched; "seed" is the training seed, other keys as in the TOML files
    seed = [0, 1, 2]                         # a list: grid axis (grid), a choice (random / optuna)
    learning_rate = {loguniform = [1e-4, 1e-3]}  # also uniform, randint (random / optuna only)

Ray is the optional ``scale`` extra; the local machine is used unless ``--address`` or ``RAY_ADDRESS`` names a
cluster (see the README, "Scaling out with Ray").
"""

from __future__ import annotations

import argparse
import copy
import csv
import io
import json
import logging
import math
import shlex
import sys
import tomllib
from pathlib import Path

from agents.training.train import ALGOS, HP_DIR, check_plain_name, load_hyperparams

__all__ = ["load_sweep_config", "run_sweep", "main", "EXAMPLE_CONFIG", "METRIC"]

EXAMPLE_CONFIG = Path(__file__).with_name("sweeps") / "example.toml"
METRIC = "selection_ratio"
SEARCHES = ("grid", "random", "optuna")
SCHEDULERS = ("fifo", "asha")
DISTRIBUTIONS = ("uniform", "loguniform", "randint")
_SWEEP_KEYS = {"name", "method", "algo", "hyperparams", "search", "num_samples", "search_seed", "cpus_per_trial",
               "max_concurrent_trials", "scheduler", "grace_evals"}


def _nest(flat):
    """``{"a.b": v}`` -> ``{"a": {"b": v}}`` (dotted keys reach into ``env_kwargs``, ``policy_kwargs`` ...)."""
    out = {}
    for key, v in flat.items():
        *parents, leaf = key.split(".")
        d = out
        for p in parents:
            d = d.setdefault(p, {})
        d[leaf] = v
    return out


_REPLACED = ("eval_scenarios",)
"""Tables that replace the base file's instead of merging into it (the selection suites are chosen as a whole)."""


def _merge(base, over):
    out = copy.deepcopy(base)
    for k, v in over.items():
        merge = isinstance(v, dict) and isinstance(out.get(k), dict) and k not in _REPLACED
        out[k] = _merge(out[k], v) if merge else copy.deepcopy(v)
    return out


def _flatten(d, prefix=""):
    out = {}
    for k, v in d.items():
        if isinstance(v, dict) and not (set(v) & set(DISTRIBUTIONS)):
            out.update(_flatten(v, f"{prefix}{k}."))
        else:
            out[f"{prefix}{k}"] = v
    return out


def load_sweep_config(path):
    """Read and check a sweep config. Returns a dict: ``name, algo, hp`` (base hyperparameters merged with
    ``[base]``), ``space`` (flat ``{dotted key: list | {dist: [lo, hi]}}``) and the ``[sweep]`` settings."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"sweep config {str(path)!r} does not exist")
    try:
        with open(path, "rb") as f:
            raw = tomllib.load(f)
    except tomllib.TOMLDecodeError as e:
        raise ValueError(f"{path}: not valid TOML ({e})") from None
    unknown = set(raw) - {"sweep", "base", "space"}
    if unknown:
        raise ValueError(f"{path}: unknown table(s) {sorted(unknown)}; valid: [sweep], [base], [space]")
    for table in ("sweep", "base", "space"):
        if not isinstance(raw.get(table, {}), dict):
            raise ValueError(f"{path}: {table} must be a table ([{table}]), got {raw[table]!r}")
    sw = dict(raw.get("sweep", {}))
    bad = set(sw) - _SWEEP_KEYS
    if bad:
        raise ValueError(f"{path}: unknown [sweep] key(s) {sorted(bad)}; valid: {sorted(_SWEEP_KEYS)}")
    method = sw.get("method", "ppo")
    if method not in ("ppo", "backprop"):
        raise ValueError(f"{path}: [sweep] method must be 'ppo' or 'backprop', got {method!r}")
    if method == "backprop" and "algo" in sw:
        raise ValueError(f"{path}: [sweep] algo applies to method = 'ppo' (SB3); method = 'backprop' has none")
    algo = "backprop" if method == "backprop" else sw.get("algo", "ppo")
    if algo not in ALGOS + ("backprop",):
        raise ValueError(f"{path}: [sweep] algo must be one of {ALGOS}, got {algo!r}")
    hp_file = sw.get("hyperparams")
    if hp_file is not None and not (isinstance(hp_file, str) and hp_file):
        raise ValueError(f"{path}: [sweep] hyperparams must name a TOML file, got {hp_file!r}")
    if hp_file is not None:
        cand = [path.parent / hp_file, HP_DIR / hp_file, Path(hp_file)]
        hp_file = next((c for c in cand if c.is_file()), None)
        if hp_file is None:
            raise ValueError(f"{path}: [sweep] hyperparams {sw['hyperparams']!r} not found (looked in "
                             f"{path.parent} and {HP_DIR})")
    search = sw.get("search", "grid")
    if search not in SEARCHES:
        raise ValueError(f"{path}: [sweep] search must be one of {SEARCHES}, got {search!r}")
    scheduler = sw.get("scheduler", "fifo")
    if scheduler not in SCHEDULERS:
        raise ValueError(f"{path}: [sweep] scheduler must be one of {SCHEDULERS}, got {scheduler!r}")
    for key, lo in (("num_samples", 1), ("cpus_per_trial", 1), ("grace_evals", 1), ("max_concurrent_trials", 1),
                    ("search_seed", 0)):
        v = sw.get(key)
        if v is not None and (not isinstance(v, int) or isinstance(v, bool) or v < lo):
            raise ValueError(f"{path}: [sweep] {key} must be an integer >= {lo}, got {v!r}")
    space = _flatten(raw.get("space", {}))
    if not space:
        raise ValueError(f"{path}: [space] is empty; give at least one searched key (e.g. seed = [0, 1])")
    for key, v in space.items():
        if isinstance(v, list):
            if not v:
                raise ValueError(f"{path}: [space] {key} is an empty list")
            continue
        if not (isinstance(v, dict) and len(v) == 1 and next(iter(v)) in DISTRIBUTIONS):
            raise ValueError(f"{path}: [space] {key} must be a list or one of {{{' | '.join(DISTRIBUTIONS)} = "
                             f"[lo, hi]}}, got {v!r}")
        (dist, bounds), = v.items()
        if not (isinstance(bounds, list) and len(bounds) == 2 and all(isinstance(b, (int, float)) for b in bounds)
                and bounds[0] < bounds[1] and (dist != "loguniform" or bounds[0] > 0)):
            raise ValueError(f"{path}: [space] {key}: {dist} needs [lo, hi] with lo < hi"
                             f"{' and lo > 0' if dist == 'loguniform' else ''}, got {bounds!r}")
        if search == "grid":
            raise ValueError(f"{path}: [space] {key}: search = 'grid' takes lists only (got {dist}); use "
                             "search = 'random' or 'optuna'")
    seeds = space.get("seed")
    if isinstance(seeds, list) and not all(isinstance(s, int) and not isinstance(s, bool) for s in seeds):
        raise ValueError(f"{path}: [space] seed must list integers (training seeds), got {seeds!r}")
    try:
        hp = _merge(load_hyperparams(algo, hp_file), _nest(raw.get("base", {})))
    except (AttributeError, TypeError):     # a dotted key into a value that is not a table
        raise ValueError(f"{path}: [base]: a dotted key reaches into a value that is not a table "
                         f"({sorted(raw.get('base', {}))})") from None
    scored = hp.get("eval_scenarios") or {"random": 0}
    missing = [n for n in hp.get("select_on") or () if n not in scored]
    if missing:
        raise ValueError(f"{path}: select_on names {missing}, which are not among the selection suites "
                         f"(eval_scenarios) {list(scored)}; set [base] select_on too")
    if hp.get("init_from"):
        hp["init_from"] = str(Path(hp["init_from"]).resolve())   # trials run in their own working directories
    try:
        check_plain_name("[sweep] name", sw.get("name", path.stem))
    except ValueError as e:
        raise ValueError(f"{path}: {e}") from None
    _check_trials(path, algo, hp, space)
    return {"name": sw.get("name", path.stem), "algo": algo, "hp": hp, "space": space, "search": search,
            "num_samples": sw.get("num_samples", 1), "search_seed": sw.get("search_seed", 0),
            "cpus_per_trial": sw.get("cpus_per_trial", 1), "max_concurrent_trials": sw.get("max_concurrent_trials"),
            "scheduler": scheduler, "grace_evals": sw.get("grace_evals", 2), "config_path": str(path.resolve())}


def _check_trials(path, algo, hp, space):
    """Every trial's hyperparameters checked as ``radar-track train`` checks them, before Ray starts: ``[base]``
    with each value of each ``[space]`` list and each distribution's bounds (a ``randint``'s as integers), and the
    training seeds; ``ValueError`` naming the config and the key."""
    from agents.training.train import TRAIN_SEEDS, check_train_hp
    cand = [("[base]", {})]
    for key, v in space.items():
        values = v if isinstance(v, list) else [
            int(b) if next(iter(v)) == "randint" else b for b in next(iter(v.values()))]
        if isinstance(v, dict) and next(iter(v)) == "randint" and not all(
                isinstance(b, int) and not isinstance(b, bool) for b in next(iter(v.values()))):
            raise ValueError(f"{path}: [space] {key}: randint needs integer bounds, got {next(iter(v.values()))!r}")
        cand += [(f"[space] {key} = {x!r}", {key: x}) for x in values]
    for where, over in cand:
        if "seed" in over:
            s = over["seed"]
            if isinstance(s, bool) or not isinstance(s, (int, float)) or s != int(s) or int(s) not in TRAIN_SEEDS:
                raise ValueError(f"{path}: {where}: a training seed must be an integer in {TRAIN_SEEDS}")
            continue
        try:
            check_train_hp(algo, _merge(hp, _nest(over)))
        except (ValueError, TypeError, AttributeError) as e:
            raise ValueError(f"{path}: {where}: {str(e).splitlines()[0]}") from None


def _param_space(cfg):
    from ray import tune
    out = {}
    for key, v in cfg["space"].items():
        if isinstance(v, list):
            out[key] = tune.grid_search(v) if cfg["search"] == "grid" else tune.choice(v)
        else:
            (dist, (lo, hi)), = v.items()
            out[key] = {"uniform": tune.uniform, "loguniform": tune.loguniform,
                        "randint": tune.randint}[dist](lo, hi)
    return out


def _trial(config, algo, hp, runs_dir, allow_pickle=False):
    """The Tune trainable: one training run, ``selection_ratio`` reported after every selection evaluation."""
    from ray import tune
    from agents.training.train import train
    config, hp = dict(config), dict(hp)
    seed = int(config.pop("seed", hp.pop("seed", 0)))
    trial_hp = _merge(hp, _nest(config))
    run_dir = Path(runs_dir) / tune.get_context().get_trial_name()

    def report(row):
        ratio = row[METRIC]
        if not math.isfinite(ratio):      # a broken run is an error, never a number
            raise ValueError(f"trial {run_dir.name}: non-finite {METRIC} {ratio!r} at {row['timesteps']} steps")
        tune.report({METRIC: float(ratio), "timesteps": int(row["timesteps"]), "run_dir": str(run_dir),
                     **{k: float(v) for k, v in row.items() if k.endswith("_ratio_imm2")}})

    summary = run_dir / "summary.json"
    if summary.is_file():
        # finished (renamed from '<trial>.partial') before Tune's last experiment save, then interrupted: on
        # restore, Tune restarts the trial; report its selection evaluations again instead of training anew
        # (train refuses a finished run folder, so the trial would fail on every retry)
        for row in json.loads(summary.read_text())["selection_history"]:
            report(row)
        return

    if algo == "backprop":
        from agents.training.backprop import train_backprop
        fit = train_backprop
    else:
        def fit(hp, **kw):
            return train(algo, hp, allow_pickle=allow_pickle, **kw)
    fit(trial_hp, seed=seed, out=run_dir.parent, progress=False, verbose=0, run_name=run_dir.name,
        command=f"radar-track sweep (trial {run_dir.name})", args={"sweep_config": config, "seed": seed},
        on_selection=report)


def _budget(algo, hp):
    """``(budget, between evaluations)`` of a trial, in the unit its selection rows count as ``timesteps``: env steps
    for SB3, optimiser steps for backprop."""
    if algo == "backprop":
        return int(hp.get("n_steps", 1)), int(hp.get("eval_every", 1))
    return int(hp.get("n_timesteps", 1_000_000)), int(hp.get("eval_freq", 100_000))


def _trial_name(trial):
    return f"trial_{trial.trial_id}"


def _scheduler(cfg):
    if cfg["scheduler"] != "asha":
        return None
    from ray.tune.schedulers import ASHAScheduler
    budget, every = _budget(cfg["algo"], cfg["hp"])
    n_evals = max(1, math.ceil(budget / every))
    return ASHAScheduler(time_attr="training_iteration", max_t=n_evals + 1, grace_period=cfg["grace_evals"])


def _search_alg(cfg):
    if cfg["search"] == "optuna":
        from ray.tune.search.optuna import OptunaSearch
        return OptunaSearch(seed=cfg["search_seed"])
    if cfg["search"] == "random":
        from ray.tune.search import BasicVariantGenerator
        return BasicVariantGenerator(random_state=cfg["search_seed"])
    return None


def results_table(result_grid, space_keys, n_timesteps, early_stopping=True, interrupted=False,
                  policy_file="policy.zip"):
    """One row per trial, best ``selection_ratio`` first (errored trials last, with their error). ``status``:
    ``done`` (reached ``n_timesteps``), ``error``, ``stopped early`` (stopped by an early-stopping scheduler:
    ``early_stopping`` and not ``interrupted``) or ``unfinished`` (an interrupted sweep's trial: run the same
    command again to resume it). ``best_policy`` is the trial's ``best/<policy_file>``."""
    # a trial TERMINATED short of n_timesteps: an early stop only under an early-stopping scheduler and without
    # an interrupt (Tune ends an interrupted trial TERMINATED too)
    trials = getattr(getattr(result_grid, "_experiment_analysis", None), "trials", None) or []
    states = [t.status for t in trials] if len(trials) == len(result_grid) else [None] * len(result_grid)
    rows = []
    for r, state in zip(result_grid, states):
        m = r.metrics or {}
        row = {"trial": (Path(m["run_dir"]).name if m.get("run_dir") else Path(r.path).name)}
        row.update({k: r.config.get(k) for k in space_keys})
        df = r.metrics_dataframe
        if df is not None and METRIC in df and len(df):
            i = df[METRIC].idxmin()
            row.update(best_selection_ratio=float(df[METRIC][i]), best_at_timesteps=int(df["timesteps"][i]),
                       last_selection_ratio=float(df[METRIC].iloc[-1]), timesteps=int(df["timesteps"].iloc[-1]),
                       evals=int(len(df)))
        else:
            row.update(best_selection_ratio=None, best_at_timesteps=None, last_selection_ratio=None, timesteps=None,
                       evals=0)
        finished = (row["timesteps"] or 0) >= n_timesteps
        stopped = early_stopping and not interrupted and state == "TERMINATED"
        row["status"] = ("error" if r.error else "done" if finished else "stopped early" if stopped else "unfinished")
        row["error"] = None if r.error is None else str(r.error).strip().splitlines()[-1][:200]
        row["best_policy"] = None
        if m.get("run_dir"):    # a trial stopped early or interrupted keeps its run in '<trial>.partial' (agents.training.train)
            d = Path(m["run_dir"])
            d = d if d.is_dir() or not d.with_name(d.name + ".partial").is_dir() else d.with_name(d.name + ".partial")
            row["best_policy"] = str(d / "best" / policy_file)
        rows.append(row)
    rows.sort(key=lambda r: (r["best_selection_ratio"] is None, r["best_selection_ratio"] or 0.0, r["trial"]))
    return rows


def format_results(rows):
    if not rows:
        return "(no trials)"
    cols = [c for c in rows[0] if c not in ("error", "best_policy")]
    def fmt(c, v):
        if v is None:
            return "-"
        if isinstance(v, float):
            return f"{v:.4f}" if c.endswith("selection_ratio") else f"{v:.4g}"
        return str(v)
    cells = [[fmt(c, r[c]) for c in cols] for r in rows]
    w = [max(len(c), *(len(x[i]) for x in cells)) for i, c in enumerate(cols)]
    lines = ["  ".join(c.rjust(w[i]) for i, c in enumerate(cols))]
    lines += ["  ".join(x[i].rjust(w[i]) for i in range(len(cols))) for x in cells]
    return "\n".join(lines)


class _Interrupts(logging.Handler):
    """Whether SIGINT (or SIGUSR1) stopped ``Tuner.fit``. Tune catches the first one itself: it stops the trials,
    saves the experiment and returns normally, telling only its log ("Stop signal received ..."), which this
    handler listens to on Tune's logger; a second SIGINT (skipping Tune's save) raises KeyboardInterrupt through
    the handler in place before (Python's default). The trials' statuses alone cannot tell: Tune ends interrupted
    trials as TERMINATED, the status an early-stopping scheduler gives."""

    def __init__(self):
        super().__init__(level=logging.WARNING)
        self.seen = False
        self.tune_logger = logging.getLogger("ray.tune.tune")

    def emit(self, record):
        if "Stop signal received" in record.getMessage() or "has been interrupted" in record.getMessage():
            self.seen = True

    def __enter__(self):
        self.tune_logger.addHandler(self)
        return self

    def __exit__(self, *exc):
        self.tune_logger.removeHandler(self)
        return False


def resume_command(config_path, out, address=None, num_cpus=None, allow_pickle=False):
    """The command line that resumes a sweep (the same command)."""
    cmd = ["radar-track", "sweep", str(config_path), "--out", str(out)] + (["--allow-pickle"] if allow_pickle else [])
    if address:
        cmd += ["--address", address]
    if num_cpus is not None:
        cmd += ["--num-cpus", str(num_cpus)]
    return " ".join(shlex.quote(c) for c in cmd)


def run_sweep(config_path, out="sweeps", address=None, num_cpus=None, verbose=1, return_state=False,
              allow_pickle=False):
    """Run (or resume) the sweep of ``config_path``. Returns ``(rows, experiment_dir)`` (``return_state``: and
    whether the sweep was interrupted by SIGINT); the table is also written as ``results.csv`` and
    ``results.json`` in ``experiment_dir`` (by renaming: a link there is replaced, not followed). Ray errors are
    a ``ValueError`` of one line naming Ray's log folder."""
    cfg = load_sweep_config(config_path)
    if cfg["hp"].get("init_from") and not allow_pickle:     # refused before Ray starts, not in every trial
        from agents.policies.checks import refuse_pickle
        raise ValueError(f"{config_path}: init_from: {refuse_pickle(cfg['hp']['init_from'])}")
    # here, not at the top: --help answers without Ray
    from agents.evaluation.parallel import ray_error_line, ray_session, require_ray
    ray = require_ray("radar-track sweep")
    from ray import tune
    exp_dir = Path(out).resolve() / cfg["name"]
    runs_dir = exp_dir / "runs"
    trainable = tune.with_resources(
        tune.with_parameters(_trial, algo=cfg["algo"], hp=cfg["hp"], runs_dir=str(runs_dir),
                             allow_pickle=allow_pickle),
        {"cpu": cfg["cpus_per_trial"]})
    trials = {k: cfg[k] for k in ("algo", "hp", "space", "search", "num_samples", "search_seed", "scheduler",
                                  "grace_evals")}
    trials = json.loads(json.dumps(trials))             # as the file holds it (tuples as lists)
    record = exp_dir / "sweep_config.json"
    if tune.Tuner.can_restore(str(exp_dir)) and record.is_file():
        # Tune restores the experiment's own search space: a changed config under the same name would run the old
        # trials with the new base hyperparameters
        old = json.loads(record.read_text())
        diff = sorted(k for k in set(old) | set(trials) if old.get(k) != trials.get(k))
        if diff:
            raise ValueError(f"{exp_dir} holds the sweep [sweep] name = {cfg['name']!r} started with another "
                             f"config (it differs in {diff}); resume it with its own config, or give a new [sweep] "
                             "name or --out")
    with ray_session(address, num_cpus, "radar-track sweep"):
        if tune.Tuner.can_restore(str(exp_dir)):
            if verbose:
                print(f"resuming the sweep in {exp_dir} (finished trials are kept)", file=sys.stderr)
            tuner = tune.Tuner.restore(str(exp_dir), trainable, resume_unfinished=True, restart_errored=True)
        else:
            tuner = tune.Tuner(
                trainable, param_space=_param_space(cfg),
                tune_config=tune.TuneConfig(metric=METRIC, mode="min", num_samples=cfg["num_samples"],
                                            search_alg=_search_alg(cfg), scheduler=_scheduler(cfg),
                                            max_concurrent_trials=cfg["max_concurrent_trials"],
                                            trial_name_creator=_trial_name, trial_dirname_creator=_trial_name),
                run_config=tune.RunConfig(name=cfg["name"], storage_path=str(exp_dir.parent), verbose=verbose))
            exp_dir.mkdir(parents=True, exist_ok=True)
            record.write_text(json.dumps(trials, indent=1))
        with _Interrupts() as sigint:
            try:
                grid = tuner.fit()
            except (ray.exceptions.RayError, tune.TuneError) as e:
                raise ValueError(ray_error_line(e, "the sweep")) from None
        interrupted = sigint.seen
    rows = results_table(grid, list(cfg["space"]), _budget(cfg["algo"], cfg["hp"])[0],
                         early_stopping=cfg["scheduler"] == "asha", interrupted=interrupted,
                         policy_file="policy.npz" if cfg["algo"] == "backprop" else "policy.zip")
    from radar_env.common.files import write_text_replacing    # here: --help imports nothing slow
    exp_dir.mkdir(parents=True, exist_ok=True)
    write_text_replacing(exp_dir / "results.json", json.dumps(
        {"config": cfg["config_path"], "metric": METRIC, "mode": "min", "interrupted": interrupted, "trials": rows},
        indent=1))
    buf = io.StringIO(newline="")
    w = csv.DictWriter(buf, fieldnames=list(rows[0]) if rows else ["trial"])
    w.writeheader()
    w.writerows(rows)
    write_text_replacing(exp_dir / "results.csv", buf.getvalue())
    return (rows, exp_dir, interrupted) if return_state else (rows, exp_dir)


def build_parser(prog="radar-track sweep"):
    ap = argparse.ArgumentParser(prog=prog, description="Seed and hyperparameter sweeps of 'radar-track train' on "
                                 "Ray Tune (grid, random or Optuna search; optional ASHA early stopping); run the "
                                 "same command again to resume.")
    ap.add_argument("config", nargs="?", default=str(EXAMPLE_CONFIG), metavar="CONFIG.toml",
                    help="sweep config TOML: the trials (seeds, hyperparameter grid or search space), their budget "
                         "in env steps and the metric (default: the example, "
                         f"{EXAMPLE_CONFIG.relative_to(Path(__file__).parents[2])})")
    ap.add_argument("--out", default="sweeps", metavar="DIR",
                    help="parent folder of the experiment folder (default: ./sweeps)")
    ap.add_argument("--address", metavar="HOST:PORT",
                    help="Ray cluster, e.g. 127.0.0.1:6379 (default: RAY_ADDRESS if set, else an embedded local Ray)")
    ap.add_argument("--num-cpus", type=int, metavar="N",
                    help="CPUs of the embedded local Ray, >= 1 (default: all of the machine's)")
    ap.add_argument("--quiet", action="store_true",
                    help="only the final table: no status lines, no per-trial reports (default: print them)")
    ap.add_argument("--allow-pickle", action="store_true",
                    help="let the config's init_from (a stable-baselines3 zip, a pickle) be unpickled: this runs "
                         "the code inside; only for files you trust (default: refused, in one line)")
    return ap


def main(argv=None, prog="radar-track sweep"):
    args = build_parser(prog).parse_args(argv)
    if args.num_cpus is not None and args.num_cpus < 1:
        raise SystemExit(f"error: --num-cpus must be >= 1, got {args.num_cpus}")
    from radar_env.common.files import check_output_dir
    try:
        if not str(args.out).strip():
            raise ValueError("--out: an empty path; give a folder name")
        check_output_dir("--out", Path(args.out))      # before Ray starts: a file there fails only at the end
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    resume = resume_command(args.config, args.out, args.address, args.num_cpus, args.allow_pickle)
    if not args.quiet:      # before Ray, torch and the env are imported
        print(f"radar-track sweep: {args.config}; starting Ray (the trials import torch and the env) ...",
              file=sys.stderr, flush=True)
    try:
        rows, exp_dir, interrupted = run_sweep(args.config, args.out, args.address, args.num_cpus,
                                               verbose=0 if args.quiet else 1, return_state=True,
                                               allow_pickle=args.allow_pickle)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    except OSError as e:        # a full disk: what and where; finished trials stay in their run folders
        raise SystemExit(f"error: could not write {e.filename or args.out} ({e.strerror or e}); finished trials "
                         f"are kept; free space and resume with: {resume}") from None
    except KeyboardInterrupt:      # a second SIGINT: Tune's last save was skipped, its periodic one is there
        raise SystemExit(f"error: interrupted; resume with: {resume}") from None
    print(format_results(rows))
    print(f"\nresults: {exp_dir / 'results.csv'} and results.json; run folders in {exp_dir / 'runs'}/")
    unfinished = sum(r["status"] == "unfinished" for r in rows)
    if interrupted:
        raise SystemExit(f"error: interrupted: {unfinished} of {len(rows)} trials unfinished (finished ones are "
                         f"kept); resume with: {resume}")
    if unfinished:
        print(f"({unfinished} unfinished trials: resume with: {resume})")
    failed = [r for r in rows if r["status"] == "error"]
    if failed:
        raise SystemExit(f"error: {len(failed)} of {len(rows)} trials failed (first: {failed[0]['trial']}: "
                         f"{failed[0]['error']}); run the same command again to retry them")
    return rows


if __name__ == "__main__":
    main(prog="python -m agents.training.sweep")
