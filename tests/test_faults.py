"""Faults and interrupts end in bounded time with one line: an unreachable Ray address, a huge --runs, SIGINT to a
sweep, Ray errors, two training runs under one name. Every case runs under a timeout (subprocesses where the
process itself is what is tested)."""

from __future__ import annotations

import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from test_ray import TINY_SWEEP

ROOT = Path(__file__).resolve().parents[1]
ENV = {**os.environ, "OMP_NUM_THREADS": "1", "MKL_NUM_THREADS": "1", "PYTHONPATH": str(ROOT)}


def _run(args, timeout, **kw):
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, *args], capture_output=True, text=True, timeout=timeout, env=ENV, cwd=kw.get(
        "cwd", ROOT))
    return r, time.monotonic() - t0


def _error_line(stderr):
    lines = [ln for ln in stderr.strip().splitlines() if ln.strip()]
    assert lines, "no error message"
    return lines[-1]


# ------------------------------------------------------------------------------------------------ Ray address
def test_an_unreachable_address_fails_within_30_s_with_one_line():
    pytest.importorskip("ray")
    from agents.evaluation.parallel import check_ray_address
    t0 = time.monotonic()
    with pytest.raises(ValueError) as e:
        check_ray_address("127.0.0.1:1")
    assert time.monotonic() - t0 < 30.0
    msg = str(e.value)
    assert "\n" not in msg and "--address" in msg and "127.0.0.1:1" in msg
    # the command: one line on stderr, exit status 1, and well under the minutes ray.init retries for
    r, dt = _run(["-m", "agents.evaluation.evaluate", "--scenario", "kim_lee_accel", "--runs", "2", "--trackers",
                  "kf_low", "--workers", "2", "--address", "127.0.0.1:1", "--no-plots", "--quiet"], timeout=180)
    assert r.returncode == 1
    assert [ln for ln in r.stderr.splitlines() if ln.strip()] == [_error_line(r.stderr)], r.stderr
    assert _error_line(r.stderr).startswith("error: --address: no Ray cluster at '127.0.0.1:1'")
    assert "Failed to connect to GCS" not in r.stderr + r.stdout


def test_an_address_that_answers_but_is_no_ray_cluster_fails_within_the_timeout():
    pytest.importorskip("ray")
    from agents.evaluation.parallel import check_ray_address
    srv = socket.socket()
    srv.bind(("127.0.0.1", 0))
    srv.listen(8)
    try:
        address = f"127.0.0.1:{srv.getsockname()[1]}"
        t0 = time.monotonic()
        with pytest.raises(ValueError) as e:
            check_ray_address(address, timeout_s=12.0)
        assert time.monotonic() - t0 < 30.0
        assert "\n" not in str(e.value) and address in str(e.value)
    finally:
        srv.close()


def test_ray_errors_are_one_line_naming_the_log_folder():
    ray = pytest.importorskip("ray")
    from agents.evaluation.parallel import ray_error_line
    for err in (ray.exceptions.WorkerCrashedError(), ray.exceptions.NodeDiedError("node 1 died"),
                ray.exceptions.RayError("something\nwith several\nlines")):
        line = ray_error_line(err, "a Ray task of the evaluation")
        assert "\n" not in line and type(err).__name__ in line and "Ray's logs: " in line and "/logs" in line


# ------------------------------------------------------------------------------------------------ huge --runs
def test_a_huge_runs_is_refused_up_front():
    r, dt = _run(["-m", "agents.evaluation.evaluate", "--scenario", "random", "--runs", "100000000", "--trackers",
                  "kf_low,imm2", "--no-plots", "--quiet"], timeout=180)
    assert r.returncode == 1
    line = _error_line(r.stderr)
    assert line.startswith("error: --runs: 100000000 runs") and "GiB of memory" in line and "available" in line


def test_a_large_runs_prints_an_estimate_first_and_one_beyond_memory_is_refused(capsys, monkeypatch):
    from agents.evaluation import evaluate as ev
    plan = [("--scenario", "random", "random", 20_000, {})]
    monkeypatch.setattr(ev, "_available_memory_bytes", lambda: 1 << 50)
    ev._check_cost(plan, ["imm2", "kf_low"], seed=0)
    err = capsys.readouterr().err
    assert err.startswith("estimate: 20000 runs") and "GiB of memory" in err and "min" in err
    monkeypatch.setattr(ev, "_available_memory_bytes", lambda: 1 << 30)
    with pytest.raises(SystemExit, match=r"^error: --runs: 20000 runs .* more than the 1 GiB available"):
        ev._check_cost(plan, ["imm2", "kf_low"], seed=0)


# ------------------------------------------------------------------------------------------------ train: one name
_HOLD = """
import fcntl, os, sys, time
fd = os.open(sys.argv[1], os.O_RDWR | os.O_CREAT, 0o644)
fcntl.flock(fd, fcntl.LOCK_EX)
print("locked", flush=True)
time.sleep(120)
"""


@pytest.mark.parametrize("method", ["ppo", "backprop"])
def test_a_second_run_under_a_name_being_written_is_refused_and_touches_nothing(tmp_path, method):
    """The first run holds its name's lock (here a process holding it, as a running ``train`` does); the second
    stops before deleting the first's ``.partial``, whichever trainer it is; once the first is gone (killed: the
    kernel drops the lock) the name can be taken again."""
    pytest.importorskip("stable_baselines3" if method == "ppo" else "torch")
    from agents.training.runs import RunLock
    from agents.training.train import main as train_main
    out = tmp_path / "runs"
    part = out / "same.partial"
    part.mkdir(parents=True)
    (part / "command.txt").write_text("the first run\n")
    holder = subprocess.Popen([sys.executable, "-c", _HOLD, str(out / ".same.lock")], stdout=subprocess.PIPE,
                              text=True)
    try:
        assert holder.stdout.readline().strip() == "locked"
        t0 = time.monotonic()
        with pytest.raises(SystemExit) as e:
            train_main((["--algo", "ppo", "--timesteps", "256", "--n-envs", "2"] if method == "ppo" else
                        ["--method", "backprop", "--hp", "n_steps=1", "--hp", "batch_episodes=2"])
                       + ["--out", str(out), "--name", "same", "--no-progress", "--quiet"])
        msg = str(e.value)
        assert "\n" not in msg and msg.startswith("error: --name: another run is writing")
        assert time.monotonic() - t0 < 60
        assert (part / "command.txt").read_text() == "the first run\n"
    finally:
        holder.kill()
        holder.wait(timeout=30)
    lock = RunLock(out / "same")                        # released by the kernel with the holder
    lock.release()
    assert not (out / ".same.lock").exists()


# ------------------------------------------------------------------------------------------------ SIGINT to sweep
SLOW_SWEEP = TINY_SWEEP.replace('name = "tiny"', 'name = "interrupted"').replace("n_timesteps = 2048",
                                                                                  "n_timesteps = 5_000_000")


def test_sigint_to_a_sweep_exits_non_zero_marks_trials_unfinished_and_prints_the_resume_command(tmp_path):
    pytest.importorskip("ray")
    pytest.importorskip("stable_baselines3")
    cfg = tmp_path / "slow.toml"
    cfg.write_text(SLOW_SWEEP)
    out = tmp_path / "out"
    p = subprocess.Popen([sys.executable, "-m", "agents.training.sweep", str(cfg), "--out", str(out), "--num-cpus",
                          "2", "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=ENV, cwd=ROOT)
    try:
        runs = out / "interrupted" / "runs"
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and not (runs.is_dir() and any(runs.glob("*.partial/config.json"))):
            assert p.poll() is None, p.communicate()
            time.sleep(1.0)
        assert any(runs.glob("*.partial/config.json")), "no trial started in 300 s"
        time.sleep(3.0)
        p.send_signal(signal.SIGINT)
        stdout, stderr = p.communicate(timeout=240)
    finally:
        if p.poll() is None:
            p.kill()
            p.communicate()
    assert p.returncode == 1, (stdout, stderr)
    line = _error_line(stderr)
    assert line.startswith("error: interrupted: 2 of 2 trials unfinished") and "resume with: radar-track sweep" in line
    assert f"--out {out}" in line
    assert "stopped early" not in stdout and "unfinished" in stdout
    res = json.loads((out / "interrupted" / "results.json").read_text())
    assert res["interrupted"] is True and {t["status"] for t in res["trials"]} == {"unfinished"}
