"""rbpf: the particle filter over the random flights' regimes, against closed forms (the exact motion of a speed
change, FilterPy's Kalman filter when the prior allows no maneuver), the exact law of a segment's end, its
reproducibility (the same looks, the same numbers in any batch), its consistency and its robustness off the prior."""

import dataclasses

import numpy as np
import pytest
from filterpy.common import Q_discrete_white_noise
from filterpy.kalman import KalmanFilter

from agents.evaluation.metrics import nees_values, score_run
from agents.evaluation.suites import TUNING_SEEDS, draw_suite
from baselines.imm_cv_ct_runner import common_start
from baselines.rbpf import DEFAULT_RBPF, RBPF_RDOT, RBPF_REF, RBPFSpec, run_rbpf
from baselines.registry import run_tracker
from radar_env.filters import rbpf as K
from radar_env.common.units import G0_M_S2
from radar_env.sim.episode import stack_episodes
from radar_env.sim.scenario import RandomScenarioConfig, Segment, SegmentScenario

SMALL = dataclasses.replace(DEFAULT_RBPF, n_particles=256)


@pytest.fixture(scope="module")
def random_eps():
    return draw_suite("random", 6, seed=TUNING_SEEDS.start)


def test_spec_refuses_values_out_of_range_naming_the_field():
    with pytest.raises(ValueError, match="n_particles"):
        RBPFSpec(n_particles=0)
    with pytest.raises(ValueError, match="onset_boost"):
        RBPFSpec(onset_boost=0.5)
    with pytest.raises(ValueError, match="broad_min_s"):
        RBPFSpec(broad_min_s=10.0, broad_max_s=5.0)
    with pytest.raises(ValueError, match="prior"):
        RBPFSpec(prior={"speed_kt": (100, 200)})


def test_speed_change_motion_is_the_scenarios_exact_motion_and_its_jacobian_the_derivative():
    a = 0.4 * G0_M_S2
    sc = SegmentScenario(np.array([100.0, -50.0, 120.0, 160.0]), [Segment(40.0, accel_m_s2=a)])
    x = np.array([100.0, -50.0, 120.0, 160.0, a])
    out, J = np.empty(5), np.empty((5, 5))
    K._accel_predict(x, 12.5, out, J)
    np.testing.assert_allclose(out[:4], sc.states_at(np.array([12.5]))[0], rtol=1e-12, atol=1e-9)
    eps = 1e-6
    for c in range(5):
        dx = np.zeros(5)
        dx[c] = eps
        o1, o2 = np.empty(5), np.empty(5)
        K._accel_predict(x + dx, 12.5, o1, np.empty((5, 5)))
        K._accel_predict(x - dx, 12.5, o2, np.empty((5, 5)))
        np.testing.assert_allclose(J[:, c], (o1 - o2) / (2 * eps), rtol=1e-6, atol=1e-6)


def _end_law(boost, n=20000, h=5.0, seed=0):
    """The law of a U(30, 300) s segment's end stepped at h as the filter draws it: a population of n particles,
    each step each one's end drawn (with the onset proposal ``boost``) and weighted, the ended ones' weights kept
    with their end times, the others resampled to equal weights (as the filter resamples)."""
    rng = np.random.default_rng(seed)
    tau, mass = 0.0, 1.0
    ends, wts = [], []
    while mass > 1e-12 and tau < 300.0:
        s = np.empty(n)
        lw = np.empty(n)
        for i in range(n):
            s[i], lw[i] = K._end_within(tau, 30.0, 300.0, h, rng.uniform(), boost)
        w = np.exp(lw) * mass / n
        ended = s >= 0.0
        ends.append(tau + s[ended])
        wts.append(w[ended])
        mass = w[~ended].sum()
        tau += h
    return np.concatenate(ends), np.concatenate(wts)


@pytest.mark.parametrize("boost", [1.0, 4.0])
def test_a_segment_ends_by_its_exact_law_with_and_without_the_onset_proposal(boost):
    """Durations U(30, 300) stepped at h = 5 s: the end times follow the uniform law, with the onset proposal's
    importance weights too."""
    ends, wts = _end_law(boost)
    assert ends.min() >= 30.0 and ends.max() <= 300.0
    assert abs(wts.sum() - 1.0) < 0.02
    for q in (60.0, 120.0, 200.0, 280.0):     # the weighted CDF against the uniform's
        cdf = np.sum(wts * (ends <= q)) / wts.sum()
        assert abs(cdf - (q - 30.0) / 270.0) < 0.02, (q, cdf)
    first = np.mean(ends < 35.0) * ends.size / 20000    # share of the population ending in the first window
    assert abs(first - (1 - (1 - 5 / 270) ** boost)) < 0.005    # the proposal ends boost x as many there


def test_without_maneuvers_in_the_prior_it_is_filterpys_kalman_filter(random_eps):
    """A prior of one leg (n_legs 1, the flight's start known), no broad regime: every particle is the same CV
    Kalman filter with the floor q; the output equals FilterPy's on the same plots."""
    q_g = 0.05
    spec = RBPFSpec(n_particles=16, q_floor_g=q_g, broad_rate_per_s=0.0, flight_start_known=True,
                    prior=RandomScenarioConfig(n_legs=(1, 1)))
    eps = random_eps[:2]
    run = run_rbpf(eps, spec)
    batch, k0, x4, P4 = common_start(eps)
    for b in range(2):
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x, kf.P = x4[b][[0, 2, 1, 3]].copy(), P4[b][np.ix_([0, 2, 1, 3], [0, 2, 1, 3])].copy()
        kf.H = np.array([[1.0, 0, 0, 0], [0, 0, 1.0, 0]])
        for k in range(k0[b] + 1, batch.n_looks[b]):
            dt = batch.t_s[b, k] - batch.t_s[b, k - 1]
            kf.F = np.kron(np.eye(2), np.array([[1.0, dt], [0.0, 1.0]]))
            kf.Q = Q_discrete_white_noise(2, dt, (q_g * G0_M_S2) ** 2, block_size=2)
            kf.predict()
            if batch.detected[b, k]:
                kf.update(batch.z_m[b, k], R=batch.R_m2[b, k])
            np.testing.assert_allclose(run.x[b, k], kf.x[[0, 2, 1, 3]], rtol=1e-9, atol=1e-6)
            np.testing.assert_allclose(run.P[b, k], kf.P[np.ix_([0, 2, 1, 3], [0, 2, 1, 3])], rtol=1e-8, atol=1e-6)


def test_same_looks_same_numbers_in_any_batch(random_eps):
    a = run_rbpf(random_eps[:4], SMALL)
    b = run_rbpf([random_eps[2], random_eps[0]], SMALL)
    n0, n2 = random_eps[0].n_looks, random_eps[2].n_looks
    np.testing.assert_array_equal(a.x[0, :n0], b.x[1, :n0])
    np.testing.assert_array_equal(a.P[2, :n2], b.P[0, :n2])
    c = run_rbpf(random_eps[:4], SMALL)
    np.testing.assert_array_equal(a.x, c.x)


def _pooled(batch, run):
    s = score_run(batch, run)
    m = s.masks["used"]
    return float(np.sqrt(np.mean(s.pos_err_m[m] ** 2))), s


def test_beats_imm_cv_ct_on_its_own_prior_and_is_consistent():
    """Position only, knowing the flight's start or not, and with the radial velocity (which must gain more)."""
    eps = draw_suite("random", 24, seed=TUNING_SEEDS.start + 500)
    batch = stack_episodes(eps)
    imm, _ = _pooled(batch, run_tracker("imm_cv_ct", eps))
    out = {}
    for spec in (DEFAULT_RBPF, RBPF_REF, RBPF_RDOT):
        run = run_rbpf(eps, dataclasses.replace(spec, n_particles=1024))
        r, s = _pooled(batch, run)
        out[spec] = r
        assert r < (0.75 if spec.radial_velocity else 0.95) * imm, (spec, r, imm)
        assert not s.lost.any()
        d = batch.truth[..., :4] - run.x
        nees = nees_values(d[s.masks["used"]], run.P[s.masks["used"]])
        assert 0.6 < np.mean(nees) / 4.0 < 1.6, np.mean(nees) / 4.0
    assert out[RBPF_RDOT] < 0.85 * out[DEFAULT_RBPF]


def test_radial_velocity_needs_its_arrays():
    eps = draw_suite("random", 1, seed=TUNING_SEEDS.start)
    batch, k0, x4, P4 = common_start(eps)
    from radar_env.filters.rbpf import rbpf_filter
    with pytest.raises(ValueError, match="radial_velocity"):
        rbpf_filter(batch.t_s, batch.z_m, batch.R_m2, batch.detected, batch.n_looks, k0 + 1, x4, P4,
                    np.zeros(1, np.uint64), dataclasses.replace(RBPF_RDOT, n_particles=16))


@pytest.mark.parametrize("suite", ["kim_lee_accel", "adsb_dev"])
def test_off_its_prior_it_stays_finite_positive_definite_and_on_track(suite):
    eps = draw_suite(suite, 3, seed=TUNING_SEEDS.start)
    batch = stack_episodes(eps)
    run = run_rbpf(eps, SMALL)
    _, s = _pooled(batch, run)
    used = s.masks["used"]
    assert np.isfinite(run.x[used]).all() and np.isfinite(run.P[used]).all()
    assert np.all(np.linalg.eigvalsh(run.P[used]) > 0)
    assert not s.lost.any() and not s.failed.any()


def test_the_parameter_table_and_the_spec_agree():
    """RBPF_PARAMS (ranges and documentation) names every tuned field of RBPFSpec with its default."""
    spec = RBPFSpec()
    names = {f.name for f in dataclasses.fields(RBPFSpec)} - {"prior", "flight_start_known", "radial_velocity"}
    assert {p[0] for p in K.RBPF_PARAMS} == names
    for name, default, lo, hi, _ in K.RBPF_PARAMS:
        assert getattr(spec, name) == default and lo <= default <= hi, name
