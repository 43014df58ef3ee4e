"""imm_cv_ct: the mixed-order CV / CT-EKF IMM against an independent per-track loop, Stone Soup's EKF, finite
differences, chi-square consistency, and the behaviours that define it (turn-rate convergence, the bound)."""

import dataclasses
import datetime

import numpy as np
import pytest
from scipy import stats
from scipy.special import logsumexp

from agents.evaluation.suites import TUNING_SEEDS, draw_suite
from baselines import imm_cv_ct_runner as I
from radar_env.sim.episode import draw_episode
from radar_env.filters.kalman import process_noise, transition_ct
from radar_env.sim.radar import Radar, RadarSite
from radar_env.sim.scenario import ScenarioBuilder
from radar_env.common.units import DEG, G0_M_S2

H5 = np.hstack([np.eye(2), np.zeros((2, 3))])


def _q5(dt, q, sig_w):
    Q = np.zeros((5, 5))
    Q[:4, :4] = process_noise(dt, q)[0]
    Q[4, 4] = sig_w ** 2 * dt
    return Q


# ------------------------------------------------------------------------------------------------ the reference
def _ref_ct_mean(x, dt):
    """CT motion through the repo's tested F_ct (radar_env.filters.kalman.transition_ct)."""
    return np.r_[transition_ct(dt, x[4])[0] @ x[:4], x[4]]


def _ref_ct_jacobian(x, dt):
    """The Jacobian from the direct closed forms (a short series only very near omega = 0)."""
    w, (vx, vy) = x[4], x[2:4]
    J = np.eye(5)
    J[:4, :4] = transition_ct(dt, w)[0]
    th = w * dt
    if abs(th) > 1e-2:
        da = (dt * np.cos(th) * w - np.sin(th)) / w ** 2
        db = (dt * np.sin(th) * w - (1 - np.cos(th))) / w ** 2
    else:
        da = dt ** 2 * (-th / 3 + th ** 3 / 30 - th ** 5 / 840)
        db = dt ** 2 * (0.5 - th ** 2 / 8 + th ** 4 / 144)
    s, c = np.sin(th), np.cos(th)
    J[:, 4] = [da * vx + db * vy, -db * vx + da * vy, dt * (-s * vx + c * vy), -dt * (c * vx + s * vy), 1.0]
    return J


def _ref_clip(x, spec):
    speed = max(np.hypot(x[2], x[3]), 1.0)
    b = min(spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2 / speed)
    x[4] = np.clip(x[4], -b, b)


def _reference_track(t, z, R, det, k0, n, x_init, P_init, spec, params=None):
    """Slow, independent per-track IMM: numpy matrices, scipy's logsumexp, explicit Joseph form. ``params``
    (K, n_par): per-look values of I.LOOK_PARAMS (spec.n_modes of them) replacing the spec's constants."""
    is_ct, q, log_Pi, log_mu = spec.mode_arrays()
    M = len(q)
    sw2, sw02 = (spec.sigma_omega_deg_s15 * DEG) ** 2, (spec.sigma_omega0_deg_s * DEG) ** 2

    def augment(x, P):
        x, P = x.copy(), P.copy()
        x[4] = 0.0
        P[4, :] = P[:, 4] = 0.0
        P[4, 4] = sw02
        return x, P

    xs = [x_init.copy() for _ in range(M)]
    Ps = [P_init.copy() for _ in range(M)]
    for m in range(M):
        if not is_ct[m]:
            xs[m], Ps[m] = augment(xs[m], Ps[m])
    out = {"x": [], "P": [], "mu": [], "omega": [], "nis": [], "xm": [], "Pm": []}
    t_last = t[k0 - 1]
    for k in range(k0, n):
        dt = t[k] - t_last
        if params is not None:   # q_cv, q_ct, sigma_omega, p_stay_cv, p_stay_ct[, q_high, p_stay_high]
            p = params[k]
            q = np.array([p[0], p[1]] + ([p[5]] if M == 3 else [])) * G0_M_S2
            stay = [p[3], p[4]] + ([p[6]] if M == 3 else [])
            log_Pi = np.log([[stay[i] if i == j else (1 - stay[i]) / (M - 1) for j in range(M)] for i in range(M)])
            sw2 = (p[2] * DEG) ** 2
        A = log_Pi + log_mu[:, None]
        log_c = logsumexp(A, axis=0)
        W = np.exp(A - log_c[None, :])
        xp, Pp = [], []
        for j in range(M):
            x0 = sum(W[i, j] * xs[i] for i in range(M))
            P0 = sum(W[i, j] * (Ps[i] + np.outer(xs[i] - x0, xs[i] - x0)) for i in range(M))
            P0 = 0.5 * (P0 + P0.T)
            if is_ct[j]:
                _ref_clip(x0, spec)
                F, xpj = _ref_ct_jacobian(x0, dt), _ref_ct_mean(x0, dt)
                Q = _q5(dt, q[j], np.sqrt(sw2))
            else:
                x0, P0 = augment(x0, P0)
                F = np.eye(5)
                F[:4, :4] = transition_ct(dt, 0.0)[0]
                xpj, Q = F @ x0, _q5(dt, q[j], 0.0)
            Pj = F @ P0 @ F.T + Q
            xp.append(xpj)
            Pp.append(0.5 * (Pj + Pj.T))
        ll = np.zeros(M)
        for j in range(M):
            if det[k]:
                S = H5 @ Pp[j] @ H5.T + R[k]
                S = 0.5 * (S + S.T)
                Kg = Pp[j] @ H5.T @ np.linalg.inv(S)
                nu = z[k] - xp[j][:2]
                xs[j] = xp[j] + Kg @ nu
                IKH = np.eye(5) - Kg @ H5
                Pj = IKH @ Pp[j] @ IKH.T + Kg @ R[k] @ Kg.T
                Ps[j] = 0.5 * (Pj + Pj.T)
                ll[j] = -0.5 * (nu @ np.linalg.solve(S, nu) + np.linalg.slogdet(2 * np.pi * S)[1])
                if is_ct[j]:
                    _ref_clip(xs[j], spec)
            else:
                xs[j], Ps[j] = xp[j].copy(), Pp[j].copy()
        a = log_c + ll
        log_mu = a - logsumexp(a)
        mu, c = np.exp(log_mu), np.exp(log_c - logsumexp(log_c))
        xc = sum(mu[j] * xs[j][:4] for j in range(M))
        Pc = sum(mu[j] * (Ps[j][:4, :4] + np.outer(xs[j][:4] - xc, xs[j][:4] - xc)) for j in range(M))
        xpc = sum(c[j] * xp[j][:4] for j in range(M))
        Ppc = sum(c[j] * (Pp[j][:4, :4] + np.outer(xp[j][:4] - xpc, xp[j][:4] - xpc)) for j in range(M))
        if det[k]:
            nu = z[k] - xpc[:2]
            nis = nu @ np.linalg.solve(Ppc[:2, :2] + R[k], nu)
        else:
            nis = 0.0
        out["x"].append(xc)
        out["P"].append(0.5 * (Pc + Pc.T))
        out["mu"].append(mu)
        out["omega"].append(sum(mu[j] * xs[j][4] for j in range(M) if is_ct[j]))
        out["nis"].append(nis)
        out["xm"].append(np.array(xs))
        out["Pm"].append(np.array(Ps))
        t_last = t[k]
    return {key: np.array(v) for key, v in out.items()}


def _two_site_radar():
    s1 = RadarSite(scan_period_s=5.0, range_noise_std_m=60.0, bearing_noise_std_rad=0.1 * DEG,
                   detection_probability=0.8, name="site1")
    s2 = s1.replace(position_m=(40e3, 25e3), scan_period_s=7.3, first_scan_s=2.1, detection_probability=0.85,
                    range_noise_std_m=120.0, name="site2")
    return Radar((s1, s2))


@pytest.fixture(scope="module")
def two_site_episodes():
    eps = draw_suite("random", 3, seed=TUNING_SEEDS.start + 500, radar=_two_site_radar())
    for e in eps:   # the test needs what it claims: two sites and missed looks
        assert len(set(e.site_index.tolist())) == 2 and not e.detected.all()
    return eps


@pytest.mark.parametrize("spec", [I.IMMCVCTSpec(), I.IMMCVCTSpec(q_high_g=3.0, p_stay_high=0.8, omega_max_deg_s=2.0)],
                         ids=["two_modes", "three_modes_tight_bound"])
def test_kernel_equals_independent_per_track_loop(two_site_episodes, spec):
    eps = two_site_episodes
    batch, k0, x4, P4 = I.common_start(eps)
    B = len(eps)
    x5 = np.c_[x4, np.zeros(B)]
    P5 = np.zeros((B, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (spec.sigma_omega0_deg_s * DEG) ** 2
    res = I.imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec,
                             keep_modes=True)
    run = I.run_imm_cv_ct(eps, spec)
    clipped = 0
    for b, e in enumerate(eps):
        ref = _reference_track(e.t_s, e.z_m, e.R_m2, e.detected, k0[b] + 1, e.n_looks, x5[b], P5[b], spec)
        ks = slice(k0[b] + 1, e.n_looks)
        np.testing.assert_allclose(res.x[b, ks], ref["x"], rtol=1e-9, atol=1e-9 * np.abs(ref["x"]).max())
        np.testing.assert_allclose(res.P[b, ks], ref["P"], rtol=1e-9, atol=1e-9 * np.abs(ref["P"]).max())
        np.testing.assert_allclose(res.mu[b, ks], ref["mu"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.omega_rad_s[b, ks], ref["omega"], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(res.nis[b, ks], ref["nis"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.x_modes[b, ks], ref["xm"], rtol=1e-9, atol=1e-9 * np.abs(ref["xm"]).max())
        np.testing.assert_allclose(res.P_modes[b, ks], ref["Pm"], rtol=1e-9, atol=1e-9 * np.abs(ref["Pm"]).max())
        assert np.all(np.isnan(res.x[b, : k0[b] + 1])) and np.all(np.isnan(res.x[b, e.n_looks:]))
        clipped += np.sum(np.isclose(np.abs(ref["xm"][:, 1, 4]), spec.omega_max_deg_s * DEG, rtol=1e-12))
        # the TrackRun: the same numbers, the start look recorded as every tracker records it
        np.testing.assert_array_equal(run.x[b, ks], res.x[b, ks])
        np.testing.assert_array_equal(run.x[b, k0[b]], x4[b])
        assert run.start_index[b] == k0[b] + 1
        np.testing.assert_array_equal(run.extra["maneuver_probability"][b, ks], 1.0 - res.mu[b, ks, 0])
        np.testing.assert_array_equal(run.declared[b, ks], res.mu[b, ks, 0] < 0.5)
    if spec.omega_max_deg_s < 5:   # the tight bound is active in this case, so the clipping is compared too
        assert clipped > 0


def test_series_and_closed_forms_agree_and_jacobian_matches_finite_differences():
    rng = np.random.default_rng(5)
    n = 400
    x = np.c_[rng.normal(0, 5e4, (n, 2)), rng.normal(0, 200, (n, 2)), np.zeros(n)]
    dts = rng.uniform(0.5, 12.0, n)
    w = rng.normal(0, 5 * DEG, n)
    # omega ~ 0 and both sides of the series threshold |omega dt| = 0.1
    w[:40] = 0.0
    w[40:80] = rng.normal(0, 1e-9, 40)
    w[80:120] = rng.normal(0, 1e-5, 40)
    w[120:160] = rng.choice([-1, 1], 40) * I.SERIES_THETA / dts[120:160] * (1 + rng.uniform(-1e-6, 1e-6, 40))
    x[:, 4] = w
    for i in range(n):
        dt = dts[i]
        f = I.ct_motion(x[i], dt)
        np.testing.assert_allclose(f, _ref_ct_mean(x[i], dt), rtol=1e-12, atol=1e-9)
        J = I.ct_jacobian(x[i], dt)
        np.testing.assert_allclose(J, _ref_ct_jacobian(x[i], dt), rtol=1e-9, atol=1e-9)
        # central differences, step scaled per component
        h = np.array([1.0, 1.0, 1e-2, 1e-2, 1e-5])
        Jfd = np.empty((5, 5))
        for c in range(5):
            e = np.zeros(5)
            e[c] = h[c]
            Jfd[:, c] = (I.ct_motion(x[i] + e, dt) - I.ct_motion(x[i] - e, dt)) / (2 * h[c])
        scale = np.abs(J).max(axis=1, keepdims=True) + 1.0
        np.testing.assert_allclose(J / scale, Jfd / scale, atol=1e-6)
    # positive omega is a clockwise (right) turn: heading north, a quarter circle ends heading east
    v, om = 100.0, 0.1
    np.testing.assert_allclose(I.ct_motion([0, 0, 0, v, om], np.pi / 2 / om), [v / om, v / om, v, 0, om], atol=1e-9)


def _ct_episode(noise_scale, rate_deg_s=3.0, seed=0, turn_deg=270.0, period_s=4.0):
    sc = (ScenarioBuilder(position_m=(0.0, 0.0), speed_kt=300, heading_deg=30.0)
          .straight(150).turn(turn_deg, rate_deg_s=rate_deg_s).straight(300).build("ct_test"))
    site = RadarSite(position_m=(60e3, -20e3), scan_period_s=period_s, range_noise_std_m=40.0 * noise_scale,
                     bearing_noise_std_rad=0.05 * DEG * noise_scale, name="ct")
    return draw_episode(sc, Radar((site,)), np.random.default_rng(seed))


def test_noise_free_constant_turn_converges_and_straight_leg_is_cv():
    # two full circles at 3 deg/s, plots every 2 s with 4e-5 m range noise (noise-free for the filter)
    ep = _ct_episode(1e-6, turn_deg=720.0, period_s=2.0)
    spec = I.DEFAULT_IMM_CV_CT
    run = I.run_imm_cv_ct([ep], spec)
    w_true = ep.truth_turn_rate_rad_s
    turning = np.flatnonzero(np.abs(w_true) > 0)
    w_est = run.extra["turn_rate_deg_s"][0]
    batch, k0, x4, P4 = I.common_start([ep])
    x5 = np.c_[x4, [0.0]]
    P5 = np.zeros((1, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (spec.sigma_omega0_deg_s * DEG) ** 2
    res = I.imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec)
    mu_ct = res.mu[0, :, 1]
    late_turn = turning[turning >= turning[0] + 30]
    assert np.all(mu_ct[late_turn] > 0.99), mu_ct[late_turn].min()
    assert np.all(run.declared[0, late_turn])
    # the error falls to a small fraction of the rate, and keeps falling
    err = np.abs(w_est - np.degrees(w_true))
    assert np.all(err[turning[-10:]] < 0.01 * 3.0), err[turning[-10:]]
    assert err[turning[-10:]].max() < err[turning[10:20]].max()
    # the straight leg after the turn, once the turn has left the filter: CV dominates, the turn rate is ~0
    after = np.flatnonzero(np.arange(ep.n_looks) > turning[-1] + 30)
    assert np.all(res.mu[0, after, 0] > 0.9), res.mu[0, after, 0].min()
    np.testing.assert_allclose(w_est[after], 0.0, atol=0.01)


def test_straight_flight_with_noise_is_cv():
    sc = ScenarioBuilder(position_m=(0.0, 0.0), speed_kt=400, heading_deg=100.0).straight(900).build("straight")
    site = RadarSite(position_m=(30e3, 60e3), scan_period_s=5.0, name="atc")
    eps = [draw_episode(sc, Radar((site,)), np.random.default_rng(s)) for s in range(10)]
    run = I.run_imm_cv_ct(eps)
    p = run.extra["maneuver_probability"]
    used = np.arange(p.shape[1])[None] >= run.start_index[:, None] + 10
    assert np.nanmean(p[used]) < 0.2
    assert np.mean(run.declared[used]) < 0.05


# ------------------------------------------------------------------------------------------------ CT-EKF alone
def _ct_only(spec, q_m_s2):
    return np.array([True]), np.array([q_m_s2]), np.zeros((1, 1)), np.zeros(1)


def test_ct_ekf_matches_stone_soup_ekf_on_identical_plots():
    from stonesoup.models.measurement.linear import LinearGaussian
    from stonesoup.models.transition.nonlinear import ConstantTurn
    from stonesoup.predictor.kalman import ExtendedKalmanPredictor
    from stonesoup.types.detection import Detection
    from stonesoup.types.hypothesis import SingleHypothesis
    from stonesoup.types.state import GaussianState
    from stonesoup.updater.kalman import ExtendedKalmanUpdater

    spec = I.IMMCVCTSpec(sigma_omega_deg_s15=0.3, omega_max_deg_s=180.0, turn_accel_max_g=100.0)
    q = 0.2 * G0_M_S2
    sig_w = spec.sigma_omega_deg_s15 * DEG
    # Stone Soup's state is [x, vx, y, vy, omega] with omega counter-clockwise positive; ours [x, y, vx, vy,
    # omega] clockwise: s = T o with the sign of omega flipped.
    T = np.zeros((5, 5))
    T[0, 0] = T[1, 2] = T[2, 1] = T[3, 3] = 1.0
    T[4, 4] = -1.0

    class OurNoiseConstantTurn(ConstantTurn):
        """Stone Soup's CT motion and its (numerical) Jacobian, with our process noise mapped to its order
        (its own covar is continuous white-noise acceleration, dt^3/3, ours piecewise constant, dt^4/4; the
        turn-rate part, turn_noise_coeff * dt, is the same model)."""

        def covar(self, time_interval, **kwargs):
            return T @ _q5(abs(time_interval.total_seconds()), q, sig_w) @ T.T

    class AnalyticJacobian(OurNoiseConstantTurn):
        def jacobian(self, state, **kwargs):
            x_ours = T.T @ np.asarray(state.state_vector, dtype=float).ravel()
            return T @ I.ct_jacobian(x_ours, kwargs["time_interval"].total_seconds()) @ T.T

    model = OurNoiseConstantTurn(linear_noise_coeffs=np.array([0.0, 0.0]), turn_noise_coeff=sig_w ** 2)
    predictor, updater = ExtendedKalmanPredictor(model), ExtendedKalmanUpdater(measurement_model=None)
    predictor_a = ExtendedKalmanPredictor(AnalyticJacobian(linear_noise_coeffs=np.array([0.0, 0.0]),
                                                           turn_noise_coeff=sig_w ** 2))
    ep = _ct_episode(1.0, rate_deg_s=2.0, seed=3)
    ep = dataclasses.replace(ep, detected=ep.detected & (np.arange(ep.n_looks) % 7 != 3))  # missed looks
    batch, k0, x4, P4 = I.common_start([ep])
    # the start's turn rate is not 0: at omega = 0 Stone Soup's transition evaluates (1 - cos(w dt)) / w at
    # w = eps and its finite-difference Jacobian steps w by 1e-8, where that cancellation loses ~10 % of the
    # d/dw column (our series form does not); from a nonzero start the two agree to the FD accuracy
    x5 = np.c_[x4, [1.0 * DEG]]
    P5 = np.zeros((1, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (2 * DEG) ** 2
    res = I.imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5, spec,
                             keep_modes=True, modes=_ct_only(spec, q))
    t0 = datetime.datetime(2026, 1, 1)
    when = lambda s: t0 + datetime.timedelta(seconds=float(s))  # noqa: E731
    state = GaussianState(T @ x5[0], T @ P5[0] @ T.T, timestamp=when(ep.t_s[k0[0]]))
    state_a = state
    n_cmp = 0
    for k in range(k0[0] + 1, ep.n_looks):
        pred = predictor.predict(state, timestamp=when(ep.t_s[k]))
        det = None
        if ep.detected[k]:
            mm = LinearGaussian(ndim_state=5, mapping=(0, 2), noise_covar=ep.R_m2[k])
            det = Detection(ep.z_m[k].reshape(2, 1), timestamp=when(ep.t_s[k]), measurement_model=mm)
            state = updater.update(SingleHypothesis(pred, det))
        else:
            state = pred
        ours_x = T @ res.x_modes[0, k, 0]
        ours_P = T @ res.P_modes[0, k, 0] @ T.T
        ss_x, ss_P = np.asarray(state.state_vector, dtype=float).ravel(), np.asarray(state.covar, dtype=float)
        # Stone Soup's Jacobian is a forward difference (steps of 1e-8 relative, >= 1e-8 absolute); on these
        # states its error reaches ~1e-5 of the entries (measured), so its EKF agrees with ours to about that
        np.testing.assert_allclose(ss_x, ours_x, rtol=1e-5, atol=1e-6 * np.abs(ours_x).max())
        np.testing.assert_allclose(ss_P, ours_P, rtol=1e-3, atol=1e-3 * np.abs(ours_P).max())
        # with its Jacobian replaced by our analytic one (mapped), Stone Soup's EKF and ours agree to rounding
        pred_a = predictor_a.predict(state_a, timestamp=when(ep.t_s[k]))
        state_a = updater.update(SingleHypothesis(pred_a, det)) if ep.detected[k] else pred_a
        np.testing.assert_allclose(np.asarray(state_a.state_vector, dtype=float).ravel(), ours_x, rtol=1e-9,
                                   atol=1e-9 * np.abs(ours_x).max())
        np.testing.assert_allclose(np.asarray(state_a.covar, dtype=float), ours_P, rtol=1e-8,
                                   atol=1e-9 * np.abs(ours_P).max())
        n_cmp += 1
    assert n_cmp > 100
    # and the turn was followed (the omega state is not inert): at the end of the turn both see ~ -2 deg/s (SS sign)
    w_true = ep.truth_turn_rate_rad_s
    last_turn = np.flatnonzero(w_true != 0)[-1]
    assert abs(np.degrees(res.x_modes[0, last_turn, 0, 4]) - 2.0) < 0.3


def test_ct_ekf_nees_and_nis_are_chi_square_consistent_on_ct_truth():
    rng = np.random.default_rng(11)
    N, K, dt = 100, 60, 5.0
    q, sig_w = 0.05 * G0_M_S2, 0.05 * DEG
    spec = I.IMMCVCTSpec(sigma_omega_deg_s15=0.05, omega_max_deg_s=180.0, turn_accel_max_g=100.0)
    R = np.diag([60.0 ** 2, 40.0 ** 2])
    Q = _q5(dt, q, sig_w)
    Lq, Lr = np.linalg.cholesky(Q + 1e-12 * np.eye(5)), np.linalg.cholesky(R)
    P0 = np.diag([100.0 ** 2, 100.0 ** 2, 10.0 ** 2, 10.0 ** 2, (1.0 * DEG) ** 2])
    truth = np.empty((N, K, 5))
    x_true0 = np.array([2e4, -3e4, 150.0, 180.0, 2.0 * DEG])
    x_init = x_true0 + rng.standard_normal((N, 5)) @ np.linalg.cholesky(P0).T
    truth[:, 0] = x_true0
    for n in range(N):
        for k in range(1, K):
            truth[n, k] = I.ct_motion(truth[n, k - 1], dt) + Lq @ rng.standard_normal(5)
    z = truth[..., :2] + rng.standard_normal((N, K, 2)) @ Lr.T
    t = np.tile(np.arange(K) * dt, (N, 1))
    res = I.imm_cv_ct_filter(t, z, np.broadcast_to(R, (N, K, 2, 2)), np.ones((N, K), bool), np.full(N, K),
                             np.ones(N, dtype=np.int64), x_init, np.broadcast_to(P0, (N, 5, 5)), spec,
                             keep_modes=True, modes=_ct_only(spec, q))
    e = truth[:, 1:] - res.x_modes[:, 1:, 0]
    nees = np.einsum("nki,nkij,nkj->nk", e, np.linalg.inv(res.P_modes[:, 1:, 0]), e).mean(axis=0)
    nis = res.nis[:, 1:].mean(axis=0)
    lo5, hi5 = stats.chi2.ppf([0.025, 0.975], 5 * N) / N
    lo2, hi2 = stats.chi2.ppf([0.025, 0.975], 2 * N) / N
    assert np.mean((nees > lo5) & (nees < hi5)) > 0.85, nees
    assert np.mean((nis > lo2) & (nis < hi2)) > 0.85, nis
    assert abs(nees.mean() / 5 - 1) < 0.1 and abs(nis.mean() / 2 - 1) < 0.1
    # the test has teeth: a filter that ignores the turn-rate noise is inconsistent on the same truth
    bad = I.imm_cv_ct_filter(t, z, np.broadcast_to(R, (N, K, 2, 2)), np.ones((N, K), bool), np.full(N, K),
                             np.ones(N, dtype=np.int64), x_init, np.broadcast_to(P0, (N, 5, 5)),
                             I.IMMCVCTSpec(sigma_omega_deg_s15=1e-3, omega_max_deg_s=180.0, turn_accel_max_g=100.0),
                             keep_modes=True, modes=_ct_only(spec, 0.1 * q))
    e = truth[:, 1:] - bad.x_modes[:, 1:, 0]
    nees_bad = np.einsum("nki,nkij,nkj->nk", e, np.linalg.inv(bad.P_modes[:, 1:, 0]), e).mean(axis=0)
    assert np.mean((nees_bad > lo5) & (nees_bad < hi5)) < 0.5


# ------------------------------------------------------------------------------------------------ the bound
def test_turn_rate_bound_holds():
    ep = _ct_episode(1.0, rate_deg_s=6.0, seed=2)
    free = I.IMMCVCTSpec(omega_max_deg_s=180.0, turn_accel_max_g=100.0)
    batch, k0, x4, P4 = I.common_start([ep])
    x5 = np.c_[x4, [0.0]]
    P5 = np.zeros((1, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (3 * DEG) ** 2
    args = (batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5)
    for spec in (I.IMMCVCTSpec(omega_max_deg_s=2.0), I.IMMCVCTSpec(turn_accel_max_g=0.5)):
        res = I.imm_cv_ct_filter(*args, spec, keep_modes=True)
        xm = res.x_modes[0, k0[0] + 1:, 1]
        speed = np.maximum(np.hypot(xm[:, 2], xm[:, 3]), 1.0)
        bound = np.minimum(spec.omega_max_deg_s * DEG, spec.turn_accel_max_g * G0_M_S2 / speed)
        assert np.all(np.abs(xm[:, 4]) <= bound * (1 + 1e-12))
        assert np.any(np.abs(xm[:, 4]) >= bound * (1 - 1e-12))   # it was active
        assert np.all(np.abs(res.omega_rad_s[0, k0[0] + 1:]) <= bound * (1 + 1e-12))
    # without the bound the same turn drives omega above both bounds: the check above can fail
    res = I.imm_cv_ct_filter(*args, free, keep_modes=True)
    assert np.nanmax(np.abs(res.x_modes[0, :, 1, 4])) > 5.0 * DEG


# ------------------------------------------------------------------------------------------------ the spec
def test_spec_validation_and_params():
    with pytest.raises(ValueError, match=r"IMMCVCTSpec.q_cv_g must be a finite number in \[1e-05, 1.0\], got -1"):
        I.IMMCVCTSpec(q_cv_g=-1)
    with pytest.raises(ValueError, match="IMMCVCTSpec.p_stay_ct"):
        I.IMMCVCTSpec(p_stay_ct=1.0)
    with pytest.raises(ValueError, match="IMMCVCTSpec.q_high_g"):
        I.IMMCVCTSpec(q_high_g="4")
    with pytest.raises(ValueError, match=r"unknown imm_cv_ct parameter name\(s\) \['q_g'\]"):
        I.imm_cv_ct_spec_from_params({"q_g": 1.0})
    s = I.imm_cv_ct_spec_from_params({"q_cv_g": 0.002, "q_high_g": 5.0})
    assert s.q_cv_g == 0.002 and s.n_modes == 3 and s.q_ct_g == I.DEFAULT_IMM_CV_CT.q_ct_g
    is_ct, q, log_Pi, log_mu0 = s.mode_arrays()
    np.testing.assert_allclose(np.exp(log_Pi).sum(axis=1), 1.0)
    np.testing.assert_allclose(np.exp(log_mu0).sum(), 1.0)
    assert list(is_ct) == [False, True, False]
    for name, _, lo, hi, _ in I.IMM_CV_CT_PARAMS:   # every bound a tuner may reach is accepted
        I.imm_cv_ct_spec_from_params({name: lo})
        I.imm_cv_ct_spec_from_params({name: hi})


def test_registered():
    from baselines.registry import TRACKER_NAMES, run_tracker

    assert "imm_cv_ct" in TRACKER_NAMES
    eps = draw_suite("bizup2002", 2, seed=1)
    run = run_tracker("imm_cv_ct", eps)
    np.testing.assert_array_equal(run.x, I.run_imm_cv_ct(eps, I.tuned_imm_cv_ct_spec()).x)


# ------------------------------------------------------------------------------------------------ per-look parameters
def _filter_args(eps, spec):
    batch, k0, x4, P4 = I.common_start(eps)
    B = len(eps)
    x5 = np.c_[x4, np.zeros(B)]
    P5 = np.zeros((B, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, (spec.sigma_omega0_deg_s * DEG) ** 2
    return batch, (batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5)


def _drawn_params(spec, shape, seed):
    """Per-look parameters scattered around the spec's constants (noises x/÷ e, stay probabilities -0.05..+0.005),
    inside their ranges."""
    rng = np.random.default_rng(seed)
    names = I.look_parameter_names(spec)
    p = np.broadcast_to(I.look_parameter_vector(spec), shape + (len(names),)).copy()
    for i, n in enumerate(names):
        lo, hi = next((lo, hi) for m, _, lo, hi, _ in I.IMM_CV_CT_PARAMS if m == n)
        p[..., i] = p[..., i] + rng.uniform(-0.05, 0.005, shape) if n.startswith("p_") else \
            p[..., i] * np.exp(rng.uniform(-1.0, 1.0, shape))
        p[..., i] = np.clip(p[..., i], lo, hi)
    return p


PER_LOOK_SUITES = {"random": 6, "random_radars": 4, "bizup2002": 2, "adsb_dev": 2}


@pytest.mark.parametrize("suite", list(PER_LOOK_SUITES) + ["two_sites_with_misses"])
def test_constant_per_look_parameters_equal_the_constant_kernel_bit_for_bit(suite, two_site_episodes):
    eps = two_site_episodes if suite == "two_sites_with_misses" else \
        draw_suite(suite, PER_LOOK_SUITES[suite], seed=TUNING_SEEDS.start + 77)
    for spec in (I.tuned_imm_cv_ct_spec(), I.IMMCVCTSpec(q_high_g=None)):
        batch, args = _filter_args(eps, spec)
        B, K = batch.t_s.shape
        ref = I.imm_cv_ct_filter(*args, spec, keep_modes=True)
        vec = I.look_parameter_vector(spec)
        for params in (np.broadcast_to(vec, (B, K, vec.size)), vec, np.broadcast_to(vec, (B, vec.size))):
            res = I.imm_cv_ct_filter(*args, spec, keep_modes=True, params=params)
            for f in IMM_FIELDS:
                np.testing.assert_array_equal(getattr(res, f), getattr(ref, f), err_msg=f)
        # the one-look-at-a-time stepper with the same constants: the same numbers
        st = I.IMMCVCTStepper(*args, spec)
        x, mu = np.full((B, K, 4), np.nan), np.full((B, K, spec.n_modes), np.nan)
        active = st.k < st.n_looks
        while active.any():
            rows = np.flatnonzero(active)
            o = st.step(None if rows.size % 2 else np.broadcast_to(vec, (rows.size, vec.size)), rows)
            x[rows, o.look_index], mu[rows, o.look_index] = o.x, o.mu
            active[rows] = ~o.done
        np.testing.assert_array_equal(x, ref.x)
        np.testing.assert_array_equal(mu, ref.mu)


IMM_FIELDS = ("x", "P", "mu", "omega_rad_s", "nis", "x_modes", "P_modes", "omega_std_rad_s")


@pytest.mark.parametrize("three_modes", [True, False], ids=["three_modes", "two_modes"])
def test_per_look_parameters_equal_the_independent_loop_and_the_stepper(two_site_episodes, three_modes):
    spec = I.tuned_imm_cv_ct_spec() if three_modes else I.IMMCVCTSpec(q_high_g=None)
    eps = two_site_episodes
    batch, args = _filter_args(eps, spec)
    B, K = batch.t_s.shape
    params = _drawn_params(spec, (B, K), seed=3)
    res = I.imm_cv_ct_filter(*args, spec, keep_modes=True, params=params)
    const = I.imm_cv_ct_filter(*args, spec)
    assert np.nanmax(np.abs(res.x - const.x)) > 10.0          # the parameters matter
    for b, e in enumerate(eps):
        k0 = args[5][b]
        ref = _reference_track(e.t_s, e.z_m, e.R_m2, e.detected, k0, e.n_looks, args[6][b], args[7][b], spec,
                               params[b])
        ks = slice(k0, e.n_looks)
        np.testing.assert_allclose(res.x[b, ks], ref["x"], rtol=1e-9, atol=1e-9 * np.abs(ref["x"]).max())
        np.testing.assert_allclose(res.P[b, ks], ref["P"], rtol=1e-9, atol=1e-9 * np.abs(ref["P"]).max())
        np.testing.assert_allclose(res.mu[b, ks], ref["mu"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(res.x_modes[b, ks], ref["xm"], rtol=1e-9, atol=1e-9 * np.abs(ref["xm"]).max())
        np.testing.assert_allclose(res.P_modes[b, ks], ref["Pm"], rtol=1e-9, atol=1e-9 * np.abs(ref["Pm"]).max())
        # the turn-rate spread: the mixture of the CT modes' (omega, var) and the CV modes' exact 0
        w, v, mu = ref["xm"][:, :, 4], ref["Pm"][:, :, 4, 4], ref["mu"]
        ct = np.asarray(spec.mode_arrays()[0])
        om = (mu * w * ct).sum(1)
        var = (mu * np.where(ct, v + (w - om[:, None]) ** 2, om[:, None] ** 2)).sum(1)
        np.testing.assert_allclose(res.omega_std_rad_s[b, ks], np.sqrt(var), rtol=1e-9, atol=1e-15)
    st = I.IMMCVCTStepper(*args, spec)
    out = {f: np.full_like(getattr(res, f), np.nan) for f in ("x", "P", "mu", "omega_rad_s", "omega_std_rad_s",
                                                             "nis")}
    active = st.k < st.n_looks
    while active.any():
        rows = np.flatnonzero(active)
        o = st.step(params[rows, st.k[rows]], rows)
        for f in out:
            out[f][rows, o.look_index] = getattr(o, f)
        active[rows] = ~o.done
    for f in out:
        np.testing.assert_array_equal(out[f], getattr(res, f), err_msg=f)
    with pytest.raises(ValueError, match="ended"):
        st.step(None, [0])


def test_per_look_parameters_are_checked(two_site_episodes):
    spec = I.tuned_imm_cv_ct_spec()
    batch, args = _filter_args(two_site_episodes, spec)
    B, K = batch.t_s.shape
    p = np.broadcast_to(I.look_parameter_vector(spec), (B, K, 7)).copy()
    for i, bad in ((0, 2.0), (3, 1.0), (6, np.nan), (2, -1.0)):
        q = p.copy()
        q[1, 5, i] = bad
        with pytest.raises(ValueError, match=rf"params\[\.\.\., {i}\] \({I.LOOK_PARAMS[i]}\) must be finite and in"):
            I.imm_cv_ct_filter(*args, spec, params=q)
    for shape in ((B, K, 5), (B + 1, K, 7), (B, K + 2, 7), (7, 1, 1, 1)):
        with pytest.raises(ValueError, match="params must be"):
            I.imm_cv_ct_filter(*args, spec, params=np.ones(shape))
    with pytest.raises(ValueError, match="modes or params"):
        I.imm_cv_ct_filter(*args, spec, params=p, modes=_ct_only(spec, 1.0))
    assert I.look_parameter_names(I.IMMCVCTSpec(q_high_g=None)) == I.LOOK_PARAMS[:5]


@pytest.mark.parametrize("three_modes", [True, False], ids=["three_modes", "two_modes"])
def test_split_look_equals_the_kernel_bit_for_bit(two_site_episodes, three_modes):
    """predict_modes then update_modes (the kernel's two halves, one track at a time; missed looks through
    update_modes(z=None)) give the filter's modes and combination bit for bit, from initial_modes."""
    from radar_env.filters.imm_cv_ct import initial_modes, predict_modes, update_modes

    spec = I.tuned_imm_cv_ct_spec() if three_modes else I.IMMCVCTSpec(q_high_g=None)
    eps = two_site_episodes
    batch, k0, x4, P4 = I.common_start(eps)
    _, args = _filter_args(eps, spec)
    ref = I.imm_cv_ct_filter(*args, spec, keep_modes=True)
    n_missed = 0
    for b, e in enumerate(eps):
        xm, Pm, log_mu = initial_modes(spec, x4[b], P4[b])
        for k in range(k0[b] + 1, e.n_looks):
            pred = predict_modes(spec, xm, Pm, log_mu, e.t_s[k] - e.t_s[k - 1])
            det = bool(e.detected[k])
            n_missed += not det
            up = update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, e.z_m[k] if det else None,
                              e.R_m2[k] if det else None)
            xm, Pm, log_mu = up.x_modes, up.P_modes, up.log_mu
            np.testing.assert_array_equal(up.x, ref.x[b, k])
            np.testing.assert_array_equal(up.P, ref.P[b, k])
            np.testing.assert_array_equal(up.mu, ref.mu[b, k])
            np.testing.assert_array_equal(up.x_modes, ref.x_modes[b, k])
            np.testing.assert_array_equal(up.P_modes, ref.P_modes[b, k])
            assert up.nis == ref.nis[b, k] and up.omega_rad_s == ref.omega_rad_s[b, k]
            # the combined prediction is the c-weighted moments of the predicted modes' 4-state marginals
            c = np.exp(pred.log_c - np.logaddexp.reduce(pred.log_c))
            mean = c @ pred.x_modes[:, :4]
            d = pred.x_modes[:, :4] - mean
            cov = np.einsum("m,mij->ij", c, pred.P_modes[:, :4, :4] + d[:, :, None] * d[:, None, :])
            np.testing.assert_allclose(pred.x, mean, rtol=1e-12)
            np.testing.assert_allclose(pred.P, cov, rtol=1e-9, atol=1e-9 * np.abs(cov).max())
    assert n_missed > 0      # the missed-look branch was exercised


def test_split_look_checks_its_inputs():
    from radar_env.filters.imm_cv_ct import initial_modes, predict_modes, update_modes

    spec = I.tuned_imm_cv_ct_spec()
    xm, Pm, log_mu = initial_modes(spec, np.array([0.0, 1e4, 100.0, 0.0]), np.eye(4) * 100.0)
    with pytest.raises(ValueError, match="dt_s must be a finite number >= 0"):
        predict_modes(spec, xm, Pm, log_mu, -1.0)
    with pytest.raises(ValueError, match="M = 2"):
        predict_modes(I.IMMCVCTSpec(q_high_g=None), xm, Pm, log_mu, 1.0)
    pred = predict_modes(spec, xm, Pm, log_mu, 0.0)          # dt = 0 works: mixing only
    assert np.isfinite(pred.x).all() and np.isfinite(pred.P).all()
    with pytest.raises(ValueError, match=r"z must be \(2,\) and R \(2, 2\)"):
        update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [1.0, 2.0], None)
    with pytest.raises(ValueError, match="finite"):
        update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [np.nan, 2.0], np.eye(2))
    with pytest.raises(ValueError, match="range_rate must be"):
        update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [1.0, 2.0], np.eye(2), range_rate=(1.0, 4.0))
    # no range rate (None, an inf or a zero variance): the position-only update, bit for bit
    ref = update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [1.0, 1e4], np.eye(2) * 100.0)
    for rr in ((-50.0, np.inf, 0.0, 0.0), (-50.0, 0.0, 0.0, 0.0)):
        up = update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [1.0, 1e4], np.eye(2) * 100.0, range_rate=rr)
        np.testing.assert_array_equal(up.x, ref.x)
    up = update_modes(spec, pred.x_modes, pred.P_modes, pred.log_c, [1.0, 1e4], np.eye(2) * 100.0,
                      range_rate=(-50.0, 1.0, 0.0, 0.0))
    assert abs(up.x[3] - ref.x[3]) > 1.0        # the range rate moves the velocity along the line of sight
