"""Tune the classical baselines on the training scenario distribution (never on evaluation seeds).

``python -m baselines.tuning [--runs N] [--trackers kf,imm2,imm_cv_ct,kf_rdot,...]`` (:data:`TUNABLE`) draws ``N``
random-scenario episodes with tuning seeds (:data:`baselines.seeds.TUNING_SEEDS`, disjoint from the evaluation's
held-out seeds) and, for each tuned tracker, minimises the pooled position RMSE after the track start over its
parameters with a continuous optimizer (:func:`minimize_with_restarts`):

* every parameter is searched in a transformed space, ``log`` for noise levels, ``logit`` for probabilities, inside
  bounds that are documented limits (:class:`Param`: why each bound is where it is);
* Nelder-Mead (``scipy.optimize.minimize``, bounded) from ``starts`` points (default 3: the previous tuned values,
  then uniform draws in the transformed box from ``numpy.random.default_rng(seed)``), then restarts from the best
  point with a fresh simplex until a restart improves the criterion by less than ``fatol`` (at most 3 restarts),
  which guards against Nelder-Mead's known stalls on a collapsed simplex;
* each parameter of the optimum is reported ``interior`` or at its lower/upper bound with that bound's documented
  meaning; an optimum on a bound marked ``search bound`` (not a physical limit) is reported as such.

Tuned trackers (:data:`TUNED_TRACKERS`): ``kf`` (``kf_tuned``'s constant q), ``imm2`` (the 2-mode CV IMM's two mode
noises and two stay probabilities), ``imm_cv_ct`` (from ``baselines.imm_cv_ct_runner``; skipped with a message if that
module or its tuning interface is not there), and ``kf_rdot``, ``imm2_rdot``, ``imm_cv_ct_rdot``: the same trackers also
updating on each plot's radial velocity, tuned on their own over the same parameters (first start: their
position-only sibling's values), and ``imm_ct_bank`` (``imm_cv_ct`` over a bank of six CT modes: its eight
parameters and three entry rates; first start: ``imm_cv_ct``'s values, the rates at
``DEFAULT_CT_BANK_RATES_DEG_S``), and ``imm_ct_bank_rdot`` (the bank with range rate; first start: the bank's
rates and ``imm_cv_ct_rdot``'s other values, :data:`FIRST_START_FROM`). The 2-mode IMM as tuned by the grid search
of earlier versions is kept as ``imm2_grid`` (:data:`IMM2_GRID_PARAMS`, its RMSE re-measured on each run), so a
change is visible.

Writes ``baselines/tuned.json``: per tracker the optimum, its tuning RMSE, the bounds and transforms, whether each
parameter is interior, every start's result, the evaluation count; and the seeds, runs and command. Trackers not
tuned in a run keep their entry from the existing file. Runtime with the default 200 runs (``tuning.seconds`` in the
file): kf + imm2, 58 + 509 criterion evaluations, 22 min on the 2-core machine shared with six other jobs (nice 10);
about 7.5 min at the idle machine's 1.2 s (kf) and 0.76 s (imm2) per evaluation.
"""

from __future__ import annotations

import json
import math
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable

import numpy as np
from scipy.optimize import minimize

from radar_env.envs.config import EnvConfig
from radar_env.sim.episode import stack_episodes

from . import trackers as T
from .seeds import TUNING_SEEDS, draw_random_episodes
from .trackers import imm2_spec_from_params
from .tuned_params import TUNED_PATH, kf_q_m_s2_from_params
from .tuning_options import TUNABLE, build_parser, check_options

__all__ = ["Param", "TunedTracker", "TUNED_TRACKERS", "IMM2_GRID_PARAMS", "minimize_with_restarts", "tune",
           "pooled_rmse", "main"]

SPACES = ("log", "logit")


@dataclass(frozen=True)
class Param:
    """One tuned parameter: its name in the params dict, bounds (in its own units), the space the optimizer
    searches (``log``: noise levels; ``logit``: probabilities in (0, 1)), and what each bound means (a physical
    limit, or ``"search bound"`` if it is only where the search stops)."""

    name: str
    lower: float
    upper: float
    space: str
    lower_means: str
    upper_means: str

    def __post_init__(self):
        if self.space not in SPACES:
            raise ValueError(f"Param {self.name!r}: space must be one of {SPACES}, got {self.space!r}")
        hi = 1.0 if self.space == "logit" else math.inf
        if not (math.isfinite(self.lower) and math.isfinite(self.upper) and 0.0 < self.lower < self.upper < hi):
            raise ValueError(f"Param {self.name!r}: bounds must satisfy 0 < lower < upper{' < 1' if hi == 1 else ''}, "
                             f"got ({self.lower!r}, {self.upper!r})")

    def to_u(self, v):
        v = float(v)
        return math.log(v) if self.space == "log" else math.log(v / (1.0 - v))

    def from_u(self, u):
        u = float(u)
        v = math.exp(u) if self.space == "log" else 1.0 / (1.0 + math.exp(-u))
        return float(min(max(v, self.lower), self.upper))      # the bounded search may round a hair outside

    @property
    def u_bounds(self):
        return self.to_u(self.lower), self.to_u(self.upper)


def minimize_with_restarts(f, params, x0, starts=3, seed=0, xatol=1e-2, fatol=1e-2, max_restarts=3,
                           maxfev_per_dim=50, edge_tol=1e-2, progress=None):
    """Minimise ``f(params_dict) -> float`` over the box of ``params`` (:class:`Param`), see the module docstring.

    Args:
        x0: the first start (dict; clipped into the bounds); the other ``starts - 1`` are uniform in the
            transformed box from ``numpy.random.default_rng(seed)``.
        starts: number of independent starts, >= 1 (the tuner uses 3).
        xatol, fatol: Nelder-Mead's tolerances, in the transformed space and in the criterion's units.
        max_restarts: restarts from the best point (fresh simplex) while one improves the best by >= ``fatol``.
        maxfev_per_dim: evaluation budget of one start, per parameter.
        edge_tol: a parameter within this distance of a bound, in the transformed space, is "at" that bound.
    Returns:
        dict: ``params`` (the optimum), ``value``, ``parameters`` (per name: value, bounds, space, ``interior``,
        ``at`` (None, "lower", "upper") and the bound's meaning), ``starts`` (each start's ``x0``, ``x``, ``value``,
        ``evaluations``, ``kind`` "start"/"restart"), ``evaluations`` (distinct points evaluated).
    A non-finite criterion raises ``ValueError`` naming the parameters (never a silent number)."""
    if isinstance(starts, bool) or not isinstance(starts, int) or starts < 1:
        raise ValueError(f"starts must be an integer >= 1, got {starts!r}")
    names = [p.name for p in params]
    lo = np.array([p.u_bounds[0] for p in params])
    hi = np.array([p.u_bounds[1] for p in params])
    cache = {}

    def to_dict(u):
        return {p.name: p.from_u(v) for p, v in zip(params, u)}

    def fu(u):
        u = np.clip(np.asarray(u, dtype=np.float64), lo, hi)
        key = tuple(np.round(u, 12))
        if key not in cache:
            d = to_dict(u)
            v = float(f(d))
            if not math.isfinite(v):
                raise ValueError(f"tuning criterion is {v} at {d}; a tracker diverged or lost every run")
            cache[key] = v
            if progress:
                progress(len(cache), v)
        return cache[key]

    def run_from(u0, step):
        n = len(params)
        simplex = np.repeat(u0[None], n + 1, axis=0)
        for i in range(n):   # a step of `step` times the box width, towards the box's interior
            d = step * (hi[i] - lo[i])
            simplex[i + 1, i] += d if u0[i] + d <= hi[i] else -d
        n0 = len(cache)
        res = minimize(fu, u0, method="Nelder-Mead", bounds=list(zip(lo, hi)),
                       options={"xatol": xatol, "fatol": fatol, "maxfev": maxfev_per_dim * n,
                                "initial_simplex": simplex})
        u = np.clip(res.x, lo, hi)
        return u, fu(u), len(cache) - n0

    rng = np.random.default_rng(seed)
    u_starts = [np.clip([p.to_u(x0[p.name]) for p in params], lo, hi)]
    u_starts += [rng.uniform(lo, hi) for _ in range(starts - 1)]
    records, best_u, best_v = [], None, math.inf
    for u0 in u_starts:
        u, v, nfev = run_from(np.asarray(u0, dtype=np.float64), 0.1)
        records.append({"kind": "start", "x0": to_dict(u0), "x": to_dict(u), "value": v, "evaluations": nfev})
        if v < best_v:
            best_u, best_v = u, v
    for _ in range(max_restarts):
        u, v, nfev = run_from(best_u, 0.02)
        records.append({"kind": "restart", "x0": to_dict(best_u), "x": to_dict(u), "value": v, "evaluations": nfev})
        improved = best_v - v
        if v < best_v:
            best_u, best_v = u, v
        if improved < fatol:
            break
    report = {}
    for p, u, a, b in zip(params, best_u, lo, hi):
        at = "lower" if u - a <= edge_tol else "upper" if b - u <= edge_tol else None
        report[p.name] = {"value": p.from_u(u), "lower": p.lower, "upper": p.upper, "space": p.space,
                          "interior": at is None, "at": at,
                          "bound_means": None if at is None else (p.lower_means if at == "lower" else p.upper_means)}
    return {"params": to_dict(best_u), "value": best_v, "parameters": report, "starts": records,
            "evaluations": len(cache), "names": names}


def _used(batch, run):
    K = run.x.shape[1]
    return batch.valid[:, :K] & (np.arange(K)[None, :] >= run.start_index[:, None])


def pooled_rmse(batch, run):
    """Pooled position RMSE (m) over the valid looks at and after each run's track start: the tuning criterion."""
    K = run.x.shape[1]
    e2 = np.sum((run.x[..., :2] - batch.truth[:, :K, :2]) ** 2, axis=-1)
    return float(np.sqrt(np.mean(e2[_used(batch, run)])))


def pooled_anees(batch, run):
    """The average NEES over the same looks, over the 4 states (1 for a consistent tracker); inf if a covariance
    there is not positive definite."""
    K = run.x.shape[1]
    used = _used(batch, run)
    d = (run.x - batch.truth[:, :K])[used]
    try:
        L = np.linalg.cholesky(run.P[used])
    except np.linalg.LinAlgError:
        return math.inf
    y = np.linalg.solve(L, d[..., None])[..., 0]
    return float(np.mean(np.sum(y * y, axis=-1)) / 4.0)


def criterion(batch, run, max_anees=None):
    """The tuning criterion: :func:`pooled_rmse`, times ``(ANEES / max_anees)^4`` where :func:`pooled_anees` exceeds
    ``max_anees`` (a consistency constraint as a steep penalty; None: none)."""
    v = pooled_rmse(batch, run)
    if max_anees is not None:
        v *= max(1.0, pooled_anees(batch, run) / max_anees) ** 4
    return v


# ------------------------------------------------------------------------------------------------ tuned trackers
@dataclass(frozen=True)
class TunedTracker:
    """A tunable tracker: ``run(params_dict, episodes, cfg) -> TrackRun`` (the tracker factory applied to
    episodes), its :class:`Param` box, the first start when no previous tuned values exist, and the consistency
    constraint of its :func:`criterion` (None: RMSE alone)."""

    name: str
    params: tuple
    run: Callable
    default_x0: dict
    max_anees: float | None = None


_NEGLIGIBLE_Q = ("1e-4 g: negligible process noise (the noise-free CV model in effect: 1e-3 m dt^2 per look against "
                 "plots of >= 10 m)")
_ACTION_MAX = "the action range's top (RadarTrack-v0's largest q level, 8.11 g)"
_ACTION_MIN = "the action range's bottom (RadarTrack-v0's smallest q level, 0.00182 g)"
_STAY_MAX = ("0.999: a mean sojourn of 1000 looks, longer than every tuning episode (at most 327 looks): above it the "
             "mode is in effect never left within an episode")
_STAY_MIN = "0.01: the mode is left at almost every look"


def _cfg_levels(cfg):
    return float(cfg.q_levels_g[0]), float(cfg.q_levels_g[-1])


def _kf_run(params, episodes, cfg, radial_velocity=False):
    q = kf_q_m_s2_from_params(params)
    return T.run_q_policy(episodes, lambda o: np.full(o.shape[0], q), "kf", T._with_range_rate(cfg, radial_velocity),
                          features=())


def _imm2_run(params, episodes, cfg, radial_velocity=False):
    return T.run_imm(episodes, imm2_spec_from_params(params), "imm2", cfg, radial_velocity=radial_velocity)


def _with_rdot(run):
    return lambda params, episodes, cfg: run(params, episodes, cfg, radial_velocity=True)


_QMIN, _QMAX = _cfg_levels(EnvConfig())
RDOT_MAX_ANEES = 2.0
"""The range-rate trackers are tuned for RMSE subject to ANEES <= 2 on the tuning episodes (:func:`criterion`): by
RMSE alone ``imm_cv_ct_rdot`` chose a CV-mode noise of 3e-5 g and an ANEES of 10 (its RMSE 2 % lower than at
ANEES 1.9): a covariance ten times too small on a real flight's straight legs, which are never noise-free."""
_KF_PARAMS = (Param("q_g", _QMIN, _QMAX, "log", _ACTION_MIN, _ACTION_MAX),)
_IMM2_PARAMS = (
    Param("q_low_g", 1e-4, 1.0, "log", _NEGLIGIBLE_Q,
          "search bound: 1 g, where the high mode's range starts (keeps the two modes' roles apart)"),
    Param("q_high_g", 1.0, _QMAX, "log", "search bound: 1 g, where the low mode's range ends", _ACTION_MAX),
    Param("p_stay_low", 0.01, 0.999, "logit", _STAY_MIN, _STAY_MAX),
    Param("p_stay_high", 0.01, 0.999, "logit", _STAY_MIN, _STAY_MAX))
_IMM2_X0 = {"q_low_g": 0.001, "q_high_g": 4.0, "p_stay_low": 0.995, "p_stay_high": 0.98}

TUNED_TRACKERS = {
    "kf": TunedTracker("kf", _KF_PARAMS, _kf_run, {"q_g": 0.75}),
    "imm2": TunedTracker("imm2", _IMM2_PARAMS, _imm2_run, _IMM2_X0),
    "kf_rdot": TunedTracker("kf_rdot", _KF_PARAMS, _with_rdot(_kf_run), {"q_g": 0.75}, RDOT_MAX_ANEES),
    "imm2_rdot": TunedTracker("imm2_rdot", _IMM2_PARAMS, _with_rdot(_imm2_run), _IMM2_X0, RDOT_MAX_ANEES),
}
"""The trackers :func:`tune` knows, by their key in ``tuned.json`` (``kf`` is the registry's ``kf_tuned``; a
``_rdot`` key is the same tracker also updating on the radial velocity, tuned on its own), besides ``imm_cv_ct`` and
``imm_cv_ct_rdot`` (:func:`tuned_tracker`)."""

IMM2_GRID_PARAMS = {"q_low_g": 0.001, "q_high_g": 4.0, "p_stay_low": 0.995, "p_stay_high": 0.98}
"""``imm2`` as tuned before the continuous tuner: the best of a 5 x 6 x 5 x 5 grid (q_low 0.001-0.1 g, q_high 1-32 g,
stay low 0.9-0.995, stay high 0.7-0.98) on the same 200 tuning episodes, on the grid's edge in three parameters.
Registered as ``imm2_grid``."""


FIRST_START_FROM = {"imm_ct_bank": ("imm_cv_ct",), "imm_ct_bank_rdot": ("imm_ct_bank", "imm_cv_ct_rdot")}
"""A tracker with no previous tuned values starts from these trackers' (the parameters they share; a later one's
value wins): the bank with range rate takes the bank's rates and imm_cv_ct_rdot's noises and switching, which
meet its ANEES constraint."""


def _first_start(old, name):
    """The merged previous values of :data:`FIRST_START_FROM`'s trackers for ``name`` (None: none of them)."""
    found = [old[k] for k in FIRST_START_FROM.get(name, ()) if k in old]
    return {k: v for entry in found for k, v in entry.items()} if found else None


def first_start_values(old, name):
    """The first start of tuned tracker ``name`` from the previous tuned file's entries ``old``: its own previous
    values, else :data:`FIRST_START_FROM`'s (the bank of CT modes: imm_cv_ct's, the rates from their defaults), else
    a range-rate variant's position-only sibling's; None: the tracker's default start."""
    return old.get(name) or _first_start(old, name) or old.get(name.removesuffix("_rdot"))


def _imm_cv_ct_entry(radial_velocity=False, bank=False):
    """The ``imm_cv_ct`` entry, built from ``baselines.imm_cv_ct_runner`` (engineer I's module) if it offers:
    ``imm_cv_ct_spec_from_params(dict)``, ``run_imm_cv_ct(episodes, spec, name, cfg[, start])``, the parameter
    table ``IMM_CV_CT_PARAMS`` (rows ``(name, unit, low, high, log_scale)``: ``log`` space if ``log_scale``, else
    ``logit``: the probabilities; the bounds are the valid ranges its spec accepts) and ``DEFAULT_IMM_CV_CT`` (a
    dataclass: the first start; a ``None`` value starts at the geometric mean of its bounds). ``bank``:
    ``imm_ct_bank``, the same IMM with a bank of six CT modes (``IMM_CT_BANK_PARAMS``: three entry rates more,
    starting at ``DEFAULT_CT_BANK_RATES_DEG_S``). Returns ``(entry, None)`` or ``(None, why it is skipped)``."""
    try:
        from . import imm_cv_ct_runner as mod
    except ImportError as e:
        return None, f"baselines.imm_cv_ct_runner is not importable ({e})"
    missing = [a for a in ("imm_cv_ct_spec_from_params", "run_imm_cv_ct", "IMM_CV_CT_PARAMS", "DEFAULT_IMM_CV_CT",
                           "IMM_CT_BANK_PARAMS", "default_ct_bank_spec") if not hasattr(mod, a)]
    if missing:
        return None, f"baselines.imm_cv_ct_runner has no {', '.join(missing)} (the tuning interface)"
    where = "the valid range of baselines.imm_cv_ct_runner.IMMCVCTSpec"
    params = tuple(Param(name, float(lo), float(hi), "log" if log_scale else "logit", where, where)
                   for name, _unit, lo, hi, log_scale in (mod.IMM_CT_BANK_PARAMS if bank else mod.IMM_CV_CT_PARAMS))
    default = mod.default_ct_bank_spec() if bank else mod.DEFAULT_IMM_CV_CT
    x0 = {}
    for p in params:
        v = (default.ct_rates_deg_s[int(p.name.split("_")[2]) - 1] if p.name.startswith("ct_rate_")
             else getattr(default, p.name, None))
        x0[p.name] = float(v) if v is not None else math.sqrt(p.lower * p.upper)
    starts = {}

    def run(p, episodes, cfg):
        key = id(episodes)
        if key not in starts:      # the common start once per episode list (it does not depend on p)
            starts.clear()
            starts[key] = mod.common_start(episodes, T._with_range_rate(cfg, radial_velocity))
        return mod.run_imm_cv_ct(episodes, mod.imm_cv_ct_spec_from_params(p), "imm_cv_ct", cfg, start=starts[key],
                                 radial_velocity=radial_velocity)

    name = ("imm_ct_bank" if bank else "imm_cv_ct") + ("_rdot" if radial_velocity else "")
    return TunedTracker(name, params, run, x0,
                        RDOT_MAX_ANEES if radial_velocity else None), None


def tuned_tracker(name):
    """The :class:`TunedTracker` ``name`` (:data:`TUNABLE`); ``(None, reason)`` semantics of
    :func:`_imm_cv_ct_entry` for ``imm_cv_ct``, ``imm_ct_bank`` and their ``_rdot`` variants, ``ValueError`` for an
    unknown name."""
    if name in ("imm_cv_ct", "imm_cv_ct_rdot", "imm_ct_bank", "imm_ct_bank_rdot"):
        return _imm_cv_ct_entry(name.endswith("_rdot"), bank=name.startswith("imm_ct_bank"))
    if name not in TUNED_TRACKERS:
        raise ValueError(f"unknown tuned tracker {name!r}; valid: {list(TUNABLE)}")
    return TUNED_TRACKERS[name], None


def tune(entry: TunedTracker, episodes, batch, cfg, x0=None, starts=3, seed=0, progress=None):
    """Tune ``entry`` on ``episodes`` (:func:`criterion`: :func:`pooled_rmse`, with ``entry.max_anees`` its ANEES
    constraint); returns the ``tuned.json`` entry: the optimum's parameters at top level, ``pos_rmse_m`` (and with
    a constraint ``anees``, ``max_anees``), and ``optimizer`` (bounds, interior flags, every start)."""
    t0 = time.time()
    first = dict(entry.default_x0)
    first.update({k: v for k, v in (x0 or {}).items() if k in first})
    res = minimize_with_restarts(lambda p: criterion(batch, entry.run(p, episodes, cfg), entry.max_anees),
                                 entry.params, first, starts=starts, seed=seed, progress=progress)
    out = dict(res["params"])
    best = entry.run(res["params"], episodes, cfg)
    out["pos_rmse_m"] = pooled_rmse(batch, best)
    if entry.max_anees is not None:
        out["anees"] = pooled_anees(batch, best)
        out["max_anees"] = entry.max_anees
    out["optimizer"] = {"method": "scipy.optimize.minimize Nelder-Mead (bounded) in log/logit space, restarts",
                        "starts": starts, "seed": seed, "parameters": res["parameters"], "runs": res["starts"],
                        "evaluations": res["evaluations"], "seconds": round(time.time() - t0, 1)}
    return out


def main(argv=None, prog="radar-track tune"):
    """``radar-track tune`` (options: :mod:`baselines.tuning_options`)."""
    args = build_parser(prog).parse_args(argv)
    names = check_options(args)
    args.out = _output_path(args)
    valid = list(TUNABLE)
    old = {}         # previous values: the file replaced, else the shipped ones (the starts and the kept entries)
    for src in (args.out, TUNED_PATH):
        try:
            with open(src) as f:
                old = json.load(f)
            break
        except (OSError, ValueError):
            continue
    old = old if isinstance(old, dict) else {}
    cfg = EnvConfig()
    t0 = time.time()
    episodes = draw_random_episodes(args.runs, seed=TUNING_SEEDS.start)
    batch = stack_episodes(episodes)
    out = {k: v for k, v in old.items() if k in valid}
    tuned, skipped = [], {}
    for name in names:
        entry, why = tuned_tracker(name)
        if entry is None:
            print(f"{name}: skipped: {why}", flush=True)
            skipped[name] = why
            continue
        tuned.append(name)

        def progress(n, v, name=name):
            if n % 25 == 0:
                print(f"  {name}: {n} evaluations, last {v:.2f} m ({time.time() - t0:.0f} s)", flush=True)

        x0 = first_start_values(old, name)
        res = tune(entry, episodes, batch, cfg, x0=x0, starts=args.starts, progress=progress)
        out[name] = res
        flags = ", ".join(f"{k} {v['value']:.4g}" + ("" if v["interior"] else f" (at {v['at']} bound)")
                          for k, v in res["optimizer"]["parameters"].items())
        anees = f", ANEES {res['anees']:.2f} (at most {res['max_anees']})" if "anees" in res else ""
        print(f"{name}: {flags}; pos RMSE {res['pos_rmse_m']:.2f} m{anees} ({res['optimizer']['evaluations']} "
              f"evaluations, {res['optimizer']['seconds']:.0f} s)", flush=True)
    grid = dict(IMM2_GRID_PARAMS)
    grid["pos_rmse_m"] = pooled_rmse(batch, T.run_imm(episodes, imm2_spec_from_params(grid), "imm2_grid", cfg))
    grid["note"] = ("imm2 as tuned by the earlier 5x6x5x5 grid search (on its edge in q_low, p_stay_low, p_stay_high); "
                    "kept for comparison as imm2_grid, its RMSE re-measured on these episodes")
    out["imm2_grid"] = grid
    out["tuning"] = {"suite": "random", "runs": args.runs, "seed_start": TUNING_SEEDS.start,
                     "seeds": [TUNING_SEEDS.start, TUNING_SEEDS.start + args.runs - 1],
                     "criterion": "pooled position RMSE after the track start",
                     "tuned_in_this_run": tuned, "skipped": skipped,
                     "command": " ".join([prog, *(sys.argv[1:] if argv is None else argv)]),
                     "seconds": round(time.time() - t0, 1)}
    replaced = _describe_replaced(args.out, old, out, tuned)
    from radar_env.common.files import write_text_replacing
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    try:
        write_text_replacing(args.out, json.dumps(out, indent=1, allow_nan=False))
    except (OSError, ValueError) as e:
        raise SystemExit(f"error: --out: could not write {args.out} ({getattr(e, 'strerror', None) or e})") from None
    print(f"wrote {args.out} ({time.time() - t0:.0f} s)" + (f"; replaced {replaced}" if replaced else ""))


def _output_path(args):
    """The file ``tune`` writes: ``--out``; with ``--replace-shipped`` the shipped ``baselines/tuned.json``; by
    default ``tuned.json`` in a new run folder ``runs/tune_<time>/``. The shipped file is written only with
    ``--replace-shipped``; an ``--out`` that exists and is not a regular file is refused (one line)."""
    from radar_env.common.files import check_output_file, same_file
    if args.replace_shipped:
        if args.out is not None and not same_file(args.out, TUNED_PATH) and Path(args.out) != TUNED_PATH:
            raise SystemExit(f"error: --replace-shipped writes {TUNED_PATH}; --out {args.out!r} names another file")
        out = TUNED_PATH
    elif args.out is None:
        stamp = time.strftime("%Y%m%d_%H%M%S")
        out = Path("runs") / f"tune_{stamp}" / "tuned.json"
        n = 1
        while out.parent.exists():
            out, n = Path("runs") / f"tune_{stamp}_{n}" / "tuned.json", n + 1
    else:
        out = Path(args.out)
        if not out.parent.is_dir():
            raise SystemExit(f"error: --out: folder {str(out.parent)!r} of {args.out!r} does not exist")
        if same_file(out, TUNED_PATH) or out.resolve() == TUNED_PATH.resolve():
            raise SystemExit(f"error: --out: {args.out!r} is the shipped {TUNED_PATH.name} every evaluation reads; "
                             "replacing it needs --replace-shipped")
    try:
        check_output_file("--out", out)
    except ValueError as e:
        raise SystemExit(f"error: {e}") from None
    return str(out)


def _describe_replaced(path, old, new, tuned):
    """What writing ``new`` over ``path`` replaces (None for a new file): the previous run's command and each
    re-tuned tracker's previous and new tuning RMSE."""
    if not Path(path).is_file():
        return None
    prev = (old.get("tuning") or {}).get("command", "an earlier run") if isinstance(old.get("tuning"), dict) \
        else "an earlier run"
    changes = ", ".join(f"{t} {old[t].get('pos_rmse_m', float('nan')):.2f} -> {new[t]['pos_rmse_m']:.2f} m"
                        for t in tuned if isinstance(old.get(t), dict) and t in new)
    return f"the parameters of {prev!r}" + (f" ({changes})" if changes else "")


if __name__ == "__main__":
    main(prog="python -m baselines.tuning")
