"""Every tracker on the one chain: the runners that used to write Tracker internals (IMM, re-initialisation,
Konle's blend) now go through the Tracker's cursor (next_look / advance / set_posterior). Their output must be
bit for bit what the old runners gave; the old logic is kept here, frozen, as the independent reference."""

import dataclasses

import numpy as np
import pytest

from agents.evaluation.suites import draw_suite
from baselines import trackers as T
from baselines.registry import run_tracker, tuned_imm2_spec
from baselines.tuned_params import tuned_parameters
from radar_env.filters.kalman import imm_step, process_noise, transition_ct, two_point_init
from radar_env.filters.tracking import Tracker, TrackStart
from radar_env.common.units import G0_M_S2


# ------------------------------------------------------------------------------------ frozen reference (old code)
def _old_start(episodes):
    tr = Tracker(len(episodes))
    return tr, tr.load(np.arange(len(episodes)), episodes)


def _old_imm(episodes, spec):
    tr, out = _old_start(episodes)
    B, K, M = tr.B, int(tr.n_looks.max()), len(spec.q_m_s2)
    x_out, P_out = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan)
    pm = np.full((B, K), np.nan)
    declared = np.zeros((B, K), dtype=bool)
    x_out[np.arange(B), out.look_index], P_out[np.arange(B), out.look_index] = out.x, out.P
    x_m, P_m = np.repeat(tr.x[:, None], M, axis=1), np.repeat(tr.P[:, None], M, axis=1)
    log_mu = np.log(np.tile(np.asarray(spec.mu0, dtype=np.float64), (B, 1)))
    with np.errstate(divide="ignore"):
        log_Pi = np.log(np.asarray(spec.Pi, dtype=np.float64))
    q, w = np.asarray(spec.q_m_s2, dtype=np.float64), np.asarray(spec.turn_rate_rad_s, dtype=np.float64)
    active = ~out.done
    d = {f: tr.look_data(f) for f in ("t_s", "z_m", "R_m2", "detected")}
    while active.any():
        rows = np.flatnonzero(active)
        k = tr.k[rows]
        t = d["t_s"][rows, k]
        dt = t - tr.t_last[rows]
        F = transition_ct(np.repeat(dt[:, None], M, 1), np.broadcast_to(w, (rows.size, M)))
        Q = process_noise(np.repeat(dt[:, None], M, 1), np.broadcast_to(q, (rows.size, M)))
        res = imm_step(log_mu[rows], x_m[rows], P_m[rows], log_Pi, F, Q, d["z_m"][rows, k], d["R_m2"][rows, k],
                       d["detected"][rows, k])
        log_mu[rows], x_m[rows], P_m[rows] = res.log_mu, res.x_modes, res.P_modes
        p_man = np.exp(res.log_mu[:, list(spec.maneuver_modes)]).sum(axis=1)
        x_out[rows, k], P_out[rows, k], pm[rows, k] = res.x, res.P, p_man
        declared[rows, k] = p_man > 0.5
        tr.t_last[rows], tr.k[rows] = t, k + 1
        active[rows] = tr.k[rows] < tr.n_looks[rows]
    return x_out, P_out, declared, {"maneuver_probability": pm}


def _old_loop(episodes, step_fn):
    tr, out = _old_start(episodes)
    B, K = tr.B, int(tr.n_looks.max())
    x_out, P_out = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan)
    x_out[np.arange(B), out.look_index], P_out[np.arange(B), out.look_index] = out.x, out.P
    active = ~out.done
    while active.any():
        rows = np.flatnonzero(active)
        o, x, P = step_fn(tr, rows)
        x_out[rows, o.look_index], P_out[rows, o.look_index] = x, P
        active[rows] = ~o.done
    return tr, x_out, P_out


def _old_reinit(episodes, q_m_s2=0.03 * G0_M_S2, n_sigma=2.0, consecutive=4):
    B = len(episodes)
    probe = Tracker(B)
    probe.load(np.arange(B), episodes)
    run_len = np.zeros(B, dtype=np.int64)
    last_plot, last_R, last_t = np.full((B, 2), np.nan), np.tile(np.eye(2), (B, 1, 1)), np.full(B, np.nan)
    for b in range(B):   # the per-row loop of the old set-up
        i = np.flatnonzero(probe.look_data("detected")[b, : probe.k[b]])[-1]
        last_plot[b], last_R[b], last_t[b] = (probe.look_data(f)[b, i] for f in ("z_m", "R_m2", "t_s"))
    K = int(probe.n_looks.max())
    declared = np.zeros((B, K), dtype=bool)

    def step(tr, rows):
        o = tr.step(np.full(rows.size, q_m_s2), rows=None if rows.size == B else rows)
        far = o.detected & (o.nis > n_sigma ** 2)
        run_len[rows] = np.where(o.detected, np.where(far, run_len[rows] + 1, 0), run_len[rows])
        fire = run_len[rows] >= consecutive
        x, P = o.x.copy(), o.P.copy()
        if fire.any():
            fr = rows[fire]
            ok = np.isfinite(last_t[fr]) & (o.t_s[fire] > last_t[fr])
            if ok.any():
                x0, P0 = two_point_init(last_plot[fr][ok], last_R[fr][ok], last_t[fr][ok], o.z_m[fire][ok],
                                        o.R_m2[fire][ok], o.t_s[fire][ok])
                idx = np.flatnonzero(fire)[ok]
                x[idx], P[idx] = x0, P0
                tr.x[fr[ok]], tr.P[fr[ok]] = x0, P0
            run_len[fr] = 0
        declared[rows, o.look_index] = fire
        upd = o.detected
        last_plot[rows[upd]], last_R[rows[upd]], last_t[rows[upd]] = o.z_m[upd], o.R_m2[upd], o.t_s[upd]
        return o, x, P

    _, x, P = _old_loop(episodes, step)
    return x, P, declared, {}


def _old_konle(episodes, weight=0.75):
    from baselines.konle import blend_speed_heading, run_konle
    from radar_env.sim.episode import stack_episodes

    batch = stack_episodes(episodes)
    kon = run_konle(batch.t_s, batch.site_xy_m, np.nan_to_num(batch.range_m), np.nan_to_num(batch.bearing_rad),
                    batch.detected, range_std_m=np.where(batch.detected, batch.range_noise_std_m, 1.0),
                    bearing_std_rad=np.where(batch.detected, batch.bearing_noise_std_rad, 1e-3),
                    sensor_id=batch.site_index)
    q = tuned_parameters()["kf"]["q_g"] * G0_M_S2

    def step(tr, rows):
        o = tr.step(np.full(rows.size, q), rows=None if rows.size == len(episodes) else rows)
        x = blend_speed_heading(o.x, kon.speed_m_s[rows, o.look_index], kon.heading_rad[rows, o.look_index], weight)
        tr.x[rows] = x
        return o, x, o.P

    _, x, P = _old_loop(episodes, step)
    return x, P, None, {}


# ------------------------------------------------------------------------------------ tests
@pytest.fixture(scope="module")
def suites():
    # random flights, random radars (missed looks, irregular dt) and two radars (two sites, plots out of step)
    return {s: draw_suite(s, n, seed=4242) for s, n in (("random", 6), ("random_radars", 6),
                                                         ("seed002_two_radars", 2))}


REFERENCES = {"imm2": lambda eps: _old_imm(eps, tuned_imm2_spec()), "imm3_ct": lambda eps: _old_imm(eps, T.IMM3_CT),
              "reinit": _old_reinit, "konle": _old_konle}


@pytest.mark.parametrize("tracker", sorted(REFERENCES))
def test_runner_bit_identical_to_old_logic(suites, tracker):
    for suite, eps in suites.items():
        x, P, declared, extra = REFERENCES[tracker](eps)
        run = run_tracker(tracker, eps)
        np.testing.assert_array_equal(run.x, x, err_msg=f"{tracker} on {suite}")
        np.testing.assert_array_equal(run.P, P, err_msg=f"{tracker} on {suite}")
        if declared is not None:
            np.testing.assert_array_equal(run.declared, declared, err_msg=f"{tracker} on {suite}")
        for k, v in extra.items():
            np.testing.assert_array_equal(run.extra[k], v, err_msg=f"{tracker} {k} on {suite}")
        assert np.isfinite(run.x[np.arange(len(eps)), run.start_index]).all()


def test_reinit_fires_on_the_suite(suites):
    # the bit-identity above must cover re-initialisations, not only the plain KF
    assert any(run_tracker("reinit", eps).declared.any() for eps in suites.values())


def test_cursor_advance_and_set_posterior():
    eps = draw_suite("random_radars", 3, seed=7)
    tr = TrackStart().tracker(3)
    tr.load(np.arange(3), eps)
    rows = np.array([0, 2])
    look = tr.next_look(rows)
    np.testing.assert_array_equal(look["k"], tr.k[rows])
    np.testing.assert_array_equal(look["t_s"], tr.look_data("t_s")[rows, tr.k[rows]])
    np.testing.assert_array_equal(look["dt_s"], look["t_s"] - tr.t_last[rows])
    x, P = np.arange(8.0).reshape(2, 4), np.tile(2.0 * np.eye(4), (2, 1, 1))
    k1 = tr.k.copy()
    done = tr.advance(rows, x, P)
    assert not done.any()
    np.testing.assert_array_equal(tr.k, k1 + np.array([1, 0, 1]))
    np.testing.assert_array_equal(tr.t_last[rows], look["t_s"])
    np.testing.assert_array_equal(tr.x[rows], x)
    tr.set_posterior([1], np.ones((1, 4)))
    np.testing.assert_array_equal(tr.x[1], np.ones(4))
    # the next step predicts from the replaced posterior
    before_P = tr.P[1].copy()
    o = tr.step(np.array([0.0]), rows=np.array([1]))
    np.testing.assert_allclose(o.x_prior[0, :2], 1.0 + o.dt_s[0] * 1.0)
    assert np.all(np.diag(o.P_prior[0]) >= np.diag(before_P))


def test_cursor_refuses_an_ended_row():
    eps = draw_suite("random", 1, seed=3)
    tr = TrackStart().tracker(1)
    tr.load([0], eps)
    while tr.remaining_looks()[0]:
        look = tr.next_look([0])
        tr.advance([0], tr.x[[0]], tr.P[[0]])
    assert look["k"][0] == tr.n_looks[0] - 1
    with pytest.raises(ValueError, match="ended"):
        tr.next_look([0])
    with pytest.raises(ValueError, match="ended"):
        tr.advance([0], tr.x[[0]], tr.P[[0]])


def test_track_start_checked_names_the_field():
    assert TrackStart().checked() == TrackStart()
    with pytest.raises(ValueError, match=r"warmup_scans must be an integer in \[1, 1000\], got 0"):
        TrackStart(warmup_scans=0).checked()
    with pytest.raises(ValueError, match=r"RadarTrack-v0: fma_weight .* got 2"):
        TrackStart(fma_weight=2).checked("RadarTrack-v0: ")


def test_trackers_accept_a_track_start_or_an_env_config():
    from radar_env.envs.config import EnvConfig

    eps = draw_suite("random", 2, seed=11)
    a = T.run_imm(eps, T.IMM2_BIZUP, cfg=TrackStart(warmup_scans=5))
    b = T.run_imm(eps, T.IMM2_BIZUP, cfg=EnvConfig(warmup_scans=5))
    c = T.run_imm(eps, T.IMM2_BIZUP)
    np.testing.assert_array_equal(a.x, b.x)
    assert (a.start_index == c.start_index - 7).all()


@pytest.mark.parametrize("kwargs, match", [
    ({"Pi": ((0.9, 0.2), (0.9, 0.1))}, r"IMMSpec.Pi must be rows of probabilities .* got \(\(0.9, 0.2\)"),
    ({"Pi": ((0.9, 0.1),)}, r"must agree on M >= 1 modes, got 2 q levels, 2 turn rates, Pi of shape \(1, 2\)"),
    ({"mu0": (1.1, -0.1)}, r"IMMSpec.mu0 must be probabilities .* got \(1.1, -0.1\)"),
    ({"mu0": (np.nan, 1.0)}, r"IMMSpec.mu0 must be probabilities"),
    ({"q_m_s2": (-1.0, 2.0)}, r"IMMSpec.q_m_s2\[0\] must be a finite number in \[0.0, 980.665\], got -1.0"),
    ({"q_m_s2": (1.0, "2")}, r"IMMSpec.q_m_s2\[1\] must be a finite number .* \(str\)"),
    ({"turn_rate_rad_s": (0.0, np.inf)}, r"IMMSpec.turn_rate_rad_s\[1\] must be a finite number"),
    ({"maneuver_modes": (2,)}, r"IMMSpec.maneuver_modes entry must be an integer in \[0, 1\], got 2"),
])
def test_imm_spec_errors_name_the_field_and_value(kwargs, match):
    with pytest.raises(ValueError, match=match):
        dataclasses.replace(T.IMM2_BIZUP, **kwargs)


@pytest.mark.parametrize("rule", ["kf_tuned", "kf_low", "cmin", "ckf", "kim_lee"])
def test_rules_observing_only_their_features_equal_the_full_observation(suites, rule):
    # the registry runs a rule on the entries it reads (none for a constant q); per-entry scaling makes that the
    # same q, estimate and declaration as the full observation gives, bit for bit
    from baselines.policies import make_policy
    for suite, eps in suites.items():
        layout, lv = T.observation_layout()
        pol = make_policy(rule, layout, "continuous", lv)
        full = T.run_q_policy(eps, pol.q_m_s2, rule, declare=getattr(pol, "declared", None))
        lean = run_tracker(rule, eps)
        for f in ("x", "P", "q_m_s2", "declared"):
            np.testing.assert_array_equal(getattr(lean, f), getattr(full, f), err_msg=f"{rule} {f} on {suite}")
        for k, v in full.extra.items():
            np.testing.assert_array_equal(lean.extra[k], v, err_msg=f"{rule} {k} on {suite}")


def test_the_shared_track_start_is_a_fresh_start_bit_for_bit(suites):
    # trackers after the first on the same episodes get a copy of the kept start: same Tracker state, same runs
    eps = suites["random_radars"]
    T._LAST_START[0] = None
    fresh = {t: run_tracker(t, eps) for t in ("imm2", "cmin", "reinit")}     # imm2 starts, the others copy
    assert T._LAST_START[0] is not None and T._LAST_START[0][1] == list(eps)
    for t, ref in fresh.items():
        T._LAST_START[0] = None                                                 # each from its own start now
        run = run_tracker(t, eps)
        for f in ("x", "P", "q_m_s2", "declared", "start_index"):
            np.testing.assert_array_equal(getattr(run, f), getattr(ref, f), err_msg=f"{t} {f}")
    tr1, out1 = T._tracker(eps, None)
    tr2, out2 = T._tracker(eps, None)
    assert out1 is out2 and not out1.x.flags.writeable and tr1 is not tr2 and tr1.x is not tr2.x
    for name in ("x", "P", "k", "t_last", "n_looks"):
        np.testing.assert_array_equal(getattr(tr1, name), getattr(tr2, name))
    tr1.step(np.full(tr1.B, 1.0))                                               # stepping one copy leaves the kept one
    np.testing.assert_array_equal(T._tracker(eps, None)[0].k, tr2.k)


def test_imm_filter_is_imm_step_look_by_look_and_refuses_bad_ranges():
    from radar_env.filters.kalman import imm_filter
    rng = np.random.default_rng(5)
    B, K, M = 5, 40, 3
    t = np.cumsum(rng.uniform(0.5, 12.0, (B, K)), axis=1)
    z = rng.normal(0, 300.0, (B, K, 2)) + 100.0 * np.arange(K)[None, :, None]
    A = rng.normal(0, 1, (B, K, 2, 2))
    R = A @ A.transpose(0, 1, 3, 2) * 400.0 + 100.0 * np.eye(2)
    det = rng.uniform(size=(B, K)) < 0.8
    z[~det], R[~det] = np.nan, np.nan                       # missed looks: never read
    n, k0 = np.array([40, 30, 25, 12, 7]), np.array([3, 1, 25, 5, 2])
    x0 = np.tile([0.0, 0.0, 100.0, 10.0], (B, M, 1)) + rng.normal(0, 50, (B, M, 4))
    P0 = np.tile(np.diag([1e4, 1e4, 1e2, 1e2]), (B, M, 1, 1))
    log_mu0 = np.log(np.tile([0.6, 0.3, 0.1], (B, 1)))
    log_Pi = np.log(np.array([[0.9, 0.05, 0.05], [0.1, 0.85, 0.05], [0.2, 0.1, 0.7]]))
    q, w = np.array([0.3, 3.0, 1.0]), np.array([0.0, 0.02, -0.05])
    x, P, lm = imm_filter(t, z, R, det, n, k0, t[np.arange(B), k0 - 1], log_mu0, x0, P0, log_Pi, q, w)
    for b in range(B):
        mu, xm, Pm = log_mu0[b:b + 1], x0[b:b + 1], P0[b:b + 1]
        assert np.isnan(x[b, :k0[b]]).all() and np.isnan(x[b, n[b]:]).all()
        for k in range(k0[b], n[b]):
            dt = np.full((1, M), t[b, k] - t[b, k - 1])
            res = imm_step(mu, xm, Pm, log_Pi, transition_ct(dt, w[None]), process_noise(dt, q[None]),
                           z[b, k:k + 1], R[b, k:k + 1], det[b, k:k + 1])
            mu, xm, Pm = res.log_mu, res.x_modes, res.P_modes
            np.testing.assert_array_equal(x[b, k], res.x[0])
            np.testing.assert_array_equal(P[b, k], res.P[0])
            np.testing.assert_array_equal(lm[b, k], res.log_mu[0])
    for bad_n, bad_k in ((n, np.array([3, 1, 26, 5, 2])), (np.array([41, 30, 25, 12, 7]), k0), (n, k0 - 4)):
        with pytest.raises(ValueError, match="k_start <= n_looks <= K"):
            imm_filter(t, z, R, det, bad_n, bad_k, t[:, 0], log_mu0, x0, P0, log_Pi, q, w)
