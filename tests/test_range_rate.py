"""The range-rate EKF update of the chain (radar_env.filters.kernels._rdot_update) against Stone Soup's
CartesianToBearingRangeRate model (its measurement function and Jacobian row, an independent implementation) and
FilterPy's EKF update on the same Jacobian; chi-square consistency of its NIS with the true noise; no update where
there is no measurement."""

import numpy as np
import pytest
from filterpy.kalman import ExtendedKalmanFilter
from scipy import stats
from stonesoup.models.measurement.nonlinear import CartesianToBearingRangeRate
from stonesoup.types.state import State

from radar_env.filters.kernels import MIN_RANGE_FOR_RDOT_M, _rdot_update


def _stonesoup_row(x, site):
    """Stone Soup's range rate and its Jacobian row in our state order [x, y, vx, vy] (3-D model, z = 0)."""
    m = CartesianToBearingRangeRate(ndim_state=6, mapping=(0, 2, 4), velocity_mapping=(1, 3, 5),
                                    noise_covar=np.diag([1e-6, 1.0, 1.0]),
                                    translation_offset=np.array([[site[0]], [site[1]], [0.0]]))
    s = State(np.array([[x[0]], [x[2]], [x[1]], [x[3]], [0.0], [0.0]]))
    J = m.jacobian(s)
    return float(m.function(s, noise=False)[2, 0]), np.array([J[2, 0], J[2, 2], J[2, 1], J[2, 3]])


@pytest.mark.parametrize("n", [4, 5])
def test_update_is_filterpys_ekf_update_with_stone_soups_measurement_row(n):
    rng = np.random.default_rng(n)
    for _ in range(20):
        site = rng.uniform(-50e3, 50e3, 2)
        x = np.r_[rng.uniform(-100e3, 100e3, 2), rng.uniform(-300, 300, 2), rng.uniform(-0.1, 0.1)][:n]
        A = rng.normal(size=(n, n))
        P = A @ A.T * rng.uniform(1, 1e4) + np.eye(n)
        h, ss_row = _stonesoup_row(x, site)
        d = x[:2] - site
        r = np.hypot(*d)
        u = d / r
        row = np.r_[(x[2:4] - h * u) / r, u]       # the closed form; Stone Soup's Jacobian is numerical
        assert h == pytest.approx(u @ x[2:4], rel=1e-12)
        fd = np.empty(4)     # Stone Soup's function differenced centrally (its own jacobian() is a cruder one)
        for j, step in enumerate((1.0, 1.0, 1e-3, 1e-3)):
            e = np.zeros(n)
            e[j] = step
            fd[j] = (_stonesoup_row(x + e, site)[0] - _stonesoup_row(x - e, site)[0]) / (2 * step)
        np.testing.assert_allclose(row, fd, rtol=1e-6, atol=1e-9)
        np.testing.assert_allclose(row, ss_row, rtol=0.05, atol=1e-5)
        var = rng.uniform(0.2, 10.0)
        z = h + rng.normal() * np.sqrt(var) * 3
        xo, Po = np.empty(n), np.empty((n, n))
        ll = _rdot_update(x, P, n, z, site[0], site[1], var, xo, Po)
        ekf = ExtendedKalmanFilter(dim_x=n, dim_z=1)
        ekf.x, ekf.P, ekf.R = x.copy(), P.copy(), np.array([[var]])
        H = np.zeros((1, n))
        H[0, :4] = row
        ekf.update(np.array([z]), HJacobian=lambda _x: H, Hx=lambda _x: np.array([h]))
        np.testing.assert_allclose(xo, ekf.x, rtol=1e-9, atol=1e-9 * np.abs(x).max())
        # FilterPy updates in Joseph form, we as P - P H^T H P / s: equal up to rounding of P-sized terms
        np.testing.assert_allclose(Po, ekf.P, rtol=1e-7, atol=1e-7 * np.abs(P).max())
        s = (H @ P @ H.T)[0, 0] + var
        assert ll == pytest.approx(-0.5 * ((z - h) ** 2 / s + np.log(2 * np.pi * s)), rel=1e-10)
        assert np.allclose(Po, Po.T) and np.all(np.linalg.eigvalsh(Po) > 0)


def test_nis_is_chi_square_with_the_true_noise():
    """States drawn from N(x, P), measured with the true noise: the NIS of the update is chi-square(1)."""
    rng = np.random.default_rng(0)
    x = np.array([40e3, 25e3, -150.0, 200.0])
    P = np.diag([50.0 ** 2, 50.0 ** 2, 3.0 ** 2, 3.0 ** 2])
    var = 1.0
    nis = []
    for _ in range(3000):
        xt = rng.multivariate_normal(x, P)
        h_true, _ = _stonesoup_row(xt, (0.0, 0.0))
        z = h_true + rng.normal() * np.sqrt(var)
        xo, Po = np.empty(4), np.empty((4, 4))
        ll = _rdot_update(x, P, 4, z, 0.0, 0.0, var, xo, Po)
        h, row = _stonesoup_row(x, (0.0, 0.0))
        s = row @ P @ row + var
        assert ll == pytest.approx(-0.5 * ((z - h) ** 2 / s + np.log(2 * np.pi * s)))
        nis.append((z - h) ** 2 / s)
    nis = np.array(nis)
    lo, hi = stats.chi2.ppf([0.025, 0.975], len(nis)) / len(nis)
    assert lo < nis.mean() < hi, nis.mean()


@pytest.mark.parametrize("var", [np.inf, np.nan, 0.0])
def test_no_measurement_no_update(var):
    x, P = np.array([1e4, 0.0, 100.0, 0.0]), np.eye(4) * 100.0
    xo, Po = np.empty(4), np.empty((4, 4))
    assert _rdot_update(x, P, 4, 50.0, 0.0, 0.0, var, xo, Po) == 0.0
    np.testing.assert_array_equal(xo, x)
    np.testing.assert_array_equal(Po, P)


def test_no_update_at_the_site():
    x, P = np.array([0.3 * MIN_RANGE_FOR_RDOT_M, 0.0, 100.0, 0.0]), np.eye(4) * 100.0
    xo, Po = np.empty(4), np.empty((4, 4))
    assert _rdot_update(x, P, 4, 50.0, 0.0, 0.0, 1.0, xo, Po) == 0.0
    np.testing.assert_array_equal(xo, x)
