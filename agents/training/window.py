"""Training a window correction by regression: ``radar-track train --method window``.

A window correction (:mod:`agents.policies.window_correction`) moves a base tracker's reported position by what an
MLP reads in the last plots. Its target is known at every look of a simulated flight (the truth), and its input
depends on the base tracker only (there is no feedback), so training is plain supervised regression: run the base
tracker once over the training flights, build every look's inputs and the truth's offset from the base estimate (in
the base's frame, in ``scale_m``), and fit the MLP by Adam on the squared offset error (torch, one thread; float64,
or float32 with ``dtype``).
``standardise_inputs`` trains on inputs scaled by their mean and sd over the training looks (folded into the first
layer when saved, :func:`_weights`); ``weight_suites`` weighs each suite's looks by 1 / the base's mean squared error
there, so every suite counts alike.

Flights: ``episodes`` of each suite in ``scenarios`` (the random generators; or a table of each suite's count,
:func:`suite_episodes`), suite ``s``'s flight ``i`` drawn as the evaluation draws run ``i`` of a suite
(:func:`agents.evaluation.suites.draw_suite`) with base seed ``S`` (the training seed): seeds ``S .. S + n_s - 1``
(``n_s`` the suite's count), inside the training range below the selection suites' 900_000;
their generator's ``first_leg_min_s`` is the hyperparameter's (:func:`training_config`; 0: a flight can turn during
its track start, so the network learns little of where flights begin: only that a first leg lasts 30 s or more).
A suite may also be a broad version of a random generator (:data:`BROAD_SCENARIOS`, ``random_broad`` and
``random_radars_broad``: the backprop recipe's broad flights, :func:`broad_config`), its flights at seeds
``S + BROAD_SEED_OFFSET ..``.
With ``fresh_flights_every`` = ``e`` > 0 the flights are drawn afresh every ``e`` epochs: draw ``d`` (epochs
``d e + 1 ..``) takes seeds ``S + d M ..`` (:func:`flight_draws`; ``M`` the largest count), every draw inside the
training range; the input standardisation is the first draw's, the suite weights each draw's own, and the covariance
head is fitted on the last draw's looks.
Looks scored are those the evaluation scores (after the common track start, the first look excluded). ``mirror``
adds every look reflected across the base track (a right turn for each left turn; the inputs' and the target's
across components change sign). Validation every ``eval_every`` epochs and at the end, as every trainer's
(:class:`agents.training.selection.SelectionSuites`: training-range seeds 900_000 + i, policy / imm2 RMSE ratio,
geometric mean over ``select_on``); the base's runs on the validation flights are computed once.

The run folder, as ``radar-track train``'s: ``config.json``, ``args.json``, ``command.txt``, ``env_config.json``
(the base's), ``policy.npz`` + ``policy.json`` (the final weights, kind ``window_correction``), ``best/`` (the best
validation epoch, with ``selection.json``), ``training.json`` + ``choice.json`` in both, ``summary.json``; with
``covariance_epochs`` > 0 the covariance head is fitted after the epochs for both weights (:func:`fit_covariance_head`,
``covariance.json`` beside each and in ``summary.json``; :func:`add_covariance` does it for a finished run). A run
that fails or is interrupted stays ``<name>.partial/`` with its last validation's checkpoint
(``checkpoints/last.npz`` + ``last.json``: the network, Adam's moments, the batch order's generator, the
standardisation, the best epoch's weights; no pickle); the same command resumes it from there, to the numbers of a
run never stopped (``summary.json``'s ``resumed_at`` lists the epochs it resumed after), and refuses a run folder of
another configuration.

Memory: the run holds the drawn looks only; each batch makes its mirrored looks from them (:func:`training_batch`)
and the standardisation covers them without making them (:func:`input_standardisation` with ``signs``), the numbers
of the mirrored arrays to the bit. Four suites of 4,000 flights (24-look windows, 160 inputs): 4.6 M drawn looks,
5.5 GiB of inputs, 6.8 GiB resident in training, against 12.8 GiB with the mirrored arrays. A covariance head
(``covariance_epochs``) draws the last draw's looks again at the end with their mirror made, twice that.
"""

from __future__ import annotations

import hashlib
import json
import os
import shlex
import sys
import time
from pathlib import Path

import numba
import numpy as np

from agents.training.runs import (CHECKPOINT_ERRORS, EVAL_SCENARIOS_HP, SELECT_ON_HP, TRAIN_SCENARIOS, adam_arrays,
                                  apply_cli_overrides, checkpoint_refusal, load_adam, load_hyperparams, resumable,
                                  run_cli, run_paths, write_checkpoint, write_run_files, writing_run)
from agents.training.selection import SELECTION_SEED_BASE, SelectionSuites, pooled_rmse

__all__ = ["HP_KEYS", "COV_SCALE_M_S", "check_hp", "training_looks", "training_flights", "draw_training_looks",
           "suite_episodes", "mirror_signs", "training_batch", "input_standardisation", "unfold_standardisation",
           "fit_covariance_head", "covariance_scale_fit", "add_covariance", "train_window", "main_from_args"]

COV_SCALE_M_S = 30.0
"""The velocity unit of the covariance head (m/s), written to ``policy.json`` as ``scale_m_s``."""
COV_LEARNING_RATE = 1e-2
COV_BATCH_LOOKS = 4096

HP_KEYS = ("base", "window_looks", "fit_looks", "q_looks", "layers", "scale_m", "episodes", "scenarios",
           "first_leg_min_s", "mirror", "standardise_inputs", "weight_suites", "epochs", "learning_rate",
           "batch_looks", "eval_every", "eval_scenarios", "select_on", "covariance_epochs", "fresh_flights_every",
           "dtype", "init")
"""Every key of ``agents/training/hyperparams/window.toml``; all required but ``init`` (default ``""``: random
weights)."""


def _int_in(hp, key, lo, hi):
    v = hp[key]
    if not isinstance(v, int) or isinstance(v, bool) or not lo <= v <= hi:
        raise ValueError(f"--hp {key}: must be an integer in [{lo}, {hi}], got {v!r}")


def _num_in(hp, key, lo, hi):
    v = hp[key]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not (lo < v <= hi):
        raise ValueError(f"--hp {key}: must be a number in ({lo}, {hi}], got {v!r}")


TRAIN_DTYPES = ("float64", "float32")
"""The network's precision in training (``dtype``): float32 steps about twice as fast on the CPU; the inputs, the
standardisation, the saved weights and everything after training stay float64."""


BROAD_SCENARIOS = {"random_broad": "random", "random_radars_broad": "random_radars"}
"""Training generators with the broad flights' laws (:func:`broad_config`): name -> the random generator drawn with
them. Their flights take seeds ``BROAD_SEED_OFFSET`` above the suite's own (:func:`draw_training_looks`)."""
BROAD_SEED_OFFSET = 300_000
WINDOW_SCENARIOS = TRAIN_SCENARIOS + tuple(BROAD_SCENARIOS)
"""The generators ``scenarios`` may name: the random suites' own and their broad versions."""


def broad_config():
    """The broad flights' :class:`~radar_env.sim.scenario.RandomScenarioConfig`: the backprop recipe's training
    flights (``agents/training/hyperparams/backprop.toml``'s ``random_config``, the PPO bundle's too: speed changes
    to 5 g, turns to 9 g and 540 deg at up to 30 deg/s, speeds 80-1,200 kt, any first leg), without its
    ``random_radar_probability`` (a window suite is drawn as ``random`` or ``random_radars``)."""
    from radar_env.sim.scenario import RandomScenarioConfig
    rc = dict(load_hyperparams("backprop")["env_kwargs"]["random_config"])
    rc.pop("random_radar_probability", None)
    return RandomScenarioConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in rc.items()})


def check_hp(hp):
    """The hyperparameters checked (``ValueError`` naming the key and its range) and the base loaded:
    ``(hp, base)`` with ``base`` a :class:`agents.policies.learned.LearnedTracker`."""
    from agents.policies.layout import IMM_KINDS, Q_POLICY_KINDS
    from agents.policies.learned import load_learned
    hp.setdefault("init", "")       # optional (every run before it started from random weights)
    missing = [k for k in HP_KEYS if k not in hp]
    unknown = sorted(set(hp) - set(HP_KEYS))
    if missing or unknown:
        raise ValueError(f"--hp: window hyperparameters missing {missing}, unknown {unknown} (every key of "
                         "agents/training/hyperparams/window.toml is required)")
    _int_in(hp, "window_looks", 1, 64)
    from agents.policies.window_correction import check_fit_looks, check_q_looks
    hp["fit_looks"] = list(check_fit_looks(hp["fit_looks"], hp["window_looks"], "--hp fit_looks"))
    hp["q_looks"] = check_q_looks(hp["q_looks"], hp["window_looks"], "--hp q_looks")
    _int_in(hp, "epochs", 1, 10_000)
    _int_in(hp, "batch_looks", 1, 1 << 20)
    _int_in(hp, "eval_every", 1, 10_000)
    _int_in(hp, "covariance_epochs", 0, 1_000)
    _int_in(hp, "fresh_flights_every", 0, 10_000)
    _num_in(hp, "scale_m", 0.0, 1e6)
    _num_in(hp, "learning_rate", 0.0, 1.0)
    v = hp["first_leg_min_s"]
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not 0.0 <= v <= 1e5:
        raise ValueError(f"--hp first_leg_min_s: must be a number of seconds in [0, 1e5], got {v!r}")
    hp["first_leg_min_s"] = float(v)
    layers = hp["layers"]
    if (not isinstance(layers, list) or not 1 <= len(layers) <= 4
            or not all(isinstance(h, int) and not isinstance(h, bool) and 1 <= h <= 1024 for h in layers)):
        raise ValueError(f"--hp layers: must be a list of 1-4 integer widths in [1, 1024], got {layers!r}")
    sc = hp["scenarios"]
    if not isinstance(sc, list) or not sc or any(s not in WINDOW_SCENARIOS for s in sc) or len(set(sc)) != len(sc):
        raise ValueError(f"--hp scenarios: a list of distinct training generators from {list(WINDOW_SCENARIOS)}, "
                         f"got {sc!r}")
    ep = hp["episodes"]
    if isinstance(ep, dict):
        if set(ep) != set(sc):
            raise ValueError(f"--hp episodes: a table's keys must be the scenarios {sc!r}, got {sorted(ep)!r}")
        for name in sc:
            v = ep[name]
            if not isinstance(v, int) or isinstance(v, bool) or not 1 <= v <= 200_000:
                raise ValueError(f"--hp episodes: {name}'s count must be an integer in [1, 200000], got {v!r}")
    else:
        _int_in(hp, "episodes", 1, 200_000)
    for key, (ok, what) in (("eval_scenarios", EVAL_SCENARIOS_HP), ("select_on", SELECT_ON_HP)):
        if not ok(hp[key]):
            raise ValueError(f"--hp {key}: {what}, got {hp[key]!r}")
    if hp["dtype"] not in TRAIN_DTYPES:
        raise ValueError(f"--hp dtype: the network's training precision, one of {list(TRAIN_DTYPES)}, "
                         f"got {hp['dtype']!r}")
    for key in ("mirror", "standardise_inputs", "weight_suites"):
        if not isinstance(hp[key], bool):
            raise ValueError(f"--hp {key}: must be true or false, got {hp[key]!r}")
    if not isinstance(hp["init"], str):
        raise ValueError(f"--hp init: a window-correction folder to start from, or \"\" for random weights, got "
                         f"{hp['init']!r}")
    if not isinstance(hp["base"], str) or not hp["base"]:
        raise ValueError(f"--hp base: a bundled learned tracker's name or a learned-tracker folder, got {hp['base']!r}")
    try:
        base = load_learned(hp["base"], kinds=Q_POLICY_KINDS + IMM_KINDS)
    except ValueError as e:
        raise ValueError(f"--hp base: {e}") from None
    if hp["q_looks"] and base.kind not in Q_POLICY_KINDS:
        raise ValueError(f"--hp q_looks: {hp['q_looks']} needs a q-policy base (the base's q as inputs); "
                         f"{hp['base']!r} is a {base.kind}")
    if hp["init"]:              # checked now, before a run folder is made or a flight drawn
        from agents.policies.window_correction import feature_count
        init_weights(hp["init"], hp, feature_count(hp["window_looks"], hp["fit_looks"], hp["q_looks"]))
    return hp, base


def training_looks(base, episodes, window_looks, scale_m, fit_looks=(), q_looks=0):
    """The base tracker on ``episodes`` and every scored look's inputs and targets: ``(F (n, features), Y (n, 2),
    V (n, 2))`` with ``Y`` the truth's offset from the base estimate along and across its velocity, in ``scale_m``,
    and ``V`` the truth's velocity less the base's, along and across, in :data:`COV_SCALE_M_S` (the covariance head's
    other target)."""
    from agents.evaluation.metrics import region_masks
    from agents.policies.window_correction import window_features
    from radar_env.sim.episode import stack_episodes
    batch = stack_episodes(episodes)
    run = base.run(episodes)
    F, ca, sa = window_features(batch.t_s, batch.z_m, batch.R_m2, batch.detected, run.x, run.P, window_looks,
                                scale_m, fit_looks, run.q_m_s2, q_looks)
    dx = batch.truth[..., 0] - run.x[..., 0]
    dy = batch.truth[..., 1] - run.x[..., 1]
    Y = np.stack([dx * ca + dy * sa, -dx * sa + dy * ca], -1) / scale_m
    dvx = batch.truth[..., 2] - run.x[..., 2]
    dvy = batch.truth[..., 3] - run.x[..., 3]
    V = np.stack([dvx * ca + dvy * sa, -dvx * sa + dvy * ca], -1) / COV_SCALE_M_S
    used = (region_masks(batch, run.start_index)["used"] & np.isfinite(F).all(-1) & np.isfinite(Y).all(-1)
            & np.isfinite(V).all(-1))
    return F[used], Y[used], V[used]


def mirrored(F, Y, window_looks, V=None, fit_looks=()):
    """``(F, Y)`` (and ``V``, if given) reflected across the track: every across component (the window's residuals,
    the fits' across coefficients and the targets') changes sign."""
    F, Y, V = F.copy(), Y.copy(), None if V is None else V.copy()
    _reflect(F, Y, window_looks, V, fit_looks)
    return (F, Y) if V is None else (F, Y, V)


def _reflect(F, Y, window_looks, V=None, fit_looks=()):
    """:func:`mirrored` in the arrays' own memory."""
    from agents.policies.window_correction import FIT_ACROSS, FIT_FEATURES
    F[:, 1:4 * window_looks:4] *= -1
    o = 4 * window_looks + 7
    for f in range(len(fit_looks)):
        F[:, [o + FIT_FEATURES * f + c for c in FIT_ACROSS]] *= -1
    Y[:, 1] *= -1
    if V is not None:
        V[:, 1] *= -1


def mirror_signs(n_inputs, window_looks, fit_looks=()):
    """The sign each input takes when a look is mirrored (:func:`mirrored`): ``-1.0`` for the across components,
    ``1.0`` for the others (``(n_inputs,)``)."""
    signs = np.ones((1, n_inputs))
    _reflect(signs, np.ones((1, 2)), window_looks, None, fit_looks)
    return signs[0]


def training_batch(F, Y, W, idx, signs=None, mean=None, sd=None):
    """The batch of looks ``idx`` (integers) of a run's training looks, as the trainer feeds it: ``(X, Yb, Wb)``.
    ``F, Y, W`` hold the drawn looks (``n`` rows, :func:`draw_training_looks` with ``with_mirror=False``); with
    ``signs`` (:func:`mirror_signs`) an index ``i >= n`` is look ``i - n`` mirrored, as row ``i`` of the
    mirrored arrays is; ``X`` standardised by ``mean`` and ``sd`` if given. The numbers are those of the rows
    ``idx`` of the mirrored, standardised arrays, to the bit (the same operations per element: a sign flip, then
    ``(x - mean) / sd``; tested), for half their memory."""
    n = len(F)
    idx = np.asarray(idx)
    src = idx % n if signs is not None else idx
    X, Yb, Wb = F[src], Y[src], W[src]
    if signs is not None:
        m = idx >= n
        X[m] *= signs
        Yb[m, 1] *= -1
    if mean is not None:
        X -= mean
        X /= sd
    return X, Yb, Wb


def _net(torch, n_in, layers, dtype="float64"):
    mods, w = [], n_in
    for h in layers:
        mods += [torch.nn.Linear(w, h), torch.nn.Tanh()]
        w = h
    out = torch.nn.Linear(w, 2)
    with torch.no_grad():        # start near "no correction"
        out.weight.mul_(0.01)
        out.bias.zero_()
    return torch.nn.Sequential(*mods, out).to(getattr(torch, dtype))


def _weights(net, layers, mean=None, sd=None):
    """The MLP's weights under :func:`agents.policies.window_correction.network_shapes`' names. A net trained on
    standardised inputs ``(F - mean) / sd`` has the standardisation folded into its first layer
    (``W / sd``, ``b - W (mean / sd)``), so the saved correction reads the raw inputs as every correction does."""
    lin = [m for m in net if hasattr(m, "weight")]
    w = {}

    def f64(t):                 # (a float32 net's weights saved in float64, as every correction reads them)
        return t.detach().double().numpy().copy()
    for i in range(len(layers)):
        w[f"layer.{i}.weight"] = f64(lin[i].weight)
        w[f"layer.{i}.bias"] = f64(lin[i].bias)
    w["out.weight"], w["out.bias"] = f64(lin[-1].weight), f64(lin[-1].bias)
    if mean is not None:
        W = w["layer.0.weight"]
        w["layer.0.bias"] = w["layer.0.bias"] - W @ (mean / sd)
        w["layer.0.weight"] = W / sd
    return w


def init_weights(folder, hp, n_in):
    """The tanh layers' and output's weights of the window correction in ``folder`` (``--hp init``), checked to be a
    network of the run's inputs and layers: ``{name: array}`` as saved (reading raw inputs). ``ValueError``, one
    line, otherwise. Its covariance head, if any, is not read (a run fits its own)."""
    from agents.policies import checks
    from agents.policies.window_correction import network_shapes
    folder = Path(folder)
    if folder.name == "policy.npz":
        folder = folder.parent
    meta_file = folder / "policy.json"
    if not meta_file.is_file():
        raise ValueError(f"--hp init: {folder} holds no policy.json (a window correction's folder)")
    try:
        meta = checks.read_json_object(meta_file, "a window correction's policy.json")
    except ValueError as e:
        raise ValueError(f"--hp init: {e}") from None
    want = (hp["window_looks"], list(hp["fit_looks"]), hp["q_looks"], list(hp["layers"]))
    arch = meta.get("architecture")
    got = (meta.get("window_looks"), meta.get("fit_looks", []), meta.get("q_looks", 0),
           arch.get("layers") if isinstance(arch, dict) else None)
    if meta.get("kind") != "window_correction" or got != want:
        raise ValueError(f"--hp init: {folder} must be a window correction with the run's window_looks, fit_looks, "
                         f"q_looks and layers {want}, got kind {meta.get('kind')!r} and {got}")
    if meta.get("version", 1) != 1:
        raise ValueError(f"--hp init: {folder} is an ensemble of window corrections (policy.json version "
                         f"{meta.get('version')!r}); give one of its members' folders (a training run's best/)")
    try:
        w = checks.read_npz(folder / "policy.npz")
    except ValueError as e:
        raise ValueError(f"--hp init: {e}") from None
    shapes = network_shapes({"input_size": n_in, "layers": hp["layers"]})
    for k, shape in shapes.items():
        if k not in w or w[k].shape != shape or not np.isfinite(w[k]).all():
            raise ValueError(f"--hp init: {folder / 'policy.npz'}: {k} must be finite of shape {shape}")
    return {k: np.asarray(w[k], dtype=np.float64) for k in shapes}


def unfold_standardisation(w, mean, sd):
    """A saved network ``w`` (its standardisation ``mean``, ``sd`` folded into the first layer: it reads raw inputs)
    as the network on standardised inputs ``(F - mean) / sd``: the inverse of :func:`_weights`' folding, ``W sd`` and
    ``b + W mean``; the same function. A new dict; the other layers are ``w``'s."""
    w = dict(w)
    W = np.asarray(w["layer.0.weight"], dtype=np.float64)
    w["layer.0.bias"] = np.asarray(w["layer.0.bias"], dtype=np.float64) + W @ mean
    w["layer.0.weight"] = W * sd
    return w


def _load_init(net, w, layers, mean=None, sd=None):
    """``w`` (:func:`init_weights`, raw inputs) into ``net``; with a standardisation, unfolded from the first layer
    (:func:`unfold_standardisation`), so the net computes the same function."""
    import torch
    if mean is not None:
        w = unfold_standardisation(w, mean, sd)
    lin = [m for m in net if hasattr(m, "weight")]
    names = [f"layer.{i}" for i in range(len(layers))] + ["out"]
    with torch.no_grad():
        for m, n in zip(lin, names):
            m.weight.copy_(torch.from_numpy(w[f"{n}.weight"]))
            m.bias.copy_(torch.from_numpy(w[f"{n}.bias"]))


def input_standardisation(F, signs=None):
    """Per-input mean and standard deviation of the training looks ``F`` (an input constant over them, such as the
    detection flags of a suite without misses, keeps sd 1); with ``signs`` (:func:`mirror_signs`), of ``F`` and its
    mirrored looks after it, without making them. numpy's ``F.mean(0)`` and ``F.std(0)`` (of the mirrored array) to
    the bit (tested), without the temporary of ``F``'s size ``F.std`` makes: that was the peak of a run's memory.
    ``F`` must be a C-ordered float64 array ``(n >= 1, m >= 2)``, as the trainer's are (numpy sums such an array
    row by row, as the compiled code does; a single column, or a Fortran-ordered array's columns, it sums pairwise,
    to other bits): else ``ValueError``."""
    if not (isinstance(F, np.ndarray) and F.ndim == 2 and F.dtype == np.float64 and F.flags.c_contiguous
            and F.shape[0] >= 1 and F.shape[1] > 1):
        desc = (f"{F.dtype} {'C-ordered' if F.flags.c_contiguous else 'not C-ordered'} array of shape {F.shape}"
                if isinstance(F, np.ndarray) else type(F).__name__)
        raise ValueError(f"F must be a C-ordered float64 array (n >= 1, m >= 2) (numpy's mean and sd to the bit), "
                         f"got a {desc}")
    if signs is not None:
        signs = np.asarray(signs, dtype=np.float64)
        if signs.shape != (F.shape[1],) or not np.isin(signs, (-1.0, 1.0)).all():
            raise ValueError(f"signs must be {F.shape[1]} values of -1 or 1 (mirror_signs), got shape {signs.shape}")
    mean, sd = _mean_sd(F, np.ones(F.shape[1]) if signs is None else signs, signs is not None)
    return mean, np.where(sd > 1e-6, sd, 1.0)


@numba.njit(cache=True, nogil=True)
def _mean_sd(F, signs, mirror):
    # row by row, in numpy's order for a reduction over the rows of a C array: the same sums to the bit; with
    # ``mirror`` the rows of F then the rows of F * signs (a sign flip is exact: the mirrored array's numbers)
    n, m = F.shape
    passes = 2 if mirror else 1
    s = np.zeros(m)
    for p in range(passes):
        for i in range(n):
            for j in range(m):
                s[j] += F[i, j] * signs[j] if p else F[i, j]
    mean = s / (n * passes)
    v = np.zeros(m)
    for p in range(passes):
        for i in range(n):
            for j in range(m):
                d = (F[i, j] * signs[j] if p else F[i, j]) - mean[j]
                v[j] += d * d
    return mean, np.sqrt(v / (n * passes))


def _torch_cov(torch, raw):
    """:func:`agents.policies.window_correction.head_covariance` before its units and rotation: ``L L^T + floor``
    of the head's outputs ``raw (n, 10)`` in the base frame and the head's units (the same clips)."""
    from agents.policies.window_correction import COV_FLOOR, COV_LOG_DIAG_CLIP, COV_OFFDIAG_CLIP, COV_TRIL
    n = raw.shape[0]
    diag = {i: torch.exp(torch.clamp(raw[:, c], -COV_LOG_DIAG_CLIP, COV_LOG_DIAG_CLIP))
            for c, (i, j) in enumerate(COV_TRIL) if i == j}
    cols = []
    for i in range(4):
        row = []
        for j in range(4):
            if j > i:
                row.append(torch.zeros(n, dtype=raw.dtype))
            elif i == j:
                row.append(diag[i])
            else:
                c = COV_TRIL.index((i, j))
                row.append(torch.clamp(raw[:, c], -COV_OFFDIAG_CLIP, COV_OFFDIAG_CLIP) * diag[j])
        cols.append(torch.stack(row, -1))
    L = torch.stack(cols, -2)
    return L @ L.transpose(1, 2) + COV_FLOOR * torch.eye(4, dtype=raw.dtype)


def fit_covariance_head(weights, layers, F, E, epochs, seed, verbose=0):
    """Fit the covariance head of a trained window correction: a linear map from its last tanh layer to the 10
    outputs of :data:`agents.policies.window_correction.COV_OUTPUTS`, by the Gaussian negative log-likelihood of the
    errors ``E (n, 4)`` (the truth less the corrected estimate: position along, across in ``scale_m``; velocity
    along, across in :data:`COV_SCALE_M_S`) with the network fixed (the correction's estimate is unchanged). Adam
    (:data:`COV_LEARNING_RATE`, cosine-decayed over ``epochs``), batches of :data:`COV_BATCH_LOOKS`, the batch order
    from ``seed``; started at the errors' own standard deviations (no correlation). ``weights``: the saved
    correction's (raw inputs ``F (n, features)``). Returns ``({"cov.weight", "cov.bias"}, stats)`` with ``stats``
    the mean negative log-likelihood and the training looks' ANEES (NEES / 4) under the fitted head."""
    import torch
    Fa = np.ascontiguousarray(F, dtype=np.float64)
    h = torch.empty((len(Fa), int(layers[-1])), dtype=torch.float64)
    with torch.no_grad():       # the last tanh layer, in chunks: a few GB for millions of looks, not several times that
        for c in range(0, len(Fa), 65536):
            y = torch.from_numpy(Fa[c:c + 65536])
            for i in range(len(layers)):
                y = torch.tanh(y @ torch.from_numpy(weights[f"layer.{i}.weight"]).T
                               + torch.from_numpy(weights[f"layer.{i}.bias"]))
            h[c:c + 65536] = y
    Et = torch.from_numpy(np.ascontiguousarray(E, dtype=np.float64))
    from agents.policies.window_correction import COV_OUTPUTS, COV_TRIL
    head = torch.nn.Linear(h.shape[1], COV_OUTPUTS).double()
    with torch.no_grad():
        head.weight.zero_()
        head.bias.zero_()
        sd = Et.std(0)
        for c, (i, j) in enumerate(COV_TRIL):
            if i == j:
                head.bias[c] = torch.log(sd[i])
    opt = torch.optim.Adam(head.parameters(), lr=COV_LEARNING_RATE)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, max(1, epochs))
    gen = torch.Generator().manual_seed(int(seed))

    def nll_nees(idx):
        S = _torch_cov(torch, head(h[idx]))
        Lc = torch.linalg.cholesky(S)
        z = torch.linalg.solve_triangular(Lc, Et[idx][..., None], upper=False)[..., 0]
        nees = (z ** 2).sum(-1)
        return 2 * torch.log(torch.diagonal(Lc, dim1=1, dim2=2)).sum(-1) + nees, nees

    for epoch in range(1, epochs + 1):
        perm = torch.randperm(len(h), generator=gen)
        for i in range(0, len(h), COV_BATCH_LOOKS):
            loss = nll_nees(perm[i:i + COV_BATCH_LOOKS])[0].mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
    with torch.no_grad():
        tot_nll = tot_nees = 0.0
        for i in range(0, len(h), 65536):
            nll, nees = nll_nees(torch.arange(i, min(i + 65536, len(h))))
            tot_nll, tot_nees = tot_nll + float(nll.sum()), tot_nees + float(nees.sum())
    stats = {"epochs": epochs, "looks": len(h), "mean_nll": tot_nll / len(h), "anees_training": tot_nees / len(h) / 4}
    if verbose:
        print(f"covariance head: {epochs} epochs, mean NLL {stats['mean_nll']:.3f}, ANEES on the training looks "
              f"{stats['anees_training']:.3f}", file=sys.stderr, flush=True)
    return {"cov.weight": head.weight.detach().numpy().copy(), "cov.bias": head.bias.detach().numpy().copy()}, stats


def _errors_after(weights, layers, F, Y, V):
    """The errors the covariance head describes: the truth less the corrected position, and the velocity error."""
    from agents.policies.recurrent import layer_weights
    from agents.policies.window_correction import network_forward
    out = np.concatenate([network_forward(layer_weights(weights), len(layers), F[i:i + 65536])
                          for i in range(0, len(F), 65536)])
    return np.concatenate([Y - out, V], -1)


def _with_covariance(folder, F, Y, V, epochs, seed, command, verbose, cache=None):
    """Fit and write the covariance head of the correction in ``folder`` (its ``policy.npz`` and ``policy.json``
    rewritten with the head, and ``covariance.json``: the fit's numbers, the seconds this folder took and the
    command). ``cache`` (a dict) keeps the fits by weights: a folder whose network is one already fitted (``best/``
    when the best epoch is the last) gets the same head without fitting it again (in about no seconds)."""
    from agents.policies import checks
    from agents.policies.window_correction import FORMAT, VERSION
    folder = Path(folder)
    d, config, env_file, npz = checks.open_weights_folder(folder, "a window correction", FORMAT, VERSION)
    if config["architecture"].get("covariance"):
        raise ValueError(f"{folder}: the correction already has a covariance head")
    layers = list(config["architecture"]["layers"])
    weights = dict(checks.read_npz(npz))
    t0 = time.time()
    key = hashlib.sha256(b"".join(np.ascontiguousarray(weights[k]).tobytes() for k in sorted(weights))).hexdigest()
    if cache is not None and key in cache:
        head, stats = cache[key]
    else:
        head, stats = fit_covariance_head(weights, layers, F, _errors_after(weights, layers, F, Y, V), epochs, seed,
                                          verbose)
        if cache is not None:
            cache[key] = head, dict(stats)
    stats = dict(stats)
    weights.update(head)
    config = {**config, "scale_m_s": COV_SCALE_M_S,
              "architecture": {**config["architecture"], "covariance": True}}
    from agents.policies.window_correction import save_window_correction
    save_window_correction(folder, weights, config, json.loads(Path(env_file).read_text()))
    stats.update({"seconds": time.time() - t0, "seed": int(seed), "command": command})
    (folder / "covariance.json").write_text(json.dumps(stats, indent=1, allow_nan=False))
    return stats


def suite_episodes(hp):
    """``{suite: training flights per draw}`` of ``hp["scenarios"]``: ``episodes`` for every suite, or its table's
    count for each."""
    ep = hp["episodes"]
    return {name: int(ep[name] if isinstance(ep, dict) else ep) for name in hp["scenarios"]}


def flight_draws(hp, seed):
    """The first seed of each draw of training flights (module docstring): ``[S]`` without ``fresh_flights_every``,
    else ``S + d M`` for each draw ``d`` over the epochs, ``M`` the largest of the suites' ``episodes``."""
    every = hp["fresh_flights_every"]
    n = -(-hp["epochs"] // every) if every else 1
    return [int(seed) + d * _most_episodes(hp) for d in range(n)]


def _most_episodes(hp):
    """The largest count of ``episodes`` (the number, or its table's largest): the seeds one draw spans."""
    ep = hp["episodes"]
    return max(ep.values()) if isinstance(ep, dict) else ep


def training_config(hp):
    """The :class:`~radar_env.sim.scenario.RandomScenarioConfig` of the training flights: the suites' own but for
    ``first_leg_min_s`` (None, the suites' own config, when it is theirs or a run saved before the key existed)."""
    from radar_env.sim.scenario import RandomScenarioConfig
    default = RandomScenarioConfig()
    v = hp.get("first_leg_min_s", default.first_leg_min_s)
    return None if v == default.first_leg_min_s else RandomScenarioConfig(first_leg_min_s=float(v))


def training_flights(hp, seed, chunk=500):
    """The training flights of one draw from seed ``seed`` (module docstring), suite by suite: yields ``(suite,
    chunks)``, ``chunks`` an iterator of lists of at most ``chunk`` episodes, drawn when reached (a chunk's base runs
    stay a few hundred MB)."""
    cfg = training_config(hp)
    for name, n_ep in suite_episodes(hp).items():
        gen, laws, s0 = ((BROAD_SCENARIOS[name], broad_config(), seed + BROAD_SEED_OFFSET) if name in BROAD_SCENARIOS
                         else (name, cfg, seed))
        yield name, _chunks(gen, laws, s0, n_ep, chunk)


def _chunks(gen, laws, s0, n_ep, chunk):
    """:func:`training_flights`' chunks of one suite (its values bound here, so a suite's chunks drawn after the
    next suite was reached are still its own)."""
    from agents.evaluation.suites import draw_suite
    for c0 in range(0, n_ep, chunk):
        yield draw_suite(gen, min(chunk, n_ep - c0), seed=s0 + c0, random_config=laws)


def draw_training_looks(base, hp, seed, with_mirror=True):
    """Every training look of a run (module docstring): ``(F, Y, V, W)``, the inputs, the position and velocity
    targets (:func:`training_looks`) and each look's weight in the loss (``1 / `` the base's mean squared error on
    its suite with ``weight_suites``, else 1; mean 1), the mirrored looks appended if ``hp["mirror"]``
    (:func:`mirrored`'s numbers) and ``with_mirror``. ``with_mirror=False`` returns the drawn looks only, half the
    memory: the trainer makes each batch's mirrored looks from them (:func:`training_batch`, the same numbers).
    The chunks of flights are copied into the final arrays and dropped one by one, so the peak memory is about one
    and a half times the result's (the drawn looks, half of it with the mirror, beside it), not three times (4.4 M
    looks of 24-look windows, their mirror included: 5.6 GB; without the mirror the drawn chunks beside an array of
    their own size)."""
    parts, sizes = [], []       # per suite: its chunks' (F, Y, V)
    fits = hp.get("fit_looks", ())         # (a run saved before the fits existed has none)
    q_looks = hp.get("q_looks", 0)         # (nor the q inputs)
    for name, chunk_list in training_flights(hp, seed):
        chunks = [training_looks(base, eps, hp["window_looks"], float(hp["scale_m"]), fits, q_looks)
                  for eps in chunk_list]
        parts.append(chunks)
        sizes.append(sum(len(c[0]) for c in chunks))
    n = sum(sizes)
    total = 2 * n if hp["mirror"] and with_mirror else n
    nf = parts[0][0][0].shape[1]
    F, Y, V, W = np.empty((total, nf)), np.empty((total, 2)), np.empty((total, 2)), np.empty(total)
    i = 0
    for chunks, size in zip(parts, sizes):
        # weight_suites: every suite's looks weigh 1 / (the base's mean squared error there), so a suite of long
        # ranges and large errors (random_radars) does not drown the others in the pooled squared error
        mse = float(np.mean(np.concatenate([(c[1] ** 2).sum(-1) for c in chunks]))) if hp["weight_suites"] else 1.0
        W[i:i + size] = 1.0 / mse
        while chunks:
            f, y, v = chunks.pop(0)
            F[i:i + len(f)], Y[i:i + len(f)], V[i:i + len(f)] = f, y, v
            i += len(f)
    W[:n] /= W[:n].mean()
    if hp["mirror"] and with_mirror:        # the mirrored looks written into the second half
        F[n:], Y[n:], V[n:], W[n:] = F[:n], Y[:n], V[:n], W[:n]
        _reflect(F[n:], Y[n:], hp["window_looks"], V[n:], fits)
    return F, Y, V, W


def covariance_scale_fit(correction, hp, seed):
    """The maximum-likelihood factor of a correction's reported covariance on training flights: ``c = mean NEES / 4``
    of its covariance with ``covariance_scale`` 1 (``c C`` then has NEES 4 on average, ANEES 1: the scale a Gaussian
    likelihood fit gives a fixed matrix, the criterion each covariance head was fitted by), over every look the
    correction moves on the flights of :func:`training_flights` (``hp``'s ``scenarios``, ``episodes`` and
    ``first_leg_min_s``; one draw from ``seed``). An ensemble's mean of heads, each fitted to its own looks, is
    more cautious than each head; this restores the heads' calibration for the ensemble.

    Returns ``{"covariance_scale", "looks", "invalid_looks", "suites": {suite: {"flights", "looks", "anees"}}}``,
    ``anees`` the suite's with scale 1. A look whose covariance is not positive definite has no NEES
    (:func:`agents.evaluation.metrics.nees_values`): counted in ``invalid_looks``; ``ValueError`` if a suite has no
    look with one (every look of it failed: the fit would not be of the mix asked for).
    """
    import copy
    from agents.evaluation.metrics import nees_values
    from radar_env.sim.episode import stack_episodes
    if not correction.has_covariance:
        raise ValueError("covariance_scale_fit: the correction has no covariance head (nothing to scale)")
    unscaled = copy.copy(correction)
    unscaled.covariance_scale = 1.0
    suites, total, looks, invalid = {}, 0.0, 0, 0
    for name, chunks in training_flights(hp, seed):
        s = {"flights": 0, "looks": 0, "nees_sum": 0.0}
        for eps in chunks:
            run = unscaled.run(eps)
            moved = np.isfinite(run.extra["correction_m"])
            nees = nees_values((run.x - stack_episodes(eps).truth)[moved], run.P[moved])
            ok = np.isfinite(nees)
            invalid += int((~ok).sum())
            s["flights"] += len(eps)
            s["looks"] += int(ok.sum())
            s["nees_sum"] += float(nees[ok].sum())
        if not s["looks"]:
            raise ValueError(f"covariance_scale_fit: suite {name!r}: no look the correction moves has a "
                             f"positive-definite covariance ({s['flights']} flights; every look failed)")
        total += s["nees_sum"]
        looks += s["looks"]
        suites[name] = {"flights": s["flights"], "looks": s["looks"], "anees": s["nees_sum"] / (4 * s["looks"])}
    return {"covariance_scale": total / (4 * looks), "looks": looks, "invalid_looks": invalid, "suites": suites}


def add_covariance(run, epochs, verbose=1, command=None):
    """Add a covariance head to a finished window-correction run (its folder and ``best/``): the training looks
    drawn again from the run's ``config.json`` (the same base, flights and seed), then :func:`fit_covariance_head`
    for each, and the stats into the run's ``summary.json`` (``covariance``, keyed as training keys them) and
    ``training.json``. What ``radar-track train --method window --add-covariance RUN`` runs; a run trained with
    ``covariance_epochs > 0`` has its head already. The run's inputs are checked against each folder's network
    first (:func:`_check_run_inputs`). Returns ``{folder: stats}``."""
    import torch
    torch.set_num_threads(1)
    from agents.policies.learned import load_learned
    from agents.policies.layout import IMM_KINDS, Q_POLICY_KINDS
    run = Path(run)
    cfg_file = run / "config.json"
    if not cfg_file.is_file():
        raise ValueError(f"--add-covariance {run}: no config.json (a window-correction run folder is expected)")
    cfg = json.loads(cfg_file.read_text())
    if cfg.get("method") != "window":
        raise ValueError(f"--add-covariance {run}: config.json's method is {cfg.get('method')!r}, not 'window'")
    if not isinstance(epochs, int) or isinstance(epochs, bool) or not 1 <= epochs <= 1000:
        raise ValueError(f"--add-covariance: the epochs must be an integer in [1, 1000], got {epochs!r}")
    folders = [f for f in (run, run / "best") if (f / "policy.npz").is_file()]
    for f in folders:           # before the flights are drawn (minutes)
        if json.loads((f / "policy.json").read_text()).get("architecture", {}).get("covariance"):
            raise ValueError(f"--add-covariance {f}: the correction already has a covariance head")
    base = load_learned(cfg["base"], kinds=Q_POLICY_KINDS + IMM_KINDS)
    _check_run_inputs(run, cfg, folders, base)
    t0 = time.time()
    # a run of the first recipe has no weight_suites in its config (the weights do not enter the head's fit)
    # the looks the head was fitted on in training: the last draw's (flight_draws)
    cfg = {"weight_suites": False, "fresh_flights_every": 0, **cfg}
    F, Y, V, _ = draw_training_looks(base, cfg, flight_draws(cfg, cfg["seed"])[-1])
    if verbose:
        print(f"{len(F):,} training looks ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
    cache = {}
    out = {str(f): _with_covariance(f, F, Y, V, epochs, int(cfg["seed"]), command, verbose, cache) for f in folders}
    summary_file = run / "summary.json"
    if summary_file.is_file():      # the run's records say it has a head, as a run trained with one does
        from agents.evaluation.metrics import jsonable
        from agents.policies.learned import read_kind, write_run_layout
        summary = json.loads(summary_file.read_text())
        summary["covariance"] = {(run.name if f == run else "best"): out[str(f)] for f in folders}
        summary_file.write_text(json.dumps(jsonable(summary), indent=1, allow_nan=False))
        write_run_layout(run, read_kind(run)[0], summary)
    return out


def _check_run_inputs(run, cfg, folders, base):
    """For :func:`add_covariance`, before the flights are drawn: the inputs the run's ``config.json`` makes
    (``window_looks``, ``fit_looks``, ``q_looks``; the q only of a q-policy base) are those each folder's network
    reads (its ``policy.json``'s, and ``architecture.input_size`` of them); else ``ValueError``, one line."""
    from agents.policies.layout import Q_POLICY_KINDS
    from agents.policies.window_correction import check_fit_looks, check_q_looks, feature_count
    where = f"--add-covariance {run}: config.json's"
    window = cfg.get("window_looks")
    if not isinstance(window, int) or isinstance(window, bool) or not 1 <= window <= 64:
        raise ValueError(f"{where} window_looks must be an integer in [1, 64], got {window!r}")
    fits = check_fit_looks(cfg.get("fit_looks", []), window, f"{where} fit_looks")      # absent in older runs
    q_looks = check_q_looks(cfg.get("q_looks", 0), window, f"{where} q_looks")
    if q_looks and base.kind not in Q_POLICY_KINDS:
        raise ValueError(f"{where} q_looks {q_looks} needs a q-policy base (the base's q as inputs); its base "
                         f"{cfg['base']!r} is a {base.kind}")
    n = feature_count(window, fits, q_looks)
    for f in folders:
        meta = json.loads((f / "policy.json").read_text())
        got = (meta.get("window_looks"), meta.get("fit_looks", []), meta.get("q_looks", 0),
               meta.get("architecture", {}).get("input_size"))
        if got != (window, list(fits), q_looks, n):
            raise ValueError(f"--add-covariance {f}: policy.json's window_looks {got[0]!r}, fit_looks {got[1]!r}, "
                             f"q_looks {got[2]!r} and architecture.input_size {got[3]!r} must be config.json's "
                             f"window_looks {window}, fit_looks {list(fits)}, q_looks {q_looks} and their {n} inputs")


def _base_field(base_name, folder):
    """``policy.json``'s ``base``: a bundled name as given, a folder relative to the saved correction's folder."""
    from agents.policies.learned import BUNDLED_LEARNED
    if base_name in BUNDLED_LEARNED:
        return base_name
    return os.path.relpath(Path(base_name).resolve(), Path(folder).resolve())


def _save(folder, hp, weights, env_kwargs, extra=None):
    from agents.policies.window_correction import feature_count, save_window_correction
    config = {"base": _base_field(hp["base"], folder), "window_looks": hp["window_looks"], "scale_m": hp["scale_m"],
              "architecture": {"input_size": feature_count(hp["window_looks"], hp["fit_looks"], hp["q_looks"]),
                               "layers": list(hp["layers"])}}
    if hp["fit_looks"]:         # absent: none (every correction saved before the fits existed)
        config["fit_looks"] = list(hp["fit_looks"])
    if hp["q_looks"]:           # absent: 0 (likewise)
        config["q_looks"] = hp["q_looks"]
    save_window_correction(folder, weights, config, env_kwargs)
    if extra is not None:
        (Path(folder) / "selection.json").write_text(json.dumps(extra, indent=1, allow_nan=False))


def _save_checkpoint(part, meta, net, opt, sched, gen, mean, sd, best_weights):
    """``checkpoints/last.npz``: the network, Adam's moments, the batch order's generator, the standardisation, the
    best epoch's saved weights and ``meta`` (the epoch, the history, the scheduler) as a JSON string, in one file
    written then renamed (a kill leaves the previous checkpoint or the new one, never a mix); ``last.json`` beside it
    is ``meta`` again, for reading. No pickle: numbers and text only."""
    arrays = {f"net/{k}": v.detach().numpy() for k, v in net.state_dict().items()}
    arrays.update(adam_arrays(opt))
    arrays["generator"] = gen.get_state().numpy()
    if mean is not None:
        arrays["mean"], arrays["sd"] = mean, sd
    arrays.update(best_weights)
    write_checkpoint(part, arrays, {**meta, "scheduler": sched.state_dict(),
                                    "lr": [g["lr"] for g in opt.param_groups]})


def _resume(part, hp, net, opt, sched, gen):
    """Load ``part``'s checkpoint (:func:`_save_checkpoint`; read without pickle) into ``net``, ``opt``, ``sched``
    and ``gen``; returns ``(meta, arrays)``. A checkpoint that cannot be read, or that does not fit the run, is a
    ``ValueError`` of one line naming it."""
    d = part / "checkpoints"
    try:
        with np.load(d / "last.npz", allow_pickle=False) as z:
            saved = {k: z[k].copy() for k in z.files}
        meta = json.loads(str(saved.pop("meta_json")))
        if bool(hp["standardise_inputs"]) != ("mean" in saved):
            raise ValueError("its standardisation does not match standardise_inputs")
        for key in ("epoch", "history", "best", "data_s", "wall_s", "resumed_at", "n_looks", "scheduler", "lr"):
            if key not in meta:
                raise ValueError(f"its meta_json has no {key!r}")
        _restore(saved, meta, net, opt, sched, gen)
    except CHECKPOINT_ERRORS as e:
        raise checkpoint_refusal(part, e) from None
    return meta, saved


def _restore(saved, meta, net, opt, sched, gen):
    """The training state of :func:`_save_checkpoint` back into ``net``, ``opt``, ``sched`` and ``gen``: the run
    goes on with the numbers it would have had without the stop (tested to the bit)."""
    import torch
    net.load_state_dict({k[4:]: torch.from_numpy(v) for k, v in saved.items() if k.startswith("net/")})
    load_adam(opt, saved)
    sched.load_state_dict(meta["scheduler"])
    for g, lr in zip(opt.param_groups, meta["lr"]):
        g["lr"] = lr
    gen.set_state(torch.from_numpy(saved["generator"]))


def train_window(hp, seed=0, out="runs", verbose=1, command=None, args=None, run_name=None):
    """Train a window correction (module docstring) with hyperparameters ``hp`` (every key of
    ``agents/training/hyperparams/window.toml``). Returns the run folder. Everything is checked (``ValueError``)
    before the run folder is made."""
    import torch
    from agents.evaluation.metrics import jsonable
    from agents.policies.window_correction import WindowCorrection, feature_count
    from agents.policies.learned import read_kind, write_run_layout
    torch.set_num_threads(1)
    numba.set_num_threads(1)
    hp, base = check_hp(dict(hp))
    seed = int(seed)
    draws = flight_draws(hp, seed)
    n_most = _most_episodes(hp)
    last = draws[-1] + n_most + (BROAD_SEED_OFFSET if set(hp["scenarios"]) & set(BROAD_SCENARIOS) else 0)
    if not 0 <= seed or last > SELECTION_SEED_BASE:
        raise ValueError(f"--seed: the training flights' seeds {seed}..{last - 1} must lie in "
                         f"[0, {SELECTION_SEED_BASE}) (below the selection suites' seeds; "
                         f"{len(draws)} draw(s) of up to {n_most} flights per suite)")
    try:
        selection = SelectionSuites(hp["eval_scenarios"], SELECTION_SEED_BASE, hp["select_on"])
    except ValueError as e:
        raise ValueError(f"--hp eval_scenarios / select_on: {e}") from None
    env_kwargs = json.loads((base.folder / "env_config.json").read_text())
    run, part = run_paths(out, run_name, f"window_s{seed}_{time.strftime('%Y%m%d-%H%M%S')}")
    # without init the config is what it was before init existed, so an older unfinished run still resumes
    config = {"method": "window", "env_id": "RadarTrack-v0", "seed": seed,
              **{k: v for k, v in hp.items() if k != "init" or v}}
    resume = part.exists() and resumable(part, config)
    every = hp["fresh_flights_every"] if len(draws) > 1 else 0

    def draw_of(epoch):         # the draw epoch `epoch` trains on
        return (epoch - 1) // every if every else 0

    n_in = feature_count(hp["window_looks"], hp["fit_looks"], hp["q_looks"])
    signs = mirror_signs(n_in, hp["window_looks"], hp["fit_looks"]) if hp["mirror"] else None
    torch.manual_seed(seed)
    gen = torch.Generator().manual_seed(seed)
    dt = getattr(torch, hp["dtype"])
    net = _net(torch, n_in, hp["layers"], hp["dtype"])
    opt = torch.optim.Adam(net.parameters(), lr=hp["learning_rate"])
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, hp["epochs"])
    with writing_run(run, part, resumable=True, keep=resume):
        t0 = time.time()
        if resume:
            (part / "FAILED").unlink(missing_ok=True)
            meta, saved = _resume(part, hp, net, opt, sched, gen)
            start = int(meta["epoch"])
            meta["resumed_at"].append(start)
            if verbose:
                print(f"resuming {part} after epoch {start}", file=sys.stderr, flush=True)
        else:
            write_run_files(part, config, args, command, env_kwargs)
            meta, saved, start = {"history": [], "best": None, "data_s": 0.0, "wall_s": 0.0, "resumed_at": []}, {}, 0
        wall0 = float(meta["wall_s"])
        scale = float(hp["scale_m"])
        data_s = float(meta["data_s"])
        # the drawn looks only (with_mirror=False): each batch makes its mirrored looks (training_batch), so a
        # run holds half the inputs (4.6 M drawn looks of 160 inputs: 5.5 GiB, not 11)
        d, F, Y, Wl, n_looks = None, None, None, None, meta.get("n_looks")
        if start < hp["epochs"]:        # (a run stopped after its last epoch has nothing left to train)
            d = draw_of(start + 1)
            F, Y, _, Wl = draw_training_looks(base, hp, draws[d], with_mirror=False)
            n_looks = 2 * len(F) if hp["mirror"] else len(F)
            data_s += time.time() - t0
            if verbose:
                print(f"{n_looks:,} training looks ({time.time() - t0:.0f} s)", file=sys.stderr, flush=True)
        if resume:              # the first draw's standardisation, as the checkpoint keeps it
            mean, sd = (saved["mean"], saved["sd"]) if "mean" in saved else (None, None)
        else:
            mean, sd = input_standardisation(F, signs) if hp["standardise_inputs"] else (None, None)
            if hp["init"]:      # fine-tuning: start from a saved correction's network
                _load_init(net, init_weights(hp["init"], hp, n_in), hp["layers"], mean, sd)
        # the validation flights: the base runs once (and is scored once), the correction is applied to its runs at
        # every validation
        val = {}
        for n, (eps, batch, imm) in selection.suites.items():
            brun = base.run(eps)
            val[n] = (batch, brun, imm, pooled_rmse(batch, brun) / imm)
        history, best = meta["history"], meta["best"]
        if resume and best is not None:     # best/ as the checkpoint knows it (a kill may have left a newer one)
            _save(part / "best", hp, {k[5:]: v for k, v in saved.items() if k.startswith("best/")}, env_kwargs, best)

        def validate(epoch, train_rmse_m):
            wc = WindowCorrection(_weights(net, hp["layers"], mean, sd), {**config, "architecture": {
                "input_size": n_in, "layers": hp["layers"]}}, base.policy, base.env_config)
            row = {"epoch": epoch, "train_rmse_m": train_rmse_m}
            for n, (batch, brun, imm, base_ratio) in val.items():
                r = pooled_rmse(batch, wc.correct(batch, brun, "window"))
                row[f"{n}_rmse_m"], row[f"{n}_ratio_imm2"] = r, r / imm
                row[f"{n}_base_ratio_imm2"] = base_ratio
            row["selection_ratio"] = float(np.exp(np.mean([np.log(row[f"{n}_ratio_imm2"])
                                                           for n in selection.select_on])))
            row["wall_s"] = wall0 + time.time() - t0
            return row

        for epoch in range(start + 1, hp["epochs"] + 1):
            if draw_of(epoch) != d:     # fresh flights; the first draw's standardisation
                d = draw_of(epoch)
                F = Y = Wl = None       # the last draw's looks freed first
                t1 = time.time()
                F, Y, _, Wl = draw_training_looks(base, hp, draws[d], with_mirror=False)
                data_s += time.time() - t1
                n_looks = 2 * len(F) if hp["mirror"] else len(F)
                if verbose:
                    print(f"draw {d}: {n_looks:,} training looks of seeds {draws[d]}+", file=sys.stderr, flush=True)
            perm = torch.randperm(n_looks, generator=gen).numpy()
            total = 0.0
            for i in range(0, n_looks, hp["batch_looks"]):
                X, Yb, Wb = (torch.from_numpy(a).to(dt) for a in training_batch(F, Y, Wl, perm[i:i + hp["batch_looks"]],
                                                                                signs, mean, sd))
                se = ((net(X) - Yb) ** 2).sum(-1)
                loss = (Wb * se).mean()
                opt.zero_grad()
                loss.backward()
                opt.step()
                total += float(se.detach().sum())
            sched.step()
            if epoch % hp["eval_every"] == 0 or epoch == hp["epochs"]:
                row = validate(epoch, float(np.sqrt(total / n_looks)) * scale)
                history.append(row)
                if best is None or row["selection_ratio"] < best["selection_ratio"]:
                    best = row
                    saved = {f"best/{k}": v for k, v in _weights(net, hp["layers"], mean, sd).items()}
                    _save(part / "best", hp, {k[5:]: v for k, v in saved.items()}, env_kwargs, jsonable(row))
                meta.update(epoch=epoch, history=history, best=best, data_s=data_s, wall_s=row["wall_s"],
                            n_looks=n_looks)
                _save_checkpoint(part, meta, net, opt, sched, gen, mean, sd,
                                 {k: v for k, v in saved.items() if k.startswith("best/")})
                if verbose:
                    print(f"epoch {epoch}: train {row['train_rmse_m']:.1f} m, selection ratio "
                          f"{row['selection_ratio']:.4f} (base " + ", ".join(
                              f"{n} {row[f'{n}_base_ratio_imm2']:.3f} -> {row[f'{n}_ratio_imm2']:.3f}"
                              for n in val) + f") {row['wall_s']:.0f} s", file=sys.stderr, flush=True)
        _save(part, hp, _weights(net, hp["layers"], mean, sd), env_kwargs)
        covariance = {}
        if hp["covariance_epochs"]:     # the head of the final weights and of the best epoch's, the network fixed
            F = Y = Wl = None       # the last draw's looks again, with their mirror made (add_covariance's inputs)
            t1 = time.time()
            F, Y, V, _ = draw_training_looks(base, hp, draws[-1])
            data_s += time.time() - t1
            cache = {}
            for f, key in ((part, run.name), (part / "best", "best")):    # the run's name, not the partial one
                covariance[key] = _with_covariance(f, F, Y, V, hp["covariance_epochs"], seed, command, verbose, cache)
        summary = {"epochs": hp["epochs"], "training_looks": n_looks, "flight_draws": len(draws), "data_s": data_s,
                   "wall_s": wall0 + time.time() - t0, "resumed_at": meta["resumed_at"],
                   "best_selection_ratio": best["selection_ratio"], "best_epoch": best["epoch"],
                   "selection_history": history, "steps": hp["epochs"], "covariance": covariance}
        (part / "summary.json").write_text(json.dumps(jsonable(summary), indent=1, allow_nan=False))
        write_run_layout(part, read_kind(part)[0], jsonable(summary))
    if verbose:
        print(f"run: {run}\nbest selection ratio {best['selection_ratio']:.4f} at epoch {best['epoch']} "
              f"({wall0 + time.time() - t0:.0f} s)", file=sys.stderr)
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
    if args.add_covariance is not None:
        try:
            out = add_covariance(args.add_covariance, hp["covariance_epochs"], verbose=0 if args.quiet else 1,
                                 command=command)
        except ValueError as e:
            raise SystemExit(f"error: {e}") from None
        if not args.quiet:
            for f, st in out.items():
                print(f"{f}: covariance head, ANEES on the training looks {st['anees_training']:.3f}",
                      file=sys.stderr)
        return Path(args.add_covariance)
    return run_cli(lambda: train_window(hp, seed=args.seed, out=args.out, verbose=0 if args.quiet else 1,
                                        command=command, args=vars(args), run_name=args.name), command, args.out)
