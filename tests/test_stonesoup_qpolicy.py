"""agents.policies.stonesoup_qpolicy: the bundled q-policies (policy_bp, policy_bp_rdot, and policy, the PPO one with
its four stacked frames) as a Stone Soup predictor/updater equal the evaluation's run
(agents.evaluation.runner.run_policy -> run_q_policy, the oracle) on every look of our episodes (estimate to 1e-6
relative, the chosen q to 1e-9), with the plots as Stone Soup polar detections; missed looks kept as predictions
(Stone Soup's trackers) or updated with a MissedDetection; a q-policy reading no range rate runs on
CartesianToBearingRange detections; Stone Soup's hypothesiser accepts it."""

import math

import numpy as np
import pytest

pytest.importorskip("stonesoup")

from stonesoup.hypothesiser.distance import DistanceHypothesiser  # noqa: E402
from stonesoup.measures import Mahalanobis  # noqa: E402
from stonesoup.types.hypothesis import SingleHypothesis  # noqa: E402
from stonesoup.types.track import Track  # noqa: E402

from agents.evaluation.runner import run_policy  # noqa: E402
from agents.policies import stonesoup_chain as C  # noqa: E402
from agents.policies import stonesoup_learned as L  # noqa: E402
from agents.policies import stonesoup_qpolicy as Q  # noqa: E402
from agents.policies.recurrent import RecurrentQPolicy, weight_shapes  # noqa: E402
from baselines import stonesoup_components as S  # noqa: E402
from baselines.trackers import observation_layout  # noqa: E402
from radar_env.envs.config import EnvConfig  # noqa: E402
from radar_env.envs.observation import DEFAULT_FEATURES  # noqa: E402
from radar_env.filters.tracking import preview_next_plot  # noqa: E402
# the learned IMM's test episodes (suites, and random flights seen by one or two radar sites with missed looks) and
# its Stone Soup loop over an episode
from tests.test_stonesoup_learned import _episodes as _eps, run_pair  # noqa: E402

REL, REL_Q = 1e-6, 1e-9


@pytest.fixture(scope="module")
def policies():
    return {n: Q.load_q_policy(n) for n in ("policy_bp", "policy_bp_rdot", "policy")}


def _position_only_policy():
    """A q-policy reading no range rate (random weights: the computation is what is compared)."""
    cfg = EnvConfig.from_kwargs(action_type="continuous",
                                features=[n for n in DEFAULT_FEATURES if n not in Q.RANGE_RATE_FEATURES])
    arch = {"input_size": len(cfg.features), "hidden_size": 8, "head": [4]}
    rng = np.random.default_rng(5)
    w = {k: 0.4 * rng.standard_normal(s) for k, s in weight_shapes(arch).items()}
    return Q.QPolicy("position_only", RecurrentQPolicy(w, arch, cfg.q_levels_g), cfg, observation_layout(cfg)[0])


def _run_stonesoup(model, e, state, k0, missed, radial_velocity=True):
    return run_pair(Q.QPolicyPredictor(policy=model), Q.QPolicyUpdater(), Q.QPolicyStatePrediction, e, state, k0,
                    missed, radial_velocity)


def _check_every_look(model, eps, missed, radial_velocity=True):
    run = run_policy(model.name, eps, model.policy, model.env_config)
    states, k0 = Q.q_track_starts(eps, model)
    n_checked = n_missed = 0
    for b, e in enumerate(eps):
        for k, ctx, state in _run_stonesoup(model, e, states[b], int(k0[b]), missed, radial_velocity):
            ref, where = run.x[b, k], f"row {b} look {k}"
            for sl in (slice(0, 2), slice(2, 4)):
                np.testing.assert_allclose(ctx.x[sl], ref[sl], rtol=0, atol=REL * np.abs(ref[sl]).max(),
                                           err_msg=where)
            np.testing.assert_allclose(ctx.P, run.P[b, k], rtol=0, atol=REL * np.abs(run.P[b, k]).max(),
                                       err_msg=where)
            assert ctx.q_m_s2 == pytest.approx(run.q_m_s2[b, k], rel=REL_Q, abs=0), where
            if not isinstance(state, Q.QPolicyStatePrediction):     # what a tracker's track shows
                x_ss = np.asarray(state.state_vector, dtype=np.float64).ravel()[S.SS_FROM_OURS]
                np.testing.assert_array_equal(x_ss, ctx.x)
                assert state.q_m_s2 == ctx.q_m_s2
            n_checked += 1
            n_missed += not e.detected[k]
    assert n_checked == sum(e.n_looks - k - 1 for e, k in zip(eps, k0))
    return run, n_missed


@pytest.mark.parametrize("name,which,missed", [("policy_bp", "bizup2002", "predict"),
                                               ("policy_bp", "random", "predict"),
                                               ("policy_bp", "one_site_with_misses", "predict"),
                                               ("policy_bp", "one_site_with_misses", "bare"),
                                               ("policy_bp", "two_sites_with_misses", "model"),
                                               ("policy_bp_rdot", "random", "predict"),
                                               ("policy_bp_rdot", "two_sites_with_misses", "model"),
                                               ("policy", "random", "predict"),
                                               ("policy", "one_site_with_misses", "bare"),
                                               ("policy", "two_sites_with_misses", "model")])
def test_stonesoup_q_policy_equals_the_runner_on_every_look(policies, name, which, missed):
    model = policies[name]
    assert model.needs_range_rate and model.env_config.track_start.radial_velocity == name.endswith("_rdot")
    run, n_missed = _check_every_look(model, _eps(which), missed)
    if "misses" in which:
        assert n_missed > 0
    q = run.q_m_s2[np.isfinite(run.q_m_s2)]
    assert q.max() / q.min() > 10       # the network's q moves look to look: its choices are what is compared


def test_position_only_q_policy_on_bearing_range_detections():
    """A q-policy whose inputs read no range rate runs on CartesianToBearingRange detections, equal to the runner
    (the episodes' range rate is not seen)."""
    model = _position_only_policy()
    assert not model.needs_range_rate
    _check_every_look(model, _eps("one_site_with_misses"), "predict", radial_velocity=False)


def test_range_rate_features_are_all_that_read_the_range_rate():
    """Every entry of the full observation is finite on plots without range rate except RANGE_RATE_FEATURES (so a
    policy reading none of them is exact on CartesianToBearingRange detections)."""
    layout = observation_layout(EnvConfig.from_kwargs(action_type="continuous"))[0]
    e = _eps("bizup2002")[0]
    states, k0 = Q.q_track_starts([e], _position_only_policy())
    ctx = states[0].context
    dets = S.detections_from_episode(e)
    nan = set()
    for k in range(int(k0[0]) + 1, int(k0[0]) + 15):
        look = S.look_from_detection(dets[k]) if dets[k] is not None else C._missed_look(ctx, e.t_s[k])
        prev = preview_next_plot(ctx.chain.x, ctx.chain.P, ctx.chain.t_last,
                                 {n: np.asarray(v)[None] for n, v in look.items()})
        phys = layout.physical(ctx.chain_out._replace(features={**ctx.chain_out.features, **prev}), np.array([1.0]))
        nan |= {n for n, v in zip(layout.names, phys[0]) if not np.isfinite(v)}
        ctx = Q._run_look(ctx, look)
    assert nan == set(Q.RANGE_RATE_FEATURES)


def test_hypothesiser_and_from_gaussian(policies):
    """Stone Soup's hypothesiser gates with the prediction (3-D polar); a track started from a bare Gaussian (an
    initiator's) with its detection tracks the target."""
    model = policies["policy_bp"]
    e = _eps("bizup2002")[0]
    states, k0 = Q.q_track_starts([e], model)
    k0 = int(k0[0])
    dets = S.detections_from_episode(e, radial_velocity=True)
    start = S.gaussian_state(states[0].context.x, states[0].context.P, e.t_s[k0])
    assert dets[k0] is not None
    track = Track([Q.QPolicyState.from_gaussian(start, model, detection=dets[k0])])
    predictor, updater = Q.q_policy_pair(model)
    # include_all: the gate is the missed-look q's (module docstring), narrow at a maneuver's onset (this
    # episode's first plot after it is ~50 sigma away; the policy raises q once it sees the plot)
    hypothesiser = DistanceHypothesiser(predictor, updater, Mahalanobis(), missed_distance=30.0, include_all=True)
    for k in range(k0 + 1, k0 + 60):
        hyps = hypothesiser.hypothesise(track, {dets[k]}, S.stamp(e.t_s[k]))
        assert isinstance(hyps[0].prediction, Q.QPolicyStatePrediction)
        track.append(updater.update(next(h for h in hyps if h)))
    err = np.hypot(*(track.state.context.x[:2] - e.truth[k0 + 59][:2]))
    assert err < 5 * math.sqrt(e.R_m2[k0 + 59].trace())
    with pytest.raises(ValueError, match="detection must be given"):
        Q.QPolicyState.from_gaussian(start, model)


def test_errors_name_the_parameter(policies):
    model = policies["policy_bp"]
    e = _eps("bizup2002")[0]
    states, k0 = Q.q_track_starts([e], model)
    k = int(k0[0]) + 1
    predictor, updater = Q.q_policy_pair(model)
    pred = predictor.predict(states[0], timestamp=S.stamp(e.t_s[k]))
    with pytest.raises(ValueError, match="must carry a range rate .*next_rdot_nu") as err:
        updater.update(SingleHypothesis(pred, S.detections_from_episode(e)[k]))
    assert "\n" not in str(err.value)
    with pytest.raises(ValueError, match="differs from the prediction"):
        updater.update(SingleHypothesis(pred, S.detections_from_episode(e, radial_velocity=True)[k + 1]))
    with pytest.raises(ValueError, match="before the track's last look"):
        predictor.predict(states[0], timestamp=S.stamp(e.t_s[k - 2]))
    with pytest.raises(ValueError, match="prior must be a QPolicyState"):
        predictor.predict(S.gaussian_state(np.zeros(4), np.eye(4), 0.0), timestamp=S.stamp(1.0))
    imm_pred = L.LearnedIMMPredictor().predict(L.track_starts([e])[0][0], timestamp=S.stamp(e.t_s[k]))
    with pytest.raises(ValueError, match="hypothesis.prediction must be a QPolicyStatePrediction"):
        updater.update(SingleHypothesis(imm_pred, S.detections_from_episode(e, radial_velocity=True)[k]))
    with pytest.raises(ValueError, match="measurement_model must be polar"):
        from stonesoup.models.measurement.linear import LinearGaussian
        from stonesoup.types.detection import Detection
        from stonesoup.types.array import StateVector
        updater.update(SingleHypothesis(pred, Detection(StateVector([1.0, 2.0]), timestamp=S.stamp(e.t_s[k]),
                                                        measurement_model=LinearGaussian(4, (0, 2), np.eye(2)))))
    with pytest.raises(ValueError, match="kind"):
        Q.load_q_policy("policy_imm_bp")


def test_multitarget_example_with_the_q_policy_small(policies):
    """A short range-rate run of the multi-target example with policy_bp added: Stone Soup's initiator starts the
    learned tracks (from its EKF updates), the tracks carry q-policy states, OSPA is in [0, c]."""
    from baselines import stonesoup_example as X

    model = policies["policy_bp"]
    truths, scans, _ = X.scenario(n_steps=15, seed=3, range_rate=True)
    tracks = X.run_tracker(scans, "policy_bp", Q.q_policy_pair(model))
    # a track the initiator starts at the last scan holds only its EKF states; every other goes on as a q-policy
    grown = [t for t in tracks if any(isinstance(s, Q.QPolicyState) for s in t.states)]
    assert grown and all(isinstance(t.state, (Q.QPolicyStateUpdate, Q.QPolicyStatePrediction)) for t in grown)
    r = X.run(n_steps=15, seed=3, filters=["imm_cv_ct"], range_rate=True,
              extra={"policy_bp": lambda: Q.q_policy_pair(model)})["policy_bp"]
    assert r["n_tracks"] > 0 and np.all((r["ospa_m"] >= 0) & (r["ospa_m"] <= X.OSPA_C_M))
    assert r["ospa_m"].min() < X.OSPA_C_M / 10
