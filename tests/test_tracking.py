"""Tracker: two-hit start and warm-up, row subsets equal to full-batch steps (bitwise), missed looks, the
known-input bound, and errors."""

import copy
import dataclasses

import numpy as np
import pytest

from radar_env.sim.catalog import make_setup
from radar_env.sim.episode import draw_episode
from radar_env.filters.kalman import predict, process_noise, transition_cv, two_point_init, update
from radar_env.sim.radar import atc_radar
from radar_env.sim.scenario import ScenarioBuilder
from radar_env.filters.tracking import MAX_Q_M_S2, Tracker, init_looks
from radar_env.common.units import G0_M_S2


def _episode(seed, name="random", pd=None):
    rng = np.random.default_rng(seed)
    radar = None if pd is None else atc_radar(detection_probability=pd)
    setup = make_setup(name, rng, radar=radar)
    return draw_episode(setup.scenario, setup.radar, rng)


def _miss(ep, idx):
    """A copy of ``ep`` with the looks ``idx`` missed (NaN plot, as draw_episode marks a miss)."""
    det, z, R = ep.detected.copy(), ep.z_m.copy(), ep.R_m2.copy()
    r, b, v = ep.range_m.copy(), ep.bearing_rad.copy(), ep.radial_velocity_m_s.copy()
    det[idx] = False
    for a in (z, R, r, b, v):
        a[idx] = np.nan
    return dataclasses.replace(ep, detected=det, z_m=z, R_m2=R, range_m=r, bearing_rad=b, radial_velocity_m_s=v)


def _assert_out_equal(a, b, rows_a=None, rows_b=None):
    """StepOutput ``a`` (optionally its rows ``rows_a``) equals ``b`` (its rows ``rows_b``) bit for bit, features
    included."""
    for name in a._fields:
        va, vb = getattr(a, name), getattr(b, name)
        if name == "features":
            assert va.keys() == vb.keys()
            for k in va:
                x = np.asarray(va[k]) if rows_a is None else np.asarray(va[k])[rows_a]
                y = np.asarray(vb[k]) if rows_b is None else np.asarray(vb[k])[rows_b]
                assert x.tobytes() == y.tobytes(), f"feature {k}"
            continue
        x = np.asarray(va) if rows_a is None else np.asarray(va)[rows_a]
        y = np.asarray(vb) if rows_b is None else np.asarray(vb)[rows_b]
        assert x.dtype == y.dtype and x.shape == y.shape and x.tobytes() == y.tobytes(), name


# ------------------------------------------------------------------------------------------------ track start
@pytest.mark.parametrize("warmup", [1, 5, 12])
def test_load_two_hit_start_then_warmup(warmup):
    ep = _miss(_episode(3), [0, 2])  # first two detected looks are 1 and 3
    i1, i2 = init_looks(ep.detected, ep.t_s)
    assert (i1, i2) == (1, 3)
    q0 = 0.03 * G0_M_S2
    tr = Tracker(1, warmup_scans=warmup, warmup_q_m_s2=q0)
    out = tr.load([0], [ep])
    n_steps = warmup
    assert tr.k[0] == i2 + 1 + n_steps
    assert out.look_index[0] == i2 + n_steps
    np.testing.assert_array_equal(out.q_m_s2, [q0])
    # the same chain written out: two_point_init of looks i1, i2, then n_steps predict/update at q0
    x, P = two_point_init(ep.z_m[[i1]], ep.R_m2[[i1]], ep.t_s[[i1]], ep.z_m[[i2]], ep.R_m2[[i2]], ep.t_s[[i2]])
    np.testing.assert_array_equal(x[0, :2], ep.z_m[i2])
    t_last = ep.t_s[i2]
    for k in range(i2 + 1, i2 + 1 + n_steps):
        dt = np.array([ep.t_s[k] - t_last])
        xp, Pp = predict(x, P, transition_cv(dt), process_noise(dt, np.array([q0])))
        u = update(xp, Pp, ep.z_m[[k]], ep.R_m2[[k]], ep.detected[[k]])
        x, P, t_last = u.x, u.P, ep.t_s[k]
    np.testing.assert_allclose(tr.x, x, rtol=1e-12, atol=1e-9)
    np.testing.assert_allclose(tr.P, P, rtol=1e-12, atol=1e-9)


def test_two_hit_start_state_before_warmup():
    """The prior of the first warm-up look is the prediction of two_point_init of the first two detections."""
    ep = _miss(_episode(8), [1])
    i1, i2 = init_looks(ep.detected, ep.t_s)
    assert (i1, i2) == (0, 2)
    tr = Tracker(1, warmup_scans=1, warmup_q_m_s2=0.0)
    out = tr.load([0], [ep])
    # closed form of the two-hit start (written out here, independent of filters.two_point_init)
    T = ep.t_s[i2] - ep.t_s[i1]
    R1, R2 = ep.R_m2[i1], ep.R_m2[i2]
    x0 = np.concatenate([ep.z_m[i2], (ep.z_m[i2] - ep.z_m[i1]) / T])
    P0 = np.block([[R2, R2 / T], [R2 / T, (R1 + R2) / T**2]])
    dt = ep.t_s[i2 + 1] - ep.t_s[i2]
    F = np.eye(4)
    F[0, 2] = F[1, 3] = dt
    np.testing.assert_allclose(out.x_prior[0], F @ x0, rtol=1e-12)
    np.testing.assert_allclose(out.P_prior[0], F @ P0 @ F.T, rtol=1e-10)  # q = 0: no process noise
    np.testing.assert_allclose(out.dt_s, [dt])


# ------------------------------------------------------------------------------------------------ row subsets
def test_step_rows_subset_equals_full_batch_bitwise():
    eps = [_episode(s, pd=0.85) for s in range(4)]
    full = Tracker(4)
    full.load(np.arange(4), eps)
    sub = copy.deepcopy(full)
    rng = np.random.default_rng(0)
    for _ in range(20):
        q = rng.uniform(0, 5 * G0_M_S2, 4)
        a = full.step(q)
        rows = np.array([2, 0])
        b = sub.step(q[rows], rows=rows)
        _assert_out_equal(a, b, rows_a=rows)
        rest = np.array([3, 1])
        c = sub.step(q[rest], rows=rest)
        _assert_out_equal(a, c, rows_a=rest)
    for name in ("x", "P", "k", "t_last"):
        assert getattr(full, name).tobytes() == getattr(sub, name).tobytes(), name
    for name, v in vars(full.bank).items():
        if isinstance(v, np.ndarray):
            assert v.tobytes() == getattr(sub.bank, name).tobytes(), f"bank.{name}"


def test_load_subset_equals_single_tracker():
    """Loading one row of a running batch (the vector env's autoreset) leaves the others alone and equals a
    fresh batch-1 tracker on that episode."""
    eps = [_episode(s) for s in range(3)]
    tr = Tracker(3)
    tr.load(np.arange(3), eps)
    for _ in range(5):
        tr.step(np.full(3, 0.5 * G0_M_S2))
    before = copy.deepcopy(tr)
    new = _episode(99, pd=0.9)
    out = tr.load([1], [new])
    one = Tracker(1)
    ref = one.load([0], [new])
    _assert_out_equal(out, ref)
    for _ in range(10):
        a = tr.step(np.full(3, 0.2 * G0_M_S2))
        b = one.step(np.full(1, 0.2 * G0_M_S2))
        c = before.step(np.full(3, 0.2 * G0_M_S2))
        _assert_out_equal(a, b, rows_a=[1])
        _assert_out_equal(a, c, rows_a=[0, 2], rows_b=[0, 2])


# ------------------------------------------------------------------------------------------------ missed looks
def test_missed_look_predicts_through():
    ep = _episode(5)
    tr = Tracker(1)
    tr.load([0], [ep])
    k = int(tr.k[0])
    tr2 = Tracker(1)
    tr2.load([0], [_miss(ep, [k, k + 1])])
    for _ in range(2):
        x_prev, P_prev, t_prev = tr2.x.copy(), tr2.P.copy(), tr2.t_last.copy()
        q = np.array([0.7 * G0_M_S2])
        out = tr2.step(q)
        dt = ep.t_s[out.look_index] - t_prev
        xp, Pp = predict(x_prev, P_prev, transition_cv(dt), process_noise(dt, q))
        assert not out.detected[0] and np.isnan(out.z_m).all()
        np.testing.assert_array_equal(out.x, out.x_prior)
        np.testing.assert_array_equal(out.P, out.P_prior)
        np.testing.assert_allclose(out.x, xp, rtol=1e-14)
        np.testing.assert_allclose(out.P, Pp, rtol=1e-14)
        assert out.nis[0] == 0 and np.all(out.nu == 0)
        assert np.all(np.isfinite([v for v in out.features.values()]))
    out = tr2.step(q)  # next detected look updates again
    assert out.detected[0] and not np.array_equal(out.x, out.x_prior)


# ------------------------------------------------------------------------------------------------ known input
def _rmse(tracker, ep, q, **kw):
    tracker.load([0], [ep], **kw)
    err = []
    while tracker.remaining_looks()[0] > 0:
        out = tracker.step(np.array([q]), **kw)
        err.append(out.x[0, :2] - out.truth[0, :2])
    return float(np.sqrt(np.mean(np.sum(np.square(err), axis=1))))


@pytest.mark.parametrize("name", ["bizup2002", "kim_lee_accel"])
def test_known_input_beats_plain_cv_on_turns(name):
    setup = make_setup(name)
    ep = draw_episode(setup.scenario, setup.radar, np.random.default_rng(0))
    known = _rmse(Tracker(1), ep, 0.0, known_input=True)
    plain0 = _rmse(Tracker(1), ep, 0.0)
    plain_hi = _rmse(Tracker(1), ep, 2 * G0_M_S2)
    assert known < 0.5 * plain0
    assert known < plain_hi


# ------------------------------------------------------------------------------------------------ errors
def test_errors():
    ep = _episode(1)
    tr = Tracker(2)
    tr.load([0, 1], [ep, _episode(2)])
    for bad in (-1.0, np.nan, np.inf, MAX_Q_M_S2 * 1.01):
        with pytest.raises(ValueError, match="q_m_s2"):
            tr.step(np.array([bad, 1.0]))
    # a failed step changes nothing
    k = tr.k.copy()
    with pytest.raises(ValueError):
        tr.step(np.array([1.0, -1.0]))
    np.testing.assert_array_equal(tr.k, k)
    # stepping a finished row
    while tr.remaining_looks()[0] > 0:
        tr.step(1.0, rows=[0])
    with pytest.raises(ValueError, match="ended"):
        tr.step(1.0, rows=[0])
    with pytest.raises(ValueError, match="ended"):
        tr.step(np.ones(2))
    tr.step(1.0, rows=[1])  # the other row still steps
    # fewer than two detections
    one_hit = _miss(ep, np.arange(1, ep.n_looks))
    with pytest.raises(ValueError, match="two"):
        Tracker(1).load([0], [one_hit])
    with pytest.raises(ValueError):
        Tracker(0)
    with pytest.raises(ValueError, match="warmup_scans"):
        Tracker(1, warmup_scans=-1)
    with pytest.raises(ValueError, match=r"warmup_scans must be in \[1"):
        Tracker(1, warmup_scans=0)


# ------------------------------------------------------------------------------------------------ next-plot preview
def test_preview_equals_next_step_at_zero_q():
    """The preview of look k+1 is the innovation that step k+1 computes: the predicted mean does not depend on q,
    and at q = 0 the step's S is the preview's S0, so nu along/cross and NIS match to rounding."""
    eps = [_episode(s) for s in (1, 2, 3)]
    tr = Tracker(3)
    out = tr.load(range(3), eps)
    for _ in range(20):
        prev = out.features
        out = tr.step(np.zeros(3))
        for k in ("nu_along", "nu_cross", "nis"):
            np.testing.assert_allclose(prev[f"next_{k}"], out.features[k], rtol=1e-9, atol=1e-12)
        np.testing.assert_allclose(prev["next_c_min_m_s2"], out.features["c_min_m_s2"], rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(prev["next_dt_s"], out.dt_s, rtol=0, atol=1e-12)
        los = out.x_prior[:, :2] - out.site_xy_m
        rdot_hat = (los * out.x_prior[:, 2:]).sum(-1) / np.hypot(los[:, 0], los[:, 1])
        np.testing.assert_allclose(prev["next_los_accel_m_s2"], (out.radial_velocity_m_s - rdot_hat) / out.dt_s,
                                   rtol=1e-9, atol=1e-9)
        np.testing.assert_allclose(prev["next_meas_std_m"], np.sqrt(0.5 * np.trace(out.R_m2, axis1=1, axis2=2)),
                                   rtol=1e-12)
        # radial-velocity innovation in sigmas: h = d rdot / d x by central differences, P_prior = F P F^T at q = 0
        sig = np.array([e.radial_velocity_noise_std_m_s[k] for e, k in zip(eps, out.look_index)])
        h = np.stack([(_rdot(out.x_prior + d, out.site_xy_m) - _rdot(out.x_prior - d, out.site_xy_m)) / (2 * d[j])
                      for j, d in enumerate(np.diag([1.0, 1.0, 1e-3, 1e-3]))], axis=1)
        s_r = np.einsum("bi,bij,bj->b", h, out.P_prior, h) + sig ** 2
        np.testing.assert_allclose(prev["next_rdot_nu"], (out.radial_velocity_m_s - rdot_hat) / np.sqrt(s_r),
                                   rtol=1e-6, atol=1e-9)
        # one-plot Kim & Lee: q^2 * trace(H Q1 H^T) = |nu|^2 - trace(S0)
        S = out.S
        phi = (out.nu ** 2).sum(-1) - (S[:, 0, 0] + S[:, 1, 1])
        np.testing.assert_allclose(prev["next_q_fit_m_s2"], np.sqrt(np.maximum(phi, 0) / (0.5 * out.dt_s ** 4)),
                                   rtol=1e-9)


def _rdot(x, site):
    los = x[:, :2] - site
    return (los * x[:, 2:]).sum(-1) / np.hypot(los[:, 0], los[:, 1])


def test_innovation_statistics_consistent_on_straight_flight():
    """With the true process noise (q = 0 on a straight, constant-speed flight, no warm-up inflation) the radial-
    velocity innovation in sigmas is N(0, 1): pooled over 100 Monte Carlo runs, mean and variance sit inside their
    99 % bounds (mean +-2.6/sqrt(n); variance by the chi-square normal approximation +-2.6 sqrt(2/n)). The
    fading-memory means of the signed innovations are 0 and that of the NIS is its 2-dof mean, 2 (run averages
    over the last looks, bounds of 99 % from their spread over the runs)."""
    s = make_setup("random", np.random.default_rng(0))
    sc = ScenarioBuilder(position_m=(-30e3, 20e3), speed_kt=350, heading_deg=100).straight(400).build()
    eps = [draw_episode(sc, s.radar, np.random.default_rng(100 + i)) for i in range(100)]
    tr = Tracker(len(eps), warmup_q_m_s2=0.0)
    out = tr.load(range(len(eps)), eps)
    v, fm = [], []
    while not out.done.all():
        v.append(out.features["next_rdot_nu"][out.features["next_detected"] > 0])
        fm.append([out.features[k] for k in ("nu_along_fm", "nu_cross_fm", "nis_fm")])
        out = tr.step(np.zeros(len(eps)))
    v = np.concatenate(v)
    n = v.size
    assert n > 5000
    assert abs(v.mean()) < 2.6 / np.sqrt(n)
    assert abs(v.var() - 1.0) < 2.6 * np.sqrt(2.0 / n)
    per_run = np.array(fm)[-40:].mean(axis=0)          # (3, runs): each run's average over its last 40 looks
    half = 2.6 * per_run.std(axis=1) / np.sqrt(per_run.shape[1])
    assert np.all(np.abs(per_run.mean(axis=1) - [0.0, 0.0, 2.0]) < half), (per_run.mean(axis=1), half)


def test_preview_is_causal_and_empty_after_last_look():
    """Changing plots after look k+1 leaves the preview at k unchanged; a missed or absent next look previews 0."""
    ep = _episode(4)
    later = ep.z_m.copy()
    later[30:] += 5e3
    ep2 = dataclasses.replace(ep, z_m=later)
    a, b = Tracker(1), Tracker(1)
    oa, ob = a.load([0], [ep]), b.load([0], [ep2])
    while int(a.k[0]) < 29:
        oa, ob = a.step(1.0), b.step(1.0)
        for k, v in oa.features.items():
            assert np.array_equal(v, ob.features[k]), k
    missed = _miss(ep, [int(a.k[0]) + 1])
    t = Tracker(1)
    o = t.load([0], [missed])
    while int(t.k[0]) < int(a.k[0]) + 1:
        o = t.step(1.0)
    assert o.features["next_detected"][0] == 0 and o.features["next_nis"][0] == 0
    assert o.features["next_q_fit_m_s2"][0] == 0 and o.features["next_c_min_m_s2"][0] == 0
    while not o.done[0]:
        o = t.step(1.0)
    f = o.features
    assert f["next_detected"][0] == 0 and f["next_dt_s"][0] == 0 and f["next_nu_along"][0] == 0


def test_preview_los_accel_sees_kim_lee_speed_change():
    """Radial flight with +-5 g speed changes (T = 1 s, 2 kt radial-velocity noise): the radial-velocity preview
    reports the acceleration on the first look of each change, sign included, and stays small on the first leg."""
    s = make_setup("kim_lee_accel")
    ep = draw_episode(s.scenario, s.radar, np.random.default_rng(0))
    tr = Tracker(1)
    out = tr.load([0], [ep])
    acc = []
    while not out.done[0]:
        acc.append((out.t_s[0] + out.features["next_dt_s"][0], out.features["next_los_accel_m_s2"][0] / G0_M_S2))
        out = tr.step(0.5 * G0_M_S2)
    t, a = np.array(acc).T
    assert a[np.argmin(np.abs(t - 26.0))] > 2.0 and a[np.argmin(np.abs(t - 66.0))] < -2.0   # first look of each change
    first_leg = t < 25.0          # before the first change (after it the 0.5 g filter still lags the 490 m/s jump)
    assert first_leg.sum() >= 5 and np.all(np.abs(a[first_leg]) < 1.5)


def test_detached_row_fed_look_by_look_is_the_tracker():
    """Tracker.detached(row) then feed(look) + step per look (plots as they come) gives the batched tracker's
    estimates and past features bit for bit; the preview is 0 (no next look) and preview_next_plot gives it."""
    from radar_env.filters import kernels as _k
    from radar_env.filters.tracking import preview_next_plot
    from radar_env.sim.looks import LOOK_COLUMNS

    eps = [_episode(11), _episode(12, pd=0.8)]
    tr = Tracker(2)
    tr.load(np.arange(2), eps)
    one = tr.detached(1)
    e = eps[1]
    assert one.B == 1 and one.k[0] == tr.k[1]
    for _ in range(25):
        k = int(tr.k[1])
        look = np.empty(_k.W_LOOK)
        for f, (c, tail) in LOOK_COLUMNS.items():
            look[c:c + (int(np.prod(tail)) if tail else 1)] = np.asarray(getattr(e, f)[k], dtype=np.float64).ravel()
        nxt = {f: np.asarray(getattr(e, f)[k + 1])[None] for f in ("t_s", "detected", "z_m", "R_m2", "bearing_rad",
                                                                  "radial_velocity_m_s", "site_xy_m",
                                                                  "radial_velocity_noise_std_m_s")}
        ref = tr.step(0.5 * G0_M_S2)
        one.feed([0], look[None])
        out = one.step(0.5 * G0_M_S2)
        np.testing.assert_array_equal(out.x[0], ref.x[1])
        np.testing.assert_array_equal(out.P[0], ref.P[1])
        for key in _k.BANK_FLOAT_KEYS:
            np.testing.assert_array_equal(out.features[key][0], ref.features[key][1], err_msg=key)
        assert all(out.features[key][0] == 0.0 for key in _k.PREVIEW_KEYS)
        prev = preview_next_plot(one.x, one.P, one.t_last, nxt)
        for key in _k.PREVIEW_KEYS:
            np.testing.assert_array_equal(prev[key][0], ref.features[key][1], err_msg=key)
    assert not e.detected[int(tr.k[1]) - 25:int(tr.k[1])].all()     # missed looks were fed too
