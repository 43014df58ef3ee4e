"""Scaling out on Ray: evaluations split over workers give the serial numbers bit for bit; sweeps on Ray Tune write
their table and resume; without the 'scale' extra a one-line error names it. One local Ray (2 CPUs) per module."""

import csv
import functools
import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest

import agents.evaluation.parallel
import agents.training.train
from agents.evaluation.evaluate import BUNDLED_POLICY, evaluate
from agents.evaluation.metrics import jsonable
from agents.evaluation.runner import run_one
from agents.evaluation.evaluate import main as evaluate_main
from agents.evaluation.parallel import (_policy_blob, _policy_in_worker, chunk_bounds, concat_runs, episodes_digest,
                             merge_chunk_runs, run_suites_ray)
from agents.evaluation.suites import draw_suite
from agents.training.sweep import _trial, load_sweep_config, run_sweep
from agents.training.sweep import main as sweep_main
from baselines import registry
from baselines.registry import run_tracker

TINY_SWEEP = """
[sweep]
name = "tiny"
algo = "ppo"
[base]
n_timesteps = 2048
n_envs = 8
n_steps = 128
batch_size = 256
n_epochs = 1
eval_freq = 1024
checkpoint_freq = 1_000_000
select_on = ["random"]
[base.eval_scenarios]
random = 4
[base.policy_kwargs]
net_arch = [16, 16]
[space]
seed = [0, 1]
"""


FAIL_SEED = 10_000_000          # bizup2002, 4 runs from this seed: chunks (0, 2), (2, 4) on 2 workers


def _fail_on_run(i, episodes, cfg):
    """A kf_tuned that raises on any batch holding run ``i`` of bizup2002 from FAIL_SEED (recognised by content, so
    also on a Ray worker that drew its own episodes)."""
    bad = episodes_digest(draw_suite("bizup2002", 1, seed=FAIL_SEED + i))
    if any(episodes_digest([ep]) == bad for ep in episodes):
        raise np.linalg.LinAlgError(f"singular matrix (simulated, run {i})")
    return registry._RUNNERS["kf_tuned"](episodes, cfg)


def _crash_worker(episodes, cfg):
    """Kills the Ray worker process running it (every retry too)."""
    import os
    os._exit(3)


FAILING_TRACKERS = {"fails_on_run0": functools.partial(_fail_on_run, 0),     # lands in chunk 0
                    "fails_on_run3": functools.partial(_fail_on_run, 3)}     # lands in chunk 1
WORKER_ONLY_TRACKERS = {"crashes_worker": _crash_worker}     # registered in Ray workers only (it kills its process)


def _register_failing_trackers():
    """Ray worker setup hook: the test trackers exist in every worker process (a monkeypatch stays in the driver)."""
    registry._RUNNERS.update(FAILING_TRACKERS)
    registry._RUNNERS.update(WORKER_ONLY_TRACKERS)


@pytest.fixture(scope="module")
def local_ray():
    ray = pytest.importorskip("ray")
    started = not ray.is_initialized()
    if started:
        ray.cloudpickle.register_pickle_by_value(sys.modules[__name__])     # workers cannot import this module
        ray.init(address="local", num_cpus=2, include_dashboard=False, log_to_driver=False,
                 runtime_env={"worker_process_setup_hook": _register_failing_trackers})
    yield ray, started
    if started:
        ray.shutdown()
        ray.cloudpickle.unregister_pickle_by_value(sys.modules[__name__])


def _assert_runs_equal(a, b):
    assert a.name == b.name
    for f in ("x", "P", "start_index", "q_m_s2"):
        x, y = getattr(a, f), getattr(b, f)
        assert x.dtype == y.dtype and x.shape == y.shape, f
        assert np.array_equal(x, y, equal_nan=True), f
    assert (a.declared is None) == (b.declared is None)
    if a.declared is not None:
        assert np.array_equal(a.declared, b.declared)
    assert sorted(a.extra) == sorted(b.extra)
    for k in a.extra:
        assert np.array_equal(a.extra[k], b.extra[k], equal_nan=True), k


# ------------------------------------------------------------------------------------------------ no Ray needed
def test_chunks_are_contiguous_and_concat_pads_like_the_serial_run():
    assert chunk_bounds(6, 2) == [(0, 3), (3, 6)]
    assert chunk_bounds(2, 5) == [(0, 1), (1, 2)]            # never an empty chunk
    bounds = chunk_bounds(7, 3)
    assert bounds[0][0] == 0 and bounds[-1][1] == 7 and all(a[1] == b[0] for a, b in zip(bounds, bounds[1:]))
    eps = draw_suite("random", 5, seed=123)                   # random flights: different lengths, so padding
    assert len({e.n_looks for e in eps}) > 1
    for tracker in ("kf_tuned", "cmin"):                      # cmin declares maneuvers: the bool array pads too
        serial = run_tracker(tracker, eps)
        parts = [run_tracker(tracker, eps[a:b]) for a, b in chunk_bounds(len(eps), 3)]
        _assert_runs_equal(concat_runs(parts, max(e.n_looks for e in eps)), serial)


@pytest.mark.parametrize("tracker", list(FAILING_TRACKERS))
def test_a_tracker_failing_in_one_chunk_fails_the_whole_suite_as_serially(monkeypatch, capsys, tracker):
    """Serially a tracker that raises gets NaN on every run of the suite; the Ray driver's merge of the chunks must
    give the same TrackRun (not NaN on one chunk only, not a KeyError from concatenating a failed chunk)."""
    monkeypatch.setitem(registry._RUNNERS, tracker, FAILING_TRACKERS[tracker])
    eps = draw_suite("bizup2002", 4, seed=FAIL_SEED)
    serial = run_one(tracker, eps)
    assert serial.error is not None and np.isnan(serial.x).all()
    capsys.readouterr()
    parts = [run_one(tracker, eps[a:b]) for a, b in chunk_bounds(len(eps), 2)]
    assert sum(p.error is not None for p in parts) == 1                    # only one chunk raised
    capsys.readouterr()
    merged = merge_chunk_runs(tracker, parts, eps)
    _assert_runs_equal(merged, serial)
    assert merged.error == serial.error
    err = capsys.readouterr().err
    assert f"warning: tracker {tracker!r} failed on this suite" in err and serial.error in err
    _assert_runs_equal(merge_chunk_runs("kf_tuned", [run_one("kf_tuned", eps[a:b]) for a, b in
                                                     chunk_bounds(len(eps), 2)], eps), run_one("kf_tuned", eps))


def test_a_finished_trial_is_reported_again_not_retrained(monkeypatch, tmp_path):
    """A trial whose run folder was finished before an interruption, restarted by Tune on restore, re-reports its
    selection history (train would refuse the existing run folder on every retry)."""
    tune = pytest.importorskip("ray.tune")
    hist = [{"timesteps": 1024, "selection_ratio": 0.9, "random_ratio_imm2": 0.9, "eval_s": 1.0},
            {"timesteps": 2048, "selection_ratio": 0.8, "random_ratio_imm2": 0.8, "eval_s": 1.0}]
    run = tmp_path / "runs" / "trial_abc"
    run.mkdir(parents=True)
    (run / "summary.json").write_text(json.dumps({"timesteps": 2048, "selection_history": hist}))
    reported = []
    monkeypatch.setattr(tune, "get_context", lambda: type("Ctx", (), {"get_trial_name": lambda self: run.name})())
    monkeypatch.setattr(tune, "report", reported.append)

    def no_train(*a, **k):
        raise AssertionError("a finished trial was trained again")
    monkeypatch.setattr(agents.training.train, "train", no_train)
    _trial({"seed": 0}, "ppo", {"n_timesteps": 2048}, str(run.parent))
    assert [r["selection_ratio"] for r in reported] == [h["selection_ratio"] for h in hist]
    assert [r["timesteps"] for r in reported] == [h["timesteps"] for h in hist]
    assert all(r["run_dir"] == str(run) and r["random_ratio_imm2"] == h["random_ratio_imm2"]
               for r, h in zip(reported, hist))


@pytest.mark.skipif(not BUNDLED_POLICY.is_file(), reason="no bundled policy")
def test_loading_the_policy_in_a_worker_leaves_no_temp_dir(monkeypatch, tmp_path):
    monkeypatch.setattr(agents.evaluation.parallel.tempfile, "tempdir", str(tmp_path))
    monkeypatch.setattr(agents.evaluation.parallel, "_POLICY_CACHE", {})
    choose_q, cfg = _policy_in_worker(_policy_blob(BUNDLED_POLICY))
    assert list(tmp_path.glob("radar_track_policy_*")) == []          # (torch may leave its own cache dirs)
    obs = np.zeros((3, len(cfg.features) * cfg.frame_stack))
    assert choose_q(obs).shape == (3,)                    # the model works with its files gone


def test_missing_ray_gives_a_one_line_error_naming_the_extra(monkeypatch, tmp_path, capsys):
    monkeypatch.setitem(sys.modules, "ray", None)             # import ray -> ImportError
    with pytest.raises(SystemExit) as e:
        evaluate_main(["--scenario", "bizup2002", "--runs", "2", "--trackers", "kf_tuned", "--workers", "2",
                       "--no-plots", "--quiet"])
    msg = str(e.value)
    assert msg.startswith("error: ") and "\n" not in msg and ".[scale]" in msg and "--workers" in msg
    cfg = tmp_path / "s.toml"
    cfg.write_text(TINY_SWEEP)
    with pytest.raises(SystemExit) as e:
        sweep_main([str(cfg), "--out", str(tmp_path / "out")])
    msg = str(e.value)
    assert msg.startswith("error: ") and "\n" not in msg and ".[scale]" in msg and "sweep" in msg


def test_workers_option_is_checked():
    with pytest.raises(SystemExit, match=r"--workers must be >= 1, got 0"):
        evaluate_main(["--scenario", "bizup2002", "--runs", "2", "--trackers", "kf_tuned", "--workers", "0",
                       "--no-plots", "--quiet"])


@pytest.mark.parametrize("body, match", [
    ("[sweep]\nsearch = 'bayes'\n[space]\nseed = [0]\n", r"search must be one of .*got 'bayes'"),
    ("[sweep]\nalgo = 'td3'\n[space]\nseed = [0]\n", r"algo must be one of .*got 'td3'"),
    ("[space]\nlearning_rate = {loguniform = [1e-4, 1e-3]}\n", r"learning_rate: search = 'grid' takes lists only"),
    ("[sweep]\nsearch = 'random'\n[space]\ngamma = {uniform = [0.99, 0.9]}\n", r"gamma: uniform needs \[lo, hi\]"),
    ("[sweep]\nnum_samples = 0\n[space]\nseed = [0]\n", r"num_samples must be an integer >= 1, got 0"),
    ("[sweep]\nworkers = 2\n[space]\nseed = [0]\n", r"unknown \[sweep\] key\(s\) \['workers'\]"),
    ("[sweep]\n", r"\[space\] is empty"),
    ("[space]\nseed = [0.5]\n", r"seed must list integers"),
    # each trial's hyperparameters checked as radar-track train checks them, before Ray starts
    ("[base]\nn_timesteps = -5\n[space]\nseed = [0]\n", r"\[base\]: --hp n_timesteps: must be an integer >= 1"),
    ("[space]\nlerning_rate = [0.1]\n", r"\[space\] lerning_rate = 0.1: --hp lerning_rate: unknown hyperparameter"),
    ("[space]\nlearning_rate = [3e-4, -1.0]\n", r"\[space\] learning_rate = -1.0: --hp learning_rate: must lie in"),
    ("[sweep]\nsearch = 'random'\n[space]\ngamma = {uniform = [0.5, 3.0]}\n", r"gamma = 3.0: --hp gamma: must lie"),
    ("[space]\n'env_kwargs.reward_type' = ['bogus']\n", r"--hp env_kwargs: RadarTrack-v0: reward_type must be one of"),
    ("[space]\nseed = [-1, 2]\n", r"\[space\] seed = -1: a training seed must be an integer in range"),
    ("[sweep]\nsearch = 'random'\n[space]\nbatch_size = {randint = [1.5, 64.2]}\n", r"randint needs integer bounds"),
    ("[sweep]\nsearch_seed = -3\n[space]\nseed = [0]\n", r"search_seed must be an integer >= 0"),
    ("[sweep]\nhyperparams = 5\n[space]\nseed = [0]\n", r"hyperparams must name a TOML file, got 5"),
    ("base = 5\n[space]\nseed = [0]\n", r"base must be a table"),
    ("[sweep]\nmethod = 'backprop'\n[base]\nn_steps = -1\n[space]\nseed = [0]\n", r"\[base\]: --hp n_steps"),
])
def test_sweep_config_errors_name_the_key(tmp_path, body, match):
    cfg = tmp_path / "bad.toml"
    cfg.write_text(body)
    with pytest.raises(ValueError, match=match):
        load_sweep_config(cfg)


def test_sweep_out_that_is_a_file_is_refused_before_ray(tmp_path):
    from agents.training.sweep import main as sweep_main
    (tmp_path / "afile").write_text("")
    with pytest.raises(SystemExit, match=r"--out: .*afile' exists and is a file; give a directory path"):
        sweep_main([str(tmp_path / "nope.toml"), "--out", str(tmp_path / "afile"), "--quiet"])


def test_sweep_config_merges_base_over_the_file(tmp_path):
    cfg = tmp_path / "s.toml"
    cfg.write_text(TINY_SWEEP)
    c = load_sweep_config(cfg)
    assert c["hp"]["eval_scenarios"] == {"random": 4}               # replaced, not merged
    assert c["hp"]["policy_kwargs"]["activation_fn"] == "tanh"      # merged: the file's key is kept
    assert c["hp"]["policy_kwargs"]["net_arch"] == [16, 16]
    assert c["space"] == {"seed": [0, 1]}


# ------------------------------------------------------------------------------------------------ on a local Ray
@pytest.mark.skipif(not BUNDLED_POLICY.is_file(), reason="no bundled policy")
def test_evaluation_on_two_workers_equals_the_serial_run(local_ray):
    """Named suites (tasks draw their own episodes) and encounter pairs (episodes sent): every TrackRun array and
    the JSON are bit-equal to the serial run, the learned policy included."""
    suites = [("bizup2002", draw_suite("bizup2002", 4, seed=10_000_000)),
              ("encounters", draw_suite("encounters", 1, seed=10_000_000))]
    trackers = ["imm2", "cmin", "policy"]          # cmin: maneuver declarations (bool arrays) are padded too
    res_s, runs_s = evaluate(suites, trackers, str(BUNDLED_POLICY), progress=False)
    res_p, runs_p = evaluate(suites, trackers, str(BUNDLED_POLICY), progress=False, workers=2, seed=10_000_000)
    assert json.dumps(jsonable(res_p)) == json.dumps(jsonable(res_s))
    for suite in runs_s:
        for t in trackers:
            _assert_runs_equal(runs_p[suite][1][t], runs_s[suite][1][t])


def test_a_tracker_failing_on_some_runs_on_two_workers_equals_the_serial_run(local_ray, monkeypatch):
    """Genuinely failing trackers on Ray workers (registered there by the module's worker setup hook): a failure in
    chunk 0 or chunk 1 gives the serial all-NaN TrackRun and error; a tracker that works is unaffected."""
    if not local_ray[1]:
        pytest.skip("Ray was started elsewhere, without this module's worker setup hook")
    for name, runner in FAILING_TRACKERS.items():
        monkeypatch.setitem(registry._RUNNERS, name, runner)
    eps = draw_suite("bizup2002", 4, seed=FAIL_SEED)
    trackers = [*FAILING_TRACKERS, "kf_tuned"]
    par = run_suites_ray([("bizup2002", eps)], trackers, workers=2, seed=FAIL_SEED)["bizup2002"]
    for t in trackers:
        serial = run_one(t, eps)
        _assert_runs_equal(par[t], serial)
        assert par[t].error == serial.error and (serial.error is None) == (t == "kf_tuned")


def test_a_worker_that_keeps_crashing_ends_in_one_line_naming_rays_logs(local_ray):
    """Ray retries a task whose worker died; when every retry dies too, the user gets one line (the error type and
    where Ray's logs are), not a Ray traceback."""
    suites = [("bizup2002", draw_suite("bizup2002", 2, seed=FAIL_SEED))]
    with pytest.raises(ValueError) as e:
        run_suites_ray(suites, ["crashes_worker"], workers=2, seed=FAIL_SEED)
    msg = str(e.value)
    assert "\n" not in msg and "WorkerCrashedError" in msg and "Ray's logs: " in msg and "/logs" in msg


def test_cli_workers_json_equals_serial(local_ray, tmp_path):
    common = ["--scenario", "kim_lee_accel", "--runs", "3", "--trackers", "imm2,kf_tuned", "--no-plots", "--quiet"]
    evaluate_main(common + ["--json", str(tmp_path / "serial.json")])
    evaluate_main(common + ["--json", str(tmp_path / "ray.json"), "--workers", "2"])
    a, b = (json.loads((tmp_path / f).read_text()) for f in ("serial.json", "ray.json"))
    a["meta"].pop("command"), b["meta"].pop("command")           # the command lines differ by --workers 2
    assert a == b


def test_sweep_of_two_trials_writes_its_table_and_resumes(local_ray, tmp_path):
    cfg = tmp_path / "tiny.toml"
    cfg.write_text(TINY_SWEEP)
    rows, exp = run_sweep(cfg, tmp_path / "out", verbose=0)
    assert len(rows) == 2 and sorted(r["seed"] for r in rows) == [0, 1]
    for r in rows:
        assert r["status"] == "done" and r["error"] is None and r["timesteps"] >= 2048
        hist = json.loads((exp / "runs" / r["trial"] / "summary.json").read_text())["selection_history"]
        assert r["evals"] == len(hist)                              # every selection evaluation reached Tune
        best = min(h["selection_ratio"] for h in hist)
        assert math.isfinite(best) and r["best_selection_ratio"] == best
        assert (exp / "runs" / r["trial"] / "best" / "policy.zip").is_file()
    assert [r["best_selection_ratio"] for r in rows] == sorted(r["best_selection_ratio"] for r in rows)
    assert json.loads((exp / "results.json").read_text())["trials"] == rows
    with open(exp / "results.csv") as f:
        table = list(csv.DictReader(f))
    assert [t["trial"] for t in table] == [r["trial"] for r in rows]
    assert [float(t["best_selection_ratio"]) for t in table] == [r["best_selection_ratio"] for r in rows]
    # the same command again resumes: the finished trials are kept, nothing is trained again
    mtimes = {r["trial"]: (exp / "runs" / r["trial"] / "summary.json").stat().st_mtime_ns for r in rows}
    rows2, _ = run_sweep(cfg, tmp_path / "out", verbose=0)
    assert rows2 == rows
    assert mtimes == {r["trial"]: (exp / "runs" / r["trial"] / "summary.json").stat().st_mtime_ns for r in rows}
    # another config under the same name is refused (Tune would run the stored space with the new base)
    changed = tmp_path / "changed.toml"
    changed.write_text(TINY_SWEEP.replace("seed = [0, 1]", "seed = [5, 6]"))
    with pytest.raises(ValueError, match=r"started with another config \(it differs in \['space'\]\)"):
        run_sweep(changed, tmp_path / "out", verbose=0)


TINY_BACKPROP_SWEEP = """
[sweep]
name = "tiny_bp"
method = "backprop"
[base]
n_steps = 2
eval_every = 1
batch_episodes = 3
chunk_looks = 6
hidden_size = 4
select_on = ["random"]
[base.eval_scenarios]
random = 3
[space]
seed = [0]
"""


def test_backprop_sweep_runs_a_trial_on_ray(local_ray, tmp_path):
    cfg = tmp_path / "tiny_bp.toml"
    cfg.write_text(TINY_BACKPROP_SWEEP)
    rows, exp = run_sweep(cfg, tmp_path / "out", verbose=0)
    (r,) = rows
    hist = json.loads((exp / "runs" / r["trial"] / "summary.json").read_text())["selection_history"]
    assert r["status"] == "done" and r["error"] is None and r["timesteps"] == 2 and r["evals"] == len(hist) == 3
    assert r["best_selection_ratio"] == min(h["selection_ratio"] for h in hist)
    assert r["best_policy"].endswith("policy.npz") and Path(r["best_policy"]).is_file()
