"""The benchmark script runs (tiny settings; its numbers are not checked: timing is never asserted in tests) and
rejects bad options with a message naming them."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_env.py"


def _bench_module():
    spec = importlib.util.spec_from_file_location("bench_env", BENCH)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod           # dataclasses look their module up there
    spec.loader.exec_module(mod)
    return mod


def test_bench_runs_with_tiny_settings(tmp_path, capsys):
    bench = _bench_module()
    out = tmp_path / "bench.json"
    res = bench.main(["--seconds", "0.05", "--num-envs", "1,2", "--min-resets-per-env", "0", "--skip-main-job",
                      "--skip-import", "--memory-envs", "2", "--markdown", "--json", str(out)])
    text = capsys.readouterr().out
    rates = [res["single"], res["cartpole_single"], res["tracker"]] + [r for pair in res["vector"].values()
                                                                       for r in pair]
    assert all(np.isfinite(r.steps_per_s) and r.steps_per_s > 0 and r.steps > 0 for r in rates)
    assert set(res["vector"]) == {1, 2}
    assert res["memory"]["rss_after_mb"] > 0 and res["memory"]["num_envs"] == 2
    assert "main_job" not in res and "import" not in res
    assert "| single env (gym.make) | 1 |" in text and text.count("| native vector env |") == 2
    assert "s per 1M steps" in text and "2 envs after 200 steps" in text
    saved = json.loads(out.read_text())
    assert saved["vector"]["2"][0]["steps"] == res["vector"][2][0].steps


@pytest.mark.parametrize("argv, option", [(["--num-envs", "0"], "--num-envs"), (["--seconds", "-1"], "--seconds"),
                                          (["--memory-envs", "x"], "--memory-envs")])
def test_bench_bad_options_name_the_option(argv, option, capsys):
    bench = _bench_module()
    with pytest.raises(SystemExit) as e:
        bench.main(argv)
    assert e.value.code == 2
    err = capsys.readouterr().err
    assert option in err and argv[1] in err


def test_main_job_is_timed_cold_then_warm_and_reported_with_the_load(monkeypatch, capsys):
    bench = _bench_module()
    caches, fake = [], iter(range(1, 10))

    def once(cache_dir):          # the real run takes minutes: record the cache handed to each run instead
        caches.append(cache_dir)
        i = next(fake)
        return {"wall_s": 10.0 * i, "cpu_s": 9.0 * i, "load_before": 0.5 * i, "load_after": 0.5}

    monkeypatch.setattr(bench, "_main_job_once", once)
    res = bench.main(["--only-main-job", "--main-job-runs", "3"])
    m = res["main_job"]
    assert len(set(caches)) == 1 and len(caches) == 4          # one numba cache: empty for the first run only
    assert m["cold"]["wall_s"] == 10.0 and [r["wall_s"] for r in m["warm"]] == [20.0, 30.0, 40.0]
    assert m["wall_s"] == 30.0 and m["cpu_s"] == 27.0            # the warm median
    text = capsys.readouterr().out
    assert "warm numba cache: 30.0 s wall, 27.0 s CPU (median of 3" in text and "cold (empty cache" in text
    assert "(load 1.0)" in text and "single env" not in text


def test_learned_cost_bench_runs(capsys):
    """benchmarks/bench_learned_cost.py: a row per tracker with its time per look and ratio (not asserted)."""
    path = BENCH.with_name("bench_learned_cost.py")
    spec = importlib.util.spec_from_file_location("bench_learned_cost", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(["--runs", "2", "--rounds", "1", "--trackers", "policy_bp"])
    text = capsys.readouterr().out
    rows = [line for line in text.splitlines() if line.startswith("| imm_cv_ct |") or line.startswith("| policy_bp |")]
    assert len(rows) == 2 and rows[0].endswith("| 1.00 |")


def test_window_step_bench_runs(capsys):
    """benchmarks/bench_window_step.py: one row per precision and their ratio (the numbers not asserted)."""
    path = BENCH.with_name("bench_window_step.py")
    spec = importlib.util.spec_from_file_location("bench_window_step", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    mod.main(["--rounds", "1", "--steps", "1", "--layers", "8", "--batch", "64"])
    text = capsys.readouterr().out
    assert [line.split("|")[1].strip() for line in text.splitlines() if line.startswith("| float")] == [
        "float64", "float32"]
    assert "float64 / float32: " in text
