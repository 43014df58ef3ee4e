"""The window trainer's optimiser step in float64 and float32 (``--hp dtype``), in one process.

    python benchmarks/bench_window_step.py [--rounds 5] [--steps 40] [--layers 128,128] [--batch 4096]

The trainer's own network (:func:`agents.training.window._net`, the bundled recipe's inputs: a 24-look window, the
fits over 6, 8, 12, 16 and 24 looks, the base's q at 12 looks) and its step (a batch converted from float64 numpy as
the trainer does, the weighted squared error, Adam), on random inputs of the real shape; one torch thread. Rounds
alternate the two precisions; the ratio of the medians is the number (rounds taken in turn make it robust to the
machine's load, the absolute times are not).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time


def step_seconds(torch, window, dtype, n_in, layers, batch, steps, seed=0):
    """Median seconds per optimiser step of the trainer's network in ``dtype`` over ``steps`` steps (after 3)."""
    import numpy as np
    rng = np.random.default_rng(seed)
    X, Y, W = rng.standard_normal((batch, n_in)), rng.standard_normal((batch, 2)), rng.random(batch)
    torch.manual_seed(seed)
    dt = getattr(torch, dtype)
    net = window._net(torch, n_in, layers, dtype)
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    times = []
    for i in range(steps + 3):
        t = time.perf_counter()
        x, y, w = (torch.from_numpy(a).to(dt) for a in (X, Y, W))
        loss = (w * ((net(x) - y) ** 2).sum(-1)).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        if i >= 3:
            times.append(time.perf_counter() - t)
    return statistics.median(times)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--steps", type=int, default=40)
    ap.add_argument("--layers", default="128,128", help="tanh widths (default: %(default)s, the bundled recipe's)")
    ap.add_argument("--batch", type=int, default=4096)
    args = ap.parse_args(argv)
    import torch
    from agents.policies.window_correction import feature_count
    from agents.training import window
    torch.set_num_threads(1)
    layers = [int(w) for w in args.layers.split(",")]
    n_in = feature_count(24, [6, 8, 12, 16, 24], 12)
    load0 = os.getloadavg()[0]
    res = {"float64": [], "float32": []}
    for _ in range(args.rounds):
        for dtype in res:
            res[dtype].append(step_seconds(torch, window, dtype, n_in, layers, args.batch, args.steps))
    m64, m32 = statistics.median(res["float64"]), statistics.median(res["float32"])
    print(f"window step, {n_in} inputs, tanh {layers}, batches of {args.batch}, one torch thread, "
          f"{args.rounds} rounds; load {load0:.2f} -> {os.getloadavg()[0]:.2f}")
    print("| dtype | ms per step (median of rounds) | rounds |\n|---|---:|---|")
    for dtype, v in res.items():
        print(f"| {dtype} | {1e3 * statistics.median(v):.1f} | {', '.join(f'{1e3 * x:.1f}' for x in v)} |")
    print(f"float64 / float32: {m64 / m32:.2f}x")


if __name__ == "__main__":
    main()
