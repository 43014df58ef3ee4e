"""benchmarks/bench_main_job.py runs on a tiny main job (its times are not checked: timing is never asserted in
tests) and reports both times, the CartPole rate and the per-tracker seconds."""

import importlib.util
import sys
from pathlib import Path

BENCH = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_main_job.py"


def test_bench_main_job_tiny(capsys):
    spec = importlib.util.spec_from_file_location("bench_main_job", BENCH)
    bench = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = bench
    spec.loader.exec_module(bench)
    res = bench.main(["--seconds", "0.05", "--runs", "1", "--scenario", "bizup2002", "--trackers", "kf_tuned,imm2"])
    text = capsys.readouterr().out
    assert res["cartpole_steps_per_s"] > 0 and res["no_plots_s"] > 0 and res["plots_s"] > 0
    assert res["with_plots_s"] == res["no_plots_s"] + res["plots_s"]
    assert set(res["per_tracker_s"]) == {"kf_tuned", "imm2"}
    assert "| without figures |" in text and "| with figures |" in text and "load average" in text
