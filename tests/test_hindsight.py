"""Hindsight bounds (baselines/hindsight.py): the kernel against the chain and torch, the bound against every
q-policy on every episode of a small suite, the turn bound against the q bound, ranges, reproducibility."""

import dataclasses

import numpy as np
import pytest

from agents.evaluation.suites import draw_suite
from baselines import hindsight as H
from baselines.registry import run_tracker
from baselines.trackers import run_q_policy
from radar_env.sim.catalog import SCENARIO_NAMES
from radar_env.envs.env import EnvConfig
from radar_env.sim.episode import Episode, stack_episodes
from radar_env.common.units import DEG, G0_M_S2

CFG = EnvConfig()
LO, HI = CFG.q_levels_g[0] * G0_M_S2, CFG.q_levels_g[-1] * G0_M_S2
ITER = 150        # enough for the margins below (the default 300 improves the last 10 % by ~1e-5)


def _short(e, n_looks):
    """The first ``n_looks`` looks of an episode (the test suite's episodes are short to keep it fast)."""
    arrays = {f.name: getattr(e, f.name)[:n_looks] for f in dataclasses.fields(Episode) if f.name != "name"}
    return Episode(name=e.name, **arrays)


def _mse(eps, run):
    """Per-episode position MSE after the track start (what the evaluation pools)."""
    b = stack_episodes(eps)
    K = b.valid.shape[1]
    used = b.valid & (np.arange(K)[None] >= run.start_index[:, None])
    e2 = np.sum((run.x[..., :2] - b.truth[..., :2]) ** 2, axis=-1)
    return np.where(used, e2, 0.0).sum(axis=1) / used.sum(axis=1)


@pytest.fixture(scope="module")
def suite():
    # random: 70 looks (350 s, the first leg lasts >= 90 s); bizup2002: its whole 94 looks hold its two turns
    eps = [_short(e, 70) for e in draw_suite("random", 6, seed=11)] + draw_suite("bizup2002", 6, seed=11)
    assert sum(int(e.maneuvering.sum()) > 0 for e in eps) >= 9     # maneuvers to be tracked, not only straight legs
    return eps


@pytest.fixture(scope="module")
def bounds(suite):
    run_q, info_q = H.run_hindsight_q(suite, iterations=ITER, return_info=True)
    run_t, (info_t, _) = H.run_hindsight_q_turn(suite, iterations=ITER, return_info=True)
    return run_q, info_q, run_t, info_t


def _schedules(eps, seed, J):
    rng = np.random.default_rng(seed)
    q = np.exp(rng.uniform(np.log(LO), np.log(HI), size=(len(eps), J)))
    w = rng.uniform(-10 * DEG, 10 * DEG, size=(len(eps), J))
    w[:, ::7] = 0.0                    # exact zeros: F_ct = F_cv, the kernel's series branch
    w[:, 3::7] = 1e-5                  # tiny turns: series branch off zero
    return q, w


def test_kernel_and_torch_forward_equal_the_chain():
    eps = [_short(e, 60) for e in draw_suite("random", 3, seed=3)] + draw_suite("seed002_two_radars", 1, seed=3)
    J = max(e.n_looks for e in eps)
    q, w = _schedules(eps, 0, J)
    for turn in (None, w):
        chain = _mse(eps, H.chain_forward(eps, q, turn))
        kern = H.kernel_forward(eps, q, turn)[0]
        tor = H.torch_forward(eps, q, turn)
        np.testing.assert_allclose(kern, chain, rtol=1e-9)
        np.testing.assert_allclose(tor, chain, rtol=1e-9)


def test_kernel_gradient_equals_torch_autograd():
    torch = pytest.importorskip("torch")
    eps = [_short(e, 40) for e in draw_suite("random", 2, seed=4)]
    prob = H._Problem(eps, CFG)
    q, w = _schedules(eps, 1, prob.J)
    _, gq, gw = H.kernel_forward(eps, q, w)
    lq = torch.tensor(np.log(q), requires_grad=True)
    om = torch.tensor(w, requires_grad=True)
    H._torch_mse(prob, lq, om).sum().backward()
    m = prob.mask
    np.testing.assert_allclose(gq[m], lq.grad.numpy()[m], rtol=1e-6, atol=1e-9 * np.abs(gq).max())
    np.testing.assert_allclose(gw[m], om.grad.numpy()[m], rtol=1e-6, atol=1e-9 * np.abs(gw).max())


def _bundled_policy_mse(eps):
    from agents.policies.bundle import BUNDLED_POLICY
    from agents.policies.loading import load_policy

    if not BUNDLED_POLICY.is_file():
        pytest.skip("no bundled policy")
    choose_q, cfg = load_policy(BUNDLED_POLICY)
    assert (cfg.warmup_scans, cfg.warmup_q_g) == (CFG.warmup_scans, CFG.warmup_q_g)   # the same track start
    return _mse(eps, run_q_policy(eps, choose_q, "policy", cfg))


def test_hindsight_q_below_every_q_policy_on_every_episode(suite, bounds):
    run_q, info_q, _, _ = bounds
    hq = _mse(suite, run_q)
    np.testing.assert_allclose(hq, info_q.mse_m2, rtol=1e-9)      # the chain reproduces the optimised MSE
    # kf_tuned and kf_low are starts (never worse by construction, so only the 1e-9 kernel/chain agreement);
    # the others are beaten by the optimisation itself: 1e-6 relative covers an unconverged last digit, far below
    # the margins measured (>= 10 % on this suite)
    others = {t: _mse(suite, run_tracker(t, suite)) for t in ("kf_tuned", "kf_low", "cmin", "ckf", "kim_lee")}
    others["bundled policy"] = _bundled_policy_mse(suite)
    for name, m in others.items():
        worse = hq > m * (1 + 1e-6)
        assert not worse.any(), (name, np.flatnonzero(worse), hq[worse], m[worse])
    # it is a real optimisation, not only the best start
    assert np.all(hq < 0.9 * info_q.start_mse_m2.min(axis=1))


def test_hindsight_turn_below_hindsight_q_and_schedules_in_range(suite, bounds):
    run_q, _, run_t, info_t = bounds
    hq, ht = _mse(suite, run_q), _mse(suite, run_t)
    np.testing.assert_allclose(ht, info_t.mse_m2, rtol=1e-9)
    assert np.all(ht <= hq * (1 + 1e-9))
    assert np.mean(ht / hq) < 0.95          # turning the prediction helps on maneuvering episodes
    b = stack_episodes(suite)
    used = b.valid & (np.arange(b.valid.shape[1])[None] >= run_q.start_index[:, None])
    for run in (run_q, run_t):
        q = run.q_m_s2[used]
        assert np.all(q >= LO * (1 - 1e-12)) and np.all(q <= HI * (1 + 1e-12))
    w = run_t.extra["turn_rate_deg_s"][used]
    assert np.all(np.isfinite(w)) and np.all(np.abs(w) <= H.DEFAULT_TURN_RATE_MAX_DEG_S * (1 + 1e-12))
    assert np.all(np.isfinite(info_t.grad_norm)) and np.all(info_t.iterations >= 1)


def test_reproducible_and_independent_of_the_batch():
    eps = [_short(e, 50) for e in draw_suite("random", 3, seed=8)]
    a = H.run_hindsight_q(eps, iterations=20)
    b = H.run_hindsight_q(eps, iterations=20)
    np.testing.assert_array_equal(a.q_m_s2, b.q_m_s2)
    np.testing.assert_array_equal(a.x, b.x)
    alone = H.run_hindsight_q(eps[1:2], iterations=20)
    k = eps[1].n_looks
    np.testing.assert_allclose(alone.q_m_s2[0, :k], a.q_m_s2[1, :k], rtol=1e-9)


@pytest.mark.parametrize("name", [n for n in SCENARIO_NAMES if n != "adrian_flower"])
def test_registered_bounds_run_on_every_scenario(name, monkeypatch):
    monkeypatch.setattr(H, "DEFAULT_ITERATIONS", 3)       # the registry's call uses the default
    eps = [_short(e, 40) for e in draw_suite(name, 1, seed=2)]
    for t in ("hindsight_q", "hindsight_q_turn"):
        run = run_tracker(t, eps)
        used = np.arange(run.x.shape[1])[None] >= run.start_index[:, None]
        used &= stack_episodes(eps).valid
        assert run.name == t and np.all(np.isfinite(run.x[used])) and np.all(np.isfinite(run.P[used]))


@pytest.mark.parametrize("kw, match", [({"q_range_g": (0.1, 0.01)}, "q_range_g"), ({"q_range_g": (0.0, 1.0)}, "q_range_g"),
                                       ({"iterations": -1}, "iterations"), ({"iterations": 2.5}, "iterations"),
                                       ({"turn_rate_max_deg_s": 0.0}, "turn_rate_max_deg_s"),
                                       ({"turn_rate_max_deg_s": float("nan")}, "turn_rate_max_deg_s")])
def test_bad_arguments_name_the_parameter(kw, match):
    eps = [_short(draw_suite("random", 1, seed=1)[0], 30)]
    with pytest.raises(ValueError, match=match):
        H.run_hindsight_q_turn(eps, **kw)
