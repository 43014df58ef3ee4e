"""RadarTrack-v0 with tracker="imm_cv_ct" (radar_env.envs.imm_env): the zero action is the imm_cv_ct tracker, any action
is the IMM stepped with the mapped parameters beside the env's own feature chain, the map stays in the ranges, the
env is reproducible, passes Gymnasium's checker, stays finite and SPD under random actions, and refuses what it
does not support."""

import json
import warnings

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding
from gymnasium.utils.env_checker import check_env

import radar_env  # noqa: F401  (registers RadarTrack-v0)
from baselines.imm_cv_ct_runner import IMMCVCTStepper, check_look_parameters, tuned_imm_cv_ct_spec
from baselines.registry import run_tracker
from baselines.tuned_params import tuned_parameters
from radar_env.sim.draws import draw_episodes
from radar_env.sim.episode import stack_episodes
from radar_env.filters.imm_cv_ct import IMM_CV_CT_PARAMS, detector_inputs, look_parameter_names
from radar_env.envs.imm_env import IMMActionMap, imm_env_defaults
from radar_env.envs.observation import ObservationLayout, measurement_sigma_m
from radar_env.common.units import DEG, G0_M_S2

IMM = dict(tracker="imm_cv_ct")


def _episode(seed, scenario="random"):
    """The episode a single env reset with ``seed`` draws (radar_env.sim.draws; tests/test_env_kernel.py)."""
    return draw_episodes(scenario, None, None, [seeding.np_random(seed)[0]], 12).episode(0)


def _run_env(env, seed, actions=None):
    """Step ``env`` through one episode; ``actions(i)`` gives step i's action (default: zero). Returns the list of
    (obs, reward, info) from the reset on."""
    obs, info = env.reset(seed=seed)
    out = [(obs, 0.0, info)]
    i = 0
    while True:
        a = np.zeros(env.action_space.shape) if actions is None else actions(i)
        obs, r, term, trunc, info = env.step(a)
        out.append((obs, r, info))
        i += 1
        if term or trunc:
            return out


def _start_look(run):
    return int(run.start_index[0]) - 1


@pytest.mark.parametrize("seed", [0, 7])
def test_the_zero_action_is_the_imm_cv_ct_tracker(seed):
    """Continuous a = 0 and the middle discrete level: the env's estimate and covariance are imm_cv_ct's on the
    same episode (to 1e-9), every look of the episode."""
    run = run_tracker("imm_cv_ct", [_episode(seed)])
    k0 = _start_look(run)
    for kw, zero in ((dict(action_type="continuous"), np.zeros(7)), (dict(action_type="discrete"), np.full(7, 2))):
        steps = _run_env(gym.make("RadarTrack-v0", **IMM, **kw), seed, lambda i: zero)
        assert len(steps) - 1 == int(np.isfinite(run.x[0, :, 0]).sum()) - 1   # every look after the start
        for i, (_, _, info) in enumerate(steps):
            k = k0 + i
            np.testing.assert_allclose(info["estimate"], run.x[0, k], rtol=1e-9, atol=1e-9)
            np.testing.assert_allclose(info["covariance"], run.P[0, k], rtol=1e-9, atol=1e-9)
            assert not info["track_lost"]


def test_vector_env_rows_are_the_single_env_and_imm_cv_ct():
    """Each row of the native vector env (zero action) is the single env with seed s + i, and imm_cv_ct on that
    row's first episode; the rows go on through autoreset."""
    n, seed = 3, 11
    venv = gym.make_vec("RadarTrack-v0", num_envs=n, vectorization_mode="vector_entry_point", action_type="continuous",
                        **IMM)
    obs, info = venv.reset(seed=seed)
    singles = [_run_env(gym.make("RadarTrack-v0", action_type="continuous", **IMM), seed + i) for i in range(n)]
    runs = [run_tracker("imm_cv_ct", [_episode(seed + i)]) for i in range(n)]
    ended = np.zeros(n, dtype=bool)
    for t in range(max(len(s) for s in singles) + 3):
        for i in np.flatnonzero(~ended):
            o, _, inf = singles[i][t]
            np.testing.assert_array_equal(obs[i], o)
            np.testing.assert_array_equal(info["estimate"][i], inf["estimate"])
            np.testing.assert_allclose(info["estimate"][i], runs[i].x[0, _start_look(runs[i]) + t], rtol=1e-9)
        obs, rew, term, trunc, info = venv.step(np.zeros((n, 7)))
        assert np.isfinite(obs).all() and np.isfinite(rew).all()
        done = term | trunc
        for i in np.flatnonzero(done & ~ended):
            assert t + 2 == len(singles[i])                     # it ends where the single env ended
            np.testing.assert_array_equal(info["final_obs"][i], singles[i][-1][0])
        ended |= done
    assert ended.all()


def test_any_action_is_the_imm_stepped_with_the_mapped_parameters_beside_the_feature_chain():
    """Random actions: the estimate is IMMCVCTStepper's with the mapped parameters, the observation's features are
    the env's CV chain at the constant feature q (Tracker + ObservationLayout, as LearnedIMM.run computes them) and
    its detectors are detector_inputs of the IMM's output."""
    seed = 5
    env = gym.make("RadarTrack-v0", action_type="continuous", **IMM)
    core = env.unwrapped._core
    rng = np.random.default_rng(0)
    acts = rng.uniform(-1, 1, (400, 7))
    steps = _run_env(env, seed, lambda i: acts[i])
    ep = _episode(seed)
    cfg, spec = env.unwrapped.config, tuned_imm_cv_ct_spec()
    tr = cfg.track_start.tracker(1)
    out = tr.load([0], [ep])
    b = stack_episodes([ep])
    k0 = int(out.look_index[0])
    x5 = np.concatenate([tr.x, np.zeros((1, 1))], 1)
    P5 = np.zeros((1, 5, 5))
    P5[:, :4, :4] = tr.P
    P5[:, 4, 4] = (spec.sigma_omega0_deg_s * DEG) ** 2
    imm = IMMCVCTStepper(b.t_s, b.z_m, b.R_m2, b.detected, b.n_looks, [k0 + 1], x5, P5, spec)
    lv = np.asarray(cfg.q_levels_g) * G0_M_S2
    layout = ObservationLayout(cfg.features, lv[0], lv[-1])
    q = imm_env_defaults()["feature_q_g"] * G0_M_S2
    F = len(cfg.features)
    np.testing.assert_array_equal(steps[0][0][:F], layout.encode(out, np.full(1, cfg.warmup_q_g * G0_M_S2))[0])
    for i, (obs, _, info) in enumerate(steps[1:]):
        par = core.action_to_parameters(acts[i][None])
        o = imm.step(par)
        np.testing.assert_allclose(info["estimate"], o.x[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(info["covariance"], o.P[0], rtol=1e-9, atol=1e-9)
        f = tr.step(np.full(1, q))
        np.testing.assert_array_equal(obs[:F], layout.encode(f, np.full(1, q))[0])
        det = np.clip(detector_inputs(o.mu, o.omega_rad_s, o.omega_std_rad_s), -1, 1).astype(np.float32)[0]
        np.testing.assert_array_equal(obs[F:], det)
        assert info["q_m_s2"] == q


def test_the_action_map_spans_the_ranges_and_is_the_tuned_value_at_zero():
    spec = tuned_imm_cv_ct_spec()
    names = look_parameter_names(spec)
    rng = {n: (lo, hi) for n, _, lo, hi, _ in IMM_CV_CT_PARAMS}
    lo, hi = np.array([rng[n][0] for n in names]), np.array([rng[n][1] for n in names])
    m = IMMActionMap(spec)
    base = np.array([getattr(spec, n) for n in names])
    np.testing.assert_array_equal(m.parameters(np.zeros((1, 7)))[0], base)      # exactly the tuned values
    np.testing.assert_allclose(m.parameters(-np.ones((1, 7)))[0], lo, rtol=1e-12)
    np.testing.assert_allclose(m.parameters(np.ones((1, 7)))[0], hi, rtol=1e-12)
    a = np.concatenate([np.random.default_rng(1).uniform(-1, 1, (2000, 7)), -np.ones((1, 7)), np.ones((1, 7))])
    a = np.sort(a, axis=0)
    p = m.parameters(a)
    assert np.all((p >= lo) & (p <= hi))
    check_look_parameters(spec, p)                         # the kernel accepts every output
    assert np.all(np.diff(p, axis=0) >= 0)                 # monotone in each parameter
    d = IMMActionMap(spec, discrete=True, levels=5)
    lev = d.parameters(np.tile(np.arange(5.0)[:, None], (1, 7)))
    np.testing.assert_array_equal(lev, m.parameters(np.tile(np.linspace(-1, 1, 5)[:, None], (1, 7))))
    np.testing.assert_array_equal(lev[2], base)
    with pytest.raises(ValueError, match="integers in"):
        d.parameters(np.full((1, 7), 5.0))
    with pytest.raises(ValueError, match=r"in \[-1, 1\]"):
        m.parameters(np.full((1, 7), 1.5))


def test_the_defaults_are_the_tuned_parameters():
    """radar_env/data/imm_cv_ct_env.json is a copy of baselines/tuned.json's imm_cv_ct parameters and kf's q (if
    this fails after a re-tuning, copy them again)."""
    t, d = tuned_parameters(), imm_env_defaults()
    assert d["feature_q_g"] == t["kf"]["q_g"]
    assert d["imm_parameters"] == {n: t["imm_cv_ct"][n] for n, *_ in IMM_CV_CT_PARAMS}
    assert json.loads(json.dumps(d))


@pytest.mark.parametrize("kw", [dict(action_type="continuous"), dict(action_type="discrete", imm_action_levels=3)])
def test_same_seed_same_episode(kw):
    def run():
        env = gym.make("RadarTrack-v0", **IMM, **kw)
        env.action_space.seed(3)
        return _run_env(env, 21, lambda i: env.action_space.sample())
    a, b = run(), run()
    assert len(a) == len(b)
    for (o1, r1, i1), (o2, r2, i2) in zip(a, b):
        np.testing.assert_array_equal(o1, o2)
        assert r1 == r2
        np.testing.assert_array_equal(i1["estimate"], i2["estimate"])
        np.testing.assert_array_equal(i1["covariance"], i2["covariance"])


@pytest.mark.parametrize("kw", [dict(action_type="continuous"), dict(action_type="discrete")])
def test_gymnasium_env_checker(kw):
    env = gym.make("RadarTrack-v0", **IMM, **kw)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        check_env(env.unwrapped, skip_render_check=True)


def _spd(P):
    return np.allclose(P, P.T, rtol=1e-12, atol=1e-9) and np.linalg.eigvalsh(0.5 * (P + P.T)).min() > 0


@pytest.mark.parametrize("policy", ["random", "low", "high", "bang"])
def test_any_actions_keep_the_filter_finite_and_P_spd(policy):
    """A few hundred steps of random or extreme actions (all -1, all +1, alternating) on random radars: every
    observation, reward, estimate finite, every covariance symmetric positive definite, observations in the Box."""
    env = gym.make("RadarTrack-v0", scenario="random_radars", action_type="continuous", **IMM)
    env.action_space.seed(0)
    obs, info = env.reset(seed=2)
    steps = 0
    while steps < 400:
        a = {"random": lambda: env.action_space.sample(), "low": lambda: -np.ones(7), "high": lambda: np.ones(7),
             "bang": lambda: np.full(7, 1.0 if steps % 6 < 3 else -1.0)}[policy]()
        obs, r, term, trunc, info = env.step(a)
        steps += 1
        assert np.isfinite(obs).all() and env.observation_space.contains(obs)
        assert np.isfinite(r) and np.isfinite(info["estimate"]).all()
        assert _spd(info["covariance"]), info["covariance"]
        if term or trunc:
            obs, info = env.reset()


def test_the_reward_is_the_default_definition_on_the_imm_estimate():
    env = gym.make("RadarTrack-v0", reward_type="squared", action_type="continuous", **IMM)
    obs, info = env.reset(seed=4)
    tr = env.unwrapped._core.tracker
    for i in range(60):
        obs, r, term, trunc, info = env.step(np.full(7, 0.5))
        k = int(tr.k[0]) - 1
        rng_true = np.hypot(*(info["truth"][:2] - tr.look_data("site_xy_m")[0, k]))
        sig = measurement_sigma_m(rng_true, tr.look_data("range_noise_std_m")[0, k],
                                  tr.look_data("bearing_noise_std_rad")[0, k])
        e = np.hypot(*(info["estimate"][:2] - info["truth"][:2])) / sig
        assert r == pytest.approx(-min(e * e, 100.0), rel=1e-12)
        assert info["reward_terms"]["position_error"] == r
        if term or trunc:
            break


def test_rendering_works_with_the_imm():
    pytest.importorskip("matplotlib")
    env = gym.make("RadarTrack-v0", render_mode="rgb_array", action_type="continuous", **IMM)
    env.reset(seed=0)
    env.step(np.zeros(7))
    frame = env.render()
    assert frame.ndim == 3 and frame.shape[2] == 3


@pytest.mark.parametrize("kw, match", [
    (dict(imm_action_levels=5), "imm_action_levels applies only with tracker='imm_cv_ct'"),
    (dict(feature_q_g=0.5), "feature_q_g applies only with tracker='imm_cv_ct'"),
    (dict(imm_parameters={}), "imm_parameters applies only with tracker='imm_cv_ct'"),
    (dict(tracker="imm"), "tracker must be one of"),
    (dict(tracker="imm_cv_ct", frame_stack=2), "frame_stack must be 1 with tracker='imm_cv_ct'"),
    (dict(tracker="imm_cv_ct", imm_action_levels=4), "imm_action_levels must be odd"),
    (dict(tracker="imm_cv_ct", imm_action_levels=1), "imm_action_levels"),
    (dict(tracker="imm_cv_ct", action_type="continuous", imm_action_levels=5), "only with action_type='discrete'"),
    (dict(tracker="imm_cv_ct", imm_parameters={"q_cv": 1.0}), "imm_parameters: unknown"),
    (dict(tracker="imm_cv_ct", imm_parameters={"p_stay_cv": 1.5}), "imm_parameters: IMMCVCTSpec.p_stay_cv"),
    (dict(tracker="imm_cv_ct", imm_parameters=[1.0]), "imm_parameters must be a dict"),
    (dict(tracker="imm_cv_ct", feature_q_g=-1.0), "feature_q_g"),
])
def test_refusals_name_the_argument(kw, match):
    with pytest.raises(ValueError, match=match):
        gym.make("RadarTrack-v0", **kw)


def test_action_refusals():
    env = gym.make("RadarTrack-v0", action_type="continuous", **IMM)
    env.reset(seed=0)
    for bad, match in ((np.zeros(6), r"shape \(7,\)"), (np.zeros((7, 1)), r"shape \(7,\).*got shape \(7, 1\)"),
                       (np.full(7, 1.5), r"finite values in \[-1, 1\]"), (np.full(7, np.nan), r"in \[-1, 1\]"),
                       (np.array(["a"] * 7), "real number")):
        with pytest.raises(ValueError, match=match):
            env.step(bad)
    denv = gym.make("RadarTrack-v0", action_type="discrete", **IMM)
    denv.reset(seed=0)
    for bad, match in ((np.full(7, 5), r"integers in \[0, 4\]"), (np.full(7, 0.5), "integers"),
                       (np.zeros(7, dtype=bool), "integer number")):
        with pytest.raises(ValueError, match=match):
            denv.step(bad)
    venv = gym.make_vec("RadarTrack-v0", num_envs=2, vectorization_mode="vector_entry_point", **IMM)
    venv.reset(seed=0)
    with pytest.raises(ValueError, match=r"shape \(2, 7\)"):
        venv.step(np.zeros(2, dtype=np.int64))
    # a refused action changes nothing: the next valid step equals a fresh env's
    ref = gym.make("RadarTrack-v0", action_type="discrete", **IMM)
    ref.reset(seed=0)
    np.testing.assert_array_equal(denv.step(np.full(7, 2))[0], ref.step(np.full(7, 2))[0])


def test_the_training_selection_runs_an_sb3_model_as_the_env_does():
    """agents.policies.loading.model_run_imm (the selection callback's run of a PPO model on tracker='imm_cv_ct')
    gives the estimates of the env stepped with that model's deterministic actions."""
    sb3 = pytest.importorskip("stable_baselines3")
    import torch
    from agents.policies.loading import model_run_imm
    torch.manual_seed(0)
    env = gym.make("RadarTrack-v0", action_type="continuous", **IMM)
    model = sb3.PPO("MlpPolicy", env, seed=0, device="cpu", policy_kwargs=dict(log_std_init=0.0))
    with torch.no_grad():                        # a policy far from zero: its actions reach the bounds
        for p in model.policy.action_net.parameters():
            p.mul_(50.0)
    seed = 9
    obs_log = []
    env2 = gym.make("RadarTrack-v0", action_type="continuous", **IMM)

    def act(i):
        a, _ = model.predict(obs_log[-1], deterministic=True)
        return a
    o, info = env2.reset(seed=seed)
    obs_log.append(o)
    est = [info["estimate"]]
    while True:
        o, _, term, trunc, info = env2.step(act(len(obs_log)))
        obs_log.append(o)
        est.append(info["estimate"])
        if term or trunc:
            break
    run = model_run_imm(model, env2.unwrapped.config)([_episode(seed)])
    k0 = _start_look(run)
    assert np.isfinite(run.x[0, k0:k0 + len(est)]).all()
    np.testing.assert_allclose(np.array(est), run.x[0, k0:k0 + len(est)], rtol=1e-9, atol=1e-9)
    assert np.nanmax(np.abs(run.extra["param_q_ct_g"][0] - tuned_imm_cv_ct_spec().q_ct_g)) > 0.1


def test_two_modes_and_other_imm_parameters():
    """imm_parameters moves the a = 0 point: without the third mode (q_high_g None) the action has 5 entries and the
    observation 4 detectors, and the zero action is imm_cv_ct with those parameters."""
    from baselines.imm_cv_ct_runner import run_imm_cv_ct
    from radar_env.filters.imm_cv_ct import imm_cv_ct_spec_from_params
    params = {**imm_env_defaults()["imm_parameters"], "q_high_g": None, "p_stay_cv": 0.95}
    env = gym.make("RadarTrack-v0", action_type="continuous", imm_parameters={"q_high_g": None, "p_stay_cv": 0.95},
                   **IMM)
    assert env.action_space.shape == (5,) and env.observation_space.shape == (27 + 4,)
    steps = _run_env(env, 3)
    run = run_imm_cv_ct([_episode(3)], imm_cv_ct_spec_from_params(params))
    k0 = _start_look(run)
    est = np.array([i["estimate"] for _, _, i in steps])
    np.testing.assert_allclose(est, run.x[0, k0:k0 + len(est)], rtol=1e-9, atol=1e-9)


def test_a_bank_of_ct_modes_in_the_env():
    """``imm_parameters`` with ``ct_rate_<k>_deg_s`` (imm_ct_bank's tuned values): six CT modes, the same 7 actions
    (the CT modes share q_ct and p_stay_ct), a detector per mode; any action is IMMCVCTStepper with the bank's spec
    and the mapped parameters, to 1e-9."""
    from baselines.imm_cv_ct_runner import IMM_CT_BANK_PARAMS
    from radar_env.filters.imm_cv_ct import imm_cv_ct_spec_from_params
    names = [n for n, *_ in IMM_CT_BANK_PARAMS]
    from baselines.tuned_params import tuned_parameters
    bank = {k: v for k, v in tuned_parameters()["imm_ct_bank"].items() if k in names}
    env = gym.make("RadarTrack-v0", action_type="continuous", imm_parameters=bank, **IMM)
    core = env.unwrapped._core
    assert core.spec.is_bank and env.action_space.shape == (7,)
    assert env.observation_space.shape == (27 + 8 + 2,)
    assert core.detector_names[1] == f"mu_ct+{core.spec.ct_rates_deg_s[0]:g}"
    seed = 4
    rng = np.random.default_rng(1)
    acts = rng.uniform(-1, 1, (400, 7))
    steps = _run_env(env, seed, lambda i: acts[i])
    ep = _episode(seed)
    spec = imm_cv_ct_spec_from_params({**imm_env_defaults()["imm_parameters"], **bank})
    tr = env.unwrapped.config.track_start.tracker(1)
    out = tr.load([0], [ep])
    b = stack_episodes([ep])
    x5 = np.concatenate([tr.x, np.zeros((1, 1))], 1)
    P5 = np.zeros((1, 5, 5))
    P5[:, :4, :4] = tr.P
    P5[:, 4, 4] = (spec.sigma_omega0_deg_s * DEG) ** 2
    imm = IMMCVCTStepper(b.t_s, b.z_m, b.R_m2, b.detected, b.n_looks, [int(out.look_index[0]) + 1], x5, P5, spec)
    for i, (obs, _, info) in enumerate(steps[1:]):
        o = imm.step(core.action_to_parameters(acts[i][None]))
        np.testing.assert_allclose(info["estimate"], o.x[0], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(info["covariance"], o.P[0], rtol=1e-9, atol=1e-9)
    assert np.ptp([i["estimate"][0] for _, _, i in steps]) > 0


def test_max_episode_steps_truncates_as_in_the_default_env():
    venv = gym.make_vec("RadarTrack-v0", num_envs=2, vectorization_mode="vector_entry_point", max_episode_steps=5,
                        **IMM)
    venv.reset(seed=0)
    for t in range(5):
        _, _, term, trunc, _ = venv.step(np.full((2, 7), 2))
        assert not term.any() and trunc.all() == (t == 4)
