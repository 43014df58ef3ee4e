"""The compiled CV chain (radar_env/filters/compiled_chain.py) against the torch chain it compiles
(radar_env/filters/torch_chain.py): posteriors and final states equal tc.run's to 1e-10, dLoss/dq equal torch
autograd's through tc.run to 1e-8 relative, on drawn episodes with missed looks, one and several radar sites (plots
of different R, dt = 0 between two sites' plots), rows of different lengths (padding), a chunk handed over mid-episode,
q from 0 to MAX_Q_M_S2, with and without the range-rate update; central differences on a few entries; refusals."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_env.common.units import G0_M_S2  # noqa: E402
from radar_env.envs.config import resolve_scenario  # noqa: E402
from radar_env.filters import compiled_chain as cc  # noqa: E402
from radar_env.filters import torch_chain as tc  # noqa: E402
from radar_env.filters.tracking import MAX_Q_M_S2, TrackStart  # noqa: E402
from radar_env.sim.draws import draw_episodes  # noqa: E402
from radar_env.sim.episode import Episode  # noqa: E402
from radar_env.sim.radar import Radar, RadarSite  # noqa: E402

TWO_SITES_SAME_TIME = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=5.0),
                             RadarSite(position_m=(40e3, 10e3), scan_period_s=5.0, detection_probability=0.8)))
MISSING = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=5.0, detection_probability=0.6),))
CASES = {"random_radars": ("random_radars", None), "two_sites_same_time": ("random", TWO_SITES_SAME_TIME),
         "missed_looks": ("random", MISSING), "random": ("random", None)}


def _episodes(scenario, radar, n, seed, max_looks=90):
    b = draw_episodes(resolve_scenario(scenario), radar, None, [np.random.default_rng([seed, i]) for i in range(n)])
    out = []
    for i in range(n):
        e = b.episode(i)
        k = max_looks - 7 * i                       # rows of different lengths: padding columns
        out.append(Episode(name=e.name, **{f.name: getattr(e, f.name)[:k] for f in dataclasses.fields(Episode)
                                           if f.name != "name"}))
    return out


def _chunk(case, rdot, n=5, seed=0, advance=0):
    """``(state, looks)`` after the track start of ``n`` episodes (``advance`` looks later: a mid-episode handover)."""
    sc, radar = CASES[case]
    eps = _episodes(sc, radar, n, seed)
    tr = TrackStart(radial_velocity=rdot).tracker(n)
    tr.load(np.arange(n), eps)
    for _ in range(advance):
        rows = np.flatnonzero(tr.k < tr.n_looks)
        tr.step(np.full(rows.size, 0.3 * G0_M_S2), rows=rows)
    return tc.handover(tr)


def _q(B, J, seed):
    """log-uniform q over the action range, with exact 0, tiny, MAX_Q_M_S2 and huge entries."""
    rng = np.random.default_rng(seed)
    q = np.exp(rng.uniform(np.log(4e-3), np.log(80.0), (B, J)))
    q[:, 3::11] = 0.0
    q[:, 5::11] = 1e-9
    q[:, 7::13] = MAX_Q_M_S2
    q[:, 9::13] = 0.5 * MAX_Q_M_S2
    return q


def _both(state, looks, q, w):
    """x, final state and dLoss/dq of the torch chain and of the compiled one for the loss ``sum(w * x)``."""
    qt = torch.tensor(q, requires_grad=True)
    run = tc.run(state, looks, qt)
    (run.x * w).sum().backward()
    qc = torch.tensor(q, requires_grad=True)
    x, end = cc.cv_run(state, looks, qc)
    (x * w).sum().backward()
    return (run.x.detach().numpy(), run.state, qt.grad.numpy()), (x.detach().numpy(), end, qc.grad.numpy())


def _rel(a, b, floor):
    return float(np.max(np.abs(a - b) / (np.abs(b) + floor)))


@pytest.mark.parametrize("rdot", [False, True], ids=["position", "range_rate"])
@pytest.mark.parametrize("case,advance", [("random_radars", 0), ("two_sites_same_time", 0), ("missed_looks", 0),
                                          ("random", 17)])
def test_outputs_and_gradient_equal_the_torch_chain(case, advance, rdot):
    state, looks = _chunk(case, rdot, advance=advance)
    assert looks.J > 40 and (~looks.scored).any()                       # padding columns
    if case == "missed_looks":
        assert (~looks.detected & looks.scored).any()
    if case == "two_sites_same_time":
        assert ((looks.dt_s == 0.0) & looks.scored).any()                 # dt = 0 between the sites' plots
    if rdot:
        assert torch.isfinite(looks.rdot[1][looks.detected]).all()
    q = _q(looks.B, looks.J, seed=1)
    w = torch.tensor(np.random.default_rng(2).normal(size=(looks.B, looks.J, 4)))
    (xt, st, gt), (xc, sc, gc) = _both(state, looks, q, w)
    assert _rel(xc, xt, 1.0) < 1e-10
    assert _rel(sc.x_c.numpy(), st.x_c.detach().numpy(), 1.0) < 1e-10
    scale = np.abs(st.P_c.detach().numpy()).max(axis=(0, 1))
    assert float(np.max(np.abs(sc.P_c.numpy() - st.P_c.detach().numpy()) / scale)) < 1e-10
    assert np.all(gc[q == 0.0] == 0.0) and np.all(gc[~looks.scored_mask.numpy()] == 0.0)
    _assert_gradients_agree(gc, gt)


def _assert_gradients_agree(gc, gt):
    """Each row's gradient to 1e-8 of its largest entry, and every entry of at least 1e-4 of it to 1e-8 relative.
    Smaller entries are cancellations (e.g. at q near MAX_Q_M_S2 the posterior is the plot, whatever q): there torch's
    own gradient moves by ~1e-5 relative when q moves by one ulp (and a row with missed looks and range rate by
    ~2e-10 of its largest entry), so they are compared through the first bound."""
    m = np.abs(gt).max(axis=1, keepdims=True)
    assert float(np.max(np.abs(gc - gt) / m)) < 1e-8
    big = np.abs(gt) >= 1e-4 * m
    assert float(np.max(np.abs(gc - gt)[big] / np.abs(gt)[big])) < 1e-8


@pytest.mark.parametrize("rdot", [False, True], ids=["position", "range_rate"])
def test_gradient_of_the_pooled_loss(rdot):
    """The trainer's loss (the pooled position MSE over the scored looks) through both chains."""
    state, looks = _chunk("random_radars", rdot, n=6, seed=4)
    q = _q(looks.B, looks.J, seed=5)
    grads = []
    for run in (lambda qq: tc.run(state, looks, qq).x, lambda qq: cc.cv_run(state, looks, qq)[0]):
        qq = torch.tensor(q, requires_grad=True)
        loss = tc.pooled_position_mse(run(qq), looks)
        loss.backward()
        grads.append((float(loss.detach()), qq.grad.numpy()))
    (lt, gt), (lc, gc) = grads
    assert abs(lc / lt - 1.0) < 1e-12
    _assert_gradients_agree(gc[None].reshape(1, -1), gt.reshape(1, -1))


@pytest.mark.parametrize("rdot", [False, True], ids=["position", "range_rate"])
def test_gradient_equals_central_differences(rdot):
    state, looks = _chunk("missed_looks", rdot, n=3, seed=7)
    looks = looks.chunk(0, 30)
    rng = np.random.default_rng(8)
    q = np.exp(rng.uniform(np.log(0.05), np.log(30.0), (looks.B, looks.J)))
    w = torch.tensor(rng.normal(size=(looks.B, looks.J, 4)))

    def loss(qn):
        return float((cc.cv_run(state, looks, torch.tensor(qn))[0] * w).sum())

    qq = torch.tensor(q, requires_grad=True)
    (cc.cv_run(state, looks, qq)[0] * w).sum().backward()
    g = qq.grad.numpy()
    det = looks.detected.T.numpy()
    picks = [(0, 0), (0, 12), (1, 5), (2, 20), (1, 29)] + [tuple(np.argwhere(det)[3])]
    for b, j in picks:
        h = 1e-3 * q[b, j]                  # the loss (~1e6) rounds at ~1e-10: a smaller step is noise
        qp, qm = q.copy(), q.copy()
        qp[b, j] += h
        qm[b, j] -= h
        fd = (loss(qp) - loss(qm)) / (2 * h)
        assert abs(g[b, j] - fd) <= 1e-5 * abs(fd) + 1e-8 * np.abs(g).max(), (b, j, g[b, j], fd)


def test_chunks_chain_through_the_final_state():
    """Two chunks, the second from the first's final state, equal one run (the state carried exactly)."""
    state, looks = _chunk("random_radars", False, n=4, seed=3)
    q = torch.tensor(_q(looks.B, looks.J, seed=3))
    x, _ = cc.cv_run(state, looks, q)
    x1, s1 = cc.cv_run(state, looks.chunk(0, 20), q[:, :20])
    x2, _ = cc.cv_run(s1, looks.chunk(20), q[:, 20:])
    assert torch.equal(torch.cat((x1, x2), 1), x)


def test_refusals():
    state, looks = _chunk("random", False, n=2, seed=1)
    looks = looks.chunk(0, 5)
    q = torch.full((2, 5), 1.0, dtype=torch.float64)
    for bad in (float("nan"), -1.0, 1.01 * MAX_Q_M_S2, float("inf")):
        qb = q.clone()
        qb[1, 2] = bad
        with pytest.raises(ValueError, match="q_m_s2"):
            cc.cv_run(state, looks, qb)
    with pytest.raises(ValueError, match="shape"):
        cc.cv_run(state, looks, q[:, :4])
    with pytest.raises(ValueError, match="detached"):
        cc.cv_run(tc.ChainState(state.x_c.clone().requires_grad_(), state.P_c), looks, q)
    bad_state = tc.ChainState(state.x_c.clone(), state.P_c.clone())
    bad_state.P_c[0, 0, 0] = float("nan")
    with pytest.raises(FloatingPointError, match="not finite"):
        cc.cv_run(bad_state, looks, q)
