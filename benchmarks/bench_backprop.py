"""Training throughput of ``radar-track train --method backprop`` (agents/training/backprop.py), single thread.

Run by hand from the repository root: ``python benchmarks/bench_backprop.py [--tracker cv|imm_cv_ct] [--batch 1000]
[--chunk 40] [--steps 10] [--hidden 32] [--flights training,random] [--chain compiled|torch] [--json PATH]``, or
``--compare N``: the optimiser step as main ran it before the compiled chain, with ``chain = "torch"`` (the reference
lockstep over the torch chain) and with ``chain = "compiled"`` (the compiled CV chain,
:mod:`radar_env.filters.compiled_chain`) in one process, N interleaved rounds on the same rows' episodes, printing the
ratios of the median step times and the load average (docs/speed.md, "Backprop training step": on the shared machine
only the ratios mean something). With ``--tracker imm_cv_ct`` (the learned IMM's recipe, ``backprop_imm_cv_ct.toml``)
``--compare N`` times ``chain = "torch"`` (eager) against ``chain = "compiled"`` (its look under ``torch.compile``;
the first rounds of warm-up include the compilation). With ``torch.set_num_threads(1)`` it builds the trainer of
``agents/training/hyperparams/backprop.toml`` (``--tracker``: its recipe; ``--hidden``, ``--batch``, ``--chunk``
override it) and times ``--steps`` optimiser steps after two warm-up steps (the lockstep numba Tracker and
observation, the GRU and the chain (the compiled CV chain by default; ``--chain torch``: the torch lockstep), the
backward pass, the Adam step; validation excluded), for each flight distribution of ``--flights``: ``training`` (the recipe's: 70 % random radars, the broad flights, about 370
looks per episode) and ``random`` (the evaluation's random suite generator: ATC radar, about 165 looks).

Reported per distribution: training episodes/s (episodes completed per second of training, in the steady state of
the stream), row-looks/s (rows x looks processed, padding included), scored looks/s, seconds per optimiser step,
the share of the step spent in the numba Tracker and observation, and CartPole-v1 steps/s measured in the same
process (``gym.make``, random actions), so that a number taken on a loaded machine can be compared with one taken on
an idle one; and the 1-minute load average.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:          # run as a script: import this checkout's packages, not installed ones
    sys.path.insert(0, str(REPO))

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import torch  # noqa: E402

from agents.training import backprop as bp  # noqa: E402
from radar_env.filters import torch_chain as tc  # noqa: E402
from agents.training.runs import load_hyperparams  # noqa: E402
from benchmarks.bench_torch_chain import _positive_int, cartpole_rate  # noqa: E402  (shared with it)

FLIGHTS = ("training", "random")


class _Timed:
    """Wraps the trainer's Tracker.step and ObservationLayout.encode to time the numba side of the lockstep."""

    def __init__(self, obj, name):
        self.fn, self.seconds = getattr(obj, name), 0.0
        setattr(obj, name, self)

    def __call__(self, *a, **kw):
        t0 = time.perf_counter()
        try:
            return self.fn(*a, **kw)
        finally:
            self.seconds += time.perf_counter() - t0


RECIPES = {"cv": "backprop", "imm_cv_ct": "backprop_imm_cv_ct"}
"""``--tracker`` -> its recipe (agents/training/hyperparams/<name>.toml)."""


def _trainer(flights, batch, chunk, hidden, seed, chain, tracker="cv"):
    """``(trainer, opt, hp)`` of ``tracker``'s recipe on ``flights`` with the model's ``chain`` (bp.CHAINS)."""
    hp = load_hyperparams(RECIPES[tracker])
    hp.update(batch_episodes=batch, chunk_looks=chunk, hidden_size=hidden, chain=chain)
    if flights == "random":
        hp["env_kwargs"] = {k: v for k, v in hp["env_kwargs"].items() if k not in ("scenario", "random_config")}
    hp, _, cfg = bp.check_hp(hp)
    torch.manual_seed(seed)
    model = bp.make_model(hp, cfg)
    opt = torch.optim.Adam(model.parameters(), lr=hp["learning_rate"])
    return bp.StreamingTrainer(model, cfg, batch, chunk, seed, loss=hp["loss"]), opt, hp


def measure(flights, batch, chunk, hidden, steps, seed=0, chain="compiled", tracker="cv"):
    """Time ``steps`` optimiser steps of the trainer on ``flights`` (one of :data:`FLIGHTS`); returns a dict."""
    trainer, opt, hp = _trainer(flights, batch, chunk, hidden, seed, chain, tracker)

    def one_step():
        bp.optimiser_step(trainer, opt, hp)

    # warm-up, then run until the stream is steady: rows start episodes at different times after a few episodes
    for _ in range(2):
        one_step()
    ts, te = _Timed(trainer.tracker, "step"), _Timed(trainer.layout, "encode")
    e0, r0, s0 = trainer.episodes_done, trainer.row_looks, trainer.scored_looks
    t0 = time.perf_counter()
    for _ in range(steps):
        one_step()
    dt = time.perf_counter() - t0
    n_ep = trainer.episodes_done - e0
    return {"flights": flights, "batch": batch, "chunk": chunk, "hidden": hidden, "steps": steps, "seconds": dt,
            "seconds_per_step": dt / steps, "episodes_per_s": n_ep / dt, "episodes": n_ep,
            "row_looks_per_s": (trainer.row_looks - r0) / dt, "scored_looks_per_s": (trainer.scored_looks - s0) / dt,
            "numba_share": (ts.seconds + te.seconds) / dt,
            "mean_looks_per_episode": (trainer.scored_looks - s0) / max(n_ep, 1)}


def _main_chunk_looks(tracker, k0, cut):
    """The chunk's looks as main built them before the compiled chain (``look_data`` of the whole store: its
    ``detected`` compares every stored look)."""
    get = tracker.look_data
    return tc.looks_from_arrays(get("t_s"), get("detected"), get("z_m"), get("R_m2"), get("truth"), cut, k0,
                                tracker.t_last, **tc.range_rate_args(get, tracker.radial_velocity))


PATHS = {"main": ("torch", _main_chunk_looks), "torch": ("torch", None), "compiled": ("compiled", None)}
"""The steps compared: ``main``, the step as it was before the compiled chain (the torch lockstep, the chunk's
looks read from the whole store); ``torch``, ``chain = "torch"`` on this code (the looks gathered by
Tracker.look_window); ``compiled``, ``chain = "compiled"`` (the default)."""


def compare(flights, batch, chunk, hidden, repeats, seed=0, warmup=2, tracker="cv"):
    """``tracker``'s optimiser step of each of :data:`PATHS` (the learned IMM: ``torch`` and ``compiled`` only) in
    this one process: trainers of the same seed (the same rows' episodes, the same initial weights; their weights
    then differ by rounding only), ``warmup`` steps each, then ``repeats`` rounds, each timing one step of each in
    a rotating order (a load change on the shared machine hits all). Returns a dict with the per-step medians, the
    ratios ``main / compiled`` (None for the IMM) and ``torch / compiled`` of the medians, the per-round ratios of
    the ``reference`` (``main``, the IMM's ``torch``) to ``compiled``, and the load average before and after."""
    import statistics
    load0 = os.getloadavg()
    paths = PATHS if tracker == "cv" else {p: PATHS[p] for p in ("torch", "compiled")}   # the IMM: no "main"
    runs = {p: _trainer(flights, batch, chunk, hidden, seed, c, tracker) for p, (c, _) in paths.items()}
    own = bp.chunk_looks
    times = {p: [] for p in runs}

    def step(p):
        bp.chunk_looks = paths[p][1] or own
        try:
            t0 = time.perf_counter()
            bp.optimiser_step(*runs[p])
            return time.perf_counter() - t0
        finally:
            bp.chunk_looks = own

    names = list(runs)
    for _ in range(warmup):
        for p in names:
            step(p)
    for i in range(repeats):
        for p in names[i % len(names):] + names[:i % len(names)]:
            times[p].append(step(p))
    med = {p: statistics.median(t) for p, t in times.items()}
    ref = "main" if "main" in med else "torch"
    return {"tracker": tracker, "flights": flights, "batch": batch, "chunk": chunk, "hidden": hidden,
            "repeats": repeats, "s_per_step": med,
            "ratio_main": med["main"] / med["compiled"] if "main" in med else None,
            "ratio_torch": med["torch"] / med["compiled"],
            "reference": ref, "ratio_per_round": [a / b for a, b in zip(times[ref], times["compiled"])],
            "times": times, "loadavg_before": load0, "loadavg_after": os.getloadavg()}


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--tracker", default="cv", choices=sorted(RECIPES),
                   help="the model and its recipe: cv (policy_bp's, default) or imm_cv_ct (the learned IMM's)")
    p.add_argument("--batch", type=_positive_int, default=1000, help="episodes side by side (default 1000)")
    p.add_argument("--chunk", type=_positive_int, default=None, help="looks per optimiser step (default: the recipe's)")
    p.add_argument("--hidden", type=_positive_int, default=None, help="GRU width (default: the recipe's)")
    p.add_argument("--steps", type=_positive_int, default=10, help="timed optimiser steps per distribution (10)")
    p.add_argument("--flights", default=",".join(FLIGHTS), help=f"comma-separated subset of {','.join(FLIGHTS)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="also write the results here")
    p.add_argument("--chain", default="compiled", choices=bp.CHAINS, help="the model's chain (default compiled)")
    p.add_argument("--compare", type=_positive_int, default=None, metavar="N",
                   help="instead: N interleaved rounds of one step as main ran it, one with chain=torch and one with "
                        "chain=compiled in this process; prints the per-step ratios (the first flight distribution "
                        "only)")
    a = p.parse_args(argv)
    flights = [f for f in a.flights.split(",") if f]
    if not flights or any(f not in FLIGHTS for f in flights):
        p.error(f"--flights must be a comma-separated subset of {','.join(FLIGHTS)}, got {a.flights!r}")
    torch.set_num_threads(1)
    import numba
    numba.set_num_threads(1)               # as train_backprop
    rec = load_hyperparams(RECIPES[a.tracker])
    chunk, hidden = a.chunk or rec["chunk_looks"], a.hidden or rec["hidden_size"]
    if a.compare:
        r = compare(flights[0], a.batch, chunk, hidden, a.compare, a.seed, tracker=a.tracker)
        m, rr = r["s_per_step"], r["ratio_per_round"]
        head = (f"main {m['main']:.3f}, " if "main" in m else "")
        ratio = (f"ratio main/compiled {r['ratio_main']:.2f}x (per round {min(rr):.2f}-{max(rr):.2f}), "
                 f"chain=torch/compiled {r['ratio_torch']:.2f}x" if "main" in m else
                 f"ratio chain=torch/compiled {r['ratio_torch']:.2f}x (per round {min(rr):.2f}-{max(rr):.2f})")
        print(f"{a.tracker}, {flights[0]} flights, batch {a.batch}, chunk {chunk}, GRU {hidden}, {a.compare} "
              f"interleaved rounds, torch {torch.__version__}, 1 thread; median s/step: {head}chain=torch "
              f"{m['torch']:.3f}, chain=compiled {m['compiled']:.3f}\n  {ratio}; load average "
              f"(1, 5, 15 min) before {', '.join(f'{v:.2f}' for v in r['loadavg_before'])}, after "
              f"{', '.join(f'{v:.2f}' for v in r['loadavg_after'])}")
        if a.json:
            Path(a.json).write_text(json.dumps(r, indent=2))
        return r
    res = {"torch": torch.__version__, "threads": torch.get_num_threads(), "loadavg_1min": os.getloadavg()[0],
           "results": []}
    print(f"batch {a.batch}, chunk {chunk}, GRU {hidden}, {a.steps} timed steps, torch {torch.__version__}, "
          f"{torch.get_num_threads()} thread(s), load average {os.getloadavg()[0]:.2f}")
    for f in flights:
        r = measure(f, a.batch, chunk, hidden, a.steps, a.seed, a.chain, a.tracker)
        res["results"].append(r)
        print(f"  {f:9s} {r['seconds_per_step']:6.3f} s/step  {r['episodes_per_s']:7.1f} episodes/s  "
              f"{r['row_looks_per_s']:9.0f} row-looks/s  {r['scored_looks_per_s']:9.0f} scored looks/s  "
              f"({r['mean_looks_per_episode']:.0f} looks/episode; numba Tracker + observation "
              f"{100 * r['numba_share']:.0f} % of the step)")
    res["cartpole_steps_per_s"] = cartpole_rate(1.0)
    res["loadavg_1min_at_end"] = os.getloadavg()[0]
    for r in res["results"]:
        r["row_looks_per_cartpole_step"] = r["row_looks_per_s"] / res["cartpole_steps_per_s"]
    print(f"  reference: CartPole-v1 {res['cartpole_steps_per_s']:.0f} steps/s; row-looks per CartPole step: "
          + ", ".join(f"{r['flights']} {r['row_looks_per_cartpole_step']:.2f}" for r in res["results"])
          + f"; load average at the end {res['loadavg_1min_at_end']:.2f}")
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    main()
