"""The paper checks compute the papers' own definitions (issue 18): Adrian's sheet, Bizup's figures 7/8 and CKF,
Kim & Lee's 1-D scenario; and docs/paper_checks.md is rendered from docs/paper_checks.json alone."""

import json
from pathlib import Path

import numpy as np
import pytest
from filterpy.kalman import KalmanFilter

from agents.reports import paper_checks
from agents.reports.paper_adrian import (OMEGA_RAD_S, T_S, V0_M_S, adrian_alg1, adrian_geometry, adrian_kf, adrian_plots,
                                 adrian_quantities, adrian_reference_turn_rate, adrian_truth, adrian_worksheet)
from agents.reports.paper_bizup import bizup_errors, ckf_fma, fma_threshold, phase_masks
from agents.reports.paper_kim_lee import kim_lee_1d_check, kim_lee_truth
from agents.evaluation.suites import draw_suite
from baselines.registry import run_tracker
from radar_env.common.units import NM_M

ROOT = Path(__file__).resolve().parents[1]


# ------------------------------------------------------------------------------------------------ Adrian
def test_adrian_geometry_is_his_printed_n():
    n1, n2, n3, n = adrian_geometry()
    assert (n1, n) == (54, 130)                      # his sheet prints n = 130
    assert n2 - n1 == pytest.approx(np.pi / (OMEGA_RAD_S * T_S))   # 180 deg at 3 deg/s = 12 looks


def test_adrian_truth_has_his_position_random_walk():
    rng = np.random.default_rng(1)
    x, w = adrian_truth(rng, 4)
    assert x.shape == (4, 6241, 4)                   # N = 130 x 48 = 6240, looks 0..N
    assert np.allclose(np.hypot(x[..., 2], x[..., 3]), V0_M_S)   # the walk is on positions only
    # residual of the kinematic step: the same draw on x and y, sd sqrt(sigma_v), sigma_v = 0.1 * 9.81 * 25 / 2
    from agents.reports.paper_adrian import _ccw
    pred = np.einsum("kij,bkj->bki", _ccw(w[1:]), x[:, :-1])
    res = x[:, 1:, :2] - pred[..., :2]
    assert np.allclose(res[..., 0], res[..., 1])
    assert np.std(res[..., 0]) == pytest.approx(np.sqrt(12.263), rel=0.03)
    x0, _ = adrian_truth(np.random.default_rng(1), 1, random_walk=False)
    assert np.allclose(x0[0, -1, :2], x0[0, 0, :2], atol=1e-6)   # 48 leaves of 30 deg: back to the start


def test_adrian_reference_turn_rate_is_the_backward_difference():
    x, w = adrian_truth(np.random.default_rng(0), 1, leaves=1, random_walk=False)
    wx = adrian_reference_turn_rate(x)[0]
    n1 = adrian_geometry()[0]
    # the step n1-1 -> n1 is the first turning step: his wx_{n1} = omega, wx_{n1-1} = 0 (ours used to flag the
    # look one step early, the rate of the segment starting at the look)
    assert wx[n1] == pytest.approx(OMEGA_RAD_S)
    assert wx[n1 - 1] == pytest.approx(0.0, abs=1e-12)
    assert np.allclose(wx[1:], w[1:])


def test_adrian_turn_rate_errors_are_absolute_and_positions_use_stdev():
    x, _ = adrian_truth(np.random.default_rng(0), 1, leaves=1, random_walk=False)
    K = x.shape[1]
    wx = adrian_reference_turn_rate(x)
    e = np.radians(0.5) * (-1.0) ** np.arange(K)     # signed error alternating +-0.5 deg/s
    off = np.zeros_like(x)
    off[..., 0] = 30.0                               # a constant 30 m offset: distance constant
    z = x[..., :2] + np.stack([np.zeros(K), 10.0 + np.arange(K) % 3], axis=-1)   # plot distances 10-12 m
    q = adrian_quantities(x, z, x + off, wx + e, x + 2 * off)
    assert q["alg2_std_deg_s"][0] == pytest.approx(0.0, abs=1e-9)      # stdev(|error|) = 0
    assert q["alg2_max_deg_s"][0] == pytest.approx(0.5)
    assert q["signed_alg2_std_deg_s"][0] == pytest.approx(0.5, rel=1e-3)
    assert q["alg2_pos_std_nm"][0] == pytest.approx(0.0, abs=1e-9)     # Stdev of a constant distance
    assert q["rms_alg2_m"][0] == pytest.approx(30.0)
    assert q["linear_pos_max_nm"][0] == pytest.approx(60.0 / NM_M)


def test_adrian_alg1_on_noise_free_plots_follows_the_reference_with_its_delay():
    x, _ = adrian_truth(np.random.default_rng(0), 1, leaves=1, random_walk=False)
    w1 = adrian_alg1(x[..., :2])[0]
    wx = adrian_reference_turn_rate(x)[0]
    n1 = adrian_geometry()[0]
    assert np.isnan(w1[:5]).all() and np.isfinite(w1[5:]).all()
    assert np.allclose(w1[5:n1], 0.0, atol=1e-9) and np.allclose(wx[5:n1], 0.0, atol=1e-12)
    assert w1[n1 + 6] == pytest.approx(OMEGA_RAD_S, rel=1e-6)           # inside the turn, chord headings turn too


def _filterpy_adrian(z, R, sigma_a, n, turn_rate):
    """Independent oracle: his KF(n) / kf(0) in his state order (x, vx, y, vy) with FilterPy."""
    def F(w):
        if w == 0:
            return np.array([[1, T_S, 0, 0], [0, 1, 0, 0], [0, 0, 1, T_S], [0, 0, 0, 1.0]])
        s, c = np.sin(w * T_S), np.cos(w * T_S)
        return np.array([[1, s / w, 0, -(1 - c) / w], [0, c, 0, -s], [0, (1 - c) / w, 1, s / w], [0, s, 0, c]])
    kf = KalmanFilter(dim_x=4, dim_z=2)
    kf.H = np.array([[1.0, 0, 0, 0], [0, 0, 1, 0]])
    kf.x = np.array([z[1, 0], (z[1, 0] - z[0, 0]) / T_S, z[1, 1], (z[1, 1] - z[0, 1]) / T_S])
    r = max(R[1, 0, 0], R[1, 1, 1])
    kf.P = np.diag([r, 2 * r / T_S ** 2, r, 2 * r / T_S ** 2])
    q1 = np.array([[T_S ** 4 / 4, T_S ** 3 / 2], [T_S ** 3 / 2, T_S ** 2]])
    kf.Q = np.kron(np.eye(2), q1) * sigma_a ** 2
    ys, w = [None, kf.x.copy()], np.zeros(len(z))
    for i in range(2, len(z)):
        kf.F = F(w[i - 1] if turn_rate else 0.0)
        kf.predict()
        kf.update(z[i], R=R[i])
        ys.append(kf.x.copy())
        if turn_rate and i > n:
            h = lambda y: np.arctan2(y[3], y[1])  # noqa: E731
            d = h(ys[i]) - h(ys[i - n])
            w[i] = (d + 2 * np.pi * (d <= -np.pi) - 2 * np.pi * (d > np.pi)) / (n * T_S)
    return np.array([[y[0], y[2], y[1], y[3]] for y in ys[1:]]), w


@pytest.mark.parametrize("turn_rate", [False, True])
def test_adrian_kf_matches_filterpy_with_his_start(turn_rate):
    rng = np.random.default_rng(3)
    x, _ = adrian_truth(rng, 1, leaves=1)
    z, R = adrian_plots(rng, x)
    y, w = adrian_kf(z, R, 0.1 * 9.81, turn_rate=turn_rate)
    y_ref, w_ref = _filterpy_adrian(z[0], R[0], 0.1 * 9.81, 4, turn_rate)
    assert np.allclose(y[0, 1:], y_ref, rtol=0, atol=1e-6)
    assert np.allclose(w[0], w_ref, atol=1e-12)


def test_adrian_worksheet_reproduces_his_plot_noise_and_is_deterministic():
    a = adrian_worksheet(runs=2, seed=5, sigma_a_g=(0.1,))[0.1]
    b = adrian_worksheet(runs=2, seed=5, sigma_a_g=(0.1,))[0.1]
    for k in a:
        assert np.array_equal(a[k], b[k]), k
    assert np.all(np.abs(a["plot_std_nm"] - 0.023) <= 0.0015)     # paper: sigma_zx / 1852 = 0.023
    assert np.all(np.abs(a["alg1_std_deg_s"] - 0.579) <= 0.03)     # paper: stdev(ewr4) = 0.579 deg/s
    with pytest.raises(ValueError, match="runs"):
        adrian_worksheet(runs=0)


# ------------------------------------------------------------------------------------------------ Bizup
@pytest.fixture(scope="module")
def bizup_eps():
    return draw_suite("bizup2002", 6, seed=10_000_000)


def test_ckf_never_switches_at_5_nm_and_equals_the_baseline(bizup_eps):
    run, fma = ckf_fma(bizup_eps)
    assert not run.declared.any()
    assert np.nanmax(fma) < 5 * NM_M / 2               # the FMA peaks far below 5 NM at 0.1 deg
    low = run_tracker("kf_low", bizup_eps)
    assert np.array_equal(run.x, low.x, equal_nan=True)
    run2, _ = ckf_fma(bizup_eps, threshold_m=0.5 * np.nanmax(fma))
    assert run2.declared.any()


def test_phase_masks_split_each_turn_and_the_60_s_after_it(bizup_eps):
    from radar_env.sim.episode import stack_episodes
    batch = stack_episodes(bizup_eps)
    m = phase_masks(batch, np.full(batch.batch_size, 14))
    t = batch.t_s[0]
    assert list(t[m["turn1"][0]]) == [290.0, 300.0, 310.0, 320.0]      # the 40 s right turn from 290 s
    assert list(t[m["turn2"][0]]) == [610.0, 620.0, 630.0]             # the 30 s left turn from 610 s
    assert t[m["after1"][0]].min() > 320 and t[m["after1"][0]].max() <= 320 + 60
    assert not (m["first_leg"] & (batch.t_s >= 290)).any()
    assert np.array_equal(m["turn1"] | m["turn2"], m["maneuver"])
    assert np.array_equal(m["after1"] | m["after2"], m["after"])


def test_fma_threshold_rule():
    fma = np.array([[100.0, 200.0, 900.0, 300.0], [150.0, 250.0, 700.0, 400.0]])
    m = {"first_leg": np.array([[True, True, False, False]] * 2),
         "maneuver": np.array([[False, False, True, True]] * 2)}
    thr, first, peaks = fma_threshold(fma, m)
    assert first == 250.0 and list(peaks) == [900.0, 700.0] and thr == pytest.approx(475.0)
    fma[0, 0] = 800.0                                  # overlap: median turn peak
    assert fma_threshold(fma, m)[0] == pytest.approx(800.0)


def test_bizup_speed_error_is_the_magnitude_error():
    class B:
        truth = np.array([[[0.0, 0.0, 100.0, 0.0]]])

    class Run:
        x = np.array([[[0.0, 0.0, 0.0, 100.0]]])       # right speed, wrong direction
    e = bizup_errors(B, Run)
    assert e["speed_m_s"][0, 0] == pytest.approx(0.0)
    assert e["vel_m_s"][0, 0] == pytest.approx(np.sqrt(2) * 100)


# ------------------------------------------------------------------------------------------------ Kim & Lee
def test_kim_lee_truth_is_their_table_1():
    t = np.arange(101.0)
    x, v, a = kim_lee_truth(t)
    assert v[0] == 120.0 and v[-1] == pytest.approx(120.0)
    assert v.max() == pytest.approx(610, abs=1)        # "maximum speed of about 610 m/s"
    assert np.array_equal(np.flatnonzero(a > 0), np.arange(26, 36))      # 5 g over 26-35 s
    assert np.array_equal(np.flatnonzero(a < 0), np.arange(66, 76))
    fine = np.linspace(0, 100, 100001)
    xf, vf, _ = kim_lee_truth(fine)
    assert np.allclose(np.gradient(xf, fine)[1:-1], vf[1:-1], atol=0.05)   # position integrates velocity


def test_kim_lee_1d_check_is_deterministic_and_shows_the_conventional_lag():
    a = kim_lee_1d_check(runs=50, seed=2)
    b = kim_lee_1d_check(runs=50, seed=2)
    assert a["trackers"] == b["trackers"]
    names = list(a["trackers"])
    conv = a["trackers"][names[0]]
    assert conv["npe_accel"] > 1 > conv["npe_cv_first_leg"]
    for s in a["trackers"].values():
        assert all(np.isfinite(v) for v in s.values())
    with pytest.raises(ValueError, match="lead_in_s"):
        kim_lee_1d_check(runs=5, lead_in_s=-1)
    with pytest.raises(ValueError, match="runs"):
        kim_lee_1d_check(runs=1)


# ------------------------------------------------------------------------------------------------ rendering
def test_paper_checks_md_is_rendered_from_the_committed_json():
    data = json.loads((ROOT / "docs" / "paper_checks.json").read_text())
    assert (ROOT / "docs" / "paper_checks.md").read_text() == paper_checks.render_markdown(data)


def test_every_check_table_has_the_four_columns():
    data = json.loads((ROOT / "docs" / "paper_checks.json").read_text())
    text = paper_checks.render_markdown(data)
    heads = [ln for ln in text.splitlines() if ln.startswith("| claim |") or ln.startswith("| quantity | paper")]
    assert len(heads) >= 4
    for h in heads:
        assert "paper's definition" in h and "our definition" in h and h.rstrip().endswith("verdict |"), h
    assert "no random" not in text and "does not say over which looks" not in text   # the old, wrong note


def test_non_finite_quantity_is_an_error():
    with pytest.raises(ValueError, match="non-finite"):
        paper_checks._stats([1.0, np.nan])
    with pytest.raises(ValueError, match=r"data\.bizup\.phases\.cmin\.all\.pos_m_mean is nan"):
        paper_checks._check_finite({"bizup": {"phases": {"cmin": {"all": {"pos_m_mean": float("nan")}}}}})
    paper_checks._check_finite({"bizup": {"convergence_s": {"cmin": [float("nan")]}}})   # "never" is allowed
    paper_checks._check_finite(json.loads((ROOT / "docs" / "paper_checks.json").read_text()))


# ------------------------------------------------------------------------------------------------ review fixes
def _committed():
    return json.loads((ROOT / "docs" / "paper_checks.json").read_text())


def test_committed_paper_checks_json_is_not_stale():
    # reruns the cheap sections with the JSON's own seed and run counts: exact equality (deterministic code)
    data = _committed()
    assert paper_checks.stale_entries(data) == []
    old = json.loads(json.dumps(data))           # a copy as older code would have written one value
    tr = old["kim_lee_paper_def"]["trackers"]["adaptive (eq 15 as printed)"]
    tr["npe_cv_first_leg"] = np.nextafter(tr["npe_cv_first_leg"], np.inf)
    old["bizup_cmin"]["delay_turn2_scans"][3] = float("nan")
    stale = paper_checks.stale_entries(old)
    assert len(stale) == 2
    assert "npe_cv_first_leg" in stale[0] and "delay_turn2_scans[3]" in stale[1]


def _kim_lee_verdict(data):
    line = [ln for ln in paper_checks.render_markdown(data).splitlines()
            if ln.startswith("| the adaptive tracker on the constant-velocity legs")]
    assert len(line) == 1
    return line[0]


def test_kim_lee_cv_verdict_needs_both_constant_velocity_legs_and_computes_its_note():
    data = _committed()
    tr = data["kim_lee_paper_def"]["trackers"]["adaptive (eq 15 as printed)"]
    tr["npe_cv_first_leg"], tr["npe_cv_last_leg"] = 0.9, 1.04       # first leg fine, last leg not
    tr["median_q_m_s2_first_leg"], tr["median_q_m_s2_last_leg"] = 12.5, 34.5
    line = _kim_lee_verdict(data)
    assert "not reproduced: worse than the raw plots on the last leg" in line
    assert "first leg 12.5, last leg 34.5 m/s^2" in line               # computed from the numbers
    tr["npe_cv_last_leg"] = 0.95
    line = _kim_lee_verdict(data)
    assert "| reproduced (NPE < 1 on both" in line and "worse" not in line


def test_bizup_delay_verdict_counts_runs_that_never_declare_the_turn():
    data = _committed()
    d = data["bizup_cmin"]["delay_turn1_scans"]
    d[:] = [1] * len(d)
    d[0] = float("nan")                               # one run never declares turn 1
    line = [ln for ln in paper_checks.render_markdown(data).splitlines() if ln.startswith("| delay to declare turn 1")]
    assert f"never declared: 1 of {len(d)} runs" in line[0] and line[0].endswith("| not reproduced |")
    d[0] = 1
    line = [ln for ln in paper_checks.render_markdown(data).splitlines() if ln.startswith("| delay to declare turn 1")]
    assert f"never declared: 0 of {len(d)} runs" in line[0] and line[0].endswith("| reproduced |")


def test_bizup_turn_2_speed_convergence_is_judged_under_both_readings():
    data = _committed()
    conv = data["bizup"]["convergence_s"]
    conv["cmin"]["speed_m_s"], conv["kf_low"]["speed_m_s"] = [100.0, 150.0], [230.0, 120.0]   # longer than both
    text = paper_checks.render_markdown(data)
    assert "turn 2 (a) reproduced (150 vs 120 s of the baseline); turn 2 (b) reproduced (150 vs 100 s" in text
    conv["cmin"]["speed_m_s"], conv["kf_low"]["speed_m_s"] = [120.0, 130.0], [230.0, 220.0]   # only (b)
    text = paper_checks.render_markdown(data)
    assert "turn 2 (a) not reproduced (130 vs 220 s of the baseline); turn 2 (b) reproduced (130 vs 120 s" in text
    conv["cmin"]["speed_m_s"] = [120.0, float("nan")]                                          # never back
    assert "turn 2 (a) reproduced (- vs 220 s" in paper_checks.render_markdown(data)


def test_bizup_variance_across_runs_excludes_the_mean_curve_and_decides_the_claim():
    from agents.reports.paper_bizup import _var_over_runs
    rng = np.random.default_rng(0)
    e = np.linspace(0.0, 100.0, 40)[None, :] + rng.standard_normal((50, 40))   # mean curve moves, spread 1
    mk = np.ones_like(e, dtype=bool)
    mk[0, :10] = False
    v = _var_over_runs(e, mk)
    ref = np.mean([np.var(e[mk[:, k], k], ddof=1) for k in range(40)])
    assert v == pytest.approx(ref, rel=1e-12) and v < 2 < np.var(e[mk])   # pooled contains the ramp (~850)
    assert np.isnan(_var_over_runs(e, np.zeros_like(mk)))                 # never a silent zero
    data = _committed()
    ph = data["bizup"]["phases"]
    ph["imm2_bizup"]["all"]["pos_m_var_runs"] = 1.5 * ph["cmin"]["all"]["pos_m_var_runs"]
    ph["imm2_bizup"]["all"]["pos_m_var_pooled"] = 1.0 * ph["cmin"]["all"]["pos_m_var_pooled"]
    line = [ln for ln in paper_checks.render_markdown(data).splitlines()
            if ln.startswith("| IMM position-error variance")][0]
    assert "across runs 1.50 overall" in line and "pooled: 1.00" in line and "| reproduced overall" in line


def test_ckf_tuned_threshold_is_chosen_on_a_disjoint_seed_block():
    from agents.reports.paper_bizup import TUNING_SEED_OFFSET, bizup_figures_check
    from radar_env.sim.episode import stack_episodes
    seed = 10_000_000
    r = bizup_figures_check(runs=3, seed=seed)["ckf"]
    assert r["threshold_tuned_seed"] == seed + TUNING_SEED_OFFSET and r["threshold_tuned_runs"] == 3
    tune = draw_suite("bizup2002", 3, seed=seed + TUNING_SEED_OFFSET)
    run, fma = ckf_fma(tune)
    thr, first, peaks = fma_threshold(fma, phase_masks(stack_episodes(tune), run.start_index))
    assert r["threshold_tuned_m"] == thr and r["threshold_tuned_first_leg_max_m"] == first
    scored = draw_suite("bizup2002", 3, seed=seed)
    run_s, fma_s = ckf_fma(scored)
    assert fma_threshold(fma_s, phase_masks(stack_episodes(scored), run_s.start_index))[0] != thr
    with pytest.raises(ValueError, match="runs must be <= 100000"):
        bizup_figures_check(runs=TUNING_SEED_OFFSET + 1)
