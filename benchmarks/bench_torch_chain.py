"""Speed of the differentiable chain (radar_env.filters.torch_chain): forward + backward through the filter, single thread.

Run by hand from the repository root: ``python benchmarks/bench_torch_chain.py [--batch 1000] [--chunk 40]
[--repeats 3] [--json PATH]``. With ``torch.set_num_threads(1)`` it draws ``--batch`` random-suite episodes
(``radar_env.sim.draws.draw_episodes``), starts their tracks in a numba Tracker, hands them over
(``torch_chain.handover``) and times, per pass over every look of every episode (best of ``--repeats``):

* ``full``: ``run`` over all looks, then ``pooled_position_mse(...).backward()`` (gradient w.r.t. log q per look);
* ``tbptt``: the same in chunks of ``--chunk`` looks, the state detached between chunks (a trainer's pattern);
* ``step``: the chunks again, one ``step`` call per look and ``collect`` per chunk (q from a policy per look);
* ``turn``: ``tbptt`` with a turn rate per look (``F_ct``);
* ``forward``: ``run`` under ``torch.no_grad()``;

and, as references measured in the same process: ``Tracker.step`` (the numba chain with its features) at the same
batch, and CartPole-v1 (``gym.make``, random actions) steps/s, so that a number taken on a loaded machine can be
compared with one taken on an idle one (the ratio to CartPole moves less than the absolute rate).

Reported: row-looks/s (batch x looks processed, padding of shorter rows included), scored looks/s, episodes/s and
the process's peak resident memory after each mode (modes run in the order given; ``full`` keeps the whole graph).
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:          # run as a script: import this checkout's radar_env, not an installed one
    sys.path.insert(0, str(REPO))

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

from radar_env.filters import torch_chain as tc  # noqa: E402
from radar_env.sim.draws import draw_episodes  # noqa: E402
from radar_env.filters.tracking import TrackStart  # noqa: E402
from radar_env.common.units import DEG, G0_M_S2  # noqa: E402

MODES = ("full", "tbptt", "step", "turn", "forward")


def _positive_int(s):
    try:
        v = int(s)
    except ValueError:
        v = 0
    if v < 1:
        raise argparse.ArgumentTypeError(f"must be an integer >= 1, got {s!r}")
    return v


def _setup(batch, seed):
    b = draw_episodes("random", None, None, [np.random.default_rng([seed, i]) for i in range(batch)])
    tr = TrackStart().tracker(batch)
    out = tr.load(np.arange(batch), [b.episode(i) for i in range(batch)])
    return tr, out


def _pass(mode, state, looks, chunk, lq, w):
    """One pass over all looks; returns the pooled MSE (float)."""
    n_total = looks.n_scored.sum()
    if mode == "forward":
        with torch.no_grad():
            return float(tc.pooled_position_mse(tc.run(state, looks, torch.exp(lq)).x, looks))
    if mode == "full":
        loss = tc.pooled_position_mse(tc.run(state, looks, torch.exp(lq)).x, looks)
        loss.backward()
        return float(loss.detach())
    total = 0.0
    for j0 in range(0, looks.J, chunk):
        part = looks.chunk(j0, j0 + chunk)
        q = torch.exp(lq[:, j0:j0 + chunk])
        if mode == "step":
            recs = []
            for j, q_j in enumerate(q.unbind(1)):     # one (B,) tensor per look, as a policy would give
                state, rec = tc.step(state, part, j, q_j)
                recs.append(rec)
            out = tc.collect(recs, state)
        else:
            out = tc.run(state, part, q, None if mode == "tbptt" else w[:, j0:j0 + chunk])
        loss = tc.pooled_position_mse(out.x, part, n_total)
        loss.backward()
        total += float(loss.detach())
        state = out.state.detach()
    return total


def cartpole_rate(seconds):
    """CartPole-v1 steps/s through gym.make (random actions drawn beforehand): the reference a rate taken under
    some load is compared with."""
    import gymnasium as gym
    env = gym.make("CartPole-v1")
    env.reset(seed=0)
    acts = np.random.default_rng(0).integers(0, 2, size=4096)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for a in acts[:512]:
            _, _, term, trunc, _ = env.step(int(a))
            if term or trunc:
                env.reset()
        n += 512
    return n / (time.perf_counter() - t0)


def _tracker_rate(batch, seed, seconds):
    tr, out = _setup(batch, seed)
    q = np.full(batch, 0.3 * G0_M_S2)
    n, t0 = 0, time.perf_counter()
    while time.perf_counter() - t0 < seconds and int(tr.remaining_looks().min()) > 0:
        tr.step(q)
        n += batch
    return n / (time.perf_counter() - t0)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--batch", type=_positive_int, default=1000, help="episodes per batch (default 1000)")
    p.add_argument("--chunk", type=_positive_int, default=40, help="looks per truncated-backprop chunk (40)")
    p.add_argument("--repeats", type=_positive_int, default=3, help="timed passes per mode, best kept (3)")
    p.add_argument("--max-looks", type=_positive_int, default=None, help="cut the episodes to this many looks")
    p.add_argument("--modes", default=",".join(MODES), help=f"comma-separated subset of {','.join(MODES)}")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--json", default=None, help="also write the results here")
    a = p.parse_args(argv)
    modes = [m for m in a.modes.split(",") if m]
    if not modes or any(m not in MODES for m in modes):
        p.error(f"--modes must be a comma-separated subset of {','.join(MODES)}, got {a.modes!r}")
    torch.set_num_threads(1)
    tr, _ = _setup(a.batch, a.seed)
    state0, looks = tc.handover(tr)
    if a.max_looks is not None and a.max_looks < looks.J:
        looks = looks.chunk(0, a.max_looks)
    B, J = looks.B, looks.J
    n_scored = int(looks.scored.sum())
    lq0 = torch.full((B, J), float(np.log(0.3 * G0_M_S2)), dtype=torch.float64)
    w = torch.full((B, J), 0.5 * DEG, dtype=torch.float64)
    res = {"batch": B, "columns": J, "scored_looks": n_scored, "mean_looks_per_episode": n_scored / B,
           "chunk": a.chunk, "torch": torch.__version__, "threads": torch.get_num_threads(),
           "loadavg_1min": os.getloadavg()[0], "modes": {}}
    print(f"batch {B} episodes, {J} columns, {n_scored / B:.0f} scored looks per episode on average, "
          f"chunk {a.chunk}, torch {torch.__version__}, {torch.get_num_threads()} thread(s), "
          f"load average {os.getloadavg()[0]:.2f}")
    for mode in modes:
        best = np.inf
        for _ in range(a.repeats):
            lq = lq0.clone().requires_grad_(mode != "forward")
            t0 = time.perf_counter()
            _pass(mode, state0, looks, a.chunk, lq, w)
            best = min(best, time.perf_counter() - t0)
        r = {"seconds": best, "row_looks_per_s": B * J / best, "scored_looks_per_s": n_scored / best,
             "episodes_per_s": B / best, "peak_rss_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
        res["modes"][mode] = r
        print(f"  {mode:8s} {best:7.3f} s/pass  {r['row_looks_per_s']:10.0f} row-looks/s  "
              f"{r['scored_looks_per_s']:10.0f} scored looks/s  {r['episodes_per_s']:8.1f} episodes/s  "
              f"(peak RSS so far {r['peak_rss_mb']:.0f} MB)")
    res["tracker_step_row_looks_per_s"] = _tracker_rate(B, a.seed, 1.0)
    res["cartpole_steps_per_s"] = cartpole_rate(1.0)
    print(f"  reference: numba Tracker.step {res['tracker_step_row_looks_per_s']:.0f} row-looks/s at batch {B}; "
          f"CartPole-v1 {res['cartpole_steps_per_s']:.0f} steps/s")
    for mode, r in res["modes"].items():
        r["ratio_to_cartpole"] = r["row_looks_per_s"] / res["cartpole_steps_per_s"]
    print("  ratio to CartPole-v1 (row-looks/s over steps/s): "
          + ", ".join(f"{m} {r['ratio_to_cartpole']:.2f}" for m, r in res["modes"].items()))
    if a.json:
        Path(a.json).write_text(json.dumps(res, indent=2))
    return res


if __name__ == "__main__":
    main()
