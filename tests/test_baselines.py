"""Classical trackers: every tracker on every scenario, the behaviours that define them, IMM vs FilterPy."""

import gymnasium as gym
import numpy as np
import pytest
from filterpy.kalman import IMMEstimator, KalmanFilter

import radar_env  # noqa: F401
from agents.evaluation.suites import draw_suite
from baselines import trackers as T
from baselines.policies import CKFPolicy, CminPolicy, POLICY_NAMES, make_policy
from baselines.registry import POLICY_TRACKERS, TRACKER_NAMES, run_tracker
from radar_env.sim.catalog import SCENARIO_NAMES
from radar_env.envs.env import EnvConfig
from radar_env.sim.episode import stack_episodes
from radar_env.filters.kalman import process_noise, transition_cv
from radar_env.envs.observation import PAST_FEATURES, ObservationLayout
from radar_env.filters.tracking import Tracker
from radar_env.common.units import G0_M_S2

CFG = EnvConfig()
LEVELS = np.asarray(CFG.q_levels_g) * G0_M_S2
LAYOUT = ObservationLayout(CFG.features, LEVELS[0], LEVELS[-1])


@pytest.fixture(scope="module")
def suites():
    out = {}
    for name in SCENARIO_NAMES:
        if name == "adrian_flower":
            continue  # 1561 looks: covered by the evaluation report, too slow for every tracker here
        out[name] = draw_suite(name, 2, seed=123)
    return out


# the hindsight bounds take seconds per episode: tests/test_hindsight.py runs them on every scenario
@pytest.mark.parametrize("tracker", [t for t in TRACKER_NAMES if t not in POLICY_TRACKERS and not t.startswith("hindsight")])
def test_every_tracker_runs_on_every_scenario(tracker, suites):
    for name, eps in suites.items():
        run = run_tracker(tracker, eps)
        batch = stack_episodes(eps)
        K = batch.valid.shape[1]
        used = batch.valid & (np.arange(K)[None] >= run.start_index[:, None])
        assert np.all(np.isfinite(run.x[used])), (tracker, name)
        assert np.all(np.isfinite(run.P[used])), (tracker, name)
        P = run.P[used]
        assert np.allclose(P, np.swapaxes(P, -1, -2), atol=1e-6 * np.abs(P).max())
        assert np.all(np.linalg.eigvalsh(0.5 * (P + np.swapaxes(P, -1, -2))) > 0), (tracker, name)


def _onsets(maneuvering):
    return np.flatnonzero(maneuvering & ~np.r_[False, maneuvering[:-1]])


def test_cmin_switches_within_two_scans_and_ckf_later():
    eps = draw_suite("bizup2002", 10, seed=7)
    batch = stack_episodes(eps)
    cmin = run_tracker("cmin", eps)
    # CKF with Bizup's 5 NM threshold never switches on the 0.1 deg radar (documented); with a threshold scaled to
    # this radar (1.5 km) it does switch, and later than c_min: the fading-memory average is slow.
    ckf_pol = CKFPolicy(LAYOUT, "continuous", LEVELS, threshold_m=1500.0)
    ckf = T.run_q_policy(eps, ckf_pol.q_m_s2, "ckf_1.5km", declare=ckf_pol.declared)
    ckf_5nm = run_tracker("ckf", eps)
    high = 0.5 * G0_M_S2
    for b in range(len(eps)):
        for k0 in _onsets(batch.maneuvering[b]):
            first_c = np.flatnonzero(cmin.q_m_s2[b, k0:] > high)
            first_k = np.flatnonzero(ckf.q_m_s2[b, k0:] > high)
            assert first_c.size and first_c[0] <= 2, (b, k0, first_c[:3])
            assert first_k.size == 0 or first_k[0] > first_c[0]
        assert np.all(ckf_5nm.q_m_s2[b][np.isfinite(ckf_5nm.q_m_s2[b])] < high)
    assert np.any(ckf.q_m_s2 > high)


def test_imm2_matches_filterpy_on_identical_measurements():
    eps = draw_suite("bizup2002", 1, seed=3)
    spec = T.IMM2_BIZUP
    run = T.run_imm(eps, spec, "imm2_bizup")
    # independent oracle: FilterPy's IMMEstimator from the same start
    tr = Tracker(1)
    tr.load([0], eps)
    e = eps[0]
    k0 = int(tr.k[0])
    filters = []
    for q in spec.q_m_s2:
        kf = KalmanFilter(dim_x=4, dim_z=2)
        kf.x = tr.x[0].copy()
        kf.P = tr.P[0].copy()
        kf.H = np.hstack([np.eye(2), np.zeros((2, 2))])
        filters.append(kf)
    imm = IMMEstimator(filters, np.array(spec.mu0), np.array(spec.Pi))
    t_last = e.t_s[k0 - 1]
    for k in range(k0, e.n_looks):
        dt = e.t_s[k] - t_last
        for kf, q in zip(filters, spec.q_m_s2):
            kf.F = transition_cv(dt)[0]
            kf.Q = process_noise(dt, q)[0]
            kf.R = e.R_m2[k]
        imm.predict()
        imm.update(e.z_m[k])
        t_last = e.t_s[k]
        np.testing.assert_allclose(run.x[0, k], imm.x, rtol=1e-8, atol=1e-6)
        np.testing.assert_allclose(run.P[0, k], imm.P, rtol=1e-7, atol=1e-6)


def test_clairvoyant_never_worse_than_mismatched_kf_on_average():
    eps = draw_suite("random", 20, seed=11)
    batch = stack_episodes(eps)

    def rmse(run):
        K = run.x.shape[1]
        used = batch.valid & (np.arange(K)[None] >= run.start_index[:, None])
        return np.sqrt(np.mean(np.sum((run.x[..., :2] - batch.truth[..., :2]) ** 2, -1)[used]))

    c = rmse(run_tracker("clairvoyant", eps))
    for other in ("kf_low", "kf_high", "kf_tuned", "imm2"):
        assert c < rmse(run_tracker(other, eps)), other


def test_reference_policies_predict_interface_in_env():
    for action_type in ("discrete", "continuous"):
        env = gym.make("RadarTrack-v0", action_type=action_type, scenario="bizup2002")
        for name in POLICY_NAMES:
            pol = make_policy(name, env.unwrapped.layout, action_type, env.unwrapped.q_levels_m_s2)
            obs, _ = env.reset(seed=5)
            for _ in range(20):
                a1, state = pol.predict(obs, deterministic=True)
                a2, _ = pol.predict(obs)
                assert state is None and np.array_equal(a1, a2)
                assert env.action_space.contains(a1), (name, a1)
                q_rule = np.clip(pol.q_m_s2(obs[None])[0], LEVELS[0], LEVELS[-1])
                obs, _, term, trunc, info = env.step(a1)
                if action_type == "continuous":   # the env applies exactly the rule's q (float32 action)
                    np.testing.assert_allclose(info["q_m_s2"], q_rule, rtol=1e-5)
                else:                             # nearest level in log10
                    assert abs(np.log10(info["q_m_s2"] / q_rule)) <= 0.5 * np.log10(LEVELS[1] / LEVELS[0]) + 1e-9
                if term or trunc:
                    break
        batch_obs = np.stack([env.observation_space.sample() for _ in range(5)])
        acts, _ = make_policy("cmin", env.unwrapped.layout, action_type, env.unwrapped.q_levels_m_s2).predict(batch_obs)
        assert len(acts) == 5


def test_cmin_policy_rule_and_continuous_action_roundtrip():
    pol = CminPolicy(LAYOUT, "continuous", LEVELS)
    obs = np.zeros((3, len(LAYOUT.names)), dtype=np.float32)
    # Bizup's timing: the c_min of the plot being filtered (the preview), not of the previous plot
    obs[:, LAYOUT.names.index("next_c_min_g")] = np.array([0.5, 1.5, 3.0]) / 8.0
    obs[:, LAYOUT.names.index("c_min_g")] = 5.0 / 8.0
    q = pol.q_m_s2(obs) / G0_M_S2
    np.testing.assert_allclose(q, [0.03, 1.5, 3.0], rtol=1e-6)
    past = ObservationLayout(PAST_FEATURES, LEVELS[0], LEVELS[-1])   # without the preview: the previous plot's
    obs_past = np.zeros((3, len(PAST_FEATURES)), dtype=np.float32)
    obs_past[:, past.names.index("c_min_g")] = np.array([0.5, 1.5, 3.0]) / 8.0
    np.testing.assert_allclose(CminPolicy(past, "continuous", LEVELS).q_m_s2(obs_past) / G0_M_S2, [0.03, 1.5, 3.0],
                               rtol=1e-6)
    # the continuous action maps back to the same q through the env's action map
    env = gym.make("RadarTrack-v0", action_type="continuous")
    core = env.unwrapped._core
    np.testing.assert_allclose(core.action_to_q(pol.predict(obs[1])[0]), 1.5 * G0_M_S2, rtol=1e-5)
    with pytest.raises(ValueError, match="needs observation feature"):
        CminPolicy(ObservationLayout(("nis",)), "continuous", LEVELS)
