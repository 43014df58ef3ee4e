"""Feedback from the first second: --help of every command answers without the slow imports (and about as fast
as Python starts), every option says its default, evaluate / train / tune print what they do before anything slow,
the evaluation's bar names the item now running with a sane estimate, and a rounded training length is said once."""

import json
import subprocess
import sys
import time
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMANDS = ("evaluate", "train", "tune", "sweep")
SLOW = ("numpy", "numba", "scipy", "torch", "stable_baselines3", "gymnasium", "matplotlib", "ray", "radar_env")


def _run(code, timeout=120):
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=timeout, cwd=ROOT)


@pytest.mark.parametrize("cmd", COMMANDS)
def test_help_imports_nothing_slow_and_names_the_command(cmd):
    code = ("import sys\nfrom agents.cli import main\n"
            f"try:\n    main([{cmd!r}, '--help'])\nexcept SystemExit:\n    pass\n"
            f"print('SLOW', [m for m in {SLOW!r} if m in sys.modules])\n")
    res = _run(code)
    assert res.returncode == 0, res.stderr
    assert f"usage: radar-track {cmd}" in res.stdout
    assert "SLOW []" in res.stdout, res.stdout.splitlines()[-1]


def _best_of(args, n=3):
    best = float("inf")
    for _ in range(n):
        t0 = time.perf_counter()
        subprocess.run(args, capture_output=True, timeout=120, cwd=ROOT, check=True)
        best = min(best, time.perf_counter() - t0)
    return best


def test_help_answers_about_as_fast_as_python_starts():
    """A generous bound relative to the interpreter's own start (the machine may be shared): within 1 s of it."""
    base = _best_of([sys.executable, "-c", "pass"])
    for cmd in COMMANDS:
        t = _best_of([sys.executable, "-m", "agents.cli", cmd, "--help"])
        assert t < base + 1.0, (cmd, t, base)


def _parsers():
    from agents.evaluation.options import build_parser as ev
    from agents.training.sweep import build_parser as sw
    from agents.training.train import build_parser as tr
    from baselines.tuning_options import build_parser as tu
    return {"evaluate": ev(), "train": tr(), "tune": tu(), "sweep": sw()}


@pytest.mark.parametrize("cmd", COMMANDS)
def test_every_option_has_help_with_its_default(cmd):
    ap = _parsers()[cmd]
    assert ap.prog == f"radar-track {cmd}"
    for a in ap._actions:
        if a.dest == "help":
            continue
        assert a.help, (cmd, a.option_strings)
        assert "default" in a.help or a.required, (cmd, a.option_strings, a.help)


def test_help_states_the_real_defaults():
    from agents.evaluation.options import DEFAULT_SUITES, DEFAULT_TRACKERS, RADAR_RANGE_HELP_KM
    from agents.evaluation.evaluate import DEFAULT_SUITES as used_suites, DEFAULT_TRACKERS as used_trackers
    from agents.training.train import load_hyperparams
    from baselines.seeds import EVAL_SEED_BASE
    from radar_env.sim.scenario import RADAR_PLACEMENT_RANGE_M
    assert tuple(v * 1e3 for v in RADAR_RANGE_HELP_KM) == RADAR_PLACEMENT_RANGE_M
    assert used_suites == DEFAULT_SUITES and used_trackers == DEFAULT_TRACKERS
    p = _parsers()
    text = p["evaluate"].format_help().replace("\n", " ")
    assert str(EVAL_SEED_BASE) in text and "10,150" in text and ", ".join(DEFAULT_SUITES[:2]) in text
    train_help = " ".join(p["train"].format_help().split())
    assert f"ppo {load_hyperparams('ppo')['n_timesteps']}" in train_help


def test_tuning_module_names_itself():
    res = subprocess.run([sys.executable, "-m", "baselines.tuning", "--help"], capture_output=True, text=True,
                         cwd=ROOT, timeout=120)
    assert res.returncode == 0 and res.stdout.startswith("usage: python -m baselines.tuning")


def _first_line_s(args):
    t0 = time.perf_counter()
    p = subprocess.Popen(args, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True, cwd=ROOT)
    try:
        line = p.stderr.readline()
        return time.perf_counter() - t0, line
    finally:
        p.kill()
        p.wait()


@pytest.mark.parametrize("args, words", [
    (["evaluate", "--scenario", "bizup2002", "--runs", "1", "--trackers", "kf_low", "--no-plots"],
     "1 tracker(s) on 1 suite(s) (bizup2002)"),
    (["train", "--algo", "ppo", "--timesteps", "8", "--out", "/nonexistent-dir/never"], "ppo on RadarTrack-v0"),
    (["tune", "--runs", "1", "--out", "/nonexistent-dir/never.json"],
     "tuning kf,imm2,imm_cv_ct,kf_rdot,imm2_rdot,imm_cv_ct_rdot,imm_ct_bank,imm_ct_bank_rdot on 1"),
])
def test_first_line_comes_before_the_slow_imports(args, words):
    base = _best_of([sys.executable, "-c", "pass"], n=2)
    t, line = _first_line_s([sys.executable, "-m", "agents.cli", *args])
    assert words in line and line.startswith(f"radar-track {args[0]}:"), line
    assert t < base + 2.0, (t, base)


@pytest.mark.parametrize("args, error", [
    (["evaluate", "--seed", "-1"], "error: --seed must be an integer >= 0, got -1"),
    (["evaluate", "--runs", "0"], "error: --runs must be >= 1, got 0"),
    (["evaluate", "--workers", "0"], "error: --workers must be >= 1, got 0"),
    (["tune", "--runs", "0"], "error: --runs must be in [1, 50,000]"),
    (["tune", "--starts", "0"], "error: --starts must be >= 1, got 0"),
    (["tune", "--trackers", "kf,nope"], "error: --trackers: expected names from"),
])
def test_a_bad_number_is_refused_before_the_first_line(args, error, capsys):
    """The one-line error alone: no "radar-track ...: ... loading the trackers" line announcing work first."""
    from agents.cli import main
    with pytest.raises(SystemExit) as e:
        main(args)
    assert str(e.value).startswith(error)
    assert capsys.readouterr().err == ""


def test_list_prints_every_suite_and_tracker(capsys):
    from agents.evaluation.evaluate import main
    from baselines.registry import TRACKER_NAMES
    from radar_env.sim.catalog import SCENARIO_NAMES
    assert main(["--list"]) == {}
    out = capsys.readouterr().out
    for name in list(SCENARIO_NAMES) + list(TRACKER_NAMES) + ["encounters", "adsb_heldout"]:
        assert f"  {name}\n" in out, name


# ------------------------------------------------------------------------------------------------ progress
def test_remaining_time_from_what_was_measured():
    from agents.evaluation.progress import remaining_s
    items = [("a: x", 100, "x"), ("a: y", 100, "y"), ("b: x", 300, "x"), ("b: y", 300, "y")]
    assert remaining_s(items, {}) is None                       # nothing measured: no guess
    # x took 10 s for 100 looks; y is not measured yet: it is guessed at x's rate
    assert remaining_s(items, {0: 10.0}) == pytest.approx(10.0 + 30.0 + 30.0)
    assert remaining_s(items, {0: 10.0, 1: 1.0}) == pytest.approx(30.0 + 3.0)
    # the running item counts what is left of it, never less than 0
    assert remaining_s(items, {0: 10.0, 1: 1.0}, current=2, current_elapsed_s=12.0) == pytest.approx(18.0 + 3.0)
    assert remaining_s(items, {0: 10.0, 1: 1.0}, current=2, current_elapsed_s=99.0) == pytest.approx(3.0)
    # a kind's latest item sets its rate (its first may have compiled kernels)
    assert remaining_s(items + [("c: x", 100, "x")], {0: 10.0, 1: 1.0, 2: 3.0}) == pytest.approx(3.0 + 1.0)


def test_the_bar_names_the_tracker_now_running(capsys, monkeypatch):
    """Each line is printed when its tracker starts (plain lines off a terminal): while a tracker runs, the last
    line names it, with its suite."""
    from agents.evaluation import evaluate as ev
    from agents.evaluation.suites import draw_suite
    seen = []
    real = ev.run_one

    def spy(t, episodes, *a):
        seen.append((t, capsys.readouterr().err.strip().splitlines()[-1]))
        return real(t, episodes, *a)

    monkeypatch.setattr(ev, "run_one", spy)
    ev.evaluate([("bizup2002", draw_suite("bizup2002", 2)), ("kim_lee_accel", draw_suite("kim_lee_accel", 2))],
                ["kf_low", "cmin"], progress=True)
    assert [t for t, _ in seen] == ["kf_low", "cmin"] * 2
    for i, ((t, line), suite) in enumerate(zip(seen, ["bizup2002"] * 2 + ["kim_lee_accel"] * 2)):
        assert line.startswith(f"[{i + 1}/4] {suite}: {t} ..."), line
        assert ("left" in line) == (i > 0)                      # an estimate once one item has been measured
    assert "evaluate: 4 of 4 items in" in capsys.readouterr().err


def test_write_plots_has_its_own_bar(tmp_path, capsys):
    from agents.evaluation.evaluate import write_plots
    from agents.evaluation.suites import draw_suite, run_scenario
    from baselines.registry import run_tracker
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("bizup2002", 2, seed=7)
    runs = {"bizup2002": (stack_episodes(eps), {t: run_tracker(t, eps) for t in ("kf_low", "cmin")})}
    files = write_plots(runs, tmp_path, {"bizup2002": run_scenario("bizup2002", 7)}, progress=True)
    err = capsys.readouterr().err
    # five kinds are drawn; the maneuver figure has no IMM among these trackers, so it writes no file
    assert len(files) == 4 and "[1/5] bizup2002: errors ..." in err and "figures: 5 of 5 items in" in err


def test_figures_drawn_by_two_processes_are_the_files_one_draws(tmp_path):
    """write_plots' forked drawing (issue 35: the main job's figures in parallel) writes the same files, byte for
    byte, in the same order, as one process."""
    from agents.evaluation.evaluate import figure_processes, write_plots
    from agents.evaluation.suites import draw_suite, run_scenario
    from baselines.registry import run_tracker
    from radar_env.sim.episode import stack_episodes
    runs, scen = {}, {}
    for suite in ("bizup2002", "kim_lee_accel"):
        eps = draw_suite(suite, 2, seed=7)
        runs[suite] = (stack_episodes(eps), {t: run_tracker(t, eps) for t in ("kf_low", "imm2")})
        scen[suite] = run_scenario(suite, 7)
    one = write_plots(runs, tmp_path / "one", scen, processes=1)
    two = write_plots(runs, tmp_path / "two", scen, processes=2)
    assert [f.name for f in one] == [f.name for f in two] and len(one) >= 8
    for a, b in zip(one, two):
        assert a.read_bytes() == b.read_bytes(), a.name
    assert not list((tmp_path / "two").glob(".plots-*"))          # the temporary folder is gone
    assert 1 <= figure_processes(35) <= 4 and figure_processes(1) == 1


# ------------------------------------------------------------------------------------------------ training
def test_trained_timesteps_are_whole_rollouts():
    import stable_baselines3 as sb3
    from agents.training.train import trained_timesteps
    assert trained_timesteps(sb3.PPO, 20_000, 128, {"n_steps": 64}) == (24_576, 8192)
    assert trained_timesteps(sb3.PPO, 16_384, 128, {"n_steps": 64}) == (16_384, 8192)
    assert trained_timesteps(sb3.PPO, 10, 2, {}) == (4096, 4096)              # PPO's default n_steps 2048
    assert trained_timesteps(sb3.DQN, 1001, 4, {"train_freq": 4}) == (1008, 16)
    assert trained_timesteps(sb3.SAC, 1001, 4, {"train_freq": [2, "step"]}) == (1008, 8)
    assert trained_timesteps(sb3.SAC, 1001, 4, {"train_freq": [1, "episode"]})[0] is None


def test_train_says_the_rounding_once_and_trains_it(tmp_path, capsys):
    from agents.training.train import load_hyperparams, train
    hp = load_hyperparams("ppo")
    hp.update(n_envs=2, n_timesteps=100, n_steps=32, batch_size=32, n_epochs=1, eval_freq=10_000, eval_runs=2,
              eval_scenarios={"random": 2, "random_radars": 2})
    hp["env_kwargs"] = {**hp["env_kwargs"], "warmup_scans": 4}
    run = train("ppo", hp, seed=3, out=tmp_path, progress=False, verbose=1, run_name="r")
    err = capsys.readouterr().err
    assert err.count("--timesteps 100 trains 128 steps") == 1, err
    assert json.loads((run / "summary.json").read_text())["timesteps"] == 128
