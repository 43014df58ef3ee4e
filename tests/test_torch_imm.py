"""The IMM in torch (radar_env/filters/torch_imm.py) against the numba kernel it copies (baselines/imm_cv_ct_runner.py): the
combined estimate and covariance, every mode's posterior, the mode probabilities, the turn rate and its spread and
the NIS equal to 1e-9 on drawn episodes of every scenario kind (single and multi-site radars, dt = 0, missed looks,
rows of different lengths), with the tuned constants and with per-look parameters; the turn-rate clip where it is
active; a 40-sigma innovation (log-space mode probabilities); chunks; gradients against finite differences
(gradcheck) through the Taylor branch at omega = 0; the CT-EKF's Jacobian column against the numba one."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from baselines import imm_cv_ct_runner as I  # noqa: E402
from radar_env.filters import torch_chain as tc  # noqa: E402
from radar_env.filters import torch_imm as ti  # noqa: E402
from radar_env.common.units import DEG  # noqa: E402
from test_torch_chain import SUITES, _episodes, _loaded  # noqa: E402

TOL = 1e-9
SPEC = I.tuned_imm_cv_ct_spec()


def _consts(spec):
    return ti.IMMConstants(**spec.filter_constants())


def _numba(eps, spec, params=None):
    batch, k0, x4, P4 = I.common_start(eps)
    B = len(eps)
    x5 = np.c_[x4, np.zeros(B)]
    P5 = np.zeros((B, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (spec.sigma_omega0_deg_s * DEG) ** 2
    return I.imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec,
                              keep_modes=True, params=params)


def _torch_params(spec, looks, params=None):
    """The kernel's arrays (baselines.imm_cv_ct_runner.kernel_parameters) at the looks' columns, as IMMParams."""
    q, sw2, lp = I.kernel_parameters(spec, None if params is None else I.check_look_parameters(spec, params))
    if params is None:
        return ti.IMMParams(*(torch.as_tensor(a) for a in (q, sw2, lp)))
    return ti.IMMParams(looks.align(q), looks.align(sw2), looks.align(lp))


def _drawn_params(spec, shape, seed):
    from test_imm_cv_ct import _drawn_params as drawn     # per-look parameters around the spec's constants
    return drawn(spec, shape, seed)


def _compare(out, res, looks):
    """Largest differences of the torch run ``out`` against the numba result ``res`` at the scored looks:
    states relative to |x| + 1, covariances relative to each matrix's largest entry, probabilities absolute,
    turn rates relative to 1 deg/s."""
    m = looks.scored_mask.numpy()
    ref = lambda a: looks.align(a).numpy()[m]   # noqa: E731
    got = lambda t: t.detach().numpy()[m]        # noqa: E731

    def rel_x(a, b):
        return float(np.max(np.abs(a - b) / (np.abs(b) + 1.0)))

    def rel_P(a, b):
        return float(np.max(np.abs(a - b) / np.abs(b).max(axis=(-2, -1), keepdims=True)))

    assert np.all(np.isfinite(ref(res.x)))
    errs = {"x": rel_x(got(out.x), ref(res.x)), "P": rel_P(got(out.P), ref(res.P)),
            "mu": float(np.max(np.abs(got(out.mu) - ref(res.mu)))),
            "omega": float(np.max(np.abs(got(out.omega) - ref(res.omega_rad_s)))) / DEG,
            "omega_std": float(np.max(np.abs(got(out.omega_std) - ref(res.omega_std_rad_s)))) / DEG,
            "nis": rel_x(got(out.nis), ref(res.nis)),
            "x_modes": rel_x(got(out.x_modes), ref(res.x_modes)), "P_modes": rel_P(got(out.P_modes), ref(res.P_modes))}
    assert max(errs.values()) < TOL, errs
    return errs


@pytest.mark.parametrize("per_look", [False, True], ids=["constant", "per_look"])
@pytest.mark.parametrize("suite", list(SUITES))
def test_torch_imm_equals_the_numba_kernel(suite, per_look):
    torch_and_numba(SPEC, suite, per_look, seed=11, param_seed=2)


def torch_and_numba(spec, suite, per_look, seed, param_seed):
    """The torch IMM and the numba kernel with ``spec`` on suite ``suite``'s drawn episodes (per-look parameters
    drawn around the spec's with ``per_look``), compared by :func:`_compare`; returns ``(torch run, numba result,
    looks)``."""
    sc, radar, n = SUITES[suite]
    eps = _episodes(sc, n, seed=seed, radar=radar)
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    B, K = len(eps), max(e.n_looks for e in eps)
    params = _drawn_params(spec, (B, K), seed=param_seed) if per_look else None
    out = ti.run(ti.start(state, _consts(spec)), looks, _torch_params(spec, looks, params), _consts(spec),
                 with_nis=True)
    res = _numba(eps, spec, params)
    _compare(out, res, looks)
    return out, res, looks


def test_two_modes_and_an_active_turn_rate_clip():
    eps = _episodes("adrian_flower", 2, seed=4) + _episodes("random", 4, seed=4)
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    for spec in (I.IMMCVCTSpec(q_high_g=None), I.IMMCVCTSpec(omega_max_deg_s=1.0), I.IMMCVCTSpec(turn_accel_max_g=0.3)):
        out = ti.run(ti.start(state, _consts(spec)), looks, _torch_params(spec, looks), _consts(spec), with_nis=True)
        res = _numba(eps, spec)
        _compare(out, res, looks)
        if spec.q_high_g is not None:       # the bound was active (the CT mode sits on it)
            w = out.x_modes[..., 1, 4].detach().numpy()[looks.scored_mask.numpy()]
            v = out.x_modes[..., 1, 2:4].detach().numpy()[looks.scored_mask.numpy()]
            bound = np.minimum(spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * 9.80665 /
                               np.maximum(np.hypot(v[:, 0], v[:, 1]), 1.0))
            assert np.mean(np.abs(np.abs(w) - bound) < 1e-12 * bound) > 0.05
            assert np.all(np.abs(w) <= bound * (1 + 1e-12))


def test_clip_gradient_where_active():
    """Where the clip is active the clipped rate is the bound: gradient 0 in the unclipped rate; with the g-limit
    the smaller bound, the gradient goes to the speed (d(a/|v|)/dvx = -a vx / |v|^3)."""
    c = _consts(I.IMMCVCTSpec(omega_max_deg_s=20.0, turn_accel_max_g=8.0))
    x = torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.0], [300.0, 30.0, 100.0], [400.0, 40.0, 0.0],
                      [0.5, -0.5, 0.001]], dtype=torch.float64, requires_grad=True)
    # row 0: |v| = 500 m/s, g-limit 0.157 rad/s < 20 deg/s; row 1: |v| = 50, the 20 deg/s bound; row 2: inside
    y = ti.clip_turn_rate(x, c)[4]
    g = torch.autograd.grad(y.sum(), x)[0]
    y = y.detach()
    a = c.accel_max_m_s2
    assert float(y[0]) == pytest.approx(a / 500.0) and float(y[1]) == pytest.approx(-20 * DEG)
    assert float(y[2]) == 0.001
    assert g[4].tolist() == [0.0, 0.0, 1.0]
    np.testing.assert_allclose(g[2:4, 0].numpy(), [-a * 300 / 500 ** 3, -a * 400 / 500 ** 3], rtol=1e-12)
    assert g[2:4, 1:].abs().sum() == 0.0


def test_forty_sigma_innovation_moves_the_mode_probabilities_without_underflow():
    eps = _episodes("random", 2, seed=8)
    e = eps[0]
    tr, _ = _loaded(eps)
    k = int(tr.k[0]) + 20
    while not e.detected[k]:
        k += 1
    sig = np.sqrt(np.linalg.eigvalsh(e.R_m2[k]).max())
    e.z_m[k] = e.z_m[k] + 40.0 * sig * np.array([0.6, 0.8]) + 3e3      # and off the prediction: NIS >> 1600
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    out = ti.run(ti.start(state, _consts(SPEC)), looks, _torch_params(SPEC, looks), _consts(SPEC), with_nis=True)
    res = _numba(eps, SPEC)
    j = k - int(tr.k[0])
    assert float(out.nis[0, j]) > 1600.0                   # exp(-NIS / 2) underflows float64's 1e-308
    assert np.exp(-0.5 * float(out.nis[0, j])) == 0.0
    mu = out.mu.detach().numpy()
    assert np.all(np.isfinite(mu[looks.scored_mask.numpy()]))
    np.testing.assert_allclose(mu[looks.scored_mask.numpy()].sum(-1), 1.0, atol=1e-12)
    assert mu[0, j, 0] < mu[0, j - 1, 0]                    # the plot moved the probability off the quiet mode
    _compare(out, res, looks)


def test_chunks_equal_one_run_and_padding_is_harmless():
    eps = _episodes("random_radars", 4, seed=9)
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    p = _torch_params(SPEC, looks, _drawn_params(SPEC, (4, max(e.n_looks for e in eps)), seed=5))
    c = _consts(SPEC)
    one = ti.run(ti.start(state, c), looks, p, c)
    s, xs = ti.start(state, c), []
    for j0 in range(0, looks.J, 17):
        j1 = min(j0 + 17, looks.J)
        part = ti.run(s, looks.chunk(j0, j1), ti.IMMParams(*(a[:, j0:j1] for a in p)), c)
        xs.append(part.x)
        s = part.state.detach()
    assert torch.equal(torch.cat(xs, 1), one.x)
    assert torch.isfinite(one.x).all() and torch.isfinite(one.P).all()   # on the padding columns too
    # step() with the parameters in the spec's mode order equals run()
    s, rec = ti.start(state, c), []
    for j in range(5):
        s, r = ti.step(s, looks, j, p.q_m_s2[:, j].T, p.sig_w2[:, j], p.log_Pi[:, j].permute(1, 2, 0), c)
        rec.append(r)
    assert torch.equal(ti.collect(rec, s, c).x, one.x[:, :5])


def test_switch_log_probs_equal_the_kernels_transition_matrix():
    for spec in (SPEC, I.IMMCVCTSpec(q_high_g=None)):
        _, _, log_Pi = I.kernel_parameters(spec)
        stay = torch.tensor([spec.p_stay_cv, spec.p_stay_ct] + ([spec.p_stay_high] if spec.n_modes == 3 else []),
                            dtype=torch.float64)
        u = torch.logit(stay)
        lp = ti.switch_log_probs(-torch.nn.functional.softplus(-u), -torch.nn.functional.softplus(u))
        np.testing.assert_allclose(lp.numpy(), log_Pi[0, 0], rtol=1e-12)


def test_gradcheck_through_the_imm_at_omega_zero():
    """Gradients of the combined estimate in log q, log sig_w2 and the transition logits equal finite differences;
    the CT mode starts at omega = 0 exactly (the Taylor branches) and turns during the looks."""
    eps = _episodes("kim_lee_accel", 2, seed=3, max_looks=60)
    tr, _ = _loaded(eps)
    state, looks = tc.handover(tr)
    looks = looks.chunk(0, 8)
    c = _consts(SPEC)
    q, sw2, lp = (torch.as_tensor(a)[0, 0] for a in I.kernel_parameters(SPEC))
    B, J = looks.B, looks.J
    th_q = torch.log(q).expand(B, J, 3).clone().requires_grad_(True)
    th_w = torch.log(sw2).expand(B, J).clone().requires_grad_(True)
    th_p = torch.logit(torch.exp(torch.diagonal(lp))).expand(B, J, 3).clone().requires_grad_(True)

    def f(tq, tw, tp):
        lpj = ti.switch_log_probs(-torch.nn.functional.softplus(-tp), -torch.nn.functional.softplus(tp))
        out = ti.run(ti.start(state, c), looks, ti.IMMParams(torch.exp(tq), torch.exp(tw), lpj), c)
        return out.x[..., :2] / 100.0, out.omega * 100.0

    assert float(ti.run(ti.start(state, c), looks, ti.IMMParams(q, sw2, lp), c).x_modes[0, 0, 1, 4]) != 0.0
    assert torch.autograd.gradcheck(f, (th_q, th_w, th_p), eps=1e-6, atol=1e-6, rtol=1e-4)


@pytest.mark.parametrize("theta", [0.0, 1e-7, 0.0999, 0.1001, 0.7, -0.3])
def test_ct_jacobian_column_equals_the_numba_one_and_is_smooth(theta):
    dt = 4.0
    x = np.array([1e4, -2e4, 180.0, -90.0, theta / dt])
    J = I.ct_jacobian(x, dt)
    w = torch.tensor([theta / dt], dtype=torch.float64, requires_grad=True)
    da, db = (v.detach() for v in tc.ct_omega_partials(torch.tensor([dt], dtype=torch.float64), w))
    vx, vy = x[2], x[3]
    np.testing.assert_allclose([float(da * vx + db * vy), float(-db * vx + da * vy)], J[:2, 4], rtol=1e-13,
                               atol=1e-13 * abs(J[:2, 4]).max())
    assert torch.autograd.gradcheck(lambda v: tc.ct_omega_partials(torch.tensor([dt], dtype=torch.float64), v),
                                    (w,), eps=1e-7, atol=1e-7, rtol=1e-5)


@pytest.mark.parametrize("suite,key", [("random_radars", None), ("three_sites_irregular", None),
                                       ("missed_looks", None), ("three_sites_irregular", "imm_ct_bank_rdot")])
def test_torch_imm_with_range_rate_equals_the_numba_kernel(suite, key):
    """Every mode updates on the radial velocity after the position, its likelihood joining the mode's: the torch
    IMM on the looks of a Tracker(radial_velocity=True) equals imm_cv_ct_filter with the same inputs to 1e-9 (with
    ``key``: the tuned spec of that tracker, the bank of CT modes of ``imm_ct_bank_rdot``)."""
    from radar_env.filters.tracking import TrackStart
    spec = I.tuned_imm_cv_ct_spec(key) if key else SPEC
    sc, radar, n = SUITES[suite]
    eps = _episodes(sc, n, seed=13, radar=radar)
    tr = TrackStart(radial_velocity=True).tracker(len(eps))
    tr.load(np.arange(len(eps)), eps)
    state, looks = tc.handover(tr)
    out = ti.run(ti.start(state, _consts(spec)), looks, _torch_params(spec, looks), _consts(spec), with_nis=True)
    batch, k0 = I.stack_episodes(eps), tr.k - 1
    B = len(eps)
    x5, P5 = np.c_[tr.x, np.zeros(B)], np.zeros((B, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = tr.P, (spec.sigma_omega0_deg_s * DEG) ** 2
    res = I.imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec,
                             keep_modes=True, **I._batch_range_rate(batch))
    _compare(out, res, looks)
    plain = ti.run(ti.start(state, _consts(spec)), looks._replace(rdot=None), _torch_params(spec, looks),
                   _consts(spec))
    assert float((plain.x - out.x).abs().max()) > 1.0       # the range rate changed the estimates
