"""Range rate in the trackers (issue 39): the chain with ``radial_velocity=True`` equals a FilterPy KF + EKF written
from the model here (an independent implementation: FilterPy's predict with its own white-noise Q, its linear
position update, its EKF update with the closed-form range-rate row), on episodes with two sites and missed looks;
the 2-mode IMM and the CV / CT IMM with one CV mode equal that chain (three implementations of the same update);
the option is off by default and changes nothing then; the registered range-rate trackers run and beat their
position-only selves on the same episodes."""

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import ExtendedKalmanFilter
from scipy.linalg import block_diag

from agents.evaluation.suites import draw_suite
from baselines.imm_cv_ct_runner import imm_cv_ct_filter
from baselines.registry import run_tracker
from baselines.tuning import pooled_rmse
from radar_env.filters.kalman import imm_filter
from radar_env.filters.tracking import TrackStart, Tracker
from radar_env.sim.episode import stack_episodes
from radar_env.common.units import G0_M_S2

Q_M_S2 = 0.7 * G0_M_S2


def _episodes(n=3, suite="seed002_two_radars"):
    return draw_suite(suite, n, seed=1_000_000)


def _started(eps, radial_velocity):
    tr = Tracker(len(eps), radial_velocity=radial_velocity)
    out = tr.load(np.arange(len(eps)), eps)
    return tr, out


def _filterpy_track(e, k0, x0, P0, q):
    """From the posterior ``x0, P0`` at look ``k0``: FilterPy's KF predict (Q of white acceleration, per axis) and
    position update, then its EKF update with the radial velocity, for every later look of episode ``e``."""
    f = ExtendedKalmanFilter(dim_x=4, dim_z=2)
    f.x, f.P = x0.copy(), P0.copy()
    xs = []
    for k in range(k0 + 1, e.n_looks):
        dt = e.t_s[k] - e.t_s[k - 1]
        f.F = np.eye(4)
        f.F[0, 2] = f.F[1, 3] = dt
        qa = Q_discrete_white_noise(dim=2, dt=dt, var=q * q)   # [pos, vel] of one axis
        f.Q = block_diag(qa, qa)[np.ix_([0, 2, 1, 3], [0, 2, 1, 3])]
        f.predict()
        if e.detected[k]:
            H = np.zeros((2, 4))
            H[0, 0] = H[1, 1] = 1.0
            f.update(e.z_m[k], HJacobian=lambda _x, H=H: H, Hx=lambda x, H=H: H @ x, R=e.R_m2[k])
            site = e.site_xy_m[k]

            def h(x, site=site):
                d = x[:2] - site
                return np.array([d @ x[2:] / np.hypot(*d)])

            def jac(x, site=site):
                d = x[:2] - site
                r = np.hypot(*d)
                u = d / r
                return np.r_[(x[2:] - (u @ x[2:]) * u) / r, u][None]

            f.update(np.array([e.radial_velocity_m_s[k]]), HJacobian=jac, Hx=h,
                     R=np.array([[e.radial_velocity_noise_std_m_s[k] ** 2]]))
        xs.append(f.x.copy())
    return np.array(xs)


def test_chain_with_range_rate_equals_filterpy_kf_and_ekf_on_two_sites_with_misses():
    eps = _episodes(2) + _episodes(2, "random_radars")
    assert any(len(np.unique(e.site_index)) == 2 for e in eps) and any((~e.detected).any() for e in eps)
    tr, out = _started(eps, True)
    k0, x0, P0 = out.look_index.copy(), tr.x.copy(), tr.P.copy()
    xs = [[] for _ in eps]
    active = tr.k < tr.n_looks
    while active.any():
        rows = np.flatnonzero(active)
        o = tr.step(np.full(rows.size, Q_M_S2), rows=rows)
        for i, r in enumerate(rows):
            xs[r].append(o.x[i].copy())
        active[rows] = ~o.done
    for b, e in enumerate(eps):
        ref = _filterpy_track(e, k0[b], x0[b], P0[b], Q_M_S2)
        np.testing.assert_allclose(np.array(xs[b]), ref, rtol=1e-7, atol=1e-6)


def _chain_run(eps, q, radial_velocity):
    """The chain at constant q from the common start: (x (B, K, 4), P, k0, start tracker)."""
    tr, out = _started(eps, radial_velocity)
    B, K = tr.B, int(tr.n_looks.max())
    x, P = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan)
    start = (out.look_index.copy(), tr.x.copy(), tr.P.copy(), tr.t_last.copy())
    active = tr.k < tr.n_looks
    while active.any():
        rows = np.flatnonzero(active)
        o = tr.step(np.full(rows.size, q), rows=rows)
        x[rows, o.look_index], P[rows, o.look_index] = o.x, o.P
        active[rows] = ~o.done
    return x, P, start


def _rr(batch):
    return dict(radial_velocity_m_s=batch.radial_velocity_m_s, site_xy_m=batch.site_xy_m,
                radial_velocity_std_m_s=batch.radial_velocity_noise_std_m_s)


@pytest.mark.parametrize("suite", ["seed002_two_radars", "random_radars"])
def test_one_mode_imms_with_range_rate_equal_the_chain(suite):
    """imm_filter (the 2-mode IMM's kernel) and imm_cv_ct_filter with a single CV mode, both with range rate, give the
    chain's estimates: the same update in three kernels."""
    eps = _episodes(4, suite)
    x, P, (k0, x4, P4, t0) = _chain_run(eps, Q_M_S2, True)
    batch = stack_episodes(eps)
    B, K = x.shape[:2]
    xi, Pi, _ = imm_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, t0,
                           np.zeros((B, 1)), x4[:, None], P4[:, None], np.zeros((1, 1)), [Q_M_S2], [0.0],
                           **_rr(batch))
    x5 = np.concatenate([x4, np.zeros((B, 1))], axis=1)
    P5 = np.zeros((B, 5, 5))
    P5[:, :4, :4], P5[:, 4, 4] = P4, 1e-4
    res = imm_cv_ct_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x5, P5,
                           modes=(np.array([False]), np.array([Q_M_S2]), np.zeros((1, 1)), np.zeros(1)),
                           **_rr(batch))
    m = np.isfinite(x[..., 0])
    assert m.sum() > 100
    for xo, Po in ((xi, Pi), (res.x, res.P)):
        np.testing.assert_allclose(xo[m], x[m], rtol=1e-9, atol=1e-6)
        np.testing.assert_allclose(Po[m], P[m], rtol=1e-7, atol=1e-7)
    # without range rate they differ from the chain with it (the test can fail)
    x_pos, _, _ = _chain_run(eps, Q_M_S2, False)
    assert np.max(np.abs(x_pos[m] - x[m])) > 1.0


def test_range_rate_is_off_by_default_and_the_position_chain_is_unchanged():
    eps = _episodes(2, "random")
    assert TrackStart().radial_velocity is False and Tracker(1).radial_velocity is False
    x0, _, _ = _chain_run(eps, Q_M_S2, False)
    tr = TrackStart().tracker(2)
    out = tr.load(np.arange(2), eps)
    o = tr.step(np.full(2, Q_M_S2))
    np.testing.assert_array_equal(o.x, x0[np.arange(2), out.look_index + 1])


def test_track_start_refuses_a_non_boolean_radial_velocity():
    with pytest.raises(ValueError, match="radial_velocity must be True or False"):
        TrackStart(radial_velocity=1.0).checked()


@pytest.mark.parametrize("name", ["kf_tuned", "imm2", "imm_cv_ct"])
def test_range_rate_trackers_run_and_beat_their_position_only_selves(name):
    eps = _episodes(30, "random")
    batch = stack_episodes(eps)
    pos, rdot = run_tracker(name, eps), run_tracker(name + "_rdot", eps)
    assert rdot.name == name + "_rdot"
    a, b = pooled_rmse(batch, pos), pooled_rmse(batch, rdot)
    assert np.isfinite(b) and b < 0.95 * a, (a, b)


def test_a_range_rate_tracker_does_not_unmake_a_position_only_bound():
    """The bounds filter the position plots only: a range-rate tracker (classical, or learned by its env config)
    below a bound leaves it a bound; a position-only tracker below it does not."""
    from agents.evaluation.evaluate import bounds_beaten
    trackers = {"imm_cv_ct_rdot": {"pos_rmse_m": 20.0}, "policy_x": {"pos_rmse_m": 21.0},
                "imm_cv_ct": {"pos_rmse_m": 40.0}, "clairvoyant": {"pos_rmse_m": 30.0}}
    assert bounds_beaten(trackers, {"imm_cv_ct_rdot", "policy_x"}) == {}
    assert bounds_beaten(trackers, {"imm_cv_ct_rdot"})["clairvoyant"]["beaten_by"] == "policy_x"
    assert bounds_beaten(trackers)["clairvoyant"]["beaten_by"] == "policy_x"     # the registry's classical set
