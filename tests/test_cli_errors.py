"""Command-line errors (one line naming the option, before any work), trajectory suites keyed by content, the
radar-site options, the packaged hyperparameter files and the TensorBoard scalars of a short run."""

import json
import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest

from agents.evaluation import evaluate as ev
from agents.evaluation.suites import draw_suite
from agents.training.train import _tb_scalars
from agents.training.train import main as train_main
from radar_env.sim.radar import atc_radar

ROOT = Path(__file__).resolve().parents[1]
QUICK = ["--no-plots", "--quiet"]


def _write_flight(path, speed_m_s=200.0, y_m=50e3, duration_s=600.0):
    """A straight, level flight at ``y_m`` from the origin, sampled every 1 s; velocity = d(position)/dt."""
    t = np.arange(0.0, duration_s + 0.5, 1.0)
    x = -60e3 + speed_m_s * t
    rows = ["t_s,x_m,y_m,vx_m_s,vy_m_s"] + [f"{ti:.1f},{xi:.1f},{y_m:.1f},{speed_m_s:.1f},0.0" for ti, xi in
                                            zip(t, x)]
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text("\n".join(rows) + "\n")
    return path


def _one_line_exit(excinfo, option):
    msg = str(excinfo.value)
    assert msg.startswith("error: ") and "\n" not in msg, msg
    assert option in msg, msg
    return msg


def _tiny_model(tmp_path, algo="PPO", **env_kwargs):
    """An untrained SB3 model of RadarTrack-v0 saved as <tmp>/<algo>/policy.zip (no env_config.json)."""
    import stable_baselines3 as sb3

    from radar_env.envs.env import RadarTrackEnv
    env = RadarTrackEnv(**env_kwargs)
    kw = {"learning_starts": 0, "buffer_size": 100} if algo == "DQN" else {"n_steps": 16, "batch_size": 16}
    model = getattr(sb3, algo)("MlpPolicy", env, device="cpu", seed=0, policy_kwargs={"net_arch": [8]}, **kw)
    d = tmp_path / algo
    d.mkdir(exist_ok=True)
    model.save(d / "policy.zip")
    return d / "policy.zip"


# ------------------------------------------------------------------------------------------------ evaluate
@pytest.mark.parametrize("args, option", [
    (["--trackers", ""], "--trackers"),
    (["--trackers", " , "], "--trackers"),
    (["--seed", "-1"], "--seed"),
    (["--scenario", "kim_lee_accel", "--radar-site", "10,20"], "--radar-site"),
    (["--scenario", "kim_lee_accel", "--radar-range-km", "5,50"], "--radar-range-km"),
    (["--scenario", "kim_lee_accel", "--scenario", "kim_lee_accel"], "--scenario"),
    (["--trajectory", "/nonexistent/flight.csv"], "--trajectory"),
    (["--trajectory", str(Path(__file__).parent)], "--trajectory"),          # a folder, not a file
    (["--scenario", "random", "--json", ""], "--json"),                       # an empty path wrote nothing
])
def test_evaluate_option_errors(args, option):
    with pytest.raises(SystemExit) as e:
        ev.main(args + ["--trackers", "kf_low"] * ("--trackers" not in args) + QUICK)
    _one_line_exit(e, option)


def test_evaluate_refuses_an_empty_plots_folder():
    with pytest.raises(SystemExit) as e:           # "" wrote the figures into the working folder
        ev.main(["--scenario", "random", "--trackers", "kf_low", "--quiet", "--out", ""])
    assert "an empty path" in _one_line_exit(e, "--out")


def test_evaluate_policy_that_is_not_a_policy(tmp_path):
    fake = tmp_path / "policy.zip"
    fake.write_text("not a model")
    with pytest.raises(SystemExit) as e:
        ev.main(["--policy", str(fake), "--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "policy", *QUICK])
    assert "is a pickle" in _one_line_exit(e, "--policy")        # refused before it is even opened
    with pytest.raises(SystemExit) as e:     # with the opt-in: opened, and refused as not a model
        ev.main(["--policy", str(fake), "--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "policy",
                 "--allow-pickle", *QUICK])
    assert "not a stable-baselines3 model" in _one_line_exit(e, "--policy")


def test_evaluate_policy_trained_with_other_features_says_what_it_needs(tmp_path):
    p = _tiny_model(tmp_path, features=["nis", "c_min_g"])      # no env_config.json beside it: defaults assumed
    with pytest.raises(SystemExit) as e:
        ev.main(["--policy", str(p), "--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "policy",
                 "--allow-pickle", *QUICK])
    msg = _one_line_exit(e, "--policy")
    assert "'features'" in msg and "2 feature names" in msg
    (p.parent / "env_config.json").write_text(json.dumps({"features": ["nis", "c_min_g"]}))
    res = ev.main(["--policy", str(p), "--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "policy",
                       "--allow-pickle", *QUICK])
    assert np.isfinite(res["kim_lee_accel"]["trackers"]["policy"]["pos_rmse_m"])
    (p.parent / "env_config.json").write_text(json.dumps({"features": ["nis", "c_min_g"], "q_levels_g": [0.1, 1.0]}))
    with pytest.raises(SystemExit) as e:
        ev.main(["--policy", str(p), "--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "policy",
                 "--allow-pickle", *QUICK])
    assert "q_levels_g" in _one_line_exit(e, "--policy")


def test_evaluate_outputs_are_checked_before_the_evaluation(tmp_path, monkeypatch):
    calls = []
    monkeypatch.setattr(ev, "evaluate", lambda *a, **k: calls.append(1))
    a_file = tmp_path / "plain.txt"
    a_file.write_text("x")
    base = ["--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "kf_low", "--quiet"]
    for args, option in [(["--out", str(a_file)], "--out"),
                         (["--out", str(a_file / "sub")], "--out"),
                         (["--no-plots", "--json", str(tmp_path / "missing" / "m.json")], "--json"),
                         (["--no-plots", "--json", str(tmp_path)], "--json")]:
        with pytest.raises(SystemExit) as e:
            ev.main(base + args)
        _one_line_exit(e, option)
    assert calls == []


# ------------------------------------------------------------------------------------------------ trajectories
def test_same_csv_by_different_paths_gives_identical_metrics(tmp_path, monkeypatch):
    f = _write_flight(tmp_path / "a.csv")
    copy = tmp_path / "elsewhere" / "renamed.csv"
    copy.parent.mkdir()
    shutil.copy(f, copy)
    monkeypatch.chdir(tmp_path)
    from agents.evaluation.suites import suite_key
    keys = {suite_key(p) for p in ("a.csv", "./a.csv", str(f), copy)}
    assert len(keys) == 1
    got = []
    for p in ("a.csv", "./a.csv", str(f), str(copy)):
        res = ev.main(["--trajectory", p, "--runs", "3", "--trackers", "kf_low,imm2", *QUICK])
        (m,) = res.values()
        got.append(m["trackers"])
    for g in got[1:]:
        assert g == got[0]
    # an edited file is another trajectory: other noise (and placement)
    f.write_text(f.read_text() + "\n")
    other = draw_suite(str(f), 1)[0]
    assert not np.array_equal(other.z_m, draw_suite(str(copy), 1)[0].z_m, equal_nan=True)


def test_two_csvs_with_the_same_stem_or_a_builtin_name_are_refused(tmp_path):
    a = _write_flight(tmp_path / "one" / "flight.csv")
    b = _write_flight(tmp_path / "two" / "flight.csv", speed_m_s=250.0)
    with pytest.raises(SystemExit) as e:
        ev.main(["--trajectory", str(a), "--trajectory", str(b), "--runs", "2", "--trackers", "kf_low", *QUICK])
    assert "flight" in _one_line_exit(e, "--trajectory")
    named = _write_flight(tmp_path / "bizup2002.csv")
    for extra in ([], ["--scenario", "bizup2002"]):
        with pytest.raises(SystemExit) as e:
            ev.main(["--trajectory", str(named), *extra, "--runs", "2", "--trackers", "kf_low", *QUICK])
        assert "built-in" in _one_line_exit(e, "--trajectory")
    res = ev.main(["--trajectory", str(a), "--trajectory", str(_write_flight(tmp_path / "flight2.csv", 250.0)),
                   "--runs", "2", "--trackers", "kf_low", *QUICK])
    assert set(res) == {"flight", "flight2"}


def test_radar_site_option_places_the_radar_and_is_validated(tmp_path):
    f = _write_flight(tmp_path / "f.csv")
    placed = draw_suite(str(f), 2)
    fixed = draw_suite(str(f), 2, radar=atc_radar(position_m=(10e3, -20e3)))
    for ep in fixed:
        assert np.all(ep.site_xy_m == (10e3, -20e3))
    assert not np.allclose(placed[0].site_xy_m[0], (10e3, -20e3))
    out = tmp_path / "m.json"
    ev.main(["--trajectory", str(f), "--radar-site", "10,-20", "--runs", "2", "--trackers", "kf_low",
             "--json", str(out), *QUICK])
    assert json.loads(out.read_text())["meta"]["radar_site_km"] == [10.0, -20.0]
    # the placement rule's range: every site lies within LO-HI km of the flight's start
    near = draw_suite(str(f), 4, radar_range_m=(20e3, 30e3))
    start = np.array([-60e3, 50e3])
    for ep in near:
        assert 20e3 <= np.hypot(*(ep.site_xy_m[0] - start)) <= 30e3
    for args, option in [(["--radar-site", "10"], "--radar-site"), (["--radar-site", "a,b"], "--radar-site"),
                         (["--radar-site", "nan,1"], "--radar-site"),
                         (["--radar-range-km", "50,20"], "--radar-range-km"),
                         (["--radar-range-km", "0,20"], "--radar-range-km"),
                         (["--radar-range-km", "10,50", "--radar-site", "1,1"], "--radar-site")]:
        with pytest.raises(SystemExit) as e:
            ev.main(["--trajectory", str(f), *args, "--runs", "2", "--trackers", "kf_low", *QUICK])
        _one_line_exit(e, option)
    with pytest.raises(ValueError, match="radar_range_m"):
        draw_suite("kim_lee_accel", 1, radar_range_m=(1e3, 2e3))


# ------------------------------------------------------------------------------------------------ train
TINY_TRAIN = ["--timesteps", "256", "--n-envs", "2", "--no-progress", "--quiet", "--hp", "eval_freq=100000",
              "--hp", 'eval_scenarios={"random": 2}', "--hp", 'select_on=["random"]',
              "--hp", "checkpoint_freq=100000"]
TINY_PPO = ["--algo", "ppo", *TINY_TRAIN, "--hp", "n_steps=128", "--hp", "batch_size=64", "--hp", "n_epochs=1"]


@pytest.mark.parametrize("args, option, text", [
    (["--hp", "gama=0.9"], "--hp gama", "unknown hyperparameter"),
    (["--hp", "gamma=abc"], "--hp gamma", "number"),
    (["--hp", "gamma=1.5"], "--hp gamma", "[0.0, 1.0]"),
    (["--hp", "n_steps=-5"], "--hp n_steps", "[1, inf]"),
    (["--hp", "n_steps=12.5"], "--hp n_steps", "integer"),
    (["--hp", "learning_rate=lin_x"], "--hp learning_rate", "lin_"),
    (["--hp", "eval_freq=0"], "--hp eval_freq", ">= 1"),
    (["--hp", "init_from=/nonexistent/policy.zip"], "--hp init_from", "does not exist"),
    (["--hyperparams", "/nonexistent/ppo.toml"], "--hyperparams", "does not exist"),
    (["--timesteps", "0"], "--timesteps", ">= 1"),
    (["--hp", 'policy_kwargs={"net_arch": [-5]}'], "--hp policy_kwargs", "layer widths in [1, 4096]"),
    (["--hp", 'target_kl="x"'], "--hp target_kl", "a number (or null)"),
    (["--hp", "stats_window_size=-1"], "--hp stats_window_size", "[1, inf]"),
    (["--hp", "ent_coef=-1"], "--hp ent_coef", "[0.0, inf]"),
])
def test_train_option_errors_leave_no_run_folder(tmp_path, args, option, text):
    with pytest.raises(SystemExit) as e:
        train_main([*TINY_PPO, "--out", str(tmp_path), "--name", "r", *args])
    assert text in _one_line_exit(e, option)
    assert not any(tmp_path.iterdir())


def test_train_init_from_a_model_of_another_algorithm(tmp_path):
    dqn = _tiny_model(tmp_path, "DQN")
    with pytest.raises(SystemExit) as e:
        train_main([*TINY_PPO, "--out", str(tmp_path / "runs"), "--hp", f"init_from={dqn}", "--allow-pickle"])
    assert "is a DQN model" in _one_line_exit(e, "--hp init_from")
    not_a_model = tmp_path / "x.zip"
    not_a_model.write_text("x")
    with pytest.raises(SystemExit) as e:
        train_main([*TINY_PPO, "--out", str(tmp_path / "runs"), "--hp", f"init_from={not_a_model}",
                    "--allow-pickle"])
    assert "not a stable-baselines3 model" in _one_line_exit(e, "--hp init_from")
    assert not (tmp_path / "runs").exists()


def test_dqn_that_never_reaches_learning_starts_warns(tmp_path):
    with pytest.warns(UserWarning, match="learning_starts"):
        run = train_main(["--algo", "dqn", *TINY_TRAIN, "--hp", "learning_starts=1000", "--hp", "buffer_size=2000",
                          "--out", str(tmp_path), "--name", "d"])
    assert json.loads((run / "summary.json").read_text())["n_updates"] == 0


def test_failed_training_run_is_marked_and_not_finished(tmp_path, monkeypatch):
    import stable_baselines3 as sb3

    def boom(self, *a, **k):
        raise RuntimeError("simulated crash during learn")
    monkeypatch.setattr(sb3.PPO, "learn", boom)
    with pytest.raises(RuntimeError, match="simulated"):
        train_main([*TINY_PPO, "--out", str(tmp_path), "--name", "r"])
    assert not (tmp_path / "r").exists()
    part = tmp_path / "r.partial"
    assert "simulated crash" in (part / "FAILED").read_text()
    assert not (part / "policy.zip").exists() and not (part / "summary.json").exists()
    monkeypatch.undo()
    run = train_main([*TINY_PPO, "--out", str(tmp_path), "--name", "r"])     # a rerun replaces the unfinished one
    assert run == tmp_path / "r" and (run / "policy.zip").is_file() and not part.exists()
    assert not (run / "FAILED").exists()
    with pytest.raises(SystemExit) as e:                 # a finished run is never overwritten
        train_main([*TINY_PPO, "--out", str(tmp_path), "--name", "r"])
    _one_line_exit(e, "--name")


def test_tensorboard_gets_the_final_evaluation_of_a_short_run(tmp_path):
    run = train_main([*TINY_PPO, "--out", str(tmp_path), "--name", "tb"])
    summary = json.loads((run / "summary.json").read_text())
    sc = _tb_scalars(run, ["eval/rmse_ratio_imm2", "eval/pos_rmse_m"])
    steps, values = sc["eval/rmse_ratio_imm2"]
    assert steps[-1] == summary["timesteps"]
    assert values[-1] == pytest.approx(summary["selection_history"][-1]["random_ratio_imm2"], rel=1e-6)
    assert sc["eval/pos_rmse_m"][0][-1] == summary["timesteps"]
    assert not (tmp_path / "tb.partial").exists() and (run / "policy.zip").is_file()


# ------------------------------------------------------------------------------------------------ packaging
def test_hyperparameter_files_are_package_data(tmp_path):
    """The wheel holds agents/training/hyperparams/*.toml (``radar-track train`` reads them from an installed package)."""
    src = tmp_path / "src"
    src.mkdir()
    for name in ("pyproject.toml", "README.md"):
        shutil.copy(ROOT / name, src / name)
    ignore = shutil.ignore_patterns("__pycache__", "*.pyc", "policy.zip", "data")
    for pkg in ("radar_env", "baselines", "agents"):
        shutil.copytree(ROOT / pkg, src / pkg, ignore=ignore)
    out = tmp_path / "wheel"
    subprocess.run([sys.executable, "-m", "pip", "wheel", "--no-deps", "--no-build-isolation", "--no-index", "-q",
                    "-w", str(out), str(src)], check=True, capture_output=True, env={**os.environ,
                                                                                   "PIP_NO_INPUT": "1"})
    (whl,) = out.glob("*.whl")
    names = set(zipfile.ZipFile(whl).namelist())
    tomls = {f"agents/training/hyperparams/{p.name}" for p in (ROOT / "agents" / "training" / "hyperparams").glob("*.toml")}
    assert tomls and tomls <= names, sorted(n for n in names if n.startswith("agents/"))
    # load_hyperparams reads them from the installed layout (the unpacked wheel, imported first)
    site = tmp_path / "site"
    zipfile.ZipFile(whl).extractall(site)
    code = ("import agents.training.train as t, pathlib; assert pathlib.Path(t.__file__).parents[2] == pathlib.Path.cwd(); "
            "print(sorted(t.load_hyperparams(a)['n_timesteps'] > 0 for a in t.ALGOS))")
    res = subprocess.run([sys.executable, "-c", code], cwd=site, capture_output=True, text=True, check=True)
    assert res.stdout.strip() == "[True, True, True]"


def test_csv_given_to_scenario_is_a_trajectory_suite_and_json_comes_first(tmp_path, monkeypatch):
    """`--scenario sub/a.csv` runs as the trajectory suite `a` (stem name, content seed), so its plots land in --out
    and its JSON is written; before, the raw path became a plot file name and the run died after the table."""
    import json

    from agents.evaluation import evaluate as ev
    sub = tmp_path / "sub"
    sub.mkdir()
    t = np.arange(0.0, 601.0, 1.0)
    rows = ["t_s,x_m,y_m,vx_m_s,vy_m_s"] + [f"{a},{50e3 + 200 * a},30000.0,200.0,0.0" for a in t]
    (sub / "a.csv").write_text("\n".join(rows) + "\n")
    monkeypatch.chdir(tmp_path)
    out, js = tmp_path / "plots", tmp_path / "r.json"
    ev.main(["--scenario", "sub/a.csv", "--runs", "2", "--trackers", "kf_tuned", "--out", str(out),
             "--json", str(js), "--quiet"])
    data = json.loads(js.read_text())
    assert list(data["suites"]) == ["a"] and "a" in data["meta"]["trajectories"]
    assert sorted(p.name for p in out.iterdir())[0].startswith("a_")
    via_traj = ev.main(["--trajectory", "sub/a.csv", "--runs", "2", "--trackers", "kf_tuned", "--no-plots",
                        "--quiet"])
    assert via_traj["a"]["trackers"]["kf_tuned"]["pos_rmse_m"] == data["suites"]["a"]["trackers"]["kf_tuned"][
        "pos_rmse_m"]


@pytest.mark.parametrize("name", ["../x", "a/b", "..", "."])
def test_train_name_must_be_a_plain_folder_name(tmp_path, name):
    with pytest.raises(SystemExit, match=r"--name: must be a plain folder name"):
        train_main(["--algo", "ppo", "--timesteps", "256", "--out", str(tmp_path), "--name", name])
    assert not any(tmp_path.parent.glob("x.partial"))
