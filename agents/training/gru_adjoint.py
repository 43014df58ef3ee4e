r"""A GRU stepped look by look without a graph, and its hand-written reverse pass over the whole chunk.

The CV q-policy trainer (:meth:`agents.training.backprop.CVQModel.chunk_forward`) must step the GRU one look at a
time (the next observation needs the numba Tracker stepped with this look's q), but wants one autograd node for
the chunk. :class:`GRURecorder` steps the cell itself (``torch.nn.GRUCell``, no graph: the same numbers as the
reference lockstep) and keeps every look's input and state; :class:`GRUSequence` returns the recorded states as a
differentiable ``(B, J, H)`` tensor whose backward is the reverse pass of the cell's formulas (gates ``r, z, n``)::

    r = sigma(W_ir x + b_ir + W_hr h + b_hr)      z = sigma(W_iz x + b_iz + W_hz h + b_hz)
    n = tanh(W_in x + b_in + r * (W_hn h + b_hn))  h' = (1 - z) n + z h

Per look, backwards: the two projections and the gates recomputed (two ``(B, .) x (., 3H)`` products, torch's
vectorised sigmoid and tanh into reused buffers), one fused numba pass for the gates' derivatives (arithmetic only,
no temporaries), one ``(B, 3H) x (3H, H)`` product (the gradient to
the previous state); then the weight gradients of all looks, one product each. The buffers live in the recorder
and are reused chunk after chunk (fresh arrays of this size cost more in page faults than the arithmetic). The
initial state gets no gradient: the trainer cuts the graph between chunks.
"""

from __future__ import annotations

import math

import numpy as np
import torch
from numba import njit

__all__ = ["GRURecorder", "GRUSequence"]


@njit(cache=True)
def _k_gates_reverse(sg, gh, tn, h, dh, g, j, d_gi, d_gh, dh_z):
    """Reverse of look ``j``'s gates (arithmetic only: the transcendental functions are torch's, vectorised):
    ``sg (B, 3H)`` holds ``r, z`` in its first ``2H`` columns, ``gh (B, 3H)`` the hidden projection, ``tn (B, H)``
    ``n``; ``h (B, H)`` the look's input state, ``dh (B, H)`` the gradient of its output state from the later looks,
    ``g[:, j] (B, H)`` the loss's own. Writes the projections' gradients ``d_gi[j], d_gh[j] (B, 3H)`` and
    ``dh_z = dLoss/dh' * z`` (the direct path to the previous state)."""
    B, H = h.shape
    for b in range(B):
        for k in range(H):
            d = dh[b, k] + g[b, j, k]
            r, z, n = sg[b, k], sg[b, H + k], tn[b, k]
            dan = d * (1.0 - z) * (1.0 - n * n)             # through n = tanh(a_n)
            dr = dan * gh[b, 2 * H + k] * r * (1.0 - r)
            dz = d * (h[b, k] - n) * z * (1.0 - z)
            d_gi[j, b, k], d_gi[j, b, H + k], d_gi[j, b, 2 * H + k] = dr, dz, dan
            d_gh[j, b, k], d_gh[j, b, H + k], d_gh[j, b, 2 * H + k] = dr, dz, dan * r
            dh_z[b, k] = d * z


class GRURecorder:
    """Steps ``cell`` (a ``torch.nn.GRUCell``) over up to ``J`` looks of ``B`` rows without a graph, recording
    inputs and states. Per chunk: :meth:`begin` ``(J)``, :meth:`step` for ``j = 0 .. J-1`` in order, then
    :meth:`states` (valid until the next :meth:`begin`: the buffers are reused)."""

    def __init__(self, cell, B, J):
        self.cell, self.B, self.Jmax, self.J = cell, B, J, 0
        H, F = cell.hidden_size, cell.input_size
        self.x = np.empty((J, B, F))
        self.h = np.empty((J + 1, B, H))                  # h[j]: the state before look j
        self.d_gi, self.d_gh = np.empty((J, B, 3 * H)), np.empty((J, B, 3 * H))
        self.gi, self.gh, self.sg = (torch.empty((B, 3 * H), dtype=torch.float64) for _ in range(3))
        self.tn = torch.empty((B, H), dtype=torch.float64)
        self.dh, self.dh_z = torch.empty((B, H), dtype=torch.float64), torch.empty((B, H), dtype=torch.float64)

    def fits(self, B, J):
        return B == self.B and J <= self.Jmax

    def begin(self, J):
        if J > self.Jmax:
            raise ValueError(f"GRURecorder: {J} looks, room for {self.Jmax}")
        self.J = J

    def step(self, j, x, h):
        """``h' (B, H)`` of look ``j`` from ``x (B, F)`` and ``h (B, H)`` (float64): ``cell(x, h)``, no graph."""
        with torch.no_grad():
            if j == 0:
                self.h[0] = h.numpy()
            self.x[j] = x.numpy()
            hn = self.cell(x, h)
            self.h[j + 1] = hn.numpy()
        return hn

    def states(self):
        """The recorded states ``(B, J, H)`` after each look, differentiable with respect to the cell's weights."""
        c = self.cell
        return GRUSequence.apply(self, c.weight_ih, c.weight_hh, c.bias_ih, c.bias_hh)


class GRUSequence(torch.autograd.Function):
    """``h (B, J, H)`` of a :class:`GRURecorder` as a function of the cell's weights (module docstring)."""

    @staticmethod
    def forward(ctx, rec, w_ih, w_hh, b_ih, b_hh):
        ctx.rec = rec
        return torch.from_numpy(rec.h[1:rec.J + 1].transpose(1, 0, 2).copy())

    @staticmethod
    def backward(ctx, g):
        rec = ctx.rec
        c = rec.cell
        J, B, H = rec.J, rec.B, c.hidden_size
        with torch.no_grad():
            w_ih_t, w_hh_t, w_hh = c.weight_ih.t(), c.weight_hh.t(), c.weight_hh
            b_ih, b_hh = c.bias_ih, c.bias_hh
            g = np.ascontiguousarray(g.numpy(), dtype=np.float64)         # (B, J, H)
            x, h = torch.from_numpy(rec.x), torch.from_numpy(rec.h)
            gi, gh, sg, tn, dh, dh_z = rec.gi, rec.gh, rec.sg, rec.tn, rec.dh, rec.dh_z
            sg_n, gh_n, tn_n, dh_n, dh_z_n = sg.numpy(), gh.numpy(), tn.numpy(), dh.numpy(), dh_z.numpy()
            d_gh_t = torch.from_numpy(rec.d_gh)
            dh.zero_()
            for j in range(J - 1, -1, -1):
                torch.addmm(b_ih, x[j], w_ih_t, out=gi)
                torch.addmm(b_hh, h[j], w_hh_t, out=gh)
                torch.sigmoid(torch.add(gi, gh, out=sg), out=sg)                       # r, z (and an unused third)
                torch.tanh(torch.addcmul(gi[:, 2 * H:], sg[:, :H], gh[:, 2 * H:], out=tn), out=tn)    # n
                _k_gates_reverse(sg_n, gh_n, tn_n, rec.h[j], dh_n, g, j, rec.d_gi, rec.d_gh, dh_z_n)
                torch.addmm(dh_z, d_gh_t[j], w_hh, out=dh)
            d_gi = torch.from_numpy(rec.d_gi[:J].reshape(J * B, 3 * H))
            d_gh = torch.from_numpy(rec.d_gh[:J].reshape(J * B, 3 * H))
            d_w_ih = d_gi.t() @ torch.from_numpy(rec.x[:J].reshape(J * B, -1))
            d_w_hh = d_gh.t() @ torch.from_numpy(rec.h[:J].reshape(J * B, H))
            if not (torch.isfinite(d_w_ih).all() and torch.isfinite(d_w_hh).all()):
                raise FloatingPointError("GRU reverse pass: the gradient is not finite")
            ones = torch.ones(J * B, dtype=torch.float64)       # bias gradients as products: torch's column
            return None, d_w_ih, d_w_hh, d_gi.t() @ ones, d_gh.t() @ ones   # sums of a tall array are ~10x slower
