"""User trackers: registration (names, clashes), the per-episode protocol and its common start, the CLI's
--tracker-module, and the Stone Soup example equal to our kf at the same q."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from agents.evaluation import evaluate as ev
from agents.evaluation.suites import draw_suite
from baselines import registry
from baselines.registry import register_tracker, run_tracker, tracker_names
from baselines.trackers import TrackRun
from baselines.tuning import pooled_rmse
from baselines.user_trackers import common_track_start, looks_of
from radar_env.sim.episode import stack_episodes

ROOT = Path(__file__).resolve().parents[1]
QUICK = ["--no-plots", "--quiet"]


@pytest.fixture(autouse=True)
def clean_registry(monkeypatch):
    """Every test registers into a copy of the registry, so no user tracker leaks into other tests."""
    monkeypatch.setattr(registry, "_RUNNERS", dict(registry._RUNNERS))
    monkeypatch.setattr(registry, "_USER", set(registry._USER))


def hold_last_plot(looks, start):
    """A toy user tracker: the latest plot (the start's position until the first plot after it), zero velocity."""
    K = looks.t_s.shape[0]
    x, P = np.full((K, 4), np.nan), np.full((K, 4, 4), np.nan)
    last = start.x[:2].copy()
    for k in range(start.index, K):
        if looks.detected[k]:
            last = looks.z_m[k]
        x[k] = [last[0], last[1], 0.0, 0.0]
        P[k] = np.diag([1e4, 1e4, 1e6, 1e6])
    return x, P


@pytest.fixture(scope="module")
def eps():
    return draw_suite("seed002_two_radars", 3, seed=4242)


def test_register_and_run_a_per_episode_tracker(eps):
    register_tracker("hold", hold_last_plot)
    assert "hold" in tracker_names() and "hold" not in registry.TRACKER_NAMES
    run = run_tracker("hold", eps)
    kf = run_tracker("kf_tuned", eps)
    np.testing.assert_array_equal(run.start_index, kf.start_index)     # the common start's scored looks
    b = stack_episodes(eps)
    for i, s in enumerate(run.start_index):
        det = np.flatnonzero(b.detected[i, s:]) + s
        np.testing.assert_array_equal(run.x[i, det, :2], b.z_m[i, det])
        assert np.isnan(run.x[i, :s]).all()
    starts = common_track_start(eps)
    np.testing.assert_array_equal([s.index for s in starts], kf.start_index)
    np.testing.assert_array_equal(starts[0].x, kf.x[0, kf.start_index[0] - 1])


def test_looks_carry_no_truth(eps):
    looks = looks_of(eps[0])
    assert not any("truth" in f or "maneuver" in f for f in looks._fields)


@pytest.mark.parametrize("name, match", [("imm2", "built-in"), ("policy", "built-in"), ("a,b", "name must be"),
                                         ("", "name must be"), ("1st", "name must be"), (3, "name must be"),
                                         ("x" * 65, "name must be")])
def test_register_rejects_bad_or_taken_names(name, match):
    with pytest.raises(ValueError, match=match):
        register_tracker(name, hold_last_plot)


def test_register_clash_and_overwrite():
    register_tracker("mine", hold_last_plot)
    with pytest.raises(ValueError, match="already registered; pass overwrite=True"):
        register_tracker("mine", hold_last_plot)
    register_tracker("mine", hold_last_plot, overwrite=True)
    with pytest.raises(ValueError, match="must be callable"):
        register_tracker("other", 42)
    for flag in ("overwrite", "batch"):         # "no" is truthy: it replaced the tracker silently
        with pytest.raises(ValueError, match=f"register_tracker: {flag} must be True or False, got 'no'"):
            register_tracker("mine", hold_last_plot, **{flag: "no"})


@pytest.mark.parametrize("episodes, match", [(5, "got int"), ([], "got list"), ([5], r"got list of \['int'\]")])
def test_run_tracker_names_what_episodes_must_be(episodes, match):
    with pytest.raises(ValueError, match=f"run_tracker: episodes must be a non-empty list of .*Episode.*{match}"):
        run_tracker("kf_tuned", episodes)
    with pytest.raises(ValueError, match=r"unknown tracker \['kf'\]"):
        run_tracker(["kf"], draw_suite("random", 1))


def test_wrong_output_shapes_name_the_tracker(eps):
    register_tracker("short", lambda looks, start: (np.zeros((2, 4)), np.zeros((2, 4, 4))))
    with pytest.raises(ValueError, match="tracker 'short' must return x of shape"):
        run_tracker("short", eps)
    register_tracker("notuple", lambda looks, start: None)
    with pytest.raises(ValueError, match="must return \\(x, P\\)"):
        run_tracker("notuple", eps)


def test_batch_tracker_is_scored_from_the_common_start(eps):
    def batch(episodes, cfg):
        r = run_tracker("kf_low", episodes)
        return TrackRun("whatever", r.x, r.P, np.zeros_like(r.start_index), r.q_m_s2)

    register_tracker("batchy", batch, batch=True)
    run = run_tracker("batchy", eps)
    assert run.name == "batchy"
    np.testing.assert_array_equal(run.start_index, run_tracker("kf_low", eps).start_index)


# ------------------------------------------------------------------------------------------------ CLI
USER_MODULE = '''
import numpy as np
from baselines.registry import register_tracker

def hold(looks, start):
    K = looks.t_s.shape[0]
    x, P = np.full((K, 4), np.nan), np.full((K, 4, 4), np.nan)
    last = start.x[:2].copy()
    for k in range(start.index, K):
        if looks.detected[k]:
            last = looks.z_m[k]
        x[k] = [last[0], last[1], 0.0, 0.0]
        P[k] = np.diag([1e4, 1e4, 1e6, 1e6])
    return x, P

register_tracker("{name}", hold)
'''


def test_cli_evaluates_a_user_tracker_from_a_file(tmp_path):
    mod = tmp_path / "my_tracker.py"
    mod.write_text(USER_MODULE.format(name="hold_cli"))
    out = tmp_path / "m.json"
    res = ev.main(["--tracker-module", str(mod), "--trackers", "hold_cli,kf_tuned", "--scenario", "kim_lee_accel",
                   "--runs", "3", "--json", str(out), *QUICK])
    m = res["kim_lee_accel"]["trackers"]
    assert np.isfinite(m["hold_cli"]["pos_rmse_m"]) and m["hold_cli"]["pos_rmse_m"] != m["kf_tuned"]["pos_rmse_m"]
    assert json.loads(out.read_text())["meta"]["tracker_modules"] == [str(mod)]


@pytest.mark.parametrize("args, text", [
    (["--tracker-module", "no_such_module_xyz"], "cannot be imported"),
    (["--tracker-module", "/nonexistent/t.py"], "does not exist"),
    (["--trackers", "not_registered_abc"], "user trackers need --tracker-module"),
])
def test_cli_user_tracker_errors_are_one_line(args, text):
    with pytest.raises(SystemExit) as e:
        ev.main(args + ["--trackers", "kf_low"] * ("--trackers" not in args) + ["--scenario", "kim_lee_accel",
                                                                             "--runs", "2", *QUICK])
    msg = str(e.value)
    assert msg.startswith("error: --") and "\n" not in msg and text in msg, msg


def test_cli_module_that_raises_and_ray_workers_are_refused(tmp_path):
    bad = tmp_path / "bad.py"
    bad.write_text("raise RuntimeError('broken\\nsecond line')\n")
    with pytest.raises(SystemExit) as e:
        ev.main(["--tracker-module", str(bad), "--trackers", "kf_low", "--scenario", "kim_lee_accel", *QUICK])
    assert "raised on import: RuntimeError: broken" in str(e.value) and "\n" not in str(e.value)
    good = tmp_path / "good.py"
    good.write_text(USER_MODULE.format(name="hold_ray"))
    with pytest.raises(SystemExit) as e:
        ev.main(["--tracker-module", str(good), "--trackers", "hold_ray", "--workers", "2", *QUICK])
    assert "--workers 1" in str(e.value)


# ------------------------------------------------------------------------------------------------ Stone Soup
pytest.importorskip("stonesoup")


def test_stonesoup_kf_equals_our_kf_at_the_same_q(eps):
    from baselines.interop_stonesoup import NAME, StoneSoupKF
    register_tracker(NAME, StoneSoupKF(), overwrite=True)
    for suite in (eps, draw_suite("random", 3, seed=99)):     # two sites; random (missed looks)
        b = stack_episodes(suite)
        ss, kf = run_tracker(NAME, suite), run_tracker("kf_tuned", suite)
        np.testing.assert_array_equal(ss.start_index, kf.start_index)
        used = b.valid & (np.arange(b.valid.shape[1])[None] >= kf.start_index[:, None])
        np.testing.assert_allclose(ss.x[used], kf.x[used], rtol=1e-6, atol=1e-6)
        np.testing.assert_allclose(ss.P[used], kf.P[used], rtol=1e-6, atol=1e-6)
        assert pooled_rmse(b, ss) == pytest.approx(pooled_rmse(b, kf), rel=1e-6)
    assert not stack_episodes(draw_suite("random", 3, seed=99)).detected.all()   # missed looks were exercised


def test_stonesoup_kf_through_the_cli(tmp_path):
    """As a user runs it: a fresh process, --tracker-module baselines.interop_stonesoup."""
    out = tmp_path / "m.json"
    cmd = [sys.executable, "-m", "agents.cli", "evaluate", "--tracker-module", "baselines.interop_stonesoup",
           "--trackers", "stonesoup_kf,kf_tuned", "--scenario", "random", "--runs", "3", "--json", str(out), *QUICK]
    subprocess.run(cmd, cwd=ROOT, check=True, capture_output=True, text=True, timeout=300)
    m = json.loads(out.read_text())["suites"]["random"]["trackers"]
    assert m["stonesoup_kf"]["pos_rmse_m"] == pytest.approx(m["kf_tuned"]["pos_rmse_m"], rel=1e-6)


@pytest.mark.parametrize("kw, match", [({"radar": 5}, r"radar must be a radar_env.sim.radar.Radar"),
                                       ({"random_config": {"first_leg_min_s": 0}},
                                        r"random_config must be a radar_env.sim.scenario.RandomScenarioConfig")])
def test_draw_suite_names_a_wrong_radar_or_random_config(kw, match):
    """(an AttributeError from inside the draw before)"""
    with pytest.raises(ValueError, match=match):
        draw_suite("random", 2, **kw)
