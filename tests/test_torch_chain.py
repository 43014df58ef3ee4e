"""The differentiable chain (radar_env/filters/torch_chain.py) against the numba chain it copies: every look's prior,
posterior, innovation and NIS equal radar_env.filters.tracking.Tracker stepped with the same q (and turn-rate) schedule to
1e-9 on drawn episodes of every scenario kind, single and multi-site radars (irregular dt, dt = 0), missed looks
and rows of different lengths in one batch; the torch track start equals Tracker.load; chunks, step() and run()
agree; gradients against finite differences (gradcheck) and finite at omega ~ 0; the building blocks against
radar_env.filters.kalman; the loss against agents.evaluation.metrics; bad inputs refused."""

import dataclasses
import importlib.util
import sys
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from radar_env.filters import kalman  # noqa: E402
from radar_env.filters import torch_chain as tc  # noqa: E402
from radar_env.envs.config import resolve_scenario  # noqa: E402
from radar_env.sim.draws import draw_episodes  # noqa: E402
from radar_env.sim.episode import Episode, stack_episodes  # noqa: E402
from radar_env.sim.radar import Radar, RadarSite  # noqa: E402
from radar_env.filters.tracking import MAX_Q_M_S2, TrackStart  # noqa: E402
from radar_env.common.units import DEG, G0_M_S2  # noqa: E402

TOL = 1e-9
Q_LO, Q_HI = 0.002 * G0_M_S2, 8.0 * G0_M_S2
# two sites looking at the same times (dt = 0 between their plots), a third on another period, one with Pd < 1
TWO_SITES_SAME_TIME = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=5.0),
                             RadarSite(position_m=(40e3, 10e3), scan_period_s=5.0, detection_probability=0.8)))
THREE_SITES = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=4.0, detection_probability=0.7),
                     RadarSite(position_m=(-30e3, 20e3), scan_period_s=6.0, first_scan_s=1.5),
                     RadarSite(position_m=(20e3, 50e3), scan_period_s=12.0, first_scan_s=3.0)))
MISSING = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=5.0, detection_probability=0.6),))


def _short(e, n_looks):
    return Episode(name=e.name, **{f.name: getattr(e, f.name)[:n_looks] for f in dataclasses.fields(Episode)
                                   if f.name != "name"})


def _episodes(name, n, seed, radar=None, max_looks=140):
    """``n`` episodes of ``name`` (seen by ``radar``), row i cut to ``max_looks - 9 i`` looks (rows of different
    lengths; short enough to keep the test fast)."""
    b = draw_episodes(resolve_scenario(name), radar, None, [np.random.default_rng([seed, i]) for i in range(n)])
    return [_short(b.episode(i), max_looks - 9 * i) for i in range(n)]


def _loaded(eps):
    tr = TrackStart().tracker(len(eps))
    out = tr.load(np.arange(len(eps)), eps)
    return tr, out


def _schedules(B, J, seed):
    rng = np.random.default_rng(seed)
    q = np.exp(rng.uniform(np.log(Q_LO), np.log(Q_HI), size=(B, J)))
    w = rng.uniform(-8 * DEG, 8 * DEG, size=(B, J))
    w[:, ::5] = 0.0                     # F_ct = F_cv exactly
    w[:, 2::5] = 1e-6                   # series branch, off zero
    w[:, 3::5] = 1e-2 / 5.0             # at the branch boundary (|omega dt| = 1e-2 at dt = 5 s)
    return q, w


def _numba_chain(tr, out, q, w=None):
    """Step the numba Tracker with column j of ``q`` (and ``w``) at each row's j-th look after ``tr``'s cursor;
    per-look outputs (B, J, ...) aligned as ChainLooks, NaN where a row has ended."""
    B, J = q.shape
    fields = ("x_prior", "P_prior", "x", "P", "nu", "S", "nis")
    res = {f: np.full((B, J) + np.shape(getattr(out, f))[1:], np.nan) for f in fields}
    start = tr.k.copy()
    active = tr.k < tr.n_looks
    while active.any():
        rows = np.flatnonzero(active)
        j = tr.k[rows] - start[rows]
        o = tr.step(q[rows, j], rows=rows, turn_rate_rad_s=None if w is None else w[rows, j])
        for f in fields:
            res[f][rows, j] = getattr(o, f)
        active[rows] = ~o.done
    return res


def _err_x(a, b):
    """Largest error of states (m, m/s) relative to |x| + 1."""
    return float(np.max(np.abs(a - b) / (np.abs(b) + 1.0)))


def _err_P(a, b):
    """Largest error of covariances relative to each matrix's largest entry."""
    scale = np.abs(b).max(axis=(-2, -1), keepdims=True)
    return float(np.max(np.abs(a - b) / scale))


def _compare(run, ref, looks):
    m = looks.scored_mask.numpy()
    assert np.all(np.isfinite(ref["x"][m])) and np.all(np.isnan(ref["x"][~m]))   # the masks agree
    errs = {"x": _err_x(run.x.detach().numpy()[m], ref["x"][m]),
            "x_prior": _err_x(run.x_prior.detach().numpy()[m], ref["x_prior"][m]),
            "P": _err_P(run.P.detach().numpy()[m], ref["P"][m]),
            "P_prior": _err_P(run.P_prior.detach().numpy()[m], ref["P_prior"][m]),
            "S": _err_P(run.S.detach().numpy()[m], ref["S"][m]),
            "nu": float(np.max(np.abs(run.nu.detach().numpy()[m] - ref["nu"][m])
                               / np.sqrt(np.abs(np.diagonal(ref["S"][m], axis1=-2, axis2=-1))))),
            "nis": float(np.max(np.abs(run.nis.detach().numpy()[m] - ref["nis"][m]) / (ref["nis"][m] + 1.0)))}
    assert max(errs.values()) < TOL, errs
    return errs


SUITES = {  # name -> (scenario, radar, runs)
    "random": ("random", None, 5),
    "random_radars": ("random_radars", None, 6),
    "bizup2002": ("bizup2002", None, 2),
    "kim_lee_accel": ("kim_lee_accel", None, 2),
    "adrian_flower": ("adrian_flower", None, 2),
    "seed002_two_radars": ("seed002_two_radars", None, 2),
    "adsb_dev": ("adsb_dev", None, 2),
    "two_sites_same_time": ("random", TWO_SITES_SAME_TIME, 3),
    "three_sites_irregular": ("random", THREE_SITES, 3),
    "missed_looks": ("kim_lee_accel", MISSING, 3),
}


@pytest.fixture(scope="module")
def mixed_batch():
    """Episodes of every suite in one batch: rows of different lengths, radars and start indices."""
    eps = []
    for i, (sc, radar, n) in enumerate(SUITES.values()):
        eps += _episodes(sc, n, seed=100 + i, radar=radar)
    return eps


def test_suites_cover_the_cases(mixed_batch):
    b = stack_episodes(mixed_batch)
    dt = np.diff(b.t_s, axis=1)[b.valid[:, 1:]]
    assert np.any(dt == 0.0) and len(np.unique(np.round(dt, 6))) > 4     # dt = 0 and irregular dt
    assert np.mean(~b.detected[b.valid]) > 0.05                           # missed looks
    assert len(set(b.n_looks)) > 5 and len(set(np.unique(b.site_index))) >= 3


@pytest.mark.parametrize("turn", [False, True], ids=["cv", "ct"])
@pytest.mark.parametrize("suite", list(SUITES))
def test_run_equals_the_numba_chain(suite, turn):
    sc, radar, n = SUITES[suite]
    eps = _episodes(sc, n, seed=7, radar=radar)
    tr, out = _loaded(eps)
    state, looks = tc.handover(tr)
    q, w = _schedules(looks.B, looks.J, seed=1)
    w = w if turn else None
    run = tc.run(state, looks, torch.tensor(q), None if w is None else torch.tensor(w))
    _compare(run, _numba_chain(tr, out, q, w), looks)


@pytest.mark.parametrize("turn", [False, True], ids=["cv", "ct"])
def test_mixed_batch_and_torch_track_start_equal_the_numba_chain(mixed_batch, turn):
    tr, out = _loaded(mixed_batch)
    state, looks = tc.start_tracks(stack_episodes(mixed_batch))
    np.testing.assert_array_equal(looks.start_index, tr.k)
    assert _err_x(state.x.numpy(), tr.x) < TOL and _err_P(state.P.numpy(), tr.P) < TOL
    h_state, h_looks = tc.handover(tr)
    for f in ("dt_s", "mask", "z_m", "R_m2", "truth", "scored"):
        assert torch.equal(getattr(looks, f), getattr(h_looks, f)), f
    q, w = _schedules(looks.B, looks.J, seed=2)
    w = w if turn else None
    run = tc.run(state, looks, torch.tensor(q), None if w is None else torch.tensor(w))
    _compare(run, _numba_chain(tr, out, q, w), looks)


def test_handover_mid_episode():
    eps = _episodes("random_radars", 4, seed=3)
    tr, out = _loaded(eps)
    for _ in range(7):
        tr.step(np.full(tr.B, 0.5 * G0_M_S2))
    state, looks = tc.handover(tr)
    np.testing.assert_array_equal(looks.start_index, tr.k)
    q, _ = _schedules(looks.B, looks.J, seed=4)
    x0 = state.x.clone()
    _compare(tc.run(state, looks, torch.tensor(q)), _numba_chain(tr, out, q), looks)
    assert torch.equal(state.x, x0)                     # a copy: stepping the Tracker does not move it
    one = tc.ChainState.from_xP(tr.x[:1], tr.P[:1])
    tr.x[0] += 1.0
    assert not torch.equal(one.x, torch.as_tensor(tr.x[:1]))


def test_padding_keeps_the_final_state():
    eps = _episodes("random", 6, seed=5)
    state, looks = tc.start_tracks(eps)
    assert len(set(looks.n_looks)) > 1
    run = tc.run(state, looks, 3.0)
    x, P = run.x.detach(), run.P.detach()
    for b in range(looks.B):
        last = int(looks.scored[:, b].sum()) - 1
        assert torch.equal(x[b, last:], x[b, last].expand_as(x[b, last:]))
        assert torch.equal(P[b, last:], P[b, last].expand_as(P[b, last:]))
        assert torch.equal(run.state.x[b], x[b, last])


# ------------------------------------------------------------------------------------------------ chunks, step
def test_chunks_and_step_equal_one_run():
    eps = _episodes("random_radars", 5, seed=6)
    state, looks = tc.start_tracks(eps)
    q, w = _schedules(looks.B, looks.J, seed=7)
    for omega in (None, torch.tensor(w)):
        lq = torch.tensor(np.log(q), requires_grad=True)
        whole = tc.run(state, looks, torch.exp(lq), omega)
        tc.pooled_position_mse(whole.x, looks).backward()
        g_whole = lq.grad.clone()
        lq.grad = None
        # chunks without detaching: the same numbers and the same gradient
        st, xs, loss = state, [], 0.0
        n = looks.n_scored.sum()
        for j0 in range(0, looks.J, 17):
            part = looks.chunk(j0, j0 + 17)
            if omega is None:
                recs = []
                for j in range(part.J):
                    st, rec = tc.step(st, part, j, torch.exp(lq[:, j0 + j]))
                    recs.append(rec)
                out = tc.collect(recs, st)
            else:
                out = tc.run(st, part, torch.exp(lq[:, j0:j0 + 17]), omega[:, j0:j0 + 17])
            st = out.state
            xs.append(out.x)
            loss = loss + tc.pooled_position_mse(out.x, part, n)
        assert torch.equal(torch.cat(xs, 1), whole.x)
        assert torch.equal(st.P_c, whole.state.P_c)
        loss.backward()
        torch.testing.assert_close(lq.grad, g_whole, rtol=1e-12, atol=1e-12 * float(g_whole.abs().max()))
        # detached chunks: the same forward numbers, a truncated gradient
        lq.grad = None
        st = state
        for j0 in range(0, looks.J, 17):
            part = looks.chunk(j0, j0 + 17)
            out = tc.run(st, part, torch.exp(lq[:, j0:j0 + 17]), None if omega is None else omega[:, j0:j0 + 17])
            tc.pooled_position_mse(out.x, part, n).backward()
            assert torch.equal(out.x.detach(), whole.x[:, j0:j0 + 17].detach())
            st = out.state.detach()
        assert torch.all(torch.isfinite(lq.grad)) and not torch.equal(lq.grad, g_whole)


# ------------------------------------------------------------------------------------------------- gradients
def _small_case():
    eps = _episodes("random", 2, seed=8, radar=THREE_SITES)
    state, looks = tc.start_tracks(eps)
    return state, looks.chunk(0, 9)


def test_gradcheck_q_omega_and_initial_state():
    state, looks = _small_case()
    assert looks.mask.min() == 0.0 and looks.dt_s.unique().numel() > 2    # a missed look, irregular dt
    B, J = looks.B, looks.J
    lq = torch.full((B, J), float(np.log(0.5 * G0_M_S2)), dtype=torch.float64)
    lq += torch.linspace(-1.0, 1.0, B * J, dtype=torch.float64).view(B, J)
    om = torch.tensor([[0.0, 1e-9, -1e-6, 2e-3, -2e-3, 0.05, -0.1, 0.0, 1e-4]] * B, dtype=torch.float64)
    scale_x = torch.tensor([1e3, 1e3, 10.0, 10.0], dtype=torch.float64)

    def f(lq_, om_, x0):
        out = tc.run(tc.ChainState(x0, state.P_c), looks, torch.exp(lq_), om_)
        return out.x / scale_x, out.P / 1e4, out.nis

    inputs = (lq.clone().requires_grad_(), om.clone().requires_grad_(), state.x_c.clone().requires_grad_())
    # fast mode: random projections u^T J v of the full Jacobian (the full one costs ~30 s here)
    assert torch.autograd.gradcheck(f, inputs, eps=1e-6, atol=1e-6, rtol=1e-4, fast_mode=True)
    # the full Jacobian through the CV path (no omega), q only
    assert torch.autograd.gradcheck(lambda lq_: tc.run(state, looks, torch.exp(lq_)).x / scale_x, (inputs[0],),
                                    eps=1e-6, atol=1e-6, rtol=1e-4)


def test_gradients_finite_and_continuous_at_omega_zero():
    dt = torch.full((9,), 5.0, dtype=torch.float64)
    edge = tc.SERIES_THETA / 5.0
    om = torch.tensor([0.0, 1e-300, -1e-12, 1e-8, edge * (1 - 1e-9), edge * (1 + 1e-9), -edge, 0.2, -0.3],
                      dtype=torch.float64, requires_grad=True)
    F = tc.transition(dt, om)
    jac = torch.stack([torch.autograd.grad(F[i, j].sum(), om, retain_graph=True)[0]
                       for i in range(4) for j in range(4)])          # (16, 9): dF_ij / d omega per entry
    assert torch.all(torch.isfinite(jac))
    # against central differences of the exact kinematics (kalman.transition_ct, the kernels' sinc forms)
    h = 1e-7
    w = om.detach().numpy()
    fd = (kalman.transition_ct(5.0 * np.ones(9), w + h) - kalman.transition_ct(5.0 * np.ones(9), w - h)) / (2 * h)
    np.testing.assert_allclose(jac.numpy().T.reshape(9, 4, 4), fd, rtol=1e-6, atol=1e-7)
    # the two sides of the series boundary agree
    np.testing.assert_allclose(jac[:, 4].numpy(), jac[:, 5].numpy(), rtol=1e-7, atol=1e-12)


def test_loss_gradient_finite_at_extreme_q():
    state, looks = _small_case()
    for q in (0.0, Q_LO, MAX_Q_M_S2):
        qt = torch.full((looks.B, looks.J), q, dtype=torch.float64, requires_grad=True)
        tc.pooled_position_mse(tc.run(state, looks, qt, torch.zeros_like(qt)).x, looks).backward()
        assert torch.all(torch.isfinite(qt.grad))


# -------------------------------------------------------------------------------------------- building blocks
def test_blocks_equal_radar_env_filters():
    rng = np.random.default_rng(9)
    n = 64
    dt = rng.uniform(0.0, 12.0, n)
    dt[:4] = 0.0
    w = rng.uniform(-0.3, 0.3, n)
    w[4:10] = [0.0, 1e-12, -1e-6, 1e-3, 2e-3, -2e-3]
    q = rng.uniform(0.0, 50.0, n)
    cf = lambda a, k: torch.tensor(np.moveaxis(a, 0, -1).copy()) if k else torch.tensor(a)   # noqa: E731
    bf = lambda t, k: np.moveaxis(t.detach().numpy(), -1, 0) if k else t.detach().numpy()   # noqa: E731
    np.testing.assert_allclose(bf(tc.transition(cf(dt, 0), cf(w, 0)), 1), kalman.transition_ct(dt, w),
                               rtol=1e-13, atol=1e-14)
    np.testing.assert_array_equal(bf(tc.transition(cf(dt, 0)), 1), kalman.transition_cv(dt))
    np.testing.assert_allclose(bf(tc.process_noise(cf(dt, 0), cf(q, 0)), 1), kalman.process_noise(dt, q),
                               rtol=1e-14, atol=0)
    A = rng.standard_normal((n, 4, 4)) * [30.0, 30.0, 3.0, 3.0]
    P = A @ np.swapaxes(A, -1, -2) + np.eye(4)
    P = 0.5 * (P + np.swapaxes(P, -1, -2))
    x = rng.standard_normal((n, 4)) * [1e4, 1e4, 200.0, 200.0]
    Fn, Qn = kalman.transition_ct(dt, w), kalman.process_noise(dt, q)
    xp, Pp = kalman.predict(x, P, Fn, Qn)
    for pred in (tc.predict(cf(x, 1), cf(P, 2), cf(Fn, 2), cf(Qn, 2)),):
        assert _err_x(bf(pred[0], 1), xp) < 1e-14 and _err_P(bf(pred[1], 2), Pp) < 1e-14
    xc, Pc = kalman.predict(x, P, kalman.transition_cv(dt), Qn)
    pred = tc.predict_cv(cf(x, 1), cf(P, 2), cf(dt, 0), cf(Qn, 2))
    assert _err_x(bf(pred[0], 1), xc) < 1e-14 and _err_P(bf(pred[1], 2), Pc) < 1e-14
    assert torch.equal(pred[1], pred[1].transpose(0, 1))          # exactly symmetric without a symmetrisation
    z = xp[:, :2] + rng.standard_normal((n, 2)) * 50.0
    B_ = rng.standard_normal((n, 2, 2)) * 40.0
    R = B_ @ np.swapaxes(B_, -1, -2) + 100.0 * np.eye(2)
    R = 0.5 * (R + np.swapaxes(R, -1, -2))
    det = rng.uniform(size=n) < 0.7
    ref = kalman.update(xp, Pp, z, R, det)
    z0, R0 = np.where(det[:, None], z, 0.0), np.where(det[:, None, None], R, np.eye(2))
    xo, Po, nu, S, S_inv = tc.update(cf(xp, 1), cf(Pp, 2), cf(z0, 1), cf(R0, 2), cf(det.astype(float), 0))
    assert _err_x(bf(xo, 1), ref.x) < 1e-12 and _err_P(bf(Po, 2), ref.P) < 1e-12   # rounding (cancellation in P+)
    assert np.array_equal(bf(xo, 1)[~det], xp[~det]) and np.array_equal(bf(Po, 2)[~det], Pp[~det])
    np.testing.assert_allclose(bf(nu, 1), ref.nu, rtol=1e-13, atol=1e-9)
    np.testing.assert_allclose(bf(S, 2), ref.S, rtol=1e-14)
    np.testing.assert_allclose(tc.nis(nu, S_inv).numpy(), ref.nis, rtol=1e-11, atol=1e-14)
    np.testing.assert_allclose(tc.log_likelihood(nu, S, S_inv, cf(det.astype(float), 0)).numpy(), ref.loglik,
                               rtol=1e-12, atol=1e-14)
    z1 = z + 300.0
    x2, P2 = kalman.two_point_init(z, R, np.zeros(n), z1, R, np.full(n, 4.5))
    t2 = tc.two_point_init(cf(z, 1), cf(R, 2), torch.zeros(n, dtype=torch.float64), cf(z1, 1), cf(R, 2),
                           torch.full((n,), 4.5, dtype=torch.float64))
    np.testing.assert_array_equal(bf(t2[0], 1), x2)
    np.testing.assert_array_equal(bf(t2[1], 2), P2)


def test_blocks_take_extra_batch_axes():
    """(4, M, B) layouts (M filters per row, e.g. IMM modes) give what each filter alone gives."""
    state, looks = _small_case()
    x = torch.stack([state.x_c, state.x_c + 10.0], 1)                   # (4, 2, B)
    P = torch.stack([state.P_c, 2.0 * state.P_c], 2)                    # (4, 4, 2, B)
    dt = looks.dt_s[0].expand(2, -1)
    F = tc.transition(dt, torch.tensor([[0.0], [0.03]], dtype=torch.float64).expand(2, looks.B))
    Q = tc.process_noise(dt, torch.tensor([[1.0], [5.0]], dtype=torch.float64))
    xp, Pp = tc.predict(x, P, F, Q)
    up = tc.update(xp, Pp, looks.z_m[0][:, None], looks.R_m2[0][:, :, None], looks.mask[0][None])
    for m in range(2):
        xm, Pm = tc.predict(x[:, m], P[:, :, m], F[:, :, m], Q[:, :, m])
        um = tc.update(xm, Pm, looks.z_m[0], looks.R_m2[0], looks.mask[0])
        for a, b in zip(up, um):
            torch.testing.assert_close(a.select(a.dim() - 2, m), b, rtol=1e-15, atol=0)


# ----------------------------------------------------------------------------------------------------- losses
def test_pooled_loss_is_what_the_evaluation_pools():
    from agents.evaluation.metrics import evaluate_run
    from baselines.hindsight import chain_forward

    eps = _episodes("random_radars", 5, seed=10) + _episodes("bizup2002", 2, seed=10)
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    q, _ = _schedules(looks.B, looks.J, seed=11)
    mse = float(tc.pooled_position_mse(tc.run(state, looks, torch.tensor(q)).x, looks))
    metrics = evaluate_run(stack_episodes(eps), chain_forward(eps, q), n_boot=10)
    np.testing.assert_allclose(mse, metrics["pos_rmse_m"] ** 2, rtol=1e-9)
    assert int(looks.scored.sum()) == metrics["looks"]


# ------------------------------------------------------------------------------------------------ bad inputs
@pytest.mark.parametrize("bad", [float("nan"), -1.0, 2.0 * MAX_Q_M_S2, float("inf")])
def test_bad_q_is_refused(bad):
    state, looks = _small_case()
    q = torch.full((looks.B, looks.J), 1.0, dtype=torch.float64)
    q[1, 3] = bad
    with pytest.raises(ValueError, match="q_m_s2"):
        tc.run(state, looks, q)
    with pytest.raises(ValueError, match="q_m_s2"):
        tc.step(state, looks, 0, q[1])
    for v in (float("nan"), float("inf")):
        w = torch.zeros_like(q)
        w[0, 0] = v
        with pytest.raises(ValueError, match="omega_rad_s must be finite"):
            tc.run(state, looks, 1.0, w)
        with pytest.raises(ValueError, match="omega_rad_s must be finite"):
            tc.step(state, looks, 0, 1.0, w[:, 0])
    with pytest.raises(ValueError, match="q_m_s2 must broadcast"):
        tc.run(state, looks, torch.ones(looks.B + 1, looks.J))


def test_too_short_episode_is_refused_by_name():
    e = _episodes("bizup2002", 1, seed=12)[0]
    with pytest.raises(ValueError, match="bizup2002.*track start needs"):
        tc.start_tracks([_short(e, 10)])
    det = np.zeros(e.n_looks, bool)
    det[0] = True
    with pytest.raises(ValueError, match="two detected looks"):
        tc.start_tracks([dataclasses.replace(e, detected=det)])


# --------------------------------------------------------------------------------------------------- benchmark
def test_bench_runs_with_tiny_settings(tmp_path, capsys):
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_torch_chain.py"
    spec = importlib.util.spec_from_file_location("bench_torch_chain", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    res = mod.main(["--batch", "3", "--chunk", "7", "--repeats", "1", "--max-looks", "20",
                    "--json", str(tmp_path / "b.json")])
    assert set(res["modes"]) == set(mod.MODES) and all(r["episodes_per_s"] > 0 for r in res["modes"].values())
    assert "row-looks/s" in capsys.readouterr().out and (tmp_path / "b.json").is_file()
    with pytest.raises(SystemExit):
        mod.main(["--modes", "nope"])


# ------------------------------------------------------------------------------------------------ range rate
@pytest.mark.parametrize("suite", ["random_radars", "two_sites_same_time", "three_sites_irregular", "missed_looks"])
def test_range_rate_run_equals_the_numba_chain_with_range_rate(suite):
    """The looks of a Tracker(radial_velocity=True) carry the range-rate inputs and the torch chain updates on them
    as the numba chain does (every look's posterior to 1e-9); torch's own track start too."""
    sc, radar, n = SUITES[suite]
    eps = _episodes(sc, n, seed=9, radar=radar)
    ts = TrackStart(radial_velocity=True)
    tr = ts.tracker(len(eps))
    out = tr.load(np.arange(len(eps)), eps)
    state, looks = tc.handover(tr)
    assert looks.rdot is not None and torch.isfinite(looks.rdot[1][looks.detected]).all()
    s_state, s_looks = tc.start_tracks(stack_episodes(eps), ts)
    assert _err_x(s_state.x.numpy(), tr.x) < TOL and _err_P(s_state.P.numpy(), tr.P) < TOL
    q, _ = _schedules(looks.B, looks.J, seed=3)
    run = tc.run(state, looks, torch.tensor(q))
    _compare(run, _numba_chain(tr, out, q), looks)
    assert s_looks.rdot is not None


def test_range_rate_gradcheck():
    eps = _episodes("random_radars", 2, seed=5, max_looks=40)
    tr = TrackStart(radial_velocity=True).tracker(2)
    tr.load(np.arange(2), eps)
    state, looks = tc.handover(tr)
    looks = looks.chunk(0, 6)
    q0 = torch.full((2, 6), 0.5 * G0_M_S2, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda q: tc.run(state, looks, q).x, (q0,), eps=1e-4, atol=1e-6)
