"""baselines.stonesoup_components: Stone Soup's predictor/updater interface around imm_cv_ct equals our own runner
(the oracle) on every look of our episodes, with the plots given as Stone Soup polar detections; the angle and
state-order conventions; Stone Soup's hypothesiser and associator accept the states; errors name the parameter."""

import datetime
import math
import re
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from scipy.stats import chi2

pytest.importorskip("stonesoup")

from stonesoup.dataassociator.neighbour import GNNWith2DAssignment  # noqa: E402
from stonesoup.hypothesiser.distance import DistanceHypothesiser  # noqa: E402
from stonesoup.measures import Mahalanobis  # noqa: E402
from stonesoup.models.measurement.linear import LinearGaussian  # noqa: E402
from stonesoup.models.measurement.nonlinear import (  # noqa: E402
    CartesianToBearingRange, CartesianToBearingRangeRate, CartesianToBearingRangeRate2D)
from stonesoup.types.array import CovarianceMatrix, StateVector  # noqa: E402
from stonesoup.types.detection import Clutter, Detection, MissedDetection  # noqa: E402
from stonesoup.types.hypothesis import SingleHypothesis  # noqa: E402
from stonesoup.types.state import GaussianState  # noqa: E402
from stonesoup.types.track import Track  # noqa: E402

from agents.evaluation.suites import draw_suite  # noqa: E402
from baselines import stonesoup_components as S  # noqa: E402
from baselines.imm_cv_ct_runner import IMMCVCTSpec, common_start, run_imm_cv_ct, tuned_imm_cv_ct_spec  # noqa: E402
from baselines.trackers import _with_range_rate  # noqa: E402
from radar_env.filters.imm_cv_ct import predict_modes  # noqa: E402
from radar_env.sim.radar import Radar, RadarSite, polar_from_cartesian  # noqa: E402
from radar_env.common.units import DEG  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
REL = 1e-6


def _two_site_radar():
    """Two sites away from the origin (the translation offset matters), different periods, missed looks."""
    s1 = RadarSite(position_m=(-20e3, 5e3), scan_period_s=5.0, range_noise_std_m=60.0,
                   bearing_noise_std_rad=0.1 * DEG, detection_probability=0.8, name="site1")
    s2 = s1.replace(position_m=(40e3, 25e3), scan_period_s=7.3, first_scan_s=2.1, detection_probability=0.85,
                    range_noise_std_m=120.0, name="site2")
    return Radar((s1, s2))


def _episodes(which):
    if which == "two_sites_with_misses":
        eps = draw_suite("random", 3, seed=1_000_000, radar=_two_site_radar())
        assert all(not e.detected.all() and len(set(e.site_index.tolist())) == 2 for e in eps)
        return eps
    return draw_suite(which, 3, seed=1_000_000)


def _run_stonesoup(e, spec, x4, P4, k0, missed="predict", radial_velocity=False):
    """The Stone Soup chain on one episode from the common start; missed looks: keep the prediction (what Stone
    Soup's trackers do) or update with a MissedDetection. Returns per-look (x, P, maneuver probability, states)."""
    predictor, updater = S.IMMCVCTPredictor(spec=spec), S.IMMCVCTUpdater()
    dets = S.detections_from_episode(e, radial_velocity=radial_velocity)
    state = S.gaussian_state(x4, P4, e.t_s[k0])
    out = []
    for k in range(k0 + 1, e.n_looks):
        when = S.stamp(e.t_s[k])
        prediction = predictor.predict(state, timestamp=when)
        if dets[k] is not None:
            state = updater.update(SingleHypothesis(prediction, dets[k]))
        elif missed == "predict":
            state = prediction
        else:
            state = updater.update(SingleHypothesis(prediction, MissedDetection(timestamp=when)))
        x, P = S.ours_from_state(state)
        out.append((k, x, P, state.maneuver_probability, state))
    return out


@pytest.mark.parametrize("radial_velocity", [False, True], ids=["imm_cv_ct", "imm_cv_ct_rdot"])
@pytest.mark.parametrize("which", ["bizup2002", "random", "two_sites_with_misses"])
def test_stonesoup_chain_equals_run_imm_cv_ct_on_every_look(which, radial_velocity):
    """Polar detections (with range rate: CartesianToBearingRangeRate2D and the range-rate IMM's tuned spec) through
    the predictor and updater give run_imm_cv_ct(..., radial_velocity) on every look."""
    eps = _episodes(which)
    spec = tuned_imm_cv_ct_spec("imm_cv_ct_rdot" if radial_velocity else "imm_cv_ct")
    start = common_start(eps, _with_range_rate(None, radial_velocity))
    run = run_imm_cv_ct(eps, spec, start=start, radial_velocity=radial_velocity)
    _, k0, x4, P4 = start
    n_checked = n_missed = 0
    for b, e in enumerate(eps):
        for k, x, P, p_man, state in _run_stonesoup(e, spec, x4[b], P4[b], k0[b], radial_velocity=radial_velocity):
            ref_x, ref_P = run.x[b, k], run.P[b, k]
            # relative to each block's scale: position, velocity (a near-zero velocity component is not its scale)
            for sl in (slice(0, 2), slice(2, 4)):
                np.testing.assert_allclose(x[sl], ref_x[sl], rtol=0, atol=REL * np.abs(ref_x[sl]).max(),
                                           err_msg=f"{which} row {b} look {k}")
            np.testing.assert_allclose(P, ref_P, rtol=0, atol=REL * np.abs(ref_P).max(),
                                       err_msg=f"{which} row {b} look {k}")
            np.testing.assert_allclose(p_man, run.extra["maneuver_probability"][b, k], rtol=REL, atol=1e-12)
            np.testing.assert_allclose(np.degrees(state.turn_rate_rad_s), run.extra["turn_rate_deg_s"][b, k],
                                       rtol=REL, atol=1e-9)
            n_checked += 1
            n_missed += not e.detected[k]
    assert n_checked == sum(e.n_looks - k - 1 for e, k in zip(eps, k0))
    if which == "two_sites_with_misses":
        assert n_missed > 0
    # the test can fail: another spec, or the other measurement (with / without range rate), gives other estimates
    other = _run_stonesoup(eps[0], IMMCVCTSpec(q_high_g=None), x4[0], P4[0], k0[0], radial_velocity=radial_velocity)
    assert max(np.abs(x - run.x[0, k]).max() for k, x, *_ in other) > 1.0
    other = _run_stonesoup(eps[0], spec, x4[0], P4[0], k0[0], radial_velocity=not radial_velocity)
    assert max(np.abs(x - run.x[0, k]).max() for k, x, *_ in other) > 1.0


@pytest.mark.parametrize("radial_velocity", [False, True], ids=["imm_ct_bank", "imm_ct_bank_rdot"])
def test_stonesoup_chain_runs_the_bank_of_ct_modes(radial_velocity):
    """The same components with imm_ct_bank's spec (six CT modes entered at their rates; with range rate
    imm_ct_bank_rdot's on range-rate detections) give run_imm_cv_ct with it on every look (the kernel's two halves
    take the spec's entry rates)."""
    eps = _episodes("two_sites_with_misses")
    spec = tuned_imm_cv_ct_spec("imm_ct_bank_rdot" if radial_velocity else "imm_ct_bank")
    assert spec.is_bank
    start = common_start(eps, _with_range_rate(None, radial_velocity))
    run = run_imm_cv_ct(eps, spec, start=start, radial_velocity=radial_velocity)
    _, k0, x4, P4 = start
    n_checked = 0
    for b, e in enumerate(eps):
        for k, x, P, p_man, state in _run_stonesoup(e, spec, x4[b], P4[b], k0[b], radial_velocity=radial_velocity):
            np.testing.assert_allclose(x, run.x[b, k], rtol=0, atol=REL * np.abs(run.x[b, k]).max())
            np.testing.assert_allclose(P, run.P[b, k], rtol=0, atol=REL * np.abs(run.P[b, k]).max())
            np.testing.assert_allclose(p_man, run.extra["maneuver_probability"][b, k], rtol=REL, atol=1e-12)
            n_checked += 1
    assert n_checked == sum(e.n_looks - k - 1 for e, k in zip(eps, k0))
    other = run_imm_cv_ct(eps, tuned_imm_cv_ct_spec(), start=start,      # the test can fail: one CT mode differs
                          radial_velocity=radial_velocity)
    assert np.nanmax(np.abs(other.x - run.x)) > 1.0


def test_range_rate_detections_position_only():
    """IMMCVCTUpdater(use_range_rate=False) on range-rate detections is the position-only imm_cv_ct."""
    eps = _episodes("bizup2002")[:1]
    spec = tuned_imm_cv_ct_spec()
    start = common_start(eps)
    run = run_imm_cv_ct(eps, spec, start=start)
    _, k0, x4, P4 = start
    e = eps[0]
    predictor, updater = S.IMMCVCTPredictor(spec=spec), S.IMMCVCTUpdater(use_range_rate=False)
    dets = S.detections_from_episode(e, radial_velocity=True)
    state = S.gaussian_state(x4[0], P4[0], e.t_s[k0[0]])
    for k in range(k0[0] + 1, e.n_looks):
        pred = predictor.predict(state, timestamp=S.stamp(e.t_s[k]))
        state = updater.update(SingleHypothesis(pred, dets[k])) if dets[k] is not None else pred
        x, P = S.ours_from_state(state)
        np.testing.assert_allclose(x, run.x[0, k], rtol=0, atol=REL * np.abs(run.x[0, k]).max())


def test_missed_detection_update_is_the_kernels_missed_look():
    """Cartesian plots (LinearGaussian, our z and R) and MissedDetection updates: the runner's numbers to rounding
    (no polar conversion in between), so the missed-look branch is the kernel's."""
    eps = _episodes("two_sites_with_misses")
    spec = tuned_imm_cv_ct_spec()
    start = common_start(eps)
    run = run_imm_cv_ct(eps, spec, start=start)
    _, k0, x4, P4 = start
    e = eps[0]
    predictor, updater = S.IMMCVCTPredictor(spec=spec), S.IMMCVCTUpdater()
    state = S.gaussian_state(x4[0], P4[0], e.t_s[k0[0]])
    for k in range(k0[0] + 1, e.n_looks):
        when = S.stamp(e.t_s[k])
        pred = predictor.predict(state, timestamp=when)
        if e.detected[k]:
            det = Detection(StateVector(e.z_m[k]), timestamp=when,
                            measurement_model=LinearGaussian(4, (0, 2), CovarianceMatrix(e.R_m2[k])))
        else:
            det = MissedDetection(timestamp=when)
        state = updater.update(SingleHypothesis(pred, det))
        x, P = S.ours_from_state(state)
        np.testing.assert_allclose(x, run.x[0, k], rtol=1e-12, atol=1e-9)
        np.testing.assert_allclose(P, run.P[0, k], rtol=1e-10, atol=1e-10 * np.abs(run.P[0, k]).max())


def test_bearing_convention_and_plot_conversion():
    """Stone Soup's bearing is pi/2 - ours; the detection converts to our episode's z_m and R_m2."""
    e = _episodes("two_sites_with_misses")[1]
    dets = S.detections_from_episode(e)
    for k in np.flatnonzero(e.detected)[:40]:
        det = dets[k]
        z, R = S.plot_from_detection(det)
        np.testing.assert_allclose(z, e.z_m[k], rtol=1e-12)
        np.testing.assert_allclose(R, e.R_m2[k], rtol=1e-9)
        # Stone Soup's own model on the truth: its bearing is pi/2 - ours, its range ours
        r, b, _ = polar_from_cartesian(e.truth[k], e.site_xy_m[k])
        truth = GaussianState(StateVector(e.truth[k][S.SS_FROM_OURS]), CovarianceMatrix(np.eye(4)))
        y = np.asarray(det.measurement_model.function(truth), dtype=np.float64).ravel()
        assert abs(math.remainder(y[0] - (0.5 * math.pi - b), 2 * math.pi)) < 1e-12
        assert abs(y[1] - r) < 1e-9 * r


def test_range_rate_convention_and_detection():
    """Stone Soup's range rate (CartesianToBearingRangeRate2D on [x, vx, y, vy]) is ours: positive receding, the same
    value on the truth; the detection carries our plot, its radial velocity, the variance and the site."""
    e = _episodes("two_sites_with_misses")[2]
    dets = S.detections_from_episode(e, radial_velocity=True)
    for k in np.flatnonzero(e.detected)[:40]:
        det = dets[k]
        assert isinstance(det.measurement_model, CartesianToBearingRangeRate2D)
        z, R = S.plot_from_detection(det)
        np.testing.assert_allclose(z, e.z_m[k], rtol=1e-12)
        np.testing.assert_allclose(R, e.R_m2[k], rtol=1e-9)
        rd, var, sx, sy = S.range_rate_from_detection(det)
        assert rd == e.radial_velocity_m_s[k] and (sx, sy) == tuple(e.site_xy_m[k])
        assert var == pytest.approx(e.radial_velocity_noise_std_m_s[k] ** 2, rel=1e-15)
        _, _, rdot_true = polar_from_cartesian(e.truth[k], e.site_xy_m[k])
        truth = GaussianState(StateVector(e.truth[k][S.SS_FROM_OURS]), CovarianceMatrix(np.eye(4)))
        y = np.asarray(det.measurement_model.function(truth), dtype=np.float64).ravel()
        assert y[2] == pytest.approx(rdot_true, rel=1e-9, abs=1e-9)
    # the sign: a target north of the site flying north recedes, positive in both
    model = S.polar_detection(2e4, 0.0, (5e3, -3e3), 50.0, 1e-3, 0.0, radial_velocity_m_s=0.0,
                              radial_velocity_noise_std_m_s=1.0).measurement_model
    away = GaussianState(StateVector([5e3, 0.0, 17e3, 200.0]), CovarianceMatrix(np.eye(4)))
    assert float(model.function(away)[2]) == pytest.approx(200.0, rel=1e-12)
    assert polar_from_cartesian(np.array([[5e3, 17e3, 0.0, 200.0]]), np.array([5e3, -3e3]))[2][0] == \
        pytest.approx(200.0, rel=1e-12)
    assert S.range_rate_from_detection(S.detections_from_episode(e)[int(np.flatnonzero(e.detected)[0])]) is None


def test_hypothesiser_gates_range_rate_detections():
    """With range rate the hypothesiser's distance is the 3-D Mahalanobis distance of the extended-Kalman prediction
    [bearing, range, range rate]; a clutter plot at the true position but 10 sigma off in range rate is gated out."""
    eps = _episodes("bizup2002")
    spec = tuned_imm_cv_ct_spec("imm_cv_ct_rdot")
    _, k0, x4, P4 = common_start(eps, _with_range_rate(None, True))
    e = eps[1]
    predictor, updater = S.IMMCVCTPredictor(spec=spec), S.IMMCVCTUpdater()
    dets = S.detections_from_episode(e, radial_velocity=True)
    track = Track([S.gaussian_state(x4[1], P4[1], e.t_s[k0[1]])])
    hypothesiser = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=math.sqrt(chi2.ppf(1 - 1e-6,
                                                                                                              3)))
    for k in range(k0[1] + 1, k0[1] + 20):
        when, true_det = S.stamp(e.t_s[k]), dets[k]
        if true_det is None:
            continue
        mp = updater.predict_measurement(predictor.predict(track, timestamp=when), true_det.measurement_model)
        y = np.asarray(true_det.state_vector, dtype=np.float64).ravel()
        clutter = Clutter(StateVector([true_det.state_vector[0], y[1], y[2] + 10 * math.sqrt(mp.covar[2, 2])]),
                          timestamp=when, measurement_model=true_det.measurement_model)
        hyps = hypothesiser.hypothesise(track, {true_det, clutter}, when)
        by_det = {h.measurement: h for h in hyps if h}
        assert true_det in by_det and clutter not in by_det
        nu = np.asarray(true_det.state_vector - mp.state_vector, dtype=np.float64).ravel()
        nu[0] = math.remainder(nu[0], 2 * math.pi)
        d = math.sqrt(nu @ np.linalg.solve(np.asarray(mp.covar, dtype=np.float64), nu))
        assert by_det[true_det].distance == pytest.approx(d, rel=1e-9)
        track.append(updater.update(by_det[true_det]))
    assert len(track) > 10 and isinstance(track.state, S.IMMCVCTStateUpdate)


def test_hypothesiser_and_associator_accept_the_prediction():
    eps = _episodes("bizup2002")
    spec = tuned_imm_cv_ct_spec()
    _, k0, x4, P4 = common_start(eps)
    e = eps[0]
    predictor, updater = S.IMMCVCTPredictor(spec=spec), S.IMMCVCTUpdater()
    dets = S.detections_from_episode(e)
    track = Track([S.gaussian_state(x4[0], P4[0], e.t_s[k0[0]])])
    gate = math.sqrt(chi2.ppf(1 - 1e-6, 2))      # a true plot falls outside once in a million looks
    hypothesiser = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=gate)
    associator = GNNWith2DAssignment(hypothesiser)
    for k in range(k0[0] + 1, k0[0] + 30):
        when = S.stamp(e.t_s[k])
        true_det = dets[k]
        # clutter at the same bearing, 10 predicted range-innovation standard deviations beyond the true plot
        s_rr = updater.predict_measurement(predictor.predict(track, timestamp=when),
                                           true_det.measurement_model).covar[1, 1]
        y = np.asarray(true_det.state_vector, dtype=np.float64).ravel()
        clutter = Clutter(StateVector([true_det.state_vector[0], y[1] + 10 * math.sqrt(s_rr)]), timestamp=when,
                          measurement_model=true_det.measurement_model)
        hyps = hypothesiser.hypothesise(track, {true_det, clutter}, when)
        pred = hyps[0].prediction
        assert isinstance(pred, S.IMMCVCTStatePrediction)
        by_det = {h.measurement: h for h in hyps if h}
        assert true_det in by_det and clutter not in by_det, [h.distance for h in hyps]   # clutter: out of the gate
        # the distance is the Mahalanobis distance of the extended-Kalman measurement prediction (polar)
        mp = updater.predict_measurement(pred, true_det.measurement_model)
        nu = np.asarray(true_det.state_vector - mp.state_vector, dtype=np.float64).ravel()
        d = math.sqrt(nu @ np.linalg.solve(np.asarray(mp.covar, dtype=np.float64), nu))
        assert by_det[true_det].distance == pytest.approx(d, rel=1e-9)
        assoc = associator.associate({track}, {true_det, clutter}, when)
        assert assoc[track].measurement is true_det
        track.append(updater.update(assoc[track]))
        # the hypothesiser passes the track: the prediction continues the track's modes (not a restart)
        np.testing.assert_array_equal(pred.mode_state_vectors,
                                      predictor.predict(track[-2], timestamp=when).mode_state_vectors)
        if k > k0[0] + 1:
            assert isinstance(track[-2], S.IMMCVCTStateUpdate)
        # the combined covariance: symmetric, positive definite
        for st in (pred, track.state):
            C = np.asarray(st.covar, dtype=np.float64)
            np.testing.assert_array_equal(C, C.T)
            assert np.linalg.eigvalsh(C).min() > 0
            assert np.isclose(st.mode_probabilities.sum(), 1.0, rtol=1e-12)
            assert all(np.linalg.eigvalsh(Pm).min() > 0 for Pm in np.asarray(st.mode_covars))
    assert isinstance(track.state, S.IMMCVCTStateUpdate) and len(track) == 30


def test_time_handling():
    spec = tuned_imm_cv_ct_spec()
    predictor = S.IMMCVCTPredictor(spec=spec)
    start = S.gaussian_state([1e4, 2e4, 150.0, -80.0], np.diag([1e4, 1e4, 100.0, 100.0]), 12.5)
    prior = S.IMMCVCTState.from_gaussian(start, spec)
    # dt = 0: the kernel's look with dt 0 (mixing only)
    p0 = predictor.predict(prior, timestamp=prior.timestamp)
    ref = predict_modes(spec, np.asarray(prior.mode_state_vectors)[:, [0, 2, 1, 3, 4]],
                        np.asarray(prior.mode_covars)[:, [0, 2, 1, 3, 4]][:, :, [0, 2, 1, 3, 4]],
                        prior.log_mode_probabilities, 0.0)
    np.testing.assert_array_equal(S.ours_from_state(p0)[0], ref.x)
    assert p0.timestamp == prior.timestamp
    # dt from the timestamps
    p = predictor.predict(prior, timestamp=prior.timestamp + datetime.timedelta(seconds=4.5))
    np.testing.assert_allclose(S.ours_from_state(p)[0][:2], [1e4 + 4.5 * 150.0, 2e4 - 4.5 * 80.0], rtol=1e-12)
    with pytest.raises(ValueError, match="before prior.timestamp"):
        predictor.predict(prior, timestamp=prior.timestamp - datetime.timedelta(seconds=1))
    with pytest.raises(ValueError, match="both be datetimes, or both None"):
        predictor.predict(prior, timestamp=None)


def test_errors_name_the_parameter():
    spec = tuned_imm_cv_ct_spec()
    updater = S.IMMCVCTUpdater()
    prior = S.gaussian_state([1e4, 2e4, 150.0, -80.0], np.diag([1e4, 1e4, 100.0, 100.0]), 0.0)
    pred = S.IMMCVCTPredictor(spec=spec).predict(prior, timestamp=S.stamp(5.0))
    polar = dict(ndim_state=4, noise_covar=np.diag([1e-6, 100.0]))
    y = StateVector([0.3, 2e4])
    cases = [
        (CartesianToBearingRange(mapping=(0, 1), **polar), "mapping must be"),
        (CartesianToBearingRange(mapping=(0, 2), rotation_offset=StateVector([0, 0, 0.1]), **polar),
         "rotation_offset must be zero"),
        (CartesianToBearingRange(ndim_state=4, mapping=(0, 2), noise_covar=np.array([[1e-6, 1e-4], [1e-4, 100.0]])),
         "noise_covar must be diagonal"),
    ]
    for model, msg in cases:
        with pytest.raises(ValueError, match=msg):
            updater.update(SingleHypothesis(pred, Detection(y, timestamp=S.stamp(5.0), measurement_model=model)))
    rr = dict(ndim_state=4, mapping=(0, 2), noise_covar=np.diag([1e-6, 100.0, 1.0]))
    y3 = StateVector([0.3, 2e4, -150.0])
    cases = [
        (CartesianToBearingRangeRate(ndim_state=4, mapping=(0, 2), noise_covar=np.diag([1e-6, 100.0, 1.0])),
         "use CartesianToBearingRangeRate2D"),
        (CartesianToBearingRangeRate2D(velocity_mapping=(2, 3), **rr), r"velocity_mapping must be \(1, 3\)"),
        (CartesianToBearingRangeRate2D(velocity=StateVector([10.0, 0.0]), **rr), "velocity must be zero"),
        (CartesianToBearingRangeRate2D(ndim_state=4, mapping=(0, 2), noise_covar=np.array(
            [[1e-6, 0, 0], [0, 100.0, 0.5], [0, 0.5, 1.0]])), "noise_covar must be diagonal"),
    ]
    for model, msg in cases:
        with pytest.raises(ValueError, match=msg):
            updater.update(SingleHypothesis(pred, Detection(y3, timestamp=S.stamp(5.0), measurement_model=model)))
    with pytest.raises(ValueError, match="3 finite numbers"):
        updater.update(SingleHypothesis(pred, Detection(y, timestamp=S.stamp(5.0),
                                                        measurement_model=CartesianToBearingRangeRate2D(**rr))))
    with pytest.raises(ValueError, match="radial_velocity_noise_std_m_s must be given"):
        S.polar_detection(2e4, 0.3, (0.0, 0.0), 50.0, 1e-3, 0.0, radial_velocity_m_s=-100.0)
    with pytest.raises(ValueError, match="no measurement_model"):
        updater.update(SingleHypothesis(pred, Detection(y, timestamp=S.stamp(5.0))))
    with pytest.raises(ValueError, match="hypothesis.prediction must be an IMMCVCTStatePrediction"):
        updater.update(SingleHypothesis(prior, Detection(y, timestamp=S.stamp(5.0),
                                                         measurement_model=cases[0][0])))
    with pytest.raises(ValueError, match="4-state Gaussian"):
        S.IMMCVCTState.from_gaussian(GaussianState(StateVector([1.0, 2.0]), np.eye(2)), spec)
    with pytest.raises(ValueError, match="IMMCVCTPredictor.spec must be an IMMCVCTSpec"):
        S.IMMCVCTPredictor(spec={"q_cv_g": 1e-3})
    with pytest.raises(ValueError, match="prior.spec differs"):
        S.IMMCVCTPredictor(spec=IMMCVCTSpec(q_high_g=None)).predict(pred, timestamp=S.stamp(6.0))


def test_import_without_stonesoup_names_the_extra():
    block = ("import importlib.abc, sys\n"
             "class _Blocked(importlib.abc.MetaPathFinder):\n"
             "    def find_spec(self, name, path=None, target=None):\n"
             "        if name == 'stonesoup' or name.startswith('stonesoup.'):\n"
             "            raise ImportError('blocked')\n"
             "        return None\n"
             "sys.meta_path.insert(0, _Blocked())\n")
    code = block + ("try:\n    import baselines.stonesoup_components\nexcept ImportError as e:\n    print(e)\n"
                    "else:\n    print('imported')\n")
    res = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120, cwd=ROOT)
    assert 'pip install -e ".[stonesoup]"' in res.stdout, res.stdout + res.stderr


def test_docs_example_runs():
    """The code block of docs/stonesoup.md marked ``example`` runs as written."""
    text = (ROOT / "docs" / "stonesoup.md").read_text()
    blocks = re.findall(r"<!-- example -->\n```python\n(.*?)```", text, flags=re.S)
    assert len(blocks) == 1
    namespace = {}
    exec(compile(blocks[0], "docs/stonesoup.md", "exec"), namespace)
    assert len(namespace["track"]) == 40
    # the simulated 3 deg/s counter-clockwise turn: detected, and negative in our clockwise-positive convention
    state = namespace["state"]
    assert state.maneuver_probability > 0.5
    assert np.degrees(state.turn_rate_rad_s) == pytest.approx(-3.0, abs=0.5)


def test_multitarget_example_small(tmp_path):
    """A short run of baselines.stonesoup_example: both filters track, OSPA is in [0, c] on the same scans; the
    IMM's tracks carry IMM states; the table and the figure are written."""
    from baselines import stonesoup_example as X

    truths, scans, _ = X.scenario(n_steps=15, seed=3)
    assert len(truths) == 4 and len(scans) == 15
    assert any(type(d).__name__ == "Clutter" for _, dets in scans for d in dets)
    tracks = X.run_tracker(scans, "imm_cv_ct")
    assert tracks and all(isinstance(t.state, (S.IMMCVCTStateUpdate, S.IMMCVCTStatePrediction)) for t in tracks)
    result = X.run(n_steps=15, seed=3, filters=["ekf_q20", "imm_cv_ct"])
    for name in ("ekf_q20", "imm_cv_ct"):
        r = result[name]
        assert r["n_tracks"] > 0 and r["t_s"].size > 5
        assert np.all((r["ospa_m"] >= 0) & (r["ospa_m"] <= X.OSPA_C_M))
        # every target tracked at some scans: OSPA far below what one missing target of four costs (c / 4)
        assert r["ospa_m"].min() < X.OSPA_C_M / 10
    np.testing.assert_array_equal(result["ekf_q20"]["t_s"], result["imm_cv_ct"]["t_s"])
    text = X.table(result, every_s=25.0)
    assert "| mean |" in text and "imm_cv_ct OSPA (m)" in text
    assert X.figure(result, tmp_path / "f.png").stat().st_size > 0
    with pytest.raises(ValueError, match="filter_name must be"):
        X.run_tracker(scans, "kf")


@pytest.mark.parametrize("kw, name", [({"range_m": -1000.0}, "range_m"), ({"bearing_rad": math.inf}, "bearing_rad"),
                                      ({"range_noise_std_m": -50.0}, "range_noise_std_m"),
                                      ({"bearing_noise_std_rad": 0.0}, "bearing_noise_std_rad"),
                                      ({"site_xy_m": (0.0, math.nan)}, "site_xy_m"),
                                      ({"radial_velocity_m_s": math.nan, "radial_velocity_noise_std_m_s": 1.0},
                                       "radial_velocity_m_s"),
                                      ({"radial_velocity_m_s": 10.0, "radial_velocity_noise_std_m_s": -1.0},
                                       "radial_velocity_noise_std_m_s"),
                                      ({"range_m": "far"}, "range_m")])
def test_polar_detection_refuses_a_bad_plot_naming_the_argument(kw, name):
    """A negative range or std was squared or turned into a garbage track; NaN failed later in the updater."""
    args = {"range_m": 40e3, "bearing_rad": 0.3, "site_xy_m": (0.0, 0.0), "range_noise_std_m": 50.0,
            "bearing_noise_std_rad": 0.002, "t_s": 5.0, **kw}
    with pytest.raises(ValueError, match=f"polar_detection: {name}"):
        S.polar_detection(**args)
