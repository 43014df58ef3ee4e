"""The compiled kernels (radar_env/filters/kernels.py) against the numpy chain they replaced (tests/numpy_reference, main
before the kernels, verbatim): every public filter / feature / preview function on random inputs, the Tracker's
outputs and features on drawn episodes (misses, several sites, row subsets, turn-rate and known-input steps), the
bundled policy's choice of q look by look, and SPD / finite outputs of the compiled step for any q, misses and
dt = 0."""

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

from radar_env.filters import features as ft
from radar_env.filters import kalman as kf
from radar_env.sim.catalog import make_setup
from radar_env.sim.episode import draw_episode
from radar_env.filters.tracking import MAX_Q_M_S2, Tracker, preview_next_plot
from radar_env.common.units import G0_M_S2
from tests.numpy_reference import features as ref_ft
from tests.numpy_reference import filters as ref_kf
from tests.numpy_reference import tracking as ref_tr

RTOL = 1e-10


def _spd(rng, shape, n, scale):
    A = rng.standard_normal(shape + (n, n))
    return scale * (A @ np.swapaxes(A, -1, -2) + n * np.eye(n))


def _close(a, b, rtol=RTOL, atol=0.0, msg=""):
    a, b = np.asarray(a), np.asarray(b)
    assert a.shape == b.shape and a.dtype == b.dtype, (msg, a.shape, b.shape, a.dtype, b.dtype)
    if a.dtype == bool:
        np.testing.assert_array_equal(a, b, err_msg=msg)
    else:
        assert np.all(np.isfinite(a) == np.isfinite(b)), msg
        np.testing.assert_allclose(a, b, rtol=rtol, atol=atol, err_msg=msg)


# ------------------------------------------------------------------------------------------------ filters
def test_filter_functions_equal_numpy_reference():
    rng = np.random.default_rng(0)
    B, M = 50, 3
    dt = rng.uniform(0.0, 20.0, B)
    dt[:3] = 0.0
    w = rng.uniform(-0.3, 0.3, B)
    w[3:6] = 0.0
    q = rng.uniform(0.0, 100.0 * G0_M_S2, B)
    for name, args in (("transition_cv", (dt,)), ("transition_ct", (dt, w)), ("process_noise", (dt, q)),
                       ("transition_ct", (4.0, w)), ("process_noise", (dt, 3.0))):
        _close(getattr(kf, name)(*args), getattr(ref_kf, name)(*args), rtol=1e-13, atol=1e-15, msg=name)
    x = rng.normal(0, 1e4, (B, 4))
    P = _spd(rng, (B,), 4, 1e3)
    F, Q = ref_kf.transition_ct(dt, w), ref_kf.process_noise(dt, q)
    u = rng.normal(0, 10, (B, 4))
    for uu in (None, u):
        for a, b in zip(kf.predict(x, P, F, Q, uu), ref_kf.predict(x, P, F, Q, uu)):
            _close(a, b, msg="predict")
    # broadcast forms: one F for all rows, Q of batch 1
    for a, b in zip(kf.predict(x, P, F[0], Q[:1]), ref_kf.predict(x, P, F[0], Q[:1])):
        _close(a, b, msg="predict broadcast")
    z = x[:, :2] + rng.normal(0, 100, (B, 2))
    R = _spd(rng, (B,), 2, 100.0)
    det = rng.random(B) < 0.7
    zn = np.where(det[:, None], z, np.nan)
    Rn = np.where(det[:, None, None], R, np.nan)
    for d in (None, det):
        a, b = kf.update(x, P, z if d is None else zn, R if d is None else Rn, d), ref_kf.update(
            x, P, z if d is None else zn, R if d is None else Rn, d)
        for name in a._fields:
            _close(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-12, msg=f"update.{name}")
    upd = kf.update(x, P, zn, Rn, det)
    assert np.array_equal(upd.x[~det], x[~det]) and np.array_equal(upd.P[~det], P[~det])  # missed: prior, bitwise
    assert np.all(upd.nis[~det] == 0) and np.all(upd.loglik[~det] == 0)
    # (B, M) batch shapes, as the IMM uses them
    xm, Pm = rng.normal(0, 1e4, (B, M, 4)), _spd(rng, (B, M), 4, 1e3)
    a, b = kf.update(xm, Pm, z[:, None], R[:, None], np.broadcast_to(det[:, None], (B, M))), ref_kf.update(
        xm, Pm, z[:, None], R[:, None], np.broadcast_to(det[:, None], (B, M)))
    for name in a._fields:
        _close(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-12, msg=f"update(B,M).{name}")
    t1 = rng.uniform(0, 100, B)
    t2 = t1 + rng.uniform(0.1, 10, B)
    R1 = _spd(rng, (B,), 2, 50.0)
    for a, b in zip(kf.two_point_init(z - 100, R1, t1, z, R, t2), ref_kf.two_point_init(z - 100, R1, t1, z, R, t2)):
        _close(a, b, msg="two_point_init")
    with pytest.raises(ValueError, match="t2_s"):
        kf.two_point_init(z, R, t2, z, R, t2)


def test_imm_functions_equal_numpy_reference():
    rng = np.random.default_rng(1)
    B, M = 40, 3
    mu = rng.dirichlet(np.ones(M), B)
    log_mu = np.log(mu)
    log_mu[0] = np.log([1.0, 1e-300, 1e-300])  # near-degenerate mode probabilities
    Pi = rng.dirichlet(np.ones(M) * 3, M)
    log_Pi = np.log(Pi)
    # modes near one another (as in a running IMM): a spread of 1e4 m would make the posterior P a difference
    # of 1e8-sized numbers, compared at the rounding of 1e8
    xm = rng.normal(0, 1e4, (B, 1, 4)) + rng.normal(0, 30, (B, M, 4))
    Pm = _spd(rng, (B, M), 4, 1e3)
    for a, b in zip(kf.imm_mix(log_mu, log_Pi, xm, Pm), ref_kf.imm_mix(log_mu, log_Pi, xm, Pm)):
        _close(a, b, rtol=1e-9, atol=1e-9, msg="imm_mix")
    log_Pi_b = np.log(rng.dirichlet(np.ones(M), (B, M)))  # per-row transition matrices
    for a, b in zip(kf.imm_mix(log_mu, log_Pi_b, xm, Pm), ref_kf.imm_mix(log_mu, log_Pi_b, xm, Pm)):
        _close(a, b, rtol=1e-9, atol=1e-9, msg="imm_mix (B,M,M)")
    ll = rng.normal(-10, 30, (B, M))
    _close(kf.imm_mode_probabilities(log_mu, ll), ref_kf.imm_mode_probabilities(log_mu, ll), rtol=1e-12, atol=1e-12)
    for a, b in zip(kf.imm_combine(log_mu, xm, Pm), ref_kf.imm_combine(log_mu, xm, Pm)):
        _close(a, b, rtol=1e-9, atol=1e-9, msg="imm_combine")
    dt = rng.uniform(0.5, 10, B)
    F = np.stack([ref_kf.transition_cv(dt), ref_kf.transition_ct(dt, 0.05), ref_kf.transition_ct(dt, -0.05)], 1)
    Q = np.stack([ref_kf.process_noise(dt, q) for q in (0.3, 5.0, 5.0)], 1)
    z = xm[:, 0, :2] + rng.normal(0, 200, (B, 2))
    R = _spd(rng, (B,), 2, 100.0)
    det = rng.random(B) < 0.7
    for d in (None, det):
        a = kf.imm_step(log_mu, xm, Pm, log_Pi, F, Q, z, R, d)
        b = ref_kf.imm_step(log_mu, xm, Pm, log_Pi, F, Q, z, R, d)
        for name in a._fields:
            _close(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-9, msg=f"imm_step.{name}")
    # broadcast F, Q (M,4,4)
    a = kf.imm_step(log_mu, xm, Pm, log_Pi, F[0], Q[0], z, R, det)
    b = ref_kf.imm_step(log_mu, xm, Pm, log_Pi, F[0], Q[0], z, R, det)
    for name in a._fields:
        _close(getattr(a, name), getattr(b, name), rtol=1e-9, atol=1e-9, msg=f"imm_step broadcast.{name}")


# ------------------------------------------------------------------------------------------------ features
def _bank_inputs(rng, B, t, p_det=0.8, degenerate=False):
    dt = rng.uniform(0.0 if degenerate else 0.5, 10.0, B)
    t = t + dt
    x_prev = rng.normal(0, 1e4, (B, 4))
    x_prev[:, 2:] = rng.normal(0, 200, (B, 2))
    if degenerate:
        x_prev[rng.random(B) < 0.3, 2:] = 0.0
    F = ref_kf.transition_cv(dt)
    x_prior = np.einsum("bij,bj->bi", F, x_prev)
    P = _spd(rng, (B,), 4, 100.0)
    R = _spd(rng, (B,), 2, 100.0)
    S = _spd(rng, (B,), 2, 500.0)
    nu = rng.standard_normal((B, 2)) * 60.0
    x_post = x_prior + rng.standard_normal((B, 4)) * 5.0
    det = rng.random(B) < p_det
    site = rng.uniform(-1e5, 1e5, (B, 2))
    return dict(x_prev=x_prev, x_prior=x_prior, P_post_prev=P, F=F, R=R, nu=nu, S=S, x_post=x_post,
                z=x_prior[:, :2] + nu, t_s=t, dt_s=dt, bearing_rad=rng.uniform(-np.pi, np.pi, B),
                radial_velocity_m_s=rng.normal(0, 250, B), detected=det, site_xy=site)


@pytest.mark.parametrize("n,N,degenerate", [(1, 1, False), (4, 12, False), (3, 5, True)])
def test_feature_bank_equals_numpy_reference(n, N, degenerate):
    rng = np.random.default_rng(2 + n)
    B = 7
    kw = dict(n_adrian=n, window_kim_lee=N, sigma_D2_m2_s4=2.0, fma_weight=0.15, fm_weight=0.3)
    bank, ref = ft.FeatureBank(B, **kw), ref_ft.FeatureBank(B, **kw)
    seed = dict(plots_xy=rng.normal(0, 1e4, (B, 2, 2)), plot_times_s=np.stack([np.zeros(B), np.ones(B)], 1),
                x=rng.normal(0, 100, (B, 4)), t_s=np.ones(B))
    bank.reset(**seed)
    ref.reset(**seed)
    t = np.ones(B)
    for k in range(40):
        inp = _bank_inputs(rng, B, t, degenerate=degenerate)
        t = inp["t_s"]
        a, b = bank.update(**inp), ref.update(**inp)
        assert list(a) == list(b)
        for key in a:
            _close(a[key], b[key], rtol=1e-9, atol=1e-9, msg=key)
        if k == 20:
            mask = rng.random(B) < 0.5
            bank.reset(mask)
            ref.reset(mask)
    for name in ("plot_xy", "plot_t", "plot_idx", "plot_count", "head", "head_t", "head_idx", "head_count", "outer",
                 "outer_idx", "outer_count", "fma", "n_detections"):
        _close(getattr(bank, name), getattr(ref, name), rtol=1e-12, msg=name)


def test_preview_equals_numpy_reference():
    rng = np.random.default_rng(4)
    B = 60
    x = rng.normal(0, 3e4, (B, 4))
    x[:, 2:] = rng.normal(0, 200, (B, 2))
    P = _spd(rng, (B,), 4, 300.0)
    t = rng.uniform(0, 100, B)
    dt = rng.uniform(0, 12, B)
    dt[:4] = 0.0
    det = rng.random(B) < 0.8
    z = x[:, :2] + dt[:, None] * x[:, 2:] + rng.normal(0, 300, (B, 2))
    nxt = {"detected": det, "t_s": t + dt, "z_m": np.where(det[:, None], z, np.nan),
           "R_m2": np.where(det[:, None, None], _spd(rng, (B,), 2, 300.0), np.nan),
           "bearing_rad": np.where(det, rng.uniform(-np.pi, np.pi, B), np.nan),
           "radial_velocity_m_s": np.where(det, rng.normal(0, 200, B), np.nan),
           "radial_velocity_noise_std_m_s": rng.uniform(0.5, 5, B), "site_xy_m": rng.uniform(-1e5, 1e5, (B, 2))}
    a, b = preview_next_plot(x, P, t, nxt), ref_tr.preview_next_plot(x, P, t, nxt)
    assert list(a) == list(b)
    for key in a:
        _close(a[key], b[key], rtol=1e-9, atol=1e-9, msg=key)


# ------------------------------------------------------------------------------------------------ the Tracker
def _episodes(names_seeds):
    out = []
    for name, seed in names_seeds:
        rng = np.random.default_rng(seed)
        s = make_setup(name, rng)
        out.append(draw_episode(s.scenario, s.radar, rng))
    return out


def _assert_outputs_close(a, b, scaled=False):
    """StepOutputs equal to 1e-9 (relative, or with ``scaled`` relative to each array's largest magnitude: for
    ill-conditioned covariances, where the two orders of the same float64 arithmetic differ by more)."""
    def close(x, y, msg):
        y_ = np.asarray(y)
        atol = 1e-9 * max(1.0, float(np.abs(y_).max())) if scaled and y_.dtype != bool and y_.size else 1e-9
        _close(x, y, rtol=1e-9, atol=atol, msg=msg)

    for name in b._fields:
        va, vb = getattr(a, name), getattr(b, name)
        if name == "features":
            assert va.keys() == vb.keys()
            for key in vb:
                close(va[key], vb[key], key)
        else:
            close(va, vb, name)


def test_tracker_equals_numpy_reference():
    """Whole episodes of several scenarios (one and several radar sites, misses), stepped with varying q, as
    full-batch steps, row subsets, coordinated-turn steps and known-input steps: every StepOutput field and
    feature agrees with the numpy chain."""
    eps = _episodes([("random", 1), ("random_radars", 2), ("bizup2002", 3), ("random_radars", 4),
                     ("kim_lee_accel", 5), ("random", 6)])
    B = len(eps)
    tr, ref = Tracker(B), ref_tr.Tracker(B)
    _assert_outputs_close(tr.load(range(B), eps), ref.load(range(B), eps))
    rng = np.random.default_rng(0)
    for step in range(400):
        live = np.flatnonzero(tr.remaining_looks() > 0)
        if live.size == 0:
            break
        q = rng.uniform(0, 5 * G0_M_S2, live.size)
        kind = step % 4
        if kind == 0 and live.size == B:
            a, b = tr.step(q), ref.step(q)
        elif kind == 1:
            w = rng.uniform(-0.05, 0.05, live.size)
            a, b = tr.step(q, rows=live, turn_rate_rad_s=w), ref.step(q, rows=live, turn_rate_rad_s=w)
        elif kind == 2:
            rows = live[::-1][: max(1, live.size // 2)]
            a, b = tr.step(q[: rows.size], rows=rows), ref.step(q[: rows.size], rows=rows)
        else:
            a, b = tr.step(q, rows=live, known_input=True), ref.step(q, rows=live, known_input=True)
        _assert_outputs_close(a, b)
        if step == 50:  # reload two rows mid-run (the vector env's autoreset)
            new = _episodes([("random_radars", 40), ("random", 41)])
            _assert_outputs_close(tr.load([4, 1], new), ref.load([4, 1], new))
    for name in ("x", "P", "k", "t_last", "n_looks"):
        _close(getattr(tr, name), getattr(ref, name), rtol=1e-9, atol=1e-9, msg=name)
    for name in ("truth", "z_m", "R_m2", "detected", "maneuvering", "t_s", "site_xy_m"):
        a, b = tr.look_data(name), ref.look_data(name)
        assert a.shape == b.shape and a.dtype == b.dtype and not a.flags.writeable
        np.testing.assert_array_equal(a, b, err_msg=name)


def test_copy_rows_from_equals_reference():
    eps = _episodes([("random", 11), ("random_radars", 12), ("random", 13)])
    src, ref_src = Tracker(3), ref_tr.Tracker(3)
    src.load(range(3), eps)
    ref_src.load(range(3), eps)
    dst, ref_dst = Tracker(3), ref_tr.Tracker(3)
    dst.load(range(3), eps[::-1])
    ref_dst.load(range(3), eps[::-1])
    dst.copy_rows_from(src, [2, 0], [0, 1])
    ref_dst.copy_rows_from(ref_src, [2, 0], [0, 1])
    for _ in range(30):
        q = np.full(3, 0.7 * G0_M_S2)
        _assert_outputs_close(dst.step(q), ref_dst.step(q))


def test_bundled_policy_chooses_the_same_q_as_with_the_numpy_chain():
    """The bundled PPO policy fed with the kernel Tracker's observations and with the numpy chain's, each
    driving its own tracker: the same q at every look of a few fixed-seed episodes of its training family."""
    pytest.importorskip("stable_baselines3")
    from stable_baselines3 import PPO

    from agents.policies.bundle import BUNDLED_POLICY, policy_env_kwargs
    from radar_env.envs.env import EnvConfig
    from radar_env.envs.observation import ObservationLayout

    if not BUNDLED_POLICY.is_file():
        pytest.skip("no bundled policy")
    cfg = EnvConfig.from_kwargs(**policy_env_kwargs())
    levels = np.asarray(cfg.q_levels_g) * G0_M_S2
    layout = ObservationLayout(cfg.features, levels[0], levels[-1])
    model = PPO.load(BUNDLED_POLICY, device="cpu")
    eps = _episodes([(cfg.scenario if isinstance(cfg.scenario, str) else "random_radars", s) for s in range(6)])
    B = len(eps)
    kw = dict(warmup_scans=cfg.warmup_scans, warmup_q_m_s2=cfg.warmup_q_g * G0_M_S2, n_adrian=cfg.n_adrian,
              window_kim_lee=cfg.window_kim_lee, fma_weight=cfg.fma_weight)
    trs = [Tracker(B, **kw), ref_tr.Tracker(B, **kw)]
    outs = [t.load(range(B), eps) for t in trs]
    q_prev = [np.full(B, cfg.warmup_q_g * G0_M_S2)] * 2
    n_looks, chosen = 0, set()
    from radar_env.envs.observation import FrameStack
    stacks = [FrameStack(B, cfg.frame_stack, len(cfg.features)) for _ in trs]   # as the env stacks them
    first = True
    while trs[0].remaining_looks().min() > 0:
        obs = [layout.encode(o, qp) for o, qp in zip(outs, q_prev)]
        obs = [(fs.reset if first else fs.push)(np.arange(B), ob) for fs, ob in zip(stacks, obs)]
        first = False
        np.testing.assert_allclose(obs[0], obs[1], rtol=0, atol=1e-6)
        acts = [model.predict(ob, deterministic=True)[0] for ob in obs]
        q = [levels[np.asarray(a).astype(np.int64)] for a in acts]
        np.testing.assert_array_equal(q[0], q[1])
        outs = [t.step(qq) for t, qq in zip(trs, q)]
        _assert_outputs_close(outs[0], outs[1])
        q_prev = q
        n_looks += B
        chosen.update(q[0].tolist())
    assert n_looks > 300 and len(chosen) > 1  # a comparison over many looks and more than one q level


# ------------------------------------------------------------------------------------------------ robustness
def _synthetic_episode(dts, det, range_m, bearing, sr, sb_deg):
    K = len(dts)
    t = np.cumsum(dts)
    sb = np.radians(sb_deg)
    s, c = np.sin(bearing), np.cos(bearing)
    J = np.array([[s, range_m * c], [c, -range_m * s]])
    R = J @ np.diag([sr**2, sb**2]) @ J.T
    truth = np.zeros((K, 4))
    truth[:, 0] = range_m * s + 200.0 * t
    truth[:, 1] = range_m * c
    truth[:, 2] = 200.0
    d = np.asarray(det, bool).copy()
    d[[0, 1]] = True
    z = truth[:, :2] + sr * np.array([3.0, -2.0])
    nanv = lambda a: np.where(d.reshape((K,) + (1,) * (a.ndim - 1)), a, np.nan)  # noqa: E731
    return ft_episode(name="synthetic", t_s=t, site_index=np.zeros(K, int), site_xy_m=np.zeros((K, 2)), truth=truth,
                      truth_accel_m_s2=np.zeros((K, 2)), truth_turn_rate_rad_s=np.zeros(K),
                      maneuvering=np.zeros(K, bool), detected=d, range_m=nanv(np.hypot(*truth[:, :2].T)),
                      bearing_rad=nanv(np.full(K, bearing)), radial_velocity_m_s=nanv(np.full(K, 200.0 * s)),
                      z_m=nanv(z), R_m2=nanv(np.broadcast_to(R, (K, 2, 2)).copy()),
                      range_noise_std_m=np.full(K, sr), bearing_noise_std_rad=np.full(K, sb),
                      radial_velocity_noise_std_m_s=np.full(K, 1.0))


def ft_episode(**kw):
    from radar_env.sim.episode import Episode
    return Episode(**kw)


@settings(max_examples=40, deadline=None)
@given(
    q_g=st.lists(st.floats(0.0, 100.0), min_size=25, max_size=25),
    dts=st.lists(st.one_of(st.just(0.0), st.floats(0.05, 60.0)), min_size=30, max_size=30),
    det=st.lists(st.booleans(), min_size=30, max_size=30),
    range_m=st.floats(500.0, 4e5),
    bearing=st.floats(-np.pi, np.pi),
    sr=st.floats(1.0, 500.0),
    sb_deg=st.floats(0.01, 2.0),
    omega=st.one_of(st.none(), st.floats(-0.5, 0.5)),
)
def test_compiled_step_keeps_P_spd_and_everything_finite(q_g, dts, det, range_m, bearing, sr, sb_deg, omega):
    """The fused kernel step for any q in [0, 100 g], missed looks and dt = 0 (two sites at one time): P stays
    symmetric and positive (semi)definite to rounding and every output and feature is finite. (Equality with the
    numpy chain is checked on drawn episodes above: here a 1 m plot after a minute of misses makes the Joseph
    update cancel numbers ~1e9 times larger than the posterior, so the two operation orders differ beyond 1e-9
    of the posterior; long runs of misses at q = 0 after a 1 m start make P nearly singular, cond ~1e14: its smallest
    eigenvalue is then below eigvalsh's own rounding, so positivity is checked relative to the largest.)"""
    dts = [1.0, 2.0] + dts[2:]  # the two-hit start needs two plots at different times
    ep = _synthetic_episode(dts, det, range_m, bearing, sr, sb_deg)
    tr = Tracker(1, warmup_scans=1)
    tr.load([0], [ep])
    for q in q_g:
        if tr.remaining_looks()[0] == 0:
            break
        qq, w = np.array([min(q * G0_M_S2, MAX_Q_M_S2)]), None if omega is None else np.array([omega])
        out = tr.step(qq, turn_rate_rad_s=w)
        for name in ("x", "P", "x_prior", "P_prior", "nu", "S", "nis", "dt_s", "t_s"):
            assert np.all(np.isfinite(getattr(out, name))), name
        for key, v in out.features.items():
            assert np.all(np.isfinite(v)), key
        assert np.array_equal(tr.P, np.swapaxes(tr.P, -1, -2))
        ev = np.linalg.eigvalsh(tr.P[0])
        assert np.all(np.diag(tr.P[0]) > 0.0) and ev.min() > -1e-12 * ev.max()
