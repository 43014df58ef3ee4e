"""Experiment (issue 38; docs/training.md, "Closing the gap to rbpf"): the GRU q-policy plus a learned correction of
its output position, along and across the estimated velocity, ``x_out = x_kf + R(v) delta``, ``delta = corr_m
tanh(0.1 W y)`` from the GRU's head (zero at the start): the filter itself is unchanged (no feedback), so a lag the
network can predict (a CV filter's in a turn) could be removed. Fine-tuned from policy_bp on its recipe (broad
flights, training seeds); validation by the torch forward on the selection suites (training-range seeds). Not a
tracker of the package (the correction is not saved with the policy):

    python scripts/explore_output_correction.py NAME LEARNING_RATE N_STEPS CORR_M      # e.g. bp_corr 0.002 800 300

writes runs/NAME as ``radar-track train --method backprop`` does.
"""
import sys

import numpy as np
import torch

from agents.training import backprop as bp
from agents.training.backprop import CVQModel, observe, DTYPE
from baselines.trackers import TrackRun
from radar_env.envs.core import actions_to_q_m_s2
from radar_env.sim.episode import stack_episodes

BUNDLED = __import__("pathlib").Path(__file__).resolve().parents[1] / "agents" / "bundled" / "backprop" / "policy.npz"


def rotate(x, d):
    """x (..., 4) estimate, d (..., 2) along/across offsets -> position offset (..., 2) (velocity detached)."""
    v = x[..., 2:4].detach()
    u = v / torch.clamp(torch.linalg.norm(v, dim=-1, keepdim=True), min=1.0)
    perp = torch.stack([u[..., 1], -u[..., 0]], -1)       # right of the velocity (clockwise)
    return d[..., :1] * u + d[..., 1:2] * perp


class CorrModel(CVQModel):
    corr_m = 300.0

    def __init__(self, *a, **k):
        super().__init__(*a, **k)
        prev = self.head_sizes[-1] if self.head_sizes else self.hidden_size
        self.corr = torch.nn.Linear(prev, 2, dtype=DTYPE)
        with torch.no_grad():
            self.corr.weight.zero_()
            self.corr.bias.zero_()

    def _y(self, h):
        y = h
        for layer in self.head:
            y = torch.tanh(layer(y))
        return y

    def delta(self, h):
        return self.corr_m * torch.tanh(self.corr(self._y(h)) * 0.1)

    def step(self, looks, j, obs):
        x, q = super().step(looks, j, obs)          # x (4, B)
        xb = x.T
        off = rotate(xb, self.delta(self.h))
        xo = torch.cat([xb[:, :2] + off, xb[:, 2:]], 1)
        return xo.T, q

    def chunk_forward(self, tracker, layout, obs, looks):
        from radar_env.filters.compiled_chain import cv_run
        J = looks.J
        active = looks.scored.numpy()
        h = self.h.detach()
        hs = []
        for j in range(J):
            h = self.gru(torch.from_numpy(obs.astype(np.float64)), h)
            hs.append(h)
            with torch.no_grad():
                a = self._head(h)
            q = actions_to_q_m_s2(a.numpy().reshape(-1, 1), "continuous", self.levels_m_s2)
            observe(tracker, layout, obs, q, active[j])
        self.h = h.detach()
        H = torch.stack(hs, 1)
        q = self.q_of_action(self._head(H))
        x, self.state = cv_run(self.state, looks, q)       # (B, J, 4)
        off = rotate(x, self.delta(H))
        return torch.cat([x[..., :2] + off, x[..., 2:]], -1)

    def validation_row(self, selection, cfg, env_kwargs):
        def run(eps):
            with torch.no_grad():
                x, looks = bp.forward_episodes(self, eps, cfg)
            batch = stack_episodes(eps)
            B, K = batch.t_s.shape
            X = np.full((B, K, 4), np.nan)
            P = np.full((B, K, 4, 4), np.nan)
            li, sc = looks.look_index, looks.scored.numpy()
            x = x.numpy()
            for b in range(B):
                ok = sc[:, b]
                X[b, li[b][ok]] = x[b, ok]
                P[b, li[b][ok]] = np.eye(4) * 1e4
            start = np.array([li[b][sc[:, b]].min() for b in range(B)])
            return TrackRun("corr", X, P, start, np.full((B, K), np.nan))
        saved = (self.h, self.state)
        try:
            return selection.score_runs(run)[0]
        finally:
            self.h, self.state = saved


bp.MODELS["cv_corr"] = (__name__, "CorrModel")      # make_model imports it by this name
bp.HP_SPEC["tracker"] = ((lambda v: v in bp.MODELS), "a model")
bp.HP_FILES["cv_corr"] = "backprop"

if __name__ == "__main__":
    from agents.training.runs import load_hyperparams
    hp = load_hyperparams("backprop")
    hp.update(tracker="cv_corr", init_from=str(BUNDLED),
              learning_rate=float(sys.argv[2]), n_steps=int(sys.argv[3]))
    CorrModel.corr_m = float(sys.argv[4])
    bp.train_backprop(hp, seed=0, out="runs", progress=False, run_name=sys.argv[1])
