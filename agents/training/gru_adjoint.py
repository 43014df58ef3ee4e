r"""A GRU stepped look by look without a graph, and its hand-written reverse pass over the whole chunk.

The CV q-policy trainer (:meth:`agents.training.backprop.CVQModel.chunk_forward`) must step the GRU one look at a
time (the next observation needs the numba Tracker stepped with this look's q), but wants one autograd node for
the chunk: torch's autograd through 40 ``GRUCell`` calls (or ``nn.GRU``, whose CPU backward is per step as well)
spent more time than the forward, the filter and the Tracker together. :class:`GRURecorder` runs the cell's
formulas (``torch.nn.GRUCell``'s, gates ``r, z, n``)::

    r = sigma(W_ir x + b_ir + W_hr h + b_hr)      z = sigma(W_iz x + b_iz + W_hz h + b_hz)
    n = tanh(W_in x + b_in + r * (W_hn h + b_hn))  h' = (1 - z) n + z h

under ``torch.no_grad`` and keeps ``x, h, r, z, n, W_hn h + b_hn`` of every look; :class:`GRUSequence` returns the
recorded states as a differentiable ``(B, J, H)`` tensor whose backward is the reverse pass: per look only the
elementwise gate derivatives and one ``(B, 3H) x (3H, H)`` product (the gradient to the previous state), then the
weight gradients of all looks in one product each. The initial state gets no gradient: the trainer cuts the graph
between chunks.
"""

from __future__ import annotations

import torch

__all__ = ["GRURecorder", "GRUSequence"]


class GRURecorder:
    """Steps the weights of ``cell`` (a ``torch.nn.GRUCell``) over ``J`` looks of ``B`` rows, recording the reverse
    pass's inputs. Call :meth:`step` for ``j = 0 .. J-1`` in order, then :meth:`states`."""

    def __init__(self, cell, B, J):
        self.cell = cell
        H, F = cell.hidden_size, cell.input_size
        kw = {"dtype": cell.weight_ih.dtype}
        self.H, self.J = H, J
        self.x = torch.empty((J, B, F), **kw)
        self.h_prev, self.h = torch.empty((J, B, H), **kw), torch.empty((J, B, H), **kw)
        self.r, self.z, self.n, self.ghn = (torch.empty((J, B, H), **kw) for _ in range(4))

    def step(self, j, x, h):
        """``h' (B, H)`` of look ``j`` from ``x (B, F)`` and ``h (B, H)`` (no graph)."""
        c, H = self.cell, self.H
        with torch.no_grad():
            gi = torch.addmm(c.bias_ih, x, c.weight_ih.t())
            gh = torch.addmm(c.bias_hh, h, c.weight_hh.t())
            r = torch.sigmoid(gi[:, :H] + gh[:, :H])
            z = torch.sigmoid(gi[:, H:2 * H] + gh[:, H:2 * H])
            ghn = gh[:, 2 * H:]
            n = torch.tanh(gi[:, 2 * H:] + r * ghn)
            hn = n + z * (h - n)
            self.x[j], self.h_prev[j], self.r[j], self.z[j], self.n[j], self.ghn[j], self.h[j] = x, h, r, z, n, ghn, hn
        return hn

    def states(self):
        """The recorded states ``(B, J, H)``, differentiable with respect to the cell's weights."""
        c = self.cell
        return GRUSequence.apply(self, c.weight_ih, c.weight_hh, c.bias_ih, c.bias_hh)


class GRUSequence(torch.autograd.Function):
    """``h (B, J, H)`` of a :class:`GRURecorder` as a function of the cell's weights (module docstring)."""

    @staticmethod
    def forward(ctx, rec, w_ih, w_hh, b_ih, b_hh):
        ctx.rec = rec
        return rec.h.permute(1, 0, 2).clone()

    @staticmethod
    def backward(ctx, g):
        rec = ctx.rec
        H, J = rec.H, rec.J
        w_hh = rec.cell.weight_hh.detach()
        g = g.permute(1, 0, 2)                             # (J, B, H)
        B = g.shape[1]
        d_gi = torch.empty((J, B, 3 * H), dtype=g.dtype)
        d_gh = torch.empty((J, B, 3 * H), dtype=g.dtype)
        dh = torch.zeros((B, H), dtype=g.dtype)
        for j in range(J - 1, -1, -1):
            dh = dh + g[j]
            r, z, n, ghn = rec.r[j], rec.z[j], rec.n[j], rec.ghn[j]
            dan = dh * (1.0 - z) * (1.0 - n * n)           # through n = tanh(a_n)
            d_gi[j, :, :H] = dr = dan * ghn * r * (1.0 - r)
            d_gi[j, :, H:2 * H] = dz = dh * (rec.h_prev[j] - n) * z * (1.0 - z)
            d_gi[j, :, 2 * H:] = dan
            d_gh[j, :, :H], d_gh[j, :, H:2 * H] = dr, dz
            d_gh[j, :, 2 * H:] = dan * r
            dh = torch.addmm(dh * z, d_gh[j], w_hh)
        gi, gh = d_gi.reshape(J * B, 3 * H), d_gh.reshape(J * B, 3 * H)
        d_w_ih = gi.t() @ rec.x.reshape(J * B, -1)
        d_w_hh = gh.t() @ rec.h_prev.reshape(J * B, H)
        if not (torch.isfinite(d_w_ih).all() and torch.isfinite(d_w_hh).all()):
            raise FloatingPointError("GRU reverse pass: the gradient is not finite")
        return None, d_w_ih, d_w_hh, gi.sum(0), gh.sum(0)
