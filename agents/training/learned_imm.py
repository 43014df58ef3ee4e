r"""Training the learned IMM by backpropagation through the torch IMM (:mod:`radar_env.torch_imm`).

The model (:class:`LearnedIMMModel`) is the network of :mod:`agents.policies.learned_imm` in torch: a GRU over the
env's observation and the IMM's own detectors, whose offsets set imm_cv_ct's per-look parameters, and the
differentiable IMM they drive. It implements the model interface of the backprop trainer of the q-policy
(``ChainModel`` of ``agents.training.backprop``: ``reset_state``, ``start_rows``, ``begin_chunk``, ``step``,
``architecture``, ``policy_weights``, ``policy_config``), so that trainer runs it as ``--tracker imm_cv_ct``.

Until that trainer is in this package, :func:`train_learned_imm` (``python -m agents.training.learned_imm``) is a
minimal driver of the same scheme: ``batch_episodes`` rows play training flights one after another (drawn by
:func:`radar_env.draws.draw_episodes` from per-row streams ``default_rng([seed, r, n])``, ``n`` the row's episode
count; training seeds ``< 900_000``); the numba :class:`radar_env.tracking.Tracker`, stepped in lockstep at the
constant ``feature_q_g``, gives the env's observation exactly as ``RadarTrack-v0`` computes it; one optimiser step
per chunk of ``chunk_looks`` looks of every row: the pooled position MSE of the chunk's looks after the track start,
backpropagated through the IMM into the network, gradient norm clipped, Adam; the graph is cut between chunks (the
GRU state, the IMM's modes and the detectors are detached). Validation every ``eval_every`` steps on fixed suites
of training-range seeds ``900_000 + i`` (disjoint from the training streams and from the held-out evaluation seeds
``>= 10_000_000``), scored as the ratio of pooled position RMSEs to imm_cv_ct's on the same episodes (geometric mean
over ``select_on``) by the numpy inference (:class:`agents.policies.learned_imm.LearnedIMM`); the best checkpoint
is kept in ``best/``.

Run folder ``<out>/<name>.partial/`` until done, then ``<out>/<name>/``: ``config.json``, ``command.txt``,
``policy.npz`` + ``policy.json`` + ``env_config.json`` (the final weights), ``best/`` (the best validation checkpoint
and its ``selection.json``), ``summary.json`` (times, throughput, the validation history), ``tb/`` (TensorBoard).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import shlex
import sys
import time
import tomllib
from pathlib import Path

import numpy as np
import torch

from baselines.imm_cv_ct import IMM_CV_CT_PARAMS, look_parameter_names, tuned_imm_cv_ct_spec
from baselines.registry import run_tracker
from baselines.trackers import observation_layout
from radar_env import torch_chain as tc
from radar_env import torch_imm as ti
from radar_env.config import EnvConfig
from radar_env.draws import draw_episodes
from radar_env.episode import stack_episodes
from radar_env.observation import DEFAULT_FEATURES
from radar_env.units import DEG, G0_M_S2

from agents.evaluation.metrics import errors, failed_runs, jsonable, region_masks
from agents.evaluation.suites import draw_suite
from agents.policies.learned_imm import (LearnedIMM, ParamMap, detector_inputs, detector_names, initial_detectors,
                                         save_learned_imm, weight_shapes)
from agents.policies.bundle import _tuples

__all__ = ["LearnedIMMModel", "make_model", "HP_FILE", "load_hp", "train_learned_imm", "pooled_rmse", "main",
           "lockstep", "forward_episodes",
           "SELECTION_SEED_BASE", "MAX_TRAIN_SEED"]

DTYPE = torch.float64
HP_FILE = Path(__file__).with_name("hyperparams") / "learned_imm.toml"
SELECTION_SEED_BASE = 900_000
MAX_TRAIN_SEED = SELECTION_SEED_BASE


# ===================================================================================================== the model
class LearnedIMMModel(torch.nn.Module):
    """The learned IMM in torch (the ``ChainModel`` interface, module docstring).

    Args:
        obs_size: entries of the env's observation. hidden_size: GRU width. head: widths of tanh layers between the
            GRU and the output layer (may be empty).
        spec: the ``IMMCVCTSpec`` whose per-look parameters the network offsets (the tuned ``imm_cv_ct``).
        feature_q_m_s2: the constant q the lockstep numba Tracker (the observation's chain) is stepped with.
        compile: run the IMM's look through ``torch.compile`` (same numbers to rounding; faster once compiled).
    """

    kind = "imm_cv_ct"

    def __init__(self, obs_size, hidden_size, head, spec, feature_q_m_s2, compile=False):
        super().__init__()
        self.spec = spec
        self.names = look_parameter_names(spec)
        self.base = {n: getattr(spec, n) for n, *_ in IMM_CV_CT_PARAMS if getattr(spec, n) is not None}
        self.pmap = ParamMap(self.base, self.names)
        self._pmap_t = self.pmap.tensors(torch)
        self.consts = ti.IMMConstants(**spec.filter_constants())
        self._inverse = torch.argsort(self.consts.order)
        self.obs_size, self.hidden_size, self.head_sizes = int(obs_size), int(hidden_size), [int(n) for n in head]
        self.n_det = len(detector_names(spec.n_modes))
        self.gru = torch.nn.GRUCell(self.obs_size + self.n_det, self.hidden_size, dtype=DTYPE)
        layers, prev = [], self.hidden_size
        for n in self.head_sizes:
            layers.append(torch.nn.Linear(prev, n, dtype=DTYPE))
            prev = n
        self.head = torch.nn.ModuleList(layers)
        self.out = torch.nn.Linear(prev, len(self.names), dtype=DTYPE)
        with torch.no_grad():          # zero offsets: imm_cv_ct with its tuned values
            self.out.weight.zero_()
            self.out.bias.zero_()
        self.feature_q_m_s2 = float(feature_q_m_s2)
        self._look = torch.compile(ti.look, dynamic=False) if compile else ti.look
        self.h = self.state = self.det = None
        idx = {n: i for i, n in enumerate(self.names)}
        M = spec.n_modes
        self._iq = [idx["q_cv_g"], idx["q_ct_g"]] + ([idx["q_high_g"]] if M == 3 else [])
        self._ip = [idx["p_stay_cv"], idx["p_stay_ct"]] + ([idx["p_stay_high"]] if M == 3 else [])
        self._iw = idx["sigma_omega_deg_s15"]

    # ---- the network and its parameters
    def offsets(self, obs, h):
        """``(delta (B, n_par), h')`` for observations ``obs (B, F)`` (float64) and state ``h``; the detectors are
        the model's (``self.det``)."""
        h = self.gru(torch.cat((obs, self.det), 1), h)
        y = h
        for layer in self.head:
            y = torch.tanh(layer(y))
        return self.out(y), h

    def imm_parameters(self, delta):
        """The IMM's per-look arrays, components first, modes in the spec's order: ``q_m_s2 (M, B)``,
        ``sig_w2 (B,)`` (rad^2/s^3), ``log_Pi (M, M, B)``, from offsets ``delta (B, n_par)``."""
        s = self.pmap.transformed(delta, torch, self._pmap_t)
        q = torch.exp(s[:, self._iq]).T * G0_M_S2
        sig_w2 = torch.exp(2.0 * s[:, self._iw]) * (DEG * DEG)
        u = s[:, self._ip]
        log_Pi = ti.switch_log_probs(-torch.nn.functional.softplus(-u), -torch.nn.functional.softplus(u))
        return q, sig_w2, log_Pi.permute(1, 2, 0)

    def physical(self, delta):
        """The parameters in their units (g, deg/s^1.5, probabilities) ``(B, n_par)``, as the numpy inference
        gives them (for logs and tests)."""
        return self.pmap.physical(delta.detach().numpy())

    # ---- the ChainModel interface
    def reset_state(self, n_rows):
        self.h = torch.zeros((n_rows, self.hidden_size), dtype=DTYPE)
        eye = torch.eye(4, dtype=DTYPE)[:, :, None].repeat(1, 1, n_rows)
        self.state = ti.start(tc.ChainState(torch.zeros((4, n_rows), dtype=DTYPE), eye), self.consts)
        self.det = torch.as_tensor(initial_detectors(self.spec, n_rows))

    def start_rows(self, tracker, rows):
        """Rows ``rows`` have just been loaded: their modes at the common track start (``tracker.x/P[rows]``),
        zero GRU state, the start's detectors."""
        r = torch.as_tensor(np.asarray(rows, dtype=np.int64))
        new = ti.start(tc.ChainState.from_xP(tracker.x[rows], tracker.P[rows]), self.consts)
        st = [t.detach().clone() for t in self.state]
        for t, n in zip(st, new):
            t[..., r] = n
        self.state = ti.IMMState(*st)
        self.h = self.h.detach().clone()
        self.h[r] = 0.0
        self.det = self.det.detach().clone()
        self.det[r] = torch.as_tensor(initial_detectors(self.spec, len(r)))

    def begin_chunk(self, tracker=None):
        self.h, self.state, self.det = self.h.detach(), self.state.detach(), self.det.detach()

    def step(self, looks, j, obs):
        """Look ``j`` of ``looks`` for every row, reading ``obs (B, F)``: returns the combined estimate
        ``x (4, B)`` (components first) and the q (m/s^2, numpy) for the lockstep Tracker (``feature_q``)."""
        delta, self.h = self.offsets(obs, self.h)
        q, sig_w2, log_Pi = self.imm_parameters(delta)
        self.state, rec = self._look(self.state, looks.dt_s[j], looks.G[j], looks.z_m[j], looks.R_m2[j],
                                     looks.mask[j], q, sig_w2, log_Pi, self.consts)
        mu = torch.exp(rec.modes.log_mu[self._inverse]).T
        self.det = detector_inputs(mu, rec.omega, torch.sqrt(rec.omega_var), torch).detach()
        self.record, self.delta = rec, delta
        return rec.x, np.full(looks.B, self.feature_q_m_s2)

    def architecture(self):
        return {"input_size": self.obs_size + self.n_det, "hidden_size": self.hidden_size,
                "head": list(self.head_sizes), "n_par": len(self.names)}

    def policy_weights(self):
        w = {"gru.weight_ih": self.gru.weight_ih, "gru.weight_hh": self.gru.weight_hh, "gru.bias_ih": self.gru.bias_ih,
             "gru.bias_hh": self.gru.bias_hh, "out.weight": self.out.weight, "out.bias": self.out.bias}
        for i, layer in enumerate(self.head):
            w[f"head.{i}.weight"], w[f"head.{i}.bias"] = layer.weight, layer.bias
        out = {k: v.detach().numpy().copy() for k, v in w.items()}
        assert {k: v.shape for k, v in out.items()} == weight_shapes(self.architecture())
        return out

    def policy_config(self, cfg):
        return {"model": self.kind, "architecture": self.architecture(), "input_features": list(cfg.features),
                "detectors": list(detector_names(self.spec.n_modes)), "parameters": list(self.names),
                "base_parameters": dict(self.base), "feature_q_g": self.feature_q_m_s2 / G0_M_S2,
                "output": "s = L + (H - L) sigmoid(u0 + out(head(h))) per parameter, L, H its range in log (noises) "
                          "or logit (stay probabilities) space, u0 at the base value; param = exp(s) or sigmoid(s)"}

    def inference(self, cfg, env_kwargs):
        """The numpy :class:`agents.policies.learned_imm.LearnedIMM` of the current weights."""
        return LearnedIMM(self.policy_weights(), self.policy_config(cfg), env_kwargs)

    def save_checkpoint(self, directory, cfg, env_kwargs, extra=None):
        """A checkpoint folder (:func:`agents.policies.learned_imm.save_learned_imm`); ``extra``:
        ``selection.json`` beside it."""
        path = save_learned_imm(directory, self.policy_weights(), self.policy_config(cfg), env_kwargs)
        if extra is not None:
            (Path(directory) / "selection.json").write_text(json.dumps(jsonable(extra), indent=1, allow_nan=False))
        return path


def make_model(hp, cfg):
    """The learned IMM for hyperparameters ``hp`` (``hidden_size``, ``head``, ``feature_q_g``, ``compile``) and the
    env config ``cfg``, around the registered imm_cv_ct's tuned spec."""
    return LearnedIMMModel(len(cfg.features), hp["hidden_size"], hp["head"], tuned_imm_cv_ct_spec(),
                           hp["feature_q_g"] * G0_M_S2, compile=bool(hp.get("compile", False)))


# ================================================================================================= the driver
def load_hp(path=None, overrides=None):
    """The hyperparameters: ``agents/training/hyperparams/learned_imm.toml`` (or ``path``), updated by
    ``overrides``; checked (``ValueError`` naming the key)."""
    hp = tomllib.loads(Path(path or HP_FILE).read_text())["RadarTrack-v0"]
    hp.update(overrides or {})
    ints = ("n_steps", "batch_episodes", "chunk_looks", "hidden_size", "eval_every")
    for k in ints:
        if not (isinstance(hp.get(k), int) and hp[k] >= 1):
            raise ValueError(f"--hp {k}: must be an integer >= 1, got {hp.get(k)!r}")
    for k in ("learning_rate", "max_grad_norm", "loss_scale_m", "feature_q_g"):
        if not (isinstance(hp.get(k), (int, float)) and math.isfinite(hp[k]) and hp[k] > 0):
            raise ValueError(f"--hp {k}: must be a number > 0, got {hp.get(k)!r}")
    if not (isinstance(hp.get("lr_final_fraction"), (int, float)) and 0 <= hp["lr_final_fraction"] <= 1):
        raise ValueError(f"--hp lr_final_fraction: must be in [0, 1], got {hp.get('lr_final_fraction')!r}")
    bad = [n for n in hp["select_on"] if n not in hp["eval_scenarios"]]
    if bad:
        raise ValueError(f"--hp select_on: {bad} are not among eval_scenarios {list(hp['eval_scenarios'])}")
    known = set(ints) | {"learning_rate", "max_grad_norm", "loss_scale_m", "feature_q_g", "lr_final_fraction",
                         "select_on", "eval_scenarios", "head", "env_kwargs", "compile", "tracker"}
    unknown = sorted(set(hp) - known)
    if unknown:
        raise ValueError(f"--hp: unknown hyperparameter(s) {unknown}; valid: {sorted(known)}")
    return hp


def _env_config(hp):
    ek = dict(hp["env_kwargs"])
    if ek.get("scenario", "random") not in ("random", "random_radars"):
        raise ValueError(f"env_kwargs: training uses the random generators only, got scenario {ek['scenario']!r}")
    ek.setdefault("features", list(DEFAULT_FEATURES))
    return ek, EnvConfig.from_kwargs(**_tuples(ek))


def pooled_rmse(batch, run):
    """Pooled position RMSE (m) after the track start; ``inf`` if any run's estimate is non-finite there."""
    used = region_masks(batch, run.start_index)["used"]
    if failed_runs(batch, run, used).any():
        return math.inf
    ep, _ = errors(batch, run)
    return float(np.sqrt(np.mean(ep[used] ** 2)))


class _Selection:
    """Fixed validation suites (training-range seeds ``900_000 + i``) and imm_cv_ct's RMSE on them."""

    def __init__(self, scenarios, select_on):
        self.select_on = tuple(select_on)
        self.suites = {}
        for name, runs in scenarios.items():
            eps = draw_suite(name, int(runs), seed=SELECTION_SEED_BASE)
            batch = stack_episodes(eps)
            self.suites[name] = (eps, batch, pooled_rmse(batch, run_tracker("imm_cv_ct", eps)))

    def score(self, imm: LearnedIMM):
        t0, row = time.time(), {}
        for name, (eps, batch, ref) in self.suites.items():
            rmse = pooled_rmse(batch, imm.run(eps))
            row[f"{name}_rmse_m"], row[f"imm_cv_ct_rmse_m_{name}"] = rmse, ref
            row[f"{name}_ratio_imm_cv_ct"] = rmse / ref if math.isfinite(rmse) else math.inf
        row["selection_ratio"] = float(np.exp(np.mean([np.log(row[f"{n}_ratio_imm_cv_ct"]) for n in self.select_on])))
        row["eval_s"] = time.time() - t0
        return row


class _Rows:
    """``B`` rows playing training flights one after another, the lockstep Tracker, one chunk per call."""

    def __init__(self, model, cfg, B, C, seed):
        self.model, self.cfg, self.B, self.C, self.seed = model, cfg, int(B), int(C), int(seed)
        self.layout, _ = observation_layout(cfg)
        self.tracker = cfg.track_start.tracker(self.B)
        self.count = np.zeros(self.B, dtype=np.int64)           # episodes each row has started
        self.obs = np.zeros((self.B, len(cfg.features)))
        self.episodes_done = self.row_looks = self.scored_looks = 0
        model.reset_state(self.B)
        self._load(np.arange(self.B))

    def _load(self, rows):
        cfg = self.cfg
        rngs = [np.random.default_rng([self.seed, int(r), int(self.count[r])]) for r in rows]
        batch = draw_episodes(cfg.scenario, cfg.radar, cfg.random_scenario_config, rngs, cfg.warmup_scans)
        out = self.tracker.load(rows, [batch.episode(i) for i in range(rows.size)])
        self.obs[rows] = self.layout.encode(out, np.full(rows.size, cfg.track_start.warmup_q_m_s2))
        self.model.start_rows(self.tracker, rows)
        self.count[rows] += 1

    def chunk(self):
        """The loss (pooled position MSE, m^2) of one chunk of every row, a graph to backpropagate."""
        tr = self.tracker
        ended = np.flatnonzero(tr.k >= tr.n_looks)
        if ended.size:
            self.episodes_done += int(ended.size)
            self._load(ended)
        self.model.begin_chunk(tr)
        get = tr.look_data
        looks = tc.looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"),
                                     np.minimum(tr.n_looks, tr.k + self.C), tr.k.copy(), tr.t_last)
        x = lockstep(self.model, tr, self.layout, self.obs, looks)
        self.row_looks += self.B * looks.J
        self.scored_looks += int(looks.scored.sum())
        return tc.pooled_position_mse(x, looks)


def lockstep(model, tracker, layout, obs, looks, records=None):
    """The columns of ``looks`` (the next looks of every row of ``tracker``): the model steps each (reading
    ``obs (B, F)``, float64, updated in place with the next observations), the numba ``tracker`` steps the rows
    that have the look with the model's q, the env's observation of its output is encoded. Returns the combined
    estimates ``x (B, J, 4)``; ``records``: a list to append ``(IMMRecord, delta)`` of each look to."""
    active = looks.scored.numpy()
    B, xs = looks.B, []
    for j in range(looks.J):
        x, q = model.step(looks, j, torch.from_numpy(obs))
        xs.append(x)
        if records is not None:
            records.append((model.record, model.delta))
        rows = np.flatnonzero(active[j])
        if rows.size:
            o = tracker.step(q[rows], rows=None if rows.size == B else rows)
            obs[rows] = layout.encode(o, q[rows])
    return torch.stack(xs).permute(2, 0, 1)


def forward_episodes(model, episodes, cfg):
    """The model over whole ``episodes`` from the common track start (lockstep, no chunks): ``(x (B, J, 4), looks,
    records)`` with ``records`` the ``(IMMRecord, delta)`` of each column (tests and diagnostics)."""
    episodes = list(episodes)
    B = len(episodes)
    layout, _ = observation_layout(cfg)
    tr = cfg.track_start.tracker(B)
    out = tr.load(np.arange(B), episodes)
    obs = layout.encode(out, np.full(B, cfg.track_start.warmup_q_m_s2)).astype(np.float64)
    model.reset_state(B)
    model.start_rows(tr, np.arange(B))
    _, looks = tc.handover(tr)
    records = []
    return lockstep(model, tr, layout, obs, looks, records), looks, records


def _lr(hp, step):
    f = hp["lr_final_fraction"]
    return hp["learning_rate"] * (f + (1.0 - f) * 0.5 * (1.0 + math.cos(math.pi * min(step / hp["n_steps"], 1.0))))


def train_learned_imm(hp, seed=0, out="runs", name=None, progress=True, verbose=1, command=None):
    """Train a learned IMM (module docstring) with hyperparameters ``hp`` (:func:`load_hp`); returns the run
    folder. ``ValueError`` for bad arguments, before the run folder is made."""
    torch.set_num_threads(1)
    seed = int(seed)
    if not 0 <= seed < MAX_TRAIN_SEED:
        raise ValueError(f"--seed: training seeds must lie in [0, {MAX_TRAIN_SEED}), got {seed}")
    env_kwargs, cfg = _env_config(hp)
    run = Path(out) / (name or f"learned_imm_s{seed}_{time.strftime('%Y%m%d-%H%M%S')}")
    part = run.with_name(run.name + ".partial")
    if run.exists():
        raise ValueError(f"--name: run folder {str(run)!r} already exists")
    torch.manual_seed(seed)
    model = make_model(hp, cfg)
    opt = torch.optim.Adam(model.parameters(), lr=hp["learning_rate"])
    selection = _Selection(hp["eval_scenarios"], hp["select_on"])
    part.mkdir(parents=True, exist_ok=True)
    config = {"method": "backprop", "tracker": "imm_cv_ct", "seed": seed, **hp, "env_kwargs": env_kwargs}
    (part / "config.json").write_text(json.dumps(config, indent=1))
    (part / "command.txt").write_text((command or "") + "\n")
    (part / "env_config.json").write_text(json.dumps(env_kwargs, indent=1))
    from torch.utils.tensorboard import SummaryWriter
    writer = SummaryWriter(str(part / "tb"))
    rows = _Rows(model, cfg, hp["batch_episodes"], hp["chunk_looks"], seed)
    history, best = [], {"ratio": math.inf, "step": None, "wall_s": None}
    t_start, train_s = time.perf_counter(), 0.0
    bar = None
    if progress:
        from tqdm import tqdm
        bar = tqdm(total=hp["n_steps"], desc="learned IMM", unit="step", file=sys.stderr)

    def validate(step):
        row = {"step": step, **selection.score(model.inference(cfg, env_kwargs)),
               "wall_s": time.perf_counter() - t_start, "episodes_done": rows.episodes_done}
        row["best"] = row["selection_ratio"] < best["ratio"]
        if row["best"]:
            best.update(ratio=row["selection_ratio"], step=step, wall_s=row["wall_s"])
            model.save_checkpoint(part / "best", cfg, env_kwargs, row)
        history.append(row)
        for k, v in row.items():
            if k.endswith("ratio_imm_cv_ct") or k == "selection_ratio":
                writer.add_scalar(f"eval/{k}", v if math.isfinite(v) else float("nan"), step)
        if verbose and bar is None:
            print(f"[eval @ step {step}] selection ratio {row['selection_ratio']:.4f}{' *best*' if row['best'] else ''}"
                  f" ({row['eval_s']:.0f} s)", file=sys.stderr, flush=True)
        (part / "history.json").write_text(json.dumps(jsonable(history), indent=1))

    validate(0)
    for step in range(1, hp["n_steps"] + 1):
        t0 = time.perf_counter()
        for g in opt.param_groups:
            g["lr"] = _lr(hp, step - 1)
        loss = rows.chunk()
        opt.zero_grad(set_to_none=True)
        (loss / hp["loss_scale_m"] ** 2).backward()
        gn = float(torch.nn.utils.clip_grad_norm_(model.parameters(), hp["max_grad_norm"]))
        if not math.isfinite(gn):
            raise FloatingPointError(f"step {step}: the gradient is not finite (loss {float(loss)!r})")
        opt.step()
        train_s += time.perf_counter() - t0
        writer.add_scalar("train/chunk_rms_error_m", math.sqrt(float(loss)), step)
        writer.add_scalar("train/grad_norm", gn, step)
        if bar is not None:
            bar.update(1)
            bar.set_postfix(rms=f"{math.sqrt(float(loss)):.3g}", best=f"{best['ratio']:.4f}")
        elif verbose and step % 10 == 0:
            print(f"step {step}: chunk rms {math.sqrt(float(loss)):.1f} m, grad norm {gn:.3g}, "
                  f"{time.perf_counter() - t_start:.0f} s", file=sys.stderr, flush=True)
        if step % hp["eval_every"] == 0 or step == hp["n_steps"]:
            validate(step)
    if bar is not None:
        bar.close()
    writer.close()
    model.save_checkpoint(part, cfg, env_kwargs)
    wall = time.perf_counter() - t_start
    summary = {"method": "backprop", "tracker": "imm_cv_ct", "seed": seed, "steps": hp["n_steps"],
               "episodes_done": rows.episodes_done, "row_looks": rows.row_looks, "scored_looks": rows.scored_looks,
               "wall_s": wall, "train_s": train_s, "validation_s": float(sum(r["eval_s"] for r in history)),
               "row_looks_per_s": rows.row_looks / max(train_s, 1e-9),
               "episodes_per_s": rows.episodes_done / max(train_s, 1e-9),
               "best_selection_ratio": best["ratio"], "best_step": best["step"], "best_wall_s": best["wall_s"],
               "loadavg_1min_at_end": os.getloadavg()[0], "torch_threads": torch.get_num_threads(),
               "selection_history": history}
    (part / "summary.json").write_text(json.dumps(jsonable(summary), indent=1))
    part.rename(run)
    if verbose:
        print(f"run: {run}\n{hp['n_steps']} steps in {wall:.0f} s; best selection ratio (learned IMM / imm_cv_ct) "
              f"{best['ratio']:.4f} at step {best['step']} ({best['wall_s']:.0f} s)", file=sys.stderr)
    return run


def main(argv=None):
    """``python -m agents.training.learned_imm [--seed S] [--out DIR] [--name N] [--hp KEY=JSON ...]``."""
    ap = argparse.ArgumentParser(prog="python -m agents.training.learned_imm",
                                 description="Train the learned IMM by backpropagation (agents/training/learned_imm.py)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", default="runs")
    ap.add_argument("--name")
    ap.add_argument("--hp", action="append", default=[], metavar="KEY=JSON")
    ap.add_argument("--hyperparams", metavar="FILE.toml")
    ap.add_argument("--no-progress", action="store_true")
    args = ap.parse_args(argv)
    over = {}
    for it in args.hp:
        k, _, v = it.partition("=")
        try:
            over[k] = json.loads(v)
        except json.JSONDecodeError:
            over[k] = v
    try:
        hp = load_hp(args.hyperparams, over)
        return train_learned_imm(hp, args.seed, args.out, args.name, progress=not args.no_progress,
                                 command=" ".join(["python -m agents.training.learned_imm",
                                                   *map(shlex.quote, argv or sys.argv[1:])]))
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None


if __name__ == "__main__":
    main()
