"""Train a q-choosing policy on RadarTrack-v0 with stable-baselines3 (PPO, DQN or SAC).

``radar-track train --algo ppo [--action-type discrete|continuous] [--timesteps N] [--n-envs N] [--seed S]
[--out runs/] [--env-kwargs JSON] [--hp KEY=VALUE ...]``

Hyperparameters come from ``agents/training/hyperparams/<algo>.toml`` (table ``"RadarTrack-v0"``, rl-zoo3 style); the
command line overrides ``n_timesteps``, ``n_envs``, env arguments (``--env-kwargs``, merged over the file's
``env_kwargs``) and any other key (``--hp gamma=0.9``, the value parsed as JSON, else kept as a string).
Special keys: ``eval_scenarios`` / ``eval_runs`` / ``eval_freq`` / ``select_on`` (selection callback),
``init_from`` (path of a saved model of the same algorithm and network to start from: fine-tuning).

Rollouts run on the native batched vector env (:class:`radar_env.envs.env.RadarTrackVectorEnv`) through the SB3
adapter (:mod:`agents.training.sb3_vec`), random scenarios only, row ``i`` seeded ``seed + i`` (training range
``[0, 1_000_000)``). Hyperparameters are checked before anything is written (unknown keys, wrong types, a missing
``init_from`` or one of another algorithm are one-line errors). The run is written into
``<out>/<name>.partial/`` and renamed to ``<out>/<name>/`` only once the final model and ``summary.json`` are saved;
a run that fails or is interrupted stays ``<name>.partial/`` with a ``FAILED`` file (the traceback; none if the
process was killed) and no final ``policy.zip``; a later run under the same name replaces it, while a finished
``<name>/`` is never overwritten (an error), and a run under the name another run is writing now is refused (an
exclusive lock on ``<out>/.<name>.lock``, held while the run writes; run and sweep names are plain folder names).
A DQN/SAC run whose ``n_timesteps`` do not exceed ``learning_starts`` warns that nothing is learned
(``summary.json`` records ``n_updates``, the number of gradient updates). The run folder
``<out>/<algo>_<action>_s<seed>_<time>/`` holds:

* the final model as a learned-tracker folder (:mod:`agents.policies.learned`; ``radar-track evaluate --learned
  <run>`` reads it): ``policy.zip``, its numpy export ``policy.npz`` (where the structure allows one),
  ``policy.json`` (kind ``ppo_q_policy``, ``dqn_q_policy``, ``sac_q_policy``, or ``learned_imm_ppo`` /
  ``learned_imm_sac`` on ``tracker="imm_cv_ct"``), ``env_config.json``, ``training.json``, ``choice.json``;
* ``best/``: the same files (plus ``selection.json``) for the model with the lowest position RMSE ratio to the
  tuned IMM on the selection suite (training-range seeds 900_000 + i, see :mod:`agents.training.callbacks`);
* ``config.json`` (hyperparameters used), ``args.json``, ``command.txt``, ``summary.json`` (wall time, env share of
  wall time, selection history), ``checkpoints/``, ``tb/`` (TensorBoard), ``vecnormalize.pkl`` if rewards were
  normalised (rewards only: the observation is already scaled, so evaluation needs no statistics).
"""

from __future__ import annotations

import argparse
import inspect
import json
import math
import shlex
import sys
import time
import warnings
from pathlib import Path

# nothing slow at import (numpy, torch, stable-baselines3 and the env are imported where they are used):
# `radar-track train` parses its options and says what it does first; the seed ranges come from the lowest layer
from baselines.seeds import TRAIN_SEEDS

from agents.policies.bundle import embed_env_config     # JSON and zipfile only

from agents.training.runs import (ENV_ID, EVAL_SCENARIOS_HP, HP_DIR, SELECT_ON_HP, TRAIN_SCENARIOS,  # noqa: F401
                                  apply_cli_overrides, check_plain_name, load_hyperparams, run_cli, run_paths,
                                  write_run_files, writing_run)

__all__ = ["main", "load_hyperparams", "train", "trained_timesteps", "plot_training_curve", "check_plain_name",
           "ALGOS", "ENV_ID", "TRAIN_SCENARIOS"]

ALGOS = ("ppo", "dqn", "sac")
ACTIVATIONS = ("tanh", "relu", "elu", "leaky_relu", "silu")
_SPECIAL = ("n_envs", "n_timesteps", "policy", "normalize_reward", "env_kwargs", "policy_kwargs", "eval_freq",
            "eval_runs", "eval_scenarios", "checkpoint_freq", "select_on", "init_from")


def _schedule(v):
    """A number, or ``"lin_<x>"``: linear decay from x to 0 over training."""
    if isinstance(v, str) and v.startswith("lin_"):
        x0 = float(v[4:])
        return lambda progress_remaining: progress_remaining * x0
    return float(v) if isinstance(v, (int, float)) else v


def _policy_kwargs(pk):
    import torch.nn as nn
    pk = dict(pk or {})
    if "activation_fn" in pk:
        name = pk["activation_fn"]
        if name not in ACTIVATIONS:
            raise ValueError(f"policy_kwargs.activation_fn must be one of {ACTIVATIONS}, got {name!r}")
        pk["activation_fn"] = {"tanh": nn.Tanh, "relu": nn.ReLU, "elu": nn.ELU, "leaky_relu": nn.LeakyReLU,
                               "silu": nn.SiLU}[name]
    return pk


# types of the special keys: (check, what it must be)
_SPECIAL_TYPES = {
    "n_envs": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "n_timesteps": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "eval_freq": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "eval_runs": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "checkpoint_freq": (lambda v: _is_int(v) and v >= 1, "an integer >= 1"),
    "policy": (lambda v: isinstance(v, str), "a policy name such as 'MlpPolicy'"),
    "normalize_reward": (lambda v: isinstance(v, bool), "true or false"),
    "env_kwargs": (lambda v: isinstance(v, dict), "a JSON object of RadarTrack-v0 arguments"),
    "policy_kwargs": (lambda v: isinstance(v, dict) and _net_arch_ok(v.get("net_arch", [])),
                      "a JSON object; its net_arch a list of at most 8 layer widths in [1, 4096], or an object of "
                      "such lists (pi, vf, qf)"),
    "eval_scenarios": ((lambda v: v == {} or EVAL_SCENARIOS_HP[0](v)),      # {}: eval_runs of random
                       EVAL_SCENARIOS_HP[1]),
    "select_on": SELECT_ON_HP,
    "init_from": (lambda v: isinstance(v, str) and v != "", "the path of a saved model"),
}
# ranges of common constructor arguments (the type comes from the constructor's default)
_RANGES = {"gamma": (0.0, 1.0), "gae_lambda": (0.0, 1.0), "learning_rate": (0.0, None), "batch_size": (1, None),
           "n_steps": (1, None), "n_epochs": (1, None), "buffer_size": (1, None), "learning_starts": (0, None),
           "clip_range": (0.0, None), "max_grad_norm": (0.0, None), "vf_coef": (0.0, None), "tau": (0.0, 1.0),
           "exploration_fraction": (0.0, 1.0), "exploration_initial_eps": (0.0, 1.0),
           "exploration_final_eps": (0.0, 1.0), "target_update_interval": (1, None), "gradient_steps": (-1, None),
           "ent_coef": (0.0, None), "stats_window_size": (1, None), "target_kl": (0.0, None)}
_OPTIONAL_NUMBERS = ("target_kl",)
"""Constructor arguments whose default is None and which take a number when given (checked as numbers, in _RANGES)."""
_NOT_HP = ("self", "policy", "env", "seed", "device", "verbose", "tensorboard_log", "policy_kwargs",
           "_init_setup_model")


def _net_arch_ok(arch):
    """SB3's ``net_arch``: a list of layer widths, or an object of such lists (``pi``, ``vf``, ``qf``)."""
    def widths(v):
        return isinstance(v, list) and len(v) <= 8 and all(_is_int(n) and 1 <= n <= 4096 for n in v)
    if isinstance(arch, dict):
        return set(arch) <= {"pi", "vf", "qf"} and all(widths(v) for v in arch.values())
    return widths(arch)


def _is_int(v):
    return isinstance(v, int) and not isinstance(v, bool)


def _is_num(v):
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _check_hp(algo, cls, hp):
    """Validate ``hp`` against the special keys and ``cls``'s constructor; returns the constructor kwargs.
    Raises ``ValueError`` naming ``--hp KEY``, what it must be and the value given."""
    params = {k: p for k, p in inspect.signature(cls.__init__).parameters.items() if k not in _NOT_HP}
    for k, v in hp.items():
        if k in _SPECIAL:
            ok, what = _SPECIAL_TYPES[k]
            if not ok(v):
                raise ValueError(f"--hp {k}: must be {what}, got {v!r}")
            continue
        if k not in params:
            raise ValueError(f"--hp {k}: unknown hyperparameter for {cls.__name__}; valid: "
                             f"{sorted([*params, *_SPECIAL])}")
        default = params[k].default
        if k in ("learning_rate", "clip_range") and isinstance(v, str):
            try:
                x0 = float(v[4:]) if v.startswith("lin_") else float("nan")
            except ValueError:
                x0 = float("nan")
            if not (math.isfinite(x0) and x0 >= 0):
                raise ValueError(f"--hp {k}: must be a number or 'lin_<x>' with x >= 0, got {v!r}")
            continue
        int_only = _is_int(default) and k != "max_grad_norm"      # DQN's default max_grad_norm is the int 10
        if int_only and not _is_int(v) and not (isinstance(v, list) and k == "train_freq"):
            raise ValueError(f"--hp {k}: must be an integer, got {v!r}")
        if _is_num(default) and not _is_num(v) and not (isinstance(v, list) and k == "train_freq"):
            raise ValueError(f"--hp {k}: must be a number, got {v!r}")
        if isinstance(default, bool) and not isinstance(v, bool):
            raise ValueError(f"--hp {k}: must be true or false, got {v!r}")
        if k in _OPTIONAL_NUMBERS and v is not None and not _is_num(v):
            raise ValueError(f"--hp {k}: must be a number (or null), got {v!r}")
        if k in _RANGES and _is_num(v):
            lo, hi = _RANGES[k]
            if not math.isfinite(v) or (lo is not None and v < lo) or (hi is not None and v > hi):
                raise ValueError(f"--hp {k}: must lie in [{lo}, {'inf' if hi is None else hi}], got {v!r}")
    return {k: v for k, v in hp.items() if k not in _SPECIAL}


def check_train_hp(algo, hp):
    """``hp`` checked as :func:`train` (or, for ``algo = "backprop"``, :func:`agents.training.backprop.check_hp`)
    checks it before a run folder is made: the special keys, the SB3 algorithm's constructor arguments and the env
    arguments; ``ValueError`` naming ``--hp KEY`` (for ``radar-track sweep``, before Ray starts). Returns the SB3
    algorithm's constructor arguments (None for backprop)."""
    if algo == "backprop":
        from agents.training.backprop import check_hp
        check_hp(hp)
        return None
    if algo not in ALGOS:
        raise ValueError(f"algo must be one of {ALGOS}, got {algo!r}")
    import stable_baselines3 as sb3
    from radar_env.envs.config import EnvConfig
    kwargs = _check_hp(algo, {"ppo": sb3.PPO, "dqn": sb3.DQN, "sac": sb3.SAC}[algo], hp)
    env_kwargs = dict(hp.get("env_kwargs") or {})
    if env_kwargs.get("scenario", "random") not in TRAIN_SCENARIOS:
        raise ValueError(f"--hp env_kwargs: training uses the random scenario generators only (scenario must be one "
                         f"of {list(TRAIN_SCENARIOS)}, got {env_kwargs['scenario']!r})")
    try:
        EnvConfig.from_kwargs(**env_kwargs)
    except (TypeError, ValueError) as e:
        raise ValueError(f"--hp env_kwargs: {str(e).splitlines()[0]}") from None
    return kwargs


def _stack_factor(src_space, new_space):
    """k if ``new_space`` is ``src_space`` stacked k times (``frame_stack``: newest frame first), else None."""
    import numpy as np
    lo, hi = np.asarray(src_space.low).ravel(), np.asarray(src_space.high).ravel()
    nlo, nhi = np.asarray(new_space.low).ravel(), np.asarray(new_space.high).ravel()
    if lo.size == 0 or nlo.size % lo.size:
        return None
    k = nlo.size // lo.size
    same = np.array_equal(np.tile(lo, k), nlo) and np.array_equal(np.tile(hi, k), nhi)
    return k if same else None


def _expanded_state(src, new, k):
    """``src``'s weights for a network whose input is ``k`` stacked frames of ``src``'s input: every first-layer
    weight (the tensors whose last axis is the observation) gets zeros for the older frames, so the fine-tuned
    network starts as exactly the source policy and learns from there what the history adds."""
    if k == 1:
        return src
    out = {}
    for name, w in src.items():
        if name in new and new[name].shape != w.shape and w.ndim == 2 and new[name].shape[1] == k * w.shape[1]:
            e = new[name].clone().zero_()
            e[:, :w.shape[1]] = w
            out[name] = e
        else:
            out[name] = w
    return out


def _load_init_from(cls, algo, path, allow_pickle=False):
    """The saved model to fine-tune from; ``ValueError`` naming ``--hp init_from`` if it is missing, not a model,
    a model of another algorithm, or (a pickle) given without ``allow_pickle`` (``--allow-pickle``)."""
    import stable_baselines3 as sb3
    from agents.policies.checks import refuse_pickle
    p = Path(path)
    if not p.is_file():
        raise ValueError(f"--hp init_from: file {str(path)!r} does not exist")
    if not allow_pickle:
        raise ValueError(f"--hp init_from: {refuse_pickle(p)}")
    try:
        return cls.load(str(p), device="cpu")
    except Exception as e:  # noqa: BLE001 - name the algorithm it belongs to, if any
        err = f"{type(e).__name__}: {e}".splitlines()[0]
    for other in ("PPO", "DQN", "SAC", "A2C", "TD3"):
        if other == cls.__name__:
            continue
        try:
            getattr(sb3, other).load(str(p), device="cpu")
        except Exception:  # noqa: BLE001 - try the next algorithm
            continue
        raise ValueError(f"--hp init_from: {str(path)!r} is a {other} model; --algo {algo} fine-tunes "
                         f"{cls.__name__} models only")
    raise ValueError(f"--hp init_from: {str(path)!r} is not a stable-baselines3 model ({err})")


def train(algo, hp, seed=0, out="runs", progress=True, verbose=1, command=None, args=None, run_name=None,
          on_selection=None, allow_pickle=False):
    """Train ``algo`` with hyperparameters ``hp`` (a dict as in the TOML files). Returns the run folder.

    ``on_selection(row)`` (optional) is called after each selection evaluation (``row`` as in ``summary.json``'s
    ``selection_history``); the sweeps (:mod:`agents.training.sweep`) report it to Ray Tune.

    Everything is checked (``ValueError``) before the run folder is made; the run is written to
    ``<out>/<name>.partial`` and renamed to ``<out>/<name>`` when complete (see the module docstring)."""
    import torch
    import stable_baselines3 as sb3
    from stable_baselines3.common.callbacks import CallbackList, CheckpointCallback
    from stable_baselines3.common.vec_env import VecNormalize

    from radar_env.envs.observation import DEFAULT_FEATURES

    from agents.training.callbacks import EnvTimeCallback, ImmRatioEvalCallback
    from agents.training.sb3_vec import make_sb3_vec_env

    torch.set_num_threads(1)
    hp = dict(hp)
    kwargs = check_train_hp(algo, hp)   # the one check (radar-track sweep's too), before any folder is made
    cls = {"ppo": sb3.PPO, "dqn": sb3.DQN, "sac": sb3.SAC}[algo]
    env_kwargs = dict(hp.get("env_kwargs") or {})
    if env_kwargs.get("scenario") == "random":
        env_kwargs.pop("scenario")
    act = env_kwargs.setdefault("action_type", "continuous" if algo == "sac" else "discrete")
    # pin the observation: a saved model keeps working when the default feature list changes
    env_kwargs.setdefault("features", list(DEFAULT_FEATURES))
    if algo == "dqn" and act != "discrete":
        raise ValueError("DQN needs action_type='discrete'")
    if algo == "sac" and act != "continuous":
        raise ValueError("SAC needs action_type='continuous'")
    n_envs, n_timesteps = int(hp.get("n_envs", 16)), int(hp.get("n_timesteps", 1_000_000))
    from agents.training.runs import check_rows_fit
    check_rows_fit("--n-envs", n_envs)          # before the seed range and any allocation
    seed = int(seed)
    if seed < TRAIN_SEEDS.start or seed + n_envs > TRAIN_SEEDS.stop:
        raise ValueError(f"--seed: training seeds must lie in {TRAIN_SEEDS}; got rows {seed}..{seed + n_envs - 1}")
    src = _load_init_from(cls, algo, hp["init_from"], allow_pickle) if hp.get("init_from") else None
    steps, per_rollout = trained_timesteps(cls, n_timesteps, n_envs, kwargs)
    if verbose and steps != n_timesteps:      # said once, before the run: SB3 finishes the rollout it is in
        print(f"note: {cls.__name__} collects {per_rollout:,} env steps at a time ({n_envs} envs x "
              f"{per_rollout // n_envs}): --timesteps {n_timesteps:,} trains "
              + (f"{steps:,} steps" if steps else "at least that many steps (train_freq counts episodes)"),
              file=sys.stderr, flush=True)
    if algo in ("dqn", "sac"):
        default_starts = inspect.signature(cls.__init__).parameters["learning_starts"].default
        starts = int(kwargs.get("learning_starts", default_starts))
        if n_timesteps <= starts:
            warnings.warn(f"--timesteps {n_timesteps} does not exceed learning_starts {starts}: {cls.__name__} makes "
                          "no gradient update, the saved policy is its random initialisation", UserWarning,
                          stacklevel=2)

    run, part = run_paths(out, run_name, f"{algo}_{act}_s{seed}_{time.strftime('%Y%m%d-%H%M%S')}")

    try:
        env, adapter = make_sb3_vec_env(n_envs, env_kwargs, seed=seed)
    except (TypeError, ValueError) as e:
        raise ValueError(f"--env-kwargs: {e}") from None
    if hp.get("normalize_reward", False):
        gamma = float(hp.get("gamma", 0.99))
        env = VecNormalize(env, norm_obs=False, norm_reward=True, gamma=gamma)
    for k in ("learning_rate", "clip_range"):
        if k in kwargs:
            kwargs[k] = _schedule(kwargs[k])
    try:
        model = cls(hp.get("policy", "MlpPolicy"), env, seed=seed, device="cpu", verbose=0,
                    tensorboard_log=str(part / "tb"), policy_kwargs=_policy_kwargs(hp.get("policy_kwargs")),
                    **kwargs)
    except (TypeError, ValueError, AssertionError, KeyError, RuntimeError) as e:
        raise ValueError(f"--hp: {cls.__name__} rejects the hyperparameters ({type(e).__name__}: {e})") from None
    if src is not None:    # fine-tuning: start from a saved model's weights (same network and spaces)
        k = _stack_factor(src.observation_space, model.observation_space)
        if k is None or src.action_space != model.action_space:
            raise ValueError(f"--hp init_from {hp['init_from']!r}: its spaces {src.observation_space}, "
                             f"{src.action_space} differ from this env's {model.observation_space}, "
                             f"{model.action_space} (the observation may only differ by frame_stack: the "
                             "source's observation stacked k times)")
        try:
            model.policy.load_state_dict(_expanded_state(src.policy.state_dict(), model.policy.state_dict(), k))
        except RuntimeError as e:
            raise ValueError(f"--hp init_from {hp['init_from']!r}: network does not match policy_kwargs "
                             f"({str(e).splitlines()[0]})") from None

    scenarios = hp.get("eval_scenarios") or {"random": int(hp.get("eval_runs", 100))}
    try:
        eval_cb = ImmRatioEvalCallback(env_kwargs, eval_freq=int(hp.get("eval_freq", 100_000)), scenarios=scenarios,
                                       best_dir=part / "best", verbose=verbose, select_on=hp.get("select_on"),
                                       on_row=on_selection)
    except ValueError as e:
        raise ValueError(f"--hp eval_scenarios / eval_runs / select_on: {e}") from None
    time_cb = EnvTimeCallback(adapter)
    ckpt_freq = max(int(hp.get("checkpoint_freq", 500_000)) // n_envs, 1)
    ckpt = CheckpointCallback(ckpt_freq, str(part / "checkpoints"), name_prefix=algo)

    with writing_run(run, part, resumable=False):   # two runs with one name: the second stops at its lock
        write_run_files(part, {"algo": algo, "env_id": ENV_ID, "seed": seed, **hp}, args, command, env_kwargs)
        t0 = time.perf_counter()
        model.learn(n_timesteps, callback=CallbackList([time_cb, eval_cb, ckpt]), progress_bar=progress,
                    tb_log_name=algo)
        wall = time.perf_counter() - t0
        model.save(part / "policy.zip")
        embed_env_config(part / "policy.zip", env_kwargs)
        from agents.policies.numpy_policy import export_saved
        export_saved(part / "policy.zip", model)        # arrays beside the pickle: evaluated without unpickling
        if isinstance(env, VecNormalize):
            env.save(str(part / "vecnormalize.pkl"))
        eval_s = float(sum(r["eval_s"] for r in eval_cb.history))
        summary = {
            "timesteps": int(model.num_timesteps), "n_updates": int(getattr(model, "_n_updates", -1)),
            "wall_s": wall, "env_s": adapter.env_time_s,
            "env_share_of_wall": adapter.env_time_s / wall, "selection_eval_s": eval_s,
            "env_share_of_wall_excluding_selection": adapter.env_time_s / max(wall - eval_s, 1e-9),
            "steps_per_s": model.num_timesteps / wall, "best_selection_ratio_imm2": eval_cb.best_ratio,
            "selection_history": eval_cb.history,
        }
        from agents.evaluation.metrics import jsonable    # inf (a failed selection evaluation) -> null, never 'Infinity'
        (part / "summary.json").write_text(json.dumps(jsonable(summary), indent=1, allow_nan=False))
        from agents.policies.learned import sb3_kind, write_run_layout
        write_run_layout(part, sb3_kind(algo, env_kwargs), jsonable(summary))    # policy.json, training/choice.json
        env.close()
    if verbose:
        print(f"run: {run}\n{model.num_timesteps} steps in {wall:.0f} s ({summary['steps_per_s']:.0f} steps/s); env "
              f"share of wall time {summary['env_share_of_wall']:.2f} ({summary['env_share_of_wall_excluding_selection']:.2f}"
              f" excluding selection evals); best selection ratio policy/imm2 {eval_cb.best_ratio:.3f}")
    try:
        plot_training_curve(run)
    except ImportError:  # pragma: no cover - matplotlib is optional
        pass
    return run


def trained_timesteps(cls, n_timesteps, n_envs, kwargs):
    """The env steps stable-baselines3 trains for ``n_timesteps``: it collects whole rollouts until it has at
    least that many (PPO: ``n_envs x n_steps`` steps per rollout; DQN / SAC: ``n_envs x train_freq`` when
    ``train_freq`` counts steps). Returns ``(steps, steps_per_rollout)``; ``steps`` is None when ``train_freq``
    counts episodes (then it depends on where the episodes end)."""
    from stable_baselines3.common.on_policy_algorithm import OnPolicyAlgorithm
    params = inspect.signature(cls.__init__).parameters
    if issubclass(cls, OnPolicyAlgorithm):      # (DQN's n_steps is its n-step return, not a rollout length)
        per = int(kwargs.get("n_steps", params["n_steps"].default))
    else:
        tf = kwargs.get("train_freq", params["train_freq"].default)
        per, unit = (int(tf), "step") if isinstance(tf, int) else (int(tf[0]), str(tf[1]))
        if unit != "step":
            return None, n_envs * per
    per *= int(n_envs)
    return -(-int(n_timesteps) // per) * per, per


def _tb_scalars(run, tags):
    """``{tag: (steps, values)}`` from the run's TensorBoard event files (empty if tensorboard is missing)."""
    try:
        from tensorboard.backend.event_processing.event_accumulator import EventAccumulator
    except ImportError:  # pragma: no cover - depends on the install
        return {}
    out = {}
    for d in sorted(Path(run, "tb").glob("*")):
        acc = EventAccumulator(str(d), size_guidance={"scalars": 0})
        acc.Reload()
        for t in tags:
            if t in acc.Tags().get("scalars", []):
                ev = acc.Scalars(t)
                s0, v0 = out.get(t, ([], []))
                out[t] = (s0 + [e.step for e in ev], v0 + [e.value for e in ev])
    return out


def _bundled_stages(cfg):
    """``[(label, selection_history, selected_timesteps)]`` of a bundled ``training.json``, first stage first
    (each fine-tuning stage's record nests the one it started from under ``fine_tuned_from``)."""
    chain = []
    while cfg:
        chain.append(cfg)
        cfg = cfg.get("fine_tuned_from")
    stages = []
    for i, c in enumerate(reversed(chain), 1):
        hp = c.get("hyperparams", {})
        how = "fine-tuned" if hp.get("init_from") else "from scratch"
        name = Path(c.get("run_folder", f"stage {i}")).name
        steps = c.get("training", {}).get("timesteps", hp.get("n_timesteps", 0))
        stages.append((f"stage {i}: {name}\n({how}, {steps / 1e6:.0f}M)", c.get("selection_history", []),
                       c.get("selected_checkpoint", {}).get("timesteps")))
    return stages


def plot_training_curve(run, png=None):
    """Training curve: the selection ratio policy/imm2 per selection suite over env steps, and the mean episode
    return when TensorBoard logs are there. Returns the PNG path.

    Args:
        run: a run folder (``summary.json``, ``config.json``, ``best/selection.json``, ``tb/``): one stage, titled
            with the run's name and whether it was trained from scratch or fine-tuned (``init_from``); or a bundled
            ``training.json`` (``agents/bundled/policy/``): every stage of its ``fine_tuned_from`` chain end to end,
            from the selection histories it records (the bundle keeps no TensorBoard logs, so no return panel).
        png: output path (default ``training_curve.png`` beside ``run``).
    """
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from agents.evaluation.plots import training_curve_figure
    run = Path(run)
    if run.is_file():
        cfg = json.loads(run.read_text())
        stages = _bundled_stages(cfg)
        png = Path(png) if png else run.with_name("training_curve.png")
        fig = training_curve_figure(stages)
        fig.suptitle(f"Bundled policy: the selected checkpoint of {Path(cfg.get('run_folder', '?')).name}, the last "
                     f"of {len(stages)} training stages", fontsize=10)
    else:
        png = Path(png) if png else run / "training_curve.png"
        hist = json.loads((run / "summary.json").read_text()).get("selection_history", [])
        cfg = json.loads((run / "config.json").read_text()) if (run / "config.json").is_file() else {}
        sel = run / "best" / "selection.json"
        chosen = json.loads(sel.read_text()).get("timesteps") if sel.is_file() else None
        how = f"fine-tuned from {cfg['init_from']}" if cfg.get("init_from") else "from scratch"
        sc = _tb_scalars(run, ["rollout/ep_rew_mean"])
        fig = training_curve_figure([(f"{run.name} ({how})", hist, chosen)], sc.get("rollout/ep_rew_mean"))
    fig.savefig(png, dpi=110)
    plt.close(fig)
    return png


def _file_defaults(key):
    """``"ppo 8000000, dqn ..., sac ..."``: ``key`` in each algorithm's hyperparameter file (for --help)."""
    out = []
    for algo in ALGOS:
        try:
            out.append(f"{algo} {load_hyperparams(algo).get(key, '-')}")
        except (OSError, ValueError):            # pragma: no cover - a broken install
            out.append(f"{algo} ?")
    return ", ".join(out)


def build_parser(prog="radar-track train"):
    ap = argparse.ArgumentParser(prog=prog, description="Train a q-choosing policy on RadarTrack-v0 (random "
                                 "scenarios, training seeds) with stable-baselines3 (--method ppo, the default) or "
                                 "end to end by backpropagation through the filter (--method backprop).",
                                 epilog="Security: the saved policy.zip (and a model given as --hp init_from=PATH) "
                                        "is a pickle: loading it runs the code inside. Load only files you trust. "
                                        "--method backprop saves policy.npz + policy.json: arrays and JSON, no "
                                        "pickle.")
    ap.add_argument("--method", choices=("ppo", "backprop", "window"), default="ppo",
                    help="ppo: reinforcement learning with stable-baselines3 (--algo); backprop: a GRU q-policy "
                         "trained by backpropagation through the filter (agents/training/backprop.py; its settings: "
                         "agents/training/hyperparams/backprop.toml); window: a window correction of a trained "
                         "tracker (--hp base=NAME), an MLP fitted by regression (agents/training/window.py; "
                         "hyperparams/window.toml) (default: ppo)")
    ap.add_argument("--algo", choices=ALGOS,
                    help="--method ppo: the stable-baselines3 algorithm (its settings: "
                         "agents/training/hyperparams/<algo>.toml) (default: none; required with --method ppo)")
    ap.add_argument("--tracker",
                    help="--method backprop: the differentiable model: 'cv', the CV filter with a GRU choosing q "
                         "(settings: hyperparams/backprop.toml); 'imm_cv_ct', the learned IMM: imm_cv_ct whose "
                         "mode-switch probabilities and noises a GRU sets per look (hyperparams/"
                         "backprop_imm_cv_ct.toml) (default: the hyperparameter file's, cv)")
    ap.add_argument("--action-type", choices=("discrete", "continuous"),
                    help="q chosen from the env's discrete levels or continuously (default: the hyperparameter "
                         "file's: discrete for ppo and dqn, continuous for sac)")
    ap.add_argument("--timesteps", type=int, metavar="N",
                    help="total env steps, >= 1; rounded up to whole rollouts (n_envs x n_steps for ppo), which "
                         f"the command says (default: the file's n_timesteps: {_file_defaults('n_timesteps')})")
    ap.add_argument("--n-envs", type=int, metavar="N",
                    help=f"rows of the vector env, >= 1 (default: the file's n_envs: {_file_defaults('n_envs')})")
    ap.add_argument("--seed", type=int, default=0, metavar="S",
                    help=f"row i of the vector env is seeded S + i; every row must lie in the training range "
                         f"[{TRAIN_SEEDS.start}, {TRAIN_SEEDS.stop}) (default 0)")
    ap.add_argument("--out", default="runs", metavar="DIR",
                    help="parent folder of the run folder (default: ./runs)")
    ap.add_argument("--name", help="run folder name inside --out (default: <algo>_<action>_s<seed>_<time>)")
    ap.add_argument("--env-kwargs", default="{}", metavar="JSON",
                    help="JSON object of RadarTrack-v0 arguments, merged over the file's env_kwargs (default: {})")
    ap.add_argument("--hp", action="append", metavar="KEY=VALUE",
                    help="override a hyperparameter, repeatable; VALUE parsed as JSON, else kept as a string; "
                         "init_from=PATH fine-tunes a saved model (a pickle: only one you trust) (default: the "
                         "file's values)")
    ap.add_argument("--hyperparams", metavar="FILE.toml",
                    help="TOML file to read instead of agents/training/hyperparams/<algo>.toml (default: that file)")
    ap.add_argument("--allow-pickle", action="store_true",
                    help="let --hp init_from=PATH (a stable-baselines3 zip, a pickle) be unpickled: this runs the "
                         "code inside; only for files you trust (default: refused, in one line)")
    ap.add_argument("--add-covariance", metavar="RUN",
                    help="--method window: instead of training, fit the covariance head of the finished window-"
                         "correction run RUN (its folder and best/; the flights drawn again from its config.json; "
                         "epochs from --hp covariance_epochs or hyperparams/window.toml) (default: none)")
    ap.add_argument("--no-progress", action="store_true",
                    help="no progress bar during training (default: stable-baselines3's bar)")
    ap.add_argument("--quiet", action="store_true",
                    help="no status lines, no selection messages, no final summary (default: print them)")
    return ap


def main(argv=None, prog="radar-track train"):
    """The ``radar-track train`` command. A user error (options, hyperparameters, ``init_from``, run folder) stops
    with a one-line ``error: --option ...`` (``SystemExit``) before the run folder is made. Returns the run folder."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = build_parser(prog).parse_args(argv)
    if args.method == "backprop":
        if not args.quiet:     # before torch and the env are imported
            what = ("a learned IMM (imm_cv_ct's parameters from a GRU)" if args.tracker == "imm_cv_ct"
                    else "a GRU q-policy")
            print(f"radar-track train: {what} by backpropagation through the filter on RadarTrack-v0; loading "
                  "torch and the env ...", file=sys.stderr, flush=True)
        from agents.training.backprop import main_from_args
        return main_from_args(args, argv)
    if args.method == "window":
        if not args.quiet:
            print("radar-track train: a window correction by regression on RadarTrack-v0's flights; loading torch "
                  "and the env ...", file=sys.stderr, flush=True)
        from agents.training.window import main_from_args as window_main
        return window_main(args, argv)
    if args.add_covariance is not None:
        raise SystemExit("error: --add-covariance applies to --method window")
    if args.algo is None:
        raise SystemExit("error: --algo is required with --method ppo (one of " + ", ".join(ALGOS) + ")")
    if args.tracker is not None:
        raise SystemExit("error: --tracker applies to --method backprop")
    if not args.quiet:     # before torch, stable-baselines3 and the env are imported (in train())
        print(f"radar-track train: {args.algo} on RadarTrack-v0; loading torch, stable-baselines3 and the env ...",
              file=sys.stderr, flush=True)
    for opt, v in (("--timesteps", args.timesteps), ("--n-envs", args.n_envs)):
        if v is not None and v < 1:
            raise SystemExit(f"error: {opt} must be an integer >= 1, got {v}")
    if args.seed < 0:
        raise SystemExit(f"error: --seed must be an integer in {TRAIN_SEEDS}, got {args.seed}")
    try:
        hp = load_hyperparams(args.algo, args.hyperparams)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    hp = apply_cli_overrides(hp, args.env_kwargs, args.hp)
    if args.action_type:
        hp["env_kwargs"]["action_type"] = args.action_type
    if args.timesteps is not None:
        hp["n_timesteps"] = args.timesteps
    if args.n_envs is not None:
        hp["n_envs"] = args.n_envs
    command = " ".join(["radar-track", "train", *map(shlex.quote, argv)])
    return run_cli(lambda: train(args.algo, hp, seed=args.seed, out=args.out, progress=not args.no_progress,
                                 verbose=0 if args.quiet else 1, command=command, args=vars(args),
                                 run_name=args.name, allow_pickle=args.allow_pickle), command, args.out)


if __name__ == "__main__":
    main(prog="python -m agents.training.train")
