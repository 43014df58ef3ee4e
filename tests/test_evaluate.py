"""Evaluation: common random numbers, metrics on hand-computed cases, the CLI and its JSON schema."""

import json

import gymnasium as gym
import numpy as np
import pytest
from gymnasium.utils import seeding

import radar_env  # noqa: F401
from agents.evaluation.evaluate import main as evaluate_main
from agents.evaluation.metrics import NEES_95_4DOF, evaluate_run, ratio_ci, region_masks
from agents.evaluation.suites import draw_suite
from baselines.registry import run_tracker
from baselines.trackers import TrackRun, run_q_policy
from radar_env.envs.env import draw_setup_and_episode
from radar_env.sim.episode import stack_episodes
from radar_env.common.units import G0_M_S2


def test_suite_draw_is_deterministic_and_suites_differ():
    a = draw_suite("random", 3, seed=42)
    b = draw_suite("random", 3, seed=42)
    c = draw_suite("random", 3, seed=43)
    for x, y in zip(a, b):
        assert np.array_equal(x.z_m, y.z_m, equal_nan=True) and np.array_equal(x.truth, y.truth)
    assert np.array_equal(a[1].truth, c[0].truth)       # run i uses seed S + i (documented)
    assert not np.array_equal(a[0].truth, a[1].truth)
    s1, s2 = draw_suite("bizup2002", 1, seed=42), draw_suite("seed002_course_changes", 1, seed=42)
    assert not np.allclose(s1[0].z_m[:5], s2[0].z_m[:5], equal_nan=True)


def test_evaluation_replays_exactly_what_the_env_saw():
    """Common random numbers end to end: the env's episode, replayed through the evaluation's chain with the
    same q, gives the env's estimates bit for bit."""
    env = gym.make("RadarTrack-v0")
    obs, info = env.reset(seed=2024)
    est = [info["estimate"]]
    while True:
        obs, r, term, trunc, info = env.step(4)   # q = 0.03 g
        est.append(info["estimate"])
        if term or trunc:
            break
    ep = draw_setup_and_episode("random", None, None, seeding.np_random(2024)[0])
    run = run_q_policy([ep], lambda o: np.full(o.shape[0], env.unwrapped.q_levels_m_s2[4]), "kf")
    k0 = int(run.start_index[0]) - 1
    got = run.x[0, k0:k0 + len(est)]
    assert np.array_equal(got, np.array(est))


def test_two_trackers_see_identical_plots_and_start():
    eps = draw_suite("bizup2002", 3, seed=9)
    lo, hi = run_tracker("kf_low", eps), run_tracker("kf_high", eps)
    k = lo.start_index - 1
    rows = np.arange(3)
    assert np.array_equal(lo.x[rows, k], hi.x[rows, k])        # same two-hit start and warm-up
    # a KF's posterior minus prior is K (z - H x-): with identical z, the implied plot is the same for both
    assert np.array_equal(lo.start_index, hi.start_index)


def _fake(truth_offsets, maneuvering, P_scale=1.0):
    """A batch of 2 runs x 6 looks with truth at 0 and estimates offset by given position errors."""
    eps = draw_suite("kim_lee_accel", 2, seed=1)
    batch = stack_episodes(eps)
    B, K = 2, 6
    sl = {f: getattr(batch, f)[:, :K] for f in ("t_s", "site_index", "site_xy_m", "truth", "truth_accel_m_s2",
                                               "truth_turn_rate_rad_s", "detected", "range_m", "bearing_rad",
                                               "radial_velocity_m_s", "z_m", "R_m2", "range_noise_std_m",
                                               "bearing_noise_std_rad", "radial_velocity_noise_std_m_s")}
    sl["maneuvering"] = np.asarray(maneuvering, dtype=bool)
    sl["t_s"] = np.tile(np.arange(K) * 100.0, (B, 1))           # 100 s apart: 'after' covers one look
    b2 = type(batch)(names=("a", "b"), valid=np.ones((B, K), bool), n_looks=np.full(B, K), **sl)
    x = b2.truth.copy()
    x[..., 0] += truth_offsets
    run = TrackRun("fake", x, np.tile(np.eye(4) * P_scale, (B, K, 1, 1)), np.zeros(B, dtype=np.int64),
                   np.full((B, K), np.nan))
    return b2, run


def test_metrics_on_hand_computed_case():
    off = np.array([[3.0, 4.0, 0.0, 0.0, 0.0, 12.0], [0.0, 0.0, 0.0, 5.0, 0.0, 0.0]])
    man = np.array([[0, 1, 0, 0, 0, 0], [0, 0, 0, 1, 0, 0]])
    batch, run = _fake(off, man)
    m = evaluate_run(batch, run, n_boot=100)
    assert m["pos_rmse_m"] == pytest.approx(np.sqrt((9 + 16 + 144 + 25) / 12))
    assert m["pos_rmse_m_maneuver"] == pytest.approx(np.sqrt((16 + 25) / 2))
    masks = region_masks(batch, run.start_index, after_window_s=60.0)
    assert masks["after"].sum() == 0                          # looks are 100 s apart
    masks = region_masks(batch, run.start_index, after_window_s=150.0)
    assert masks["after"][0, 2] and masks["after"][1, 4] and not masks["after"][0, 3]
    assert m["peak_pos_err_m"] == pytest.approx((12 + 5) / 2)
    nees = off ** 2                                             # P = I
    assert m["anees"] == pytest.approx(nees.mean() / 4)
    assert m["nees_in_95"] == pytest.approx((nees <= NEES_95_4DOF).mean())
    assert m["vel_rmse_m_s"] == 0.0
    lo, hi = m["pos_rmse_m_ci95"]
    assert lo <= m["pos_rmse_m"] <= hi


def test_ratio_ci_and_detection_stats():
    off = np.full((2, 6), 10.0)
    batch, run_a = _fake(off, np.zeros((2, 6)))
    _, run_b = _fake(2 * off, np.zeros((2, 6)))
    r, (lo, hi) = ratio_ci(batch, run_a, run_b, n_boot=200)
    assert r == pytest.approx(0.5) and lo == pytest.approx(0.5) and hi == pytest.approx(0.5)
    man = np.array([[0, 1, 1, 0, 0, 0], [0, 0, 0, 0, 0, 0]])
    batch, run = _fake(off, man)
    run.declared = np.zeros((2, 6), bool)
    run.declared[0, 2] = True                                   # one look after onset
    run.declared[1, 5] = True                                   # a false alarm on a straight look
    m = evaluate_run(batch, run, n_boot=50)
    assert m["detection_delay_looks"] == 1.0 and m["missed_maneuvers"] == 0.0
    straight = region_masks(batch, run.start_index)["straight"]
    assert m["false_alarm_rate"] == pytest.approx(1 / straight.sum())


def test_cli_json_schema_and_outputs(tmp_path, capsys):
    out = tmp_path / "m.json"
    evaluate_main(["--scenario", "kim_lee_accel", "--runs", "3", "--trackers", "kf_low,imm2,cmin", "--out",
                   str(tmp_path / "plots"), "--json", str(out), "--quiet"])
    d = json.loads(out.read_text())
    assert set(d) == {"meta", "suites"}
    s = d["suites"]["kim_lee_accel"]
    assert s["runs"] == 3 and set(s["trackers"]) == {"kf_low", "imm2", "cmin"}
    for m in s["trackers"].values():
        for key in ("pos_rmse_m", "pos_rmse_m_ci95", "pos_rmse_m_maneuver", "pos_rmse_m_after",
                    "pos_rmse_m_straight", "vel_rmse_m_s", "peak_pos_err_m", "anees", "nees_in_95",
                    "track_loss_rate", "npe"):
            assert key in m, key
    assert "detection_delay_looks" in s["trackers"]["cmin"] and "ratio_vs_imm2" in s
    assert s["ratio_vs_imm2"]["imm2"][0] == pytest.approx(1.0)
    assert sorted(p.name for p in (tmp_path / "plots").iterdir()) == [
        "kim_lee_accel_errors.png", "kim_lee_accel_features.png", "kim_lee_accel_maneuver.png", "kim_lee_accel_q.png",
        "kim_lee_accel_trajectory.png"]
    assert "kim_lee_accel" in capsys.readouterr().out


@pytest.mark.parametrize("args, msg", [
    (["--scenario", "nope"], "unknown scenario"),
    (["--trackers", "kf_low,bogus"], "unknown tracker"),
    (["--policy", "/nonexistent/policy.zip"], "does not exist"),
    (["--runs", "0"], "--runs"),
])
def test_cli_errors(args, msg):
    with pytest.raises(SystemExit, match=msg):
        evaluate_main(args + ["--no-plots", "--quiet"])


def test_cli_trajectory_csv(tmp_path):
    t = np.arange(0, 300.0, 5.0)
    p = tmp_path / "flight.csv"
    rows = ["t_s,x_m,y_m,vx_m_s,vy_m_s"] + [f"{ti},{150 * ti},{40000.0},150,0" for ti in t]
    p.write_text("\n".join(rows) + "\n")
    res = evaluate_main(["--trajectory", str(p), "--runs", "2", "--trackers", "kf_low", "--no-plots", "--quiet"])
    assert res["flight"]["trackers"]["kf_low"]["runs"] == 2
    bad = tmp_path / "bad.csv"
    bad.write_text("t_s,x_m,y_m,vx_m_s,vy_m_s\n0,0,0,100,0\n5,500,zz,100,0\n")
    with pytest.raises(SystemExit, match=r"line 3, column 'y_m'"):
        evaluate_main(["--trajectory", str(bad), "--runs", "1", "--no-plots", "--quiet"])


def test_q_policy_q_is_recorded():
    eps = draw_suite("kim_lee_accel", 1, seed=0)
    run = run_q_policy(eps, lambda o: np.full(o.shape[0], 0.5 * G0_M_S2), "kf")
    k = int(run.start_index[0])
    assert np.allclose(run.q_m_s2[0, k:eps[0].n_looks], 0.5 * G0_M_S2)
