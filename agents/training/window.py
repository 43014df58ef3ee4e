"""Training a window correction by regression: ``radar-track train --method window``.

A window correction (:mod:`agents.policies.window_correction`) moves a base tracker's reported position by what an
MLP reads in the last plots. Its target is known at every look of a simulated flight (the truth), and its input
depends on the base tracker only (there is no feedback), so training is plain supervised regression: run the base
tracker once over the training flights, build every look's inputs and the truth's offset from the base estimate (in
the base's frame, in ``scale_m``), and fit the MLP by Adam on the squared offset error (float64 torch, one thread).
``standardise_inputs`` trains on inputs scaled by their mean and sd over the training looks (folded into the first
layer when saved, :func:`_weights`); ``weight_suites`` weighs each suite's looks by 1 / the base's mean squared error
there, so every suite counts alike.

Flights: ``episodes`` of each suite in ``scenarios`` (the random generators), suite ``s``'s flight ``i`` drawn as
the evaluation draws run ``i`` of a suite (:func:`agents.evaluation.suites.draw_suite`) with base seed ``S`` (the
training seed): seeds ``S .. S + episodes - 1``, inside the training range below the selection suites' 900_000.
Looks scored are those the evaluation scores (after the common track start, the first look excluded). ``mirror``
adds every look reflected across the base track (a right turn for each left turn; the inputs' and the target's
across components change sign). Validation every ``eval_every`` epochs and at the end, as every trainer's
(:class:`agents.training.selection.SelectionSuites`: training-range seeds 900_000 + i, policy / imm2 RMSE ratio,
geometric mean over ``select_on``); the base's runs on the validation flights are computed once.

The run folder, as ``radar-track train``'s: ``config.json``, ``args.json``, ``command.txt``, ``env_config.json``
(the base's), ``policy.npz`` + ``policy.json`` (the final weights, kind ``window_correction``), ``best/`` (the best
validation epoch, with ``selection.json``), ``training.json`` + ``choice.json`` in both, ``summary.json``. A run
that fails or is interrupted stays ``<name>.partial/`` and starts again from scratch (a run takes minutes).
"""

from __future__ import annotations

import json
import os
import shlex
import sys
import time
from pathlib import Path

import numpy as np

from agents.training.runs import (TRAIN_SCENARIOS, apply_cli_overrides, load_hyperparams, run_cli, run_paths,
                                  write_run_files, writing_run)
from agents.training.selection import SELECTION_SEED_BASE, SelectionSuites, pooled_rmse

__all__ = ["HP_KEYS", "check_hp", "training_looks", "train_window", "main_from_args"]

HP_KEYS = ("base", "window_looks", "layers", "scale_m", "episodes", "scenarios", "mirror", "standardise_inputs",
           "weight_suites", "epochs", "learning_rate", "batch_looks", "eval_every", "eval_scenarios", "select_on")
"""Every key of ``agents/training/hyperparams/window.toml``; all required."""


def _int_in(hp, key, lo, hi):
    v = hp[key]
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise ValueError(f"--hp {key}: must be an integer in [{lo}, {hi}], got {v!r}")


def _num_in(hp, key, lo, hi):
    v = hp[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo < v <= hi):
        raise ValueError(f"--hp {key}: must be a number in ({lo}, {hi}], got {v!r}")


def check_hp(hp):
    """The hyperparameters checked (``ValueError`` naming the key and its range) and the base loaded:
    ``(hp, base)`` with ``base`` a :class:`agents.policies.learned.LearnedTracker`."""
    from agents.policies.layout import IMM_KINDS, Q_POLICY_KINDS
    from agents.policies.learned import load_learned
    missing = [k for k in HP_KEYS if k not in hp]
    unknown = sorted(set(hp) - set(HP_KEYS))
    if missing or unknown:
        raise ValueError(f"--hp: window hyperparameters missing {missing}, unknown {unknown} (every key of "
                         "agents/training/hyperparams/window.toml is required)")
    _int_in(hp, "window_looks", 1, 64)
    _int_in(hp, "episodes", 1, 200_000)
    _int_in(hp, "epochs", 1, 10_000)
    _int_in(hp, "batch_looks", 1, 1 << 20)
    _int_in(hp, "eval_every", 1, 10_000)
    _num_in(hp, "scale_m", 0.0, 1e6)
    _num_in(hp, "learning_rate", 0.0, 1.0)
    layers = hp["layers"]
    if (not isinstance(layers, list) or not 1 <= len(layers) <= 4
            or not all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= 1024 for h in layers)):
        raise ValueError(f"--hp layers: must be a list of 1-4 integer widths in [1, 1024], got {layers!r}")
    sc = hp["scenarios"]
    if not isinstance(sc, list) or not sc or any(s not in TRAIN_SCENARIOS for s in sc) or len(set(sc)) != len(sc):
        raise ValueError(f"--hp scenarios: a list of distinct training generators from {list(TRAIN_SCENARIOS)}, "
                         f"got {sc!r}")
    for key in ("mirror", "standardise_inputs", "weight_suites"):
        if not isinstance(hp[key], bool):
            raise ValueError(f"--hp {key}: must be true or false, got {hp[key]!r}")
    if not isinstance(hp["base"], str) or not hp["base"]:
        raise ValueError(f"--hp base: a bundled learned tracker's name or a learned-tracker folder, got {hp['base']!r}")
    try:
        base = load_learned(hp["base"], kinds=Q_POLICY_KINDS + IMM_KINDS)
    except ValueError as e:
        raise ValueError(f"--hp base: {e}") from None
    return hp, base


def training_looks(base, episodes, window_looks, scale_m):
    """The base tracker on ``episodes`` and every scored look's inputs and target: ``(F (n, features), Y (n, 2))``
    with ``Y`` the truth's offset from the base estimate along and across its velocity, in ``scale_m``."""
    from agents.evaluation.metrics import region_masks
    from agents.policies.window_correction import window_features
    from radar_env.sim.episode import stack_episodes
    batch = stack_episodes(episodes)
    run = base.run(episodes)
    F, ca, sa = window_features(batch.t_s, batch.z_m, batch.R_m2, batch.detected, run.x, run.P, window_looks,
                                scale_m)
    dx = batch.truth[..., 0] - run.x[..., 0]
    dy = batch.truth[..., 1] - run.x[..., 1]
    Y = np.stack([dx * ca + dy * sa, -dx * sa + dy * ca], -1) / scale_m
    used = region_masks(batch, run.start_index)["used"] & np.isfinite(F).all(-1) & np.isfinite(Y).all(-1)
    return F[used], Y[used]


def mirrored(F, Y, window_looks):
    """``(F, Y)`` reflected across the track: every across component (the window's residuals and the target's)
    changes sign."""
    F, Y = F.copy(), Y.copy()
    F[:, 1:4 * window_looks:4] *= -1
    Y[:, 1] *= -1
    return F, Y


def _net(torch, n_in, layers):
    mods, w = [], n_in
    for h in layers:
        mods += [torch.nn.Linear(w, h), torch.nn.Tanh()]
        w = h
    out = torch.nn.Linear(w, 2)
    with torch.no_grad():        # start near "no correction"
        out.weight.mul_(0.01)
        out.bias.zero_()
    return torch.nn.Sequential(*mods, out).double()


def _weights(net, layers, mean=None, sd=None):
    """The MLP's weights under :func:`agents.policies.window_correction.network_shapes`' names. A net trained on
    standardised inputs ``(F - mean) / sd`` has the standardisation folded into its first layer
    (``W / sd``, ``b - W (mean / sd)``), so the saved correction reads the raw inputs as every correction does."""
    lin = [m for m in net if hasattr(m, "weight")]
    w = {}
    for i in range(len(layers)):
        w[f"layer.{i}.weight"] = lin[i].weight.detach().numpy().copy()
        w[f"layer.{i}.bias"] = lin[i].bias.detach().numpy().copy()
    w["out.weight"], w["out.bias"] = lin[-1].weight.detach().numpy().copy(), lin[-1].bias.detach().numpy().copy()
    if mean is not None:
        W = w["layer.0.weight"]
        w["layer.0.bias"] = w["layer.0.bias"] - W @ (mean / sd)
        w["layer.0.weight"] = W / sd
    return w


def input_standardisation(F):
    """Per-input mean and standard deviation of the training looks ``F`` (an input constant over them, such as the
    detection flags of a suite without misses, keeps sd 1)."""
    mean, sd = F.mean(0), F.std(0)
    return mean, np.where(sd > 1e-6, sd, 1.0)


def _base_field(base_name, folder):
    """``policy.json``'s ``base``: a bundled name as given, a folder relative to the saved correction's folder."""
    from agents.policies.learned import BUNDLED_LEARNED
    if base_name in BUNDLED_LEARNED:
        return base_name
    return os.path.relpath(Path(base_name).resolve(), Path(folder).resolve())


def _save(folder, hp, weights, env_kwargs, extra=None):
    from agents.policies.window_correction import feature_count, save_window_correction
    config = {"base": _base_field(hp["base"], folder), "window_looks": hp["window_looks"], "scale_m": hp["scale_m"],
              "architecture": {"input_size": feature_count(hp["window_looks"]), "layers": list(hp["layers"])}}
    save_window_correction(folder, weights, config, env_kwargs)
    if extra is not None:
        (Path(folder) / "selection.json").write_text(json.dumps(extra, indent=1, allow_nan=False))


def train_window(hp, seed=0, out="runs", verbose=1, command=None, args=None, run_name=None):
    """Train a window correction (module docstring) with hyperparameters ``hp`` (every key of
    ``agents/training/hyperparams/window.toml``). Returns the run folder. Everything is checked (``ValueError``)
    before the run folder is made."""
    import torch
    from agents.evaluation.metrics import jsonable
    from agents.evaluation.suites import draw_suite
    from agents.policies.window_correction import WindowCorrection
    from agents.policies.learned import read_kind, write_run_layout
    torch.set_num_threads(1)
    import numba
    numba.set_num_threads(1)
    hp, base = check_hp(dict(hp))
    seed = int(seed)
    if not 0 <= seed or seed + hp["episodes"] > SELECTION_SEED_BASE:
        raise ValueError(f"--seed: the training flights' seeds {seed}..{seed + hp['episodes'] - 1} must lie in "
                         f"[0, {SELECTION_SEED_BASE}) (below the selection suites' seeds)")
    try:
        selection = SelectionSuites(hp["eval_scenarios"], SELECTION_SEED_BASE, hp["select_on"])
    except ValueError as e:
        raise ValueError(f"--hp eval_scenarios / select_on: {e}") from None
    env_kwargs = json.loads((base.folder / "env_config.json").read_text())
    run, part = run_paths(out, run_name, f"window_s{seed}_{time.strftime('%Y%m%d-%H%M%S')}")
    config = {"method": "window", "env_id": "RadarTrack-v0", "seed": seed, **hp}
    with writing_run(run, part, resumable=False):
        write_run_files(part, config, args, command, env_kwargs)
        t0 = time.time()
        K, scale = hp["window_looks"], float(hp["scale_m"])
        Fs, Ys, Ws = [], [], []
        for name in hp["scenarios"]:
            n0 = len(Fs)
            for c0 in range(0, hp["episodes"], 500):       # chunks: the base's runs stay a few hundred MB
                eps = draw_suite(name, min(500, hp["episodes"] - c0), seed=seed + c0)
                F, Y = training_looks(base, eps, K, scale)
                Fs.append(F)
                Ys.append(Y)
            # weight_suites: every suite's looks weigh 1 / (the base's mean squared error there), so a suite of long
            # ranges and large errors (random_radars) does not drown the others in the pooled squared error
            mse = float(np.mean(np.concatenate([(y ** 2).sum(-1) for y in Ys[n0:]]))) if hp["weight_suites"] else 1.0
            Ws += [np.full(len(y), 1.0 / mse) for y in Ys[n0:]]
        F, Y, Wl = np.concatenate(Fs), np.concatenate(Ys), np.concatenate(Ws)
        Wl /= Wl.mean()
        del Fs, Ys, Ws
        if hp["mirror"]:
            Fm, Ym = mirrored(F, Y, K)
            F, Y, Wl = np.concatenate([F, Fm]), np.concatenate([Y, Ym]), np.concatenate([Wl, Wl])
        mean, sd = input_standardisation(F) if hp["standardise_inputs"] else (None, None)
        data_s = time.time() - t0
        if verbose:
            print(f"{len(F):,} training looks ({data_s:.0f} s)", file=sys.stderr, flush=True)
        # the validation flights: the base runs once (and is scored once), the correction is applied to its runs at
        # every validation
        val = {}
        for n, (eps, batch, imm) in selection.suites.items():
            brun = base.run(eps)
            val[n] = (batch, brun, imm, pooled_rmse(batch, brun) / imm)
        torch.manual_seed(seed)
        gen = torch.Generator().manual_seed(seed)
        net = _net(torch, F.shape[1], hp["layers"])
        opt = torch.optim.Adam(net.parameters(), lr=hp["learning_rate"])
        sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, hp["epochs"])
        Ft = torch.from_numpy(F if mean is None else (F - mean) / sd)
        Yt, Wt = torch.from_numpy(Y), torch.from_numpy(Wl)
        del F
        history, best = [], None

        def validate(epoch, train_rmse_m):
            wc = WindowCorrection(_weights(net, hp["layers"], mean, sd), {**config, "architecture": {
                "input_size": Ft.shape[1], "layers": hp["layers"]}}, base.policy, base.env_config)
            row = {"epoch": epoch, "train_rmse_m": train_rmse_m}
            for n, (batch, brun, imm, base_ratio) in val.items():
                r = pooled_rmse(batch, wc.correct(batch, brun, "window"))
                row[f"{n}_rmse_m"], row[f"{n}_ratio_imm2"] = r, r / imm
                row[f"{n}_base_ratio_imm2"] = base_ratio
            row["selection_ratio"] = float(np.exp(np.mean([np.log(row[f"{n}_ratio_imm2"])
                                                           for n in selection.select_on])))
            row["wall_s"] = time.time() - t0
            return row

        for epoch in range(1, hp["epochs"] + 1):
            perm = torch.randperm(len(Ft), generator=gen)
            total = 0.0
            for i in range(0, len(Ft), hp["batch_looks"]):
                idx = perm[i:i + hp["batch_looks"]]
                se = ((net(Ft[idx]) - Yt[idx]) ** 2).sum(-1)
                loss = (Wt[idx] * se).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += float(se.detach().sum())
            sched.step()
            if epoch % hp["eval_every"] == 0 or epoch == hp["epochs"]:
                row = validate(epoch, float(np.sqrt(total / len(Ft))) * scale)
                history.append(row)
                if best is None or row["selection_ratio"] < best["selection_ratio"]:
                    best = row
                    _save(part / "best", hp, _weights(net, hp["layers"], mean, sd), env_kwargs, jsonable(row))
                if verbose:
                    print(f"epoch {epoch}: train {row['train_rmse_m']:.1f} m, selection ratio "
                          f"{row['selection_ratio']:.4f} (base " + ", ".join(
                              f"{n} {row[f'{n}_base_ratio_imm2']:.3f} -> {row[f'{n}_ratio_imm2']:.3f}"
                              for n in val) + f") {row['wall_s']:.0f} s", file=sys.stderr, flush=True)
        _save(part, hp, _weights(net, hp["layers"], mean, sd), env_kwargs)
        summary = {"epochs": hp["epochs"], "training_looks": len(Ft), "data_s": data_s, "wall_s": time.time() - t0,
                   "best_selection_ratio": best["selection_ratio"], "best_epoch": best["epoch"],
                   "selection_history": history, "steps": hp["epochs"]}
        (part / "summary.json").write_text(json.dumps(jsonable(summary), indent=1, allow_nan=False))
        write_run_layout(part, read_kind(part)[0], jsonable(summary))
    if verbose:
        print(f"run: {run}\nbest selection ratio {best['selection_ratio']:.4f} at epoch {best['epoch']} "
              f"({time.time() - t0:.0f} s)", file=sys.stderr)
    return run


def main_from_args(args, argv):
    """``radar-track train --method window`` (called by :func:`agents.training.train.main`). Returns the run
    folder."""
    for opt, v in (("--algo", args.algo), ("--action-type", args.action_type), ("--timesteps", args.timesteps),
                   ("--n-envs", args.n_envs), ("--tracker", args.tracker)):
        if v is not None:
            raise SystemExit(f"error: {opt} does not apply to --method window (its settings: --hp KEY=VALUE, "
                             "agents/training/hyperparams/window.toml)")
    if args.env_kwargs not in (None, "{}"):
        raise SystemExit("error: --env-kwargs does not apply to --method window (the base tracker's env config is "
                         "used; the flights are --hp scenarios)")
    try:
        hp = load_hyperparams("window", args.hyperparams)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    hp = apply_cli_overrides(hp, "{}", args.hp)
    hp.pop("env_kwargs", None)
    command = " ".join(["radar-track", "train", *map(shlex.quote, argv)])
    return run_cli(lambda: train_window(hp, seed=args.seed, out=args.out, verbose=0 if args.quiet else 1,
                                        command=command, args=vars(args), run_name=args.name), command, args.out)
