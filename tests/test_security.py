"""Issue 40: no file runs code unless the user says so, every loader checks what it loads, every fault is one line.

Every refusal here is a one-line ``ValueError`` / ``SystemExit`` naming the file (or option) and the field."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings, strategies as st

from agents.evaluation import evaluate as ev
from agents.policies.learned import BUNDLED_LEARNED, load_learned
from agents.policies.loading import load_policy

QUICK = ["--no-plots", "--quiet", "--scenario", "kim_lee_accel", "--runs", "1"]
KINDS_ON_DISK = [n for n in ("policy", "policy_bp", "policy_imm_bp", "policy_imm_ppo") if BUNDLED_LEARNED[n].is_dir()]


def _one_line(excinfo, *words):
    msg = str(excinfo.value)
    assert "\n" not in msg and "Traceback" not in msg, msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


def _copy(tmp_path, name, dest="t"):
    """A copy of the bundled tracker ``name``'s files (no subfolders)."""
    d = tmp_path / dest
    d.mkdir()
    for f in BUNDLED_LEARNED[name].iterdir():
        if f.is_file() and f.suffix in (".npz", ".json", ".zip"):
            shutil.copy(f, d / f.name)
    return d


def _edit_json(f, fn):
    v = json.loads(f.read_text())
    v = fn(v)
    f.write_text(json.dumps(v))


# ------------------------------------------------------------------------------------------------ 1. no pickle
@pytest.mark.parametrize("name", [n for n in ("policy", "policy_imm_ppo") if n in KINDS_ON_DISK])
def test_a_zip_without_its_export_is_not_unpickled_without_the_opt_in(tmp_path, name):
    d = _copy(tmp_path, name)
    (d / "policy.npz").unlink()
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, "policy.zip", "pickle", "--allow-pickle")
    with pytest.raises(ValueError) as e:
        load_policy(d / "policy.zip")
    _one_line(e, "--allow-pickle")


@pytest.mark.parametrize("option", ["--policy", "--policy-bp", "--policy-imm-ppo", "--learned"])
def test_every_policy_option_refuses_a_pickle_in_one_line(tmp_path, option):
    name = "policy_imm_ppo" if option == "--policy-imm-ppo" else "policy"
    if name not in KINDS_ON_DISK:
        pytest.skip("no bundled SB3 policy")
    d = _copy(tmp_path, name)
    (d / "policy.npz").unlink()
    with pytest.raises(SystemExit) as e:
        ev.main([option, str(d if option == "--learned" else d / "policy.zip"), *QUICK])
    _one_line(e, option, "pickle", "--allow-pickle")


def test_a_stale_export_is_not_a_way_to_the_pickle(tmp_path):
    if "policy" not in KINDS_ON_DISK:
        pytest.skip("no bundled SB3 policy")
    d = _copy(tmp_path, "policy")
    with open(d / "policy.zip", "ab") as f:        # the zip changed since its export
        f.write(b"\0")
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, "another file", "--allow-pickle")


def test_a_torch_checkpoint_is_refused_as_a_pickle(tmp_path):
    f = tmp_path / "model.pt"
    f.write_bytes(b"\x80\x04\x95 not really a pickle")
    (tmp_path / "env_config.json").write_text("{}")
    with pytest.raises(ValueError) as e:
        load_policy(f)
    _one_line(e, "model.pt", "pickle", "--allow-pickle")


def test_the_export_command_needs_the_opt_in(tmp_path):
    from agents.policies.numpy_policy import main as export_main
    with pytest.raises(SystemExit) as e:
        export_main([str(tmp_path / "policy.zip")])
    _one_line(e, "--allow-pickle")


@pytest.mark.parametrize("name", KINDS_ON_DISK)
def test_the_bundled_trackers_load_without_pickle(name, monkeypatch):
    import pickle
    monkeypatch.setattr(pickle, "loads", lambda *a, **k: pytest.fail("unpickled"))
    monkeypatch.setattr(pickle, "load", lambda *a, **k: pytest.fail("unpickled"))
    assert load_learned(name).name == name


def test_train_init_from_needs_the_opt_in(tmp_path):
    from agents.training.train import main as train_main
    z = tmp_path / "policy.zip"
    z.write_bytes(b"PK")
    with pytest.raises(SystemExit) as e:
        train_main(["--algo", "ppo", "--timesteps", "1", "--quiet", "--out", str(tmp_path), "--hp",
                    f"init_from={z}"])
    _one_line(e, "init_from", "--allow-pickle")


# ------------------------------------------------------------------------------------------------ 2. one validation
NPZ_KINDS = [n for n in ("policy_bp", "policy_imm_bp") if n in KINDS_ON_DISK]


@pytest.mark.parametrize("name", KINDS_ON_DISK)
@pytest.mark.parametrize("damage", ["empty", "truncated", "garbage"])
def test_a_damaged_npz_is_refused_in_one_line(tmp_path, name, damage):
    d = _copy(tmp_path, name)
    data = (d / "policy.npz").read_bytes()
    (d / "policy.npz").write_bytes({"empty": b"", "truncated": data[:len(data) // 2], "garbage": b"x" * 99}[damage])
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, "policy.npz")


def _rewrite_weights(d, fn):
    with np.load(d / "policy.npz") as z:
        w = {k: z[k] for k in z.files}
    np.savez(d / "policy.npz", **fn(w))


@pytest.mark.parametrize("name", NPZ_KINDS)
@pytest.mark.parametrize("case,words", [
    ("inf", ["gru.weight_hh", "non-finite"]), ("nan", ["gru.weight_hh", "non-finite"]),
    ("int32", ["gru.weight_hh", "float64"]), ("float32", ["gru.weight_hh", "float64"]),
    ("shape", ["gru.weight_hh", "shape"]), ("missing", ["missing", "gru.weight_hh"]),
    ("extra", ["unexpected", "evil"])])
def test_bad_weights_are_refused_naming_the_array(tmp_path, name, case, words):
    d = _copy(tmp_path, name)

    def damage(w):
        k = "gru.weight_hh"
        if case == "inf":
            w[k] = w[k].copy(); w[k][0, 0] = np.inf          # noqa: E702
        elif case == "nan":
            w[k] = w[k].copy(); w[k][1, 1] = np.nan          # noqa: E702
        elif case in ("int32", "float32"):
            w[k] = w[k].astype(case)
        elif case == "shape":
            w[k] = w[k][:, :-1]
        elif case == "missing":
            del w[k]
        else:
            w["evil"] = np.zeros(1)
        return w
    _rewrite_weights(d, damage)
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, "policy.npz", *words)


JSON_CASES = {
    "policy.json is a list": ("policy.json", lambda v: [v], ["policy.json"]),
    "architecture a list": ("policy.json", lambda v: {**v, "architecture": [1, 2]}, ["policy.json", "architecture"]),
    "architecture sizes strings": ("policy.json", lambda v: {**v, "architecture": {
        **v["architecture"], "hidden_size": "32"}}, ["policy.json", "architecture"]),
    "input_features a number": ("policy.json", lambda v: {**v, "input_features": 3}, ["input_features"]),
    "env_config a list": ("env_config.json", lambda v: [], ["env_config.json", "object"]),
    "env_config unknown key": ("env_config.json", lambda v: {**v, "evil": 1}, ["env_config.json", "evil"]),
    "env_config a string": ("env_config.json", lambda v: "x", ["env_config.json", "object"]),
}
IMM_JSON_CASES = {
    "base parameters NaN": ("policy.json", lambda v: {**v, "base_parameters": {
        **v["base_parameters"], next(iter(v["base_parameters"])): float("nan")}}, ["policy.json", "NaN"]),
    "base parameters a list": ("policy.json", lambda v: {**v, "base_parameters": [1]}, ["base_parameters"]),
    "parameters a number": ("policy.json", lambda v: {**v, "parameters": 7}, ["parameters"]),
    "feature_q_g infinite": ("policy.json", lambda v: {**v, "feature_q_g": 1e999}, ["policy.json"]),
    "n_par missing": ("policy.json", lambda v: {**v, "architecture": {
        k: x for k, x in v["architecture"].items() if k != "n_par"}}, ["n_par"]),
}


@pytest.mark.parametrize("name", NPZ_KINDS)
@pytest.mark.parametrize("case", list(JSON_CASES) + list(IMM_JSON_CASES))
def test_malformed_json_is_refused_naming_the_file_and_field(tmp_path, name, case):
    if case in IMM_JSON_CASES and name != "policy_imm_bp":
        pytest.skip("a learned IMM field")
    fname, fn, words = {**JSON_CASES, **IMM_JSON_CASES}[case]
    d = _copy(tmp_path, name)
    (d / fname).write_text(json.dumps(fn(json.loads((d / fname).read_text()))).replace("1e+999", "1e999"))
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, *words)


@pytest.mark.parametrize("name", NPZ_KINDS)
def test_the_file_named_is_the_file_loaded(tmp_path, name):
    d = _copy(tmp_path, name)
    shutil.copy(d / "policy.npz", d / "other.npz")
    with pytest.raises(ValueError) as e:
        load_learned(d / "other.npz")
    _one_line(e, "other.npz", "policy.npz")
    opt = "--policy-imm-bp" if name == "policy_imm_bp" else "--policy-bp"
    with pytest.raises(SystemExit) as e:
        ev.main([opt, str(d / "other.npz"), *QUICK])
    _one_line(e, opt, "other.npz")


@pytest.mark.skipif(not set(NPZ_KINDS) >= {"policy_bp", "policy_imm_bp"}, reason="bundled checkpoints")
@pytest.mark.parametrize("name,option,kind", [("policy_bp", "--policy-imm-bp", "gru_q_policy"),
                                              ("policy_imm_bp", "--policy-bp", "learned_imm_gru"),
                                              ("policy_imm_bp", "--policy", "learned_imm_gru")])
def test_a_checkpoint_of_another_kind_is_refused_with_its_kind(tmp_path, name, option, kind):
    d = _copy(tmp_path, name)
    with pytest.raises(SystemExit) as e:
        ev.main([option, str(d / "policy.npz"), *QUICK])
    _one_line(e, option, kind)


@pytest.mark.skipif("policy_bp" not in NPZ_KINDS, reason="bundled checkpoint")
def test_a_legacy_policy_json_of_another_kind_is_refused(tmp_path):
    """A recurrent policy.json without 'kind' whose format says learned IMM: the loader of that format refuses."""
    d = _copy(tmp_path, "policy_bp")
    _edit_json(d / "policy.json", lambda v: {**{k: x for k, x in v.items() if k != "kind"},
                                             "format": "radar-track-learned-imm"})
    with pytest.raises(SystemExit) as e:
        ev.main(["--policy-imm-bp", str(d), *QUICK])
    _one_line(e, "--policy-imm-bp")


# ------------------------------------------------------------------------------------------------ 7. property test
def _fingerprint(lt):
    """The weights the loaded tracker runs and its env config."""
    w = getattr(lt.policy, "w", None)
    if w is None:      # an SB3 kind: its numpy export (inside a choose_q closure or the IMM wrapper)
        from agents.policies.numpy_policy import load_export
        w = load_export(lt.file).arrays()
    return {k: np.asarray(v).tobytes() for k, v in w.items()}, repr(lt.env_config)


@pytest.mark.parametrize("name", KINDS_ON_DISK)
@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_corruptions_of_the_weights_are_refused_or_harmless(tmp_path_factory, name, data):
    """Any byte corruption of a valid checkpoint's policy.npz: a one-line ValueError, or the very same tracker
    (the zip's CRC catches a changed array; a changed header field that does not matter loads the same)."""
    ref = _fingerprint(load_learned(name))
    d = _copy(tmp_path_factory.mktemp("c"), name)
    raw = bytearray((d / "policy.npz").read_bytes())
    n = data.draw(st.integers(1, 8))
    for _ in range(n):
        i = data.draw(st.integers(0, len(raw) - 1))
        raw[i] = data.draw(st.integers(0, 255))
    cut = data.draw(st.one_of(st.none(), st.integers(0, len(raw))))
    (d / "policy.npz").write_bytes(bytes(raw[:cut] if cut is not None else raw))
    try:
        lt = load_learned(d)
    except ValueError as e:
        assert "\n" not in str(e) and "policy.npz" in str(e), str(e)
        return
    assert _fingerprint(lt) == ref


@pytest.mark.parametrize("name", NPZ_KINDS)
@pytest.mark.parametrize("fname", ["policy.json", "env_config.json"])
@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.data())
def test_random_corruptions_of_the_json_are_refused_in_one_line_or_load(tmp_path_factory, name, fname, data):
    """A corrupted JSON file that still parses may be a legitimate edit; anything else is a one-line refusal."""
    d = _copy(tmp_path_factory.mktemp("j"), name)
    raw = bytearray((d / fname).read_bytes())
    for _ in range(data.draw(st.integers(1, 4))):
        raw[data.draw(st.integers(0, len(raw) - 1))] = data.draw(st.integers(0, 255))
    (d / fname).write_bytes(bytes(raw))
    try:
        load_learned(d)
    except ValueError as e:
        assert "\n" not in str(e), str(e)


# ------------------------------------------------------------------------------------------------ 5. tune's output
@pytest.fixture
def shipped(tmp_path, monkeypatch):
    """A copy of the shipped tuned.json standing in for it; the working folder is tmp_path."""
    import baselines.tuning as tuning
    f = tmp_path / "shipped" / "tuned.json"
    f.parent.mkdir()
    shutil.copy(tuning.TUNED_PATH, f)
    monkeypatch.setattr(tuning, "TUNED_PATH", f)
    monkeypatch.chdir(tmp_path)
    return f


TUNE = ["--runs", "1", "--trackers", "kf", "--starts", "1"]


def test_tune_writes_a_run_folder_by_default_and_the_shipped_file_only_when_asked(shipped, tmp_path, capsys):
    from baselines.tuning import main as tune_main
    before = shipped.read_bytes()
    tune_main(TUNE)
    written = list((tmp_path / "runs").glob("tune_*/tuned.json"))
    assert len(written) == 1 and shipped.read_bytes() == before
    new = json.loads(written[0].read_text())
    assert set(json.loads(before)) <= set(new)        # the other trackers' entries kept from the shipped file
    assert "replaced" not in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:               # the shipped file by path: refused without the option
        tune_main([*TUNE, "--out", str(shipped)])
    _one_line(e, "--out", "--replace-shipped")
    assert shipped.read_bytes() == before
    tune_main([*TUNE, "--replace-shipped"])
    out = capsys.readouterr().out
    assert f"wrote {shipped}" in out and "replaced the parameters of" in out and "kf " in out
    assert json.loads(shipped.read_text())["tuning"]["runs"] == 1


@pytest.mark.parametrize("target", ["/dev/null", "fifo", "link", "missing-folder"])
def test_tune_out_refuses_what_is_not_a_regular_file(shipped, tmp_path, target):
    import os
    from baselines.tuning import main as tune_main
    path = target
    if target == "fifo":
        os.mkfifo(tmp_path / "fifo")
    elif target == "link":
        (tmp_path / "link").symlink_to(shipped)
    elif target == "missing-folder":
        path = str(tmp_path / "nope" / "x.json")
    with pytest.raises(SystemExit) as e:
        tune_main([*TUNE, "--out", path])
    _one_line(e, "--out")
    assert not (tmp_path / "runs").exists()


# ------------------------------------------------------------------------------------------------ 3. outputs
@pytest.mark.parametrize("kind", ["device", "fifo", "socket", "link"])
def test_evaluate_json_and_out_refuse_special_files(tmp_path, kind):
    import os
    import socket
    target = tmp_path / "t"
    sock = None
    if kind == "device":
        target = Path("/dev/null")
    elif kind == "fifo":
        os.mkfifo(target)
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        sock.bind(str(target))
    else:
        (tmp_path / "real").mkdir()
        target.symlink_to(tmp_path / "real")
    try:
        base = ["--scenario", "kim_lee_accel", "--runs", "1", "--trackers", "kf_low", "--quiet"]
        with pytest.raises(SystemExit) as e:
            ev.main([*base, "--no-plots", "--json", str(target)])
        _one_line(e, "--json")
        with pytest.raises(SystemExit) as e:
            ev.main([*base, "--out", str(target)])
        _one_line(e, "--out")
    finally:
        if sock is not None:
            sock.close()
    assert Path("/dev/null").is_char_device()


@pytest.mark.parametrize("kind", ["fifo", "link"])
def test_train_out_refuses_special_files(tmp_path, kind):
    import os
    from agents.training.runs import open_run_folder
    if kind == "fifo":
        os.mkfifo(tmp_path / "out")
    else:
        (tmp_path / "real").mkdir()
        (tmp_path / "out").symlink_to(tmp_path / "real")
    with pytest.raises(ValueError) as e:
        open_run_folder(tmp_path / "out" / "run", tmp_path / "out" / "run.partial")
    _one_line(e, "--out")


# ------------------------------------------------------------------------------------------------ 6. Ctrl-C in train
def test_ctrl_c_in_train_ends_in_one_line_with_the_resume_command(tmp_path, monkeypatch):
    """SIGINT (KeyboardInterrupt) during a backprop run: one line naming the kept .partial folder and the command
    that resumes it; that command finishes the run from its last checkpoint."""
    import shlex
    from agents.training import backprop as bp
    from agents.training.train import main as train_main
    real = bp.train_backprop

    def interrupted(*a, **k):
        def ctrl_c(row):
            if row["timesteps"] == 2:
                raise KeyboardInterrupt
        return real(*a, **{**k, "on_selection": ctrl_c})
    argv = ["--method", "backprop", "--out", str(tmp_path), "--no-progress", "--quiet", "--hp", "n_steps=4",
            "--hp", "eval_every=2", "--hp", "batch_episodes=2", "--hp", "hidden_size=4", "--hp", "chunk_looks=5",
            "--hp", 'eval_scenarios={"random": 2, "random_radars": 2}']
    monkeypatch.setattr(bp, "train_backprop", interrupted)
    with pytest.raises(SystemExit) as e:
        train_main(argv)
    msg = _one_line(e, "interrupted", ".partial", "resume", "--name")
    part = next(tmp_path.glob("*.partial"))
    assert str(part) in msg and (part / "checkpoints" / "last.json").is_file()
    monkeypatch.setattr(bp, "train_backprop", real)
    again = shlex.split(msg.split("last checkpoint: ", 1)[1])
    assert again[:2] == ["radar-track", "train"]
    run = train_main(again[2:])
    assert run == part.with_name(part.name.removesuffix(".partial")) and not part.exists()
    assert json.loads((run / "summary.json").read_text())["resumed_at"] == [2]


@pytest.mark.parametrize("cmd, target", [("evaluate", "agents.evaluation.evaluate.main"),
                                         ("tune", "baselines.tuning.main")])
def test_ctrl_c_in_evaluate_and_tune_is_one_line(cmd, target, monkeypatch):
    """Ctrl-C in ``radar-track evaluate`` / ``tune``: one line, no traceback."""
    import importlib
    from agents.cli import main as cli_main
    mod, fn = target.rsplit(".", 1)

    def ctrl_c(argv):
        raise KeyboardInterrupt
    monkeypatch.setattr(importlib.import_module(mod), fn, ctrl_c)
    with pytest.raises(SystemExit) as e:
        cli_main([cmd, "--runs", "1"] + (["--quiet"] if cmd == "evaluate" else []))
    msg = _one_line(e, f"radar-track {cmd}: interrupted")
    assert "complete" in msg


def test_ctrl_c_in_a_ppo_run_names_the_command_to_start_again(tmp_path):
    from agents.training.runs import RunInterrupted
    msg = RunInterrupted(tmp_path / "x.partial", resumable=False).message("radar-track train --algo ppo")
    assert "\n" not in msg and "start it again" in msg and msg.endswith("radar-track train --algo ppo --name x")


# ------------------------------------------------------------------------------------------------ 4. bounds
@pytest.mark.parametrize("scenario", ["random", "bizup2002"])
def test_a_scan_period_beyond_memory_is_refused_before_allocation(scenario):
    import gymnasium as gym

    import radar_env  # noqa: F401
    from radar_env.sim.radar import Radar, RadarSite
    with pytest.raises(ValueError) as e:
        env = gym.make("RadarTrack-v0", scenario=scenario, radar=Radar((RadarSite(scan_period_s=1e-6),)))
        env.reset(seed=0)
    _one_line(e, "scan_period_s", "looks")


@pytest.mark.parametrize("argv,option", [(["--algo", "ppo", "--n-envs", "100000000"], "--n-envs"),
                                         (["--method", "backprop", "--hp", "batch_episodes=1000000000"],
                                          "--hp batch_episodes")])
def test_training_rows_beyond_memory_are_refused_naming_the_option(tmp_path, argv, option):
    from agents.training.train import main as train_main
    with pytest.raises(SystemExit) as e:
        train_main([*argv, "--out", str(tmp_path), "--quiet"])
    _one_line(e, option, "GiB")
    assert not list(tmp_path.iterdir())          # no .partial folder left


# ------------------------------------------------------------------------------------------------ 6. faults
def _enospc(path):
    import errno
    import os

    def fail(*a, **k):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))
    return fail


def test_a_full_disk_in_evaluate_is_one_line_and_leaves_no_partial_json(tmp_path, monkeypatch):
    js = tmp_path / "m.json"
    monkeypatch.setattr(ev, "write_text_replacing", _enospc(js))
    with pytest.raises(SystemExit) as e:
        ev.main(["--scenario", "kim_lee_accel", "--runs", "1", "--trackers", "kf_low", "--quiet", "--no-plots",
                 "--json", str(js)])
    _one_line(e, "--json", "m.json", "No space left")
    assert not js.exists()
    monkeypatch.setattr(ev, "write_plots", _enospc(tmp_path / "out" / "x.png"))
    with pytest.raises(SystemExit) as e:
        ev.main(["--scenario", "kim_lee_accel", "--runs", "1", "--trackers", "kf_low", "--quiet",
                 "--out", str(tmp_path / "out")])
    _one_line(e, "--out", "No space left")


def test_a_full_disk_in_train_is_one_line_and_keeps_the_partial_run(tmp_path, monkeypatch):
    from agents.training import backprop as bp
    from agents.training.train import main as train_main
    real = bp._save_policy
    calls = []

    def save(*a, **k):          # the first save (best/) works, the next hits a full disk
        calls.append(1)
        if len(calls) > 1:
            _enospc(tmp_path / "x")()
        return real(*a, **k)
    monkeypatch.setattr(bp, "_save_policy", save)
    with pytest.raises(SystemExit) as e:
        train_main(["--method", "backprop", "--out", str(tmp_path), "--no-progress", "--quiet", "--hp", "n_steps=4",
                    "--hp", "eval_every=2", "--hp", "batch_episodes=2", "--hp", "hidden_size=4", "--hp",
                    "chunk_looks=5", "--hp", 'eval_scenarios={"random": 2, "random_radars": 2}'])
    _one_line(e, "could not write", "No space left", ".partial")
    part = next(tmp_path.glob("*.partial"))
    assert (part / "checkpoints" / "last.json").is_file()


def test_a_radar_site_out_of_range_of_the_whole_flight_is_refused():
    import gymnasium as gym

    import radar_env  # noqa: F401
    from radar_env.sim.radar import atc_radar
    with pytest.raises(ValueError) as e:
        gym.make("RadarTrack-v0", scenario="bizup2002", radar=atc_radar(position_m=(1e9, 0.0))).reset(seed=0)
    _one_line(e, "RadarSite.position_m", "bizup2002", "km")


@pytest.mark.parametrize("fname", ["model.pt", "env_config.json", "notes.txt"])
def test_a_file_that_is_not_a_policy_file_is_not_swapped_for_the_folders(tmp_path, fname):
    d = _copy(tmp_path, "policy_bp")
    (d / fname).write_text("{}")
    with pytest.raises(ValueError) as e:
        load_learned(d / fname)
    _one_line(e, fname, "give the folder")


def test_a_sweep_with_init_from_needs_the_opt_in_before_ray_starts(tmp_path):
    pytest.importorskip("ray")
    from agents.training.sweep import main as sweep_main
    z = tmp_path / "policy.zip"
    z.write_bytes(b"PK")
    cfg = tmp_path / "s.toml"
    cfg.write_text(f'[sweep]\nname = "s"\nalgo = "ppo"\nsearch = "grid"\n\n[base]\ninit_from = "{z}"\n\n'
                   '[space]\nseed = [0]\n')
    with pytest.raises(SystemExit) as e:
        sweep_main([str(cfg), "--out", str(tmp_path / "out"), "--quiet"])
    _one_line(e, "init_from", "--allow-pickle")
    assert not (tmp_path / "out").exists()


@pytest.mark.skipif("policy" not in KINDS_ON_DISK, reason="no bundled SB3 policy")
def test_a_ray_worker_unpickles_only_with_the_drivers_opt_in(tmp_path):
    from agents.evaluation.parallel import _policy_blob, _policy_in_worker
    d = _copy(tmp_path, "policy")
    (d / "policy.npz").unlink()
    blob = _policy_blob(d / "policy.zip")
    with pytest.raises(ValueError) as e:
        _policy_in_worker(blob)
    _one_line(e, "--allow-pickle")
    choose_q, cfg = _policy_in_worker(blob, allow_pickle=True)
    assert callable(choose_q)


@pytest.mark.parametrize("name", [n for n in ("policy", "policy_imm_ppo") if n in KINDS_ON_DISK])
@pytest.mark.parametrize("text,word", [("[]", "object"), ('{"scan": NaN}', "finite"), ("{", "JSON"),
                                       ('{"evil": 1}', "evil")])
def test_an_sb3_folders_env_config_goes_through_the_same_checks(tmp_path, name, text, word):
    d = _copy(tmp_path, name)
    if word == "evil":      # an unknown key beside the real ones
        text = json.dumps({**json.loads((d / "env_config.json").read_text()), "evil": 1})
    (d / "env_config.json").write_text(text)
    with pytest.raises(ValueError) as e:
        load_learned(d)
    _one_line(e, "env_config.json", word)


def test_a_full_disk_in_sweep_is_one_line_with_the_resume_command(tmp_path, monkeypatch):
    pytest.importorskip("ray")
    from agents.training import sweep
    monkeypatch.setattr(sweep, "run_sweep", _enospc(tmp_path / "out" / "results.csv"))
    with pytest.raises(SystemExit) as e:
        sweep.main([str(sweep.EXAMPLE_CONFIG), "--out", str(tmp_path / "out"), "--quiet"])
    _one_line(e, "results.csv", "No space left", "resume with: radar-track sweep")


@pytest.mark.parametrize("runs", ["0", "50001", "20000000"])
def test_tune_runs_are_bounded_before_any_episode_is_drawn(tmp_path, runs):
    """20,000,000 used to start drawing (about 2 TB of episodes, past the tuning seeds)."""
    from baselines.tuning import main as tune_main
    with pytest.raises(SystemExit, match=r"--runs must be in \[1, 50,000\]") as e:
        tune_main(["--runs", runs, "--trackers", "kf", "--starts", "1", "--out", str(tmp_path / "t.json")])
    assert "\n" not in str(e.value) and not (tmp_path / "t.json").exists()
