"""The small-scale window-correction regression both exploration scripts train (explore_rdot_window.py,
explore_window_bases.py): not the trainer's (agents/training/window.py has the mirror, the redraws, the selection),
only what an A/B between two input sets or two bases needs, the same for both arms."""

import math
import time

import numpy as np
import torch


def fit_regression(train, val, epochs, seed, scale_m, tag="", t0=None):
    """An MLP (tanh 128-128, linear output of 2, zero-initialised) fitted to the looks of ``train`` (a list of
    ``(X, Y)``, one per suite; each suite's looks weighted by 1 / its mean squared target, mean weight 1) on
    standardised inputs, Adam lr 2e-3 cosine-decayed over ``epochs``, batches of 4,096 looks, float64, seeded by
    ``seed``. After each epoch the RMSE (m, ``Y`` in units of ``scale_m``) on each ``val`` suite (``{name: (X, Y)}``)
    is printed and kept; returns that history."""
    torch.set_default_dtype(torch.float64)
    t0 = time.time() if t0 is None else t0
    torch.manual_seed(seed)
    X = np.concatenate([x for x, _ in train])
    Y = np.concatenate([y for _, y in train])
    W = np.concatenate([np.full(len(y), 1.0 / np.mean((y ** 2).sum(-1))) for _, y in train])
    W /= W.mean()
    mu, sd = X.mean(0), X.std(0)
    sd[sd < 1e-9] = 1.0
    Xt, Yt, Wt = torch.from_numpy((X - mu) / sd), torch.from_numpy(Y), torch.from_numpy(W)
    net = torch.nn.Sequential(torch.nn.Linear(X.shape[1], 128), torch.nn.Tanh(), torch.nn.Linear(128, 128),
                              torch.nn.Tanh(), torch.nn.Linear(128, 2))
    with torch.no_grad():
        net[-1].weight.zero_()
        net[-1].bias.zero_()
    opt = torch.optim.Adam(net.parameters(), lr=2e-3)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, epochs)
    g = torch.Generator().manual_seed(seed)
    hist = []
    for ep in range(epochs):
        perm = torch.randperm(len(Yt), generator=g)
        for i in range(0, len(perm), 4096):
            idx = perm[i:i + 4096]
            loss = (Wt[idx] * ((net(Xt[idx]) - Yt[idx]) ** 2).sum(-1)).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
        sched.step()
        row = {"epoch": ep + 1}
        with torch.no_grad():
            for name, (xv, yv) in val.items():
                o = net(torch.from_numpy((xv - mu) / sd)).numpy()
                row[name] = math.sqrt((((yv - o) ** 2).sum(-1) * scale_m ** 2).mean())
        hist.append(row)
        print(tag, {k: (round(v, 2) if isinstance(v, float) else v) for k, v in row.items()},
              f"({time.time() - t0:.0f} s)", flush=True)
    return hist


class ClassicalBase:
    """A classical tracker of the registry as a window's base: ``run(episodes)`` as a learned tracker's."""

    def __init__(self, name):
        self.name = name

    def run(self, episodes):
        from baselines.registry import run_tracker
        return run_tracker(self.name, episodes)
