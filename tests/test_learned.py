"""One learned-tracker interface (agents.policies.learned): the bundled folders share one layout, one loader reads
any of them by the kind its policy.json names, and ``radar-track evaluate --learned`` runs them by that kind."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest

from agents.evaluation import evaluate as ev
from agents.policies.bundle import BUNDLED_POLICIES
from agents.policies.learned import (BUNDLED_LEARNED, CORRECTION_KINDS, IMM_KINDS, KINDS, Q_POLICY_KINDS, SB3_KINDS,
                                    load_learned, read_kind, resolve_learned)

EXPECTED_KIND = {"policy": "ppo_q_policy", "policy_bp": "gru_q_policy", "policy_imm_bp": "learned_imm_gru",
                 "policy_imm_ppo": "learned_imm_ppo", "policy_bp_rdot": "gru_q_policy",
                 "policy_imm_bp_rdot": "learned_imm_gru", "policy_imm_bp_prior": "learned_imm_gru",
                 "policy_window": "window_correction",
                 "policy_bp_prior": "gru_q_policy"}
LAYOUT = {"policy.npz", "policy.json", "env_config.json", "training.json", "choice.json"}
QUICK = ["--scenario", "random", "--runs", "2", "--no-plots", "--quiet"]

needs_bundle = pytest.mark.skipif(not all(p.is_file() for p in BUNDLED_POLICIES.values()),
                                  reason="no bundled learned trackers")


@needs_bundle
@pytest.mark.parametrize("name", list(BUNDLED_LEARNED))
def test_bundled_folders_share_one_layout_and_load_by_kind(name):
    folder = BUNDLED_LEARNED[name]
    assert LAYOUT <= {f.name for f in folder.iterdir()}, name
    assert json.loads((folder / "policy.json").read_text())["kind"] == EXPECTED_KIND[name]
    # the weights file the --policy options take: the zip for a stable-baselines3 kind, the npz otherwise
    assert BUNDLED_POLICIES[name].is_file()
    assert (BUNDLED_POLICIES[name].suffix == ".zip") == (EXPECTED_KIND[name] in SB3_KINDS), name
    lt = load_learned(name)
    assert (lt.kind, lt.name, lt.folder) == (EXPECTED_KIND[name], name, folder)
    assert bool(getattr(lt.policy, "is_tracker", False)) == (lt.kind in IMM_KINDS + CORRECTION_KINDS)
    # by folder path: the same tracker, reported under its bundled name
    assert load_learned(str(folder)).name == name
    # its own run is the evaluation's run of it (the same numbers, under its name)
    from agents.evaluation.runner import run_policy
    from agents.evaluation.suites import draw_suite
    eps = draw_suite("kim_lee_accel", 2)
    mine, evals = lt.run(eps), run_policy(name, eps, lt.policy, lt.env_config)
    assert mine.name == name and np.isfinite(mine.x[:, -1]).all()          # NaN before a track starts only
    assert np.array_equal(mine.x, evals.x, equal_nan=True)
    # the chosen seed's weights are the bundled ones (the choice record says which); an ensemble's chosen seeds are
    # its members (ensemble.json's digests; tests/test_window_ensemble.py checks the networks)
    choice = json.loads((folder / "choice.json").read_text())
    if choice.get("ensemble"):
        import hashlib
        made = json.loads((folder / "ensemble.json").read_text())
        assert [m["policy_npz_sha256"] for m in made["members"]] == [
            hashlib.sha256((folder / "seeds" / c / "policy.npz").read_bytes()).hexdigest() for c in choice["chosen"]]
    elif (folder / "seeds").is_dir():
        assert (folder / "seeds" / choice["chosen"] / "policy.npz").read_bytes() == (folder / "policy.npz").read_bytes()


@needs_bundle
def test_kind_is_read_from_policy_json_and_refused_where_not_accepted(tmp_path, monkeypatch):
    d = tmp_path / "my_imm"
    shutil.copytree(BUNDLED_LEARNED["policy_imm_bp"], d, ignore=shutil.ignore_patterns("seeds"))
    with pytest.raises(ValueError, match=r"my_imm/policy.json: kind 'learned_imm_gru'") as e:
        load_learned(d, kinds=Q_POLICY_KINDS)
    assert "\n" not in str(e.value)
    meta = json.loads((d / "policy.json").read_text())
    (d / "policy.json").write_text(json.dumps({**meta, "kind": "nope"}))
    with pytest.raises(ValueError, match=r"policy.json: field 'kind' is 'nope'"):
        read_kind(d)
    (d / "policy.json").write_text("[1, 2]")
    with pytest.raises(ValueError, match=r"policy.json: must hold a JSON object with a 'kind' field"):
        read_kind(d)
    (d / "policy.json").unlink()
    with pytest.raises(ValueError, match=r"not a learned tracker folder"):
        read_kind(d)
    with pytest.raises(ValueError, match=r"neither a bundled learned tracker"):
        resolve_learned(tmp_path / "missing")
    # a bundled name means the bundled tracker even beside a folder of that name (given as ./policy_bp)
    (tmp_path / "policy_bp").mkdir()
    monkeypatch.chdir(tmp_path)
    assert resolve_learned("policy_bp") == (BUNDLED_LEARNED["policy_bp"], None, "policy_bp")
    assert resolve_learned("./policy_bp")[0].resolve() == (tmp_path / "policy_bp").resolve()
    assert set(Q_POLICY_KINDS) | set(IMM_KINDS) | set(CORRECTION_KINDS) == set(KINDS)


@needs_bundle
@pytest.mark.parametrize("name, change, match", [
    ("policy_imm_bp", {"kind": ["learned_imm_gru"]}, r"field 'kind' is \['learned_imm_gru'\], not one of"),
    ("policy", {"version": True}, r"must have format 'radar-track-learned-tracker' and version 1, got .* and True"),
    ("policy", {"version": 99}, r"version 1, got .* and 99"),
    ("policy_imm_ppo", {"format": "zzz"}, r"must have format 'radar-track-learned-tracker'"),
    ("policy_bp", {"version": True}, r"version True; this package reads version 1"),
    ("policy_imm_bp", {"model": "zzz"}, r"field 'model' is 'zzz'; a learned IMM runs the 'imm_cv_ct' model"),
])
def test_a_policy_json_field_of_the_wrong_type_or_value_is_refused_in_one_line(tmp_path, name, change, match):
    d = tmp_path / "t"
    shutil.copytree(BUNDLED_LEARNED[name], d, ignore=shutil.ignore_patterns("seeds", "recipe", "realisations"))
    meta = json.loads((d / "policy.json").read_text())
    (d / "policy.json").write_text(json.dumps({**meta, **change}))
    with pytest.raises(ValueError, match=match) as e:
        load_learned(d)
    assert "\n" not in str(e.value)


@needs_bundle
def test_a_policy_json_that_is_deep_or_not_a_file_is_refused_in_one_line(tmp_path):
    d = tmp_path / "t"
    shutil.copytree(BUNDLED_LEARNED["policy"], d, ignore=shutil.ignore_patterns("recipe"))
    (d / "policy.json").write_text("[" * 100_000 + "]" * 100_000)
    with pytest.raises(ValueError, match=r"policy.json: not readable as JSON of finite numbers"):
        load_learned(d)
    (d / "policy.json").unlink()
    (d / "policy.json").mkdir()        # not silently guessed from policy.zip
    with pytest.raises(ValueError, match=r"policy.json: is not a regular file"):
        load_learned(d)
    (d / "policy.json").rmdir()
    (d / "policy.json").symlink_to(d / "policy.json")
    with pytest.raises(ValueError, match=r"policy.json: is not a regular file"):
        load_learned(d)


@needs_bundle
def test_an_sb3_export_with_a_foreign_array_or_half_precision_weights_is_refused():
    from agents.policies.checks import read_npz
    from agents.policies.numpy_policy import NumpyPolicy
    arrays = read_npz(BUNDLED_LEARNED["policy"] / "policy.npz")
    NumpyPolicy(arrays)                                                   # as shipped: loads
    with pytest.raises(ValueError, match=r"arrays \['W9'\] are not part of the format"):
        NumpyPolicy({**arrays, "W9": arrays["W0"]})
    with pytest.raises(ValueError, match=r"W1 is float16, not float32 or float64"):
        NumpyPolicy({**arrays, "W1": arrays["W1"].astype(np.float16)})


def test_folders_before_the_layout_get_their_kind_from_their_files(tmp_path):
    """A training run written before policy.json named the kind: an SB3 zip (algo from config.json, the IMM from
    env_config.json), a recurrent checkpoint (its policy.json's format)."""
    from agents.policies import learned_imm, recurrent
    run = tmp_path / "run"
    (run / "best").mkdir(parents=True)
    (run / "config.json").write_text(json.dumps({"algo": "sac"}))
    (run / "best" / "policy.zip").write_bytes(b"")
    (run / "best" / "env_config.json").write_text(json.dumps({"tracker": "imm_cv_ct"}))
    assert read_kind(run / "best")[0] == "learned_imm_sac"
    (run / "best" / "env_config.json").write_text("{}")
    assert read_kind(run / "best")[0] == "sac_q_policy"
    for fmt, kind in ((recurrent.FORMAT, "gru_q_policy"), (learned_imm.FORMAT, "learned_imm_gru")):
        (run / "policy.json").write_text(json.dumps({"format": fmt, "version": 1}))
        assert read_kind(run) == (kind, str(run / "policy.json"))


@needs_bundle
def test_evaluate_learned_by_name_and_by_user_folder(tmp_path, capsys):
    """``--learned`` takes bundled names and folders; a user folder runs as its kind under its folder's name with
    the same numbers as the bundled tracker it copies; the old option is an alias with a note on stderr."""
    mine = tmp_path / "my_bp"
    shutil.copytree(BUNDLED_LEARNED["policy_bp"], mine, ignore=shutil.ignore_patterns("seeds"))
    out = tmp_path / "r.json"
    res = ev.main(["--learned", "policy_bp", "--learned", str(mine), "--trackers", "imm2", "--json", str(out), *QUICK])
    t = res["random"]["trackers"]
    assert list(t) == ["imm2", "policy_bp", "my_bp"]
    assert t["my_bp"]["pos_rmse_m"] == t["policy_bp"]["pos_rmse_m"] and np.isfinite(t["my_bp"]["pos_rmse_m"])
    meta = json.loads(out.read_text())["meta"]
    assert meta["learned"]["my_bp"] == {"kind": "gru_q_policy", "folder": str(mine)}
    capsys.readouterr()
    res = ev.main(["--policy-bp", str(mine / "policy.npz"), "--trackers", "policy_bp", *QUICK])
    assert res["random"]["trackers"]["policy_bp"]["pos_rmse_m"] == t["policy_bp"]["pos_rmse_m"]
    err = capsys.readouterr().err
    assert "--policy-bp is deprecated" in err and len([ln for ln in err.splitlines() if "deprecated" in ln]) == 1


@needs_bundle
def test_evaluate_learned_adds_a_bundled_tracker_outside_the_default_list(tmp_path):
    """Without ``--trackers``, ``--learned policy_window`` (bundled, not among the main job's defaults: the README's
    command) runs after the default learned trackers, and a user folder after it, in the order given (it was
    dropped without a word)."""
    mine = tmp_path / "my_bp"
    shutil.copytree(BUNDLED_LEARNED["policy_bp"], mine, ignore=shutil.ignore_patterns("seeds"))
    res = ev.main(["--learned", "policy_window", "--learned", str(mine), *QUICK])
    names = list(res["random"]["trackers"])
    default_learned = [t for t in names if t in BUNDLED_LEARNED and t != "policy_window"]
    assert names[len(default_learned):len(default_learned) + 2] == ["policy_window", "my_bp"], names
    assert np.isfinite(res["random"]["trackers"]["policy_window"]["pos_rmse_m"])


def test_first_line_counts_each_learned_tracker_once():
    from agents.evaluation.options import first_line
    parse = ev.build_parser("radar-track evaluate").parse_args
    for args, n in [(["--learned", "policy_window", "--trackers", "imm2"], 2),
                    (["--learned", "policy_bp", "--trackers", "policy_bp,imm2"], 2),
                    (["--learned", "runs/mine/best", "--trackers", "imm2"], 2)]:
        assert f": {n} tracker(s) on" in first_line(parse(args)), (args, first_line(parse(args)))


@needs_bundle
def test_evaluate_refuses_a_wrong_kind_a_clashing_label_and_a_tracker_given_twice(tmp_path):
    imm = tmp_path / "my_imm"
    shutil.copytree(BUNDLED_LEARNED["policy_imm_bp"], imm, ignore=shutil.ignore_patterns("seeds"))
    cases = [(["--policy-bp", str(imm / "policy.npz"), "--trackers", "imm2"],
              "error: --policy-bp: ", "kind 'learned_imm_gru'"),
             (["--policy-imm-ppo", str(BUNDLED_POLICIES["policy"]), "--trackers", "imm2"],
              "error: --policy-imm-ppo: ", "kind 'ppo_q_policy'"),
             (["--learned", str(shutil.copytree(imm, tmp_path / "imm2")), "--trackers", "kf_tuned"],
              "error: --learned: ", "'imm2' (the folder's name) is a built-in tracker's name"),
             (["--learned", "policy_bp", "--learned", str(BUNDLED_LEARNED["policy_bp"]), "--trackers", "imm2"],
              "error: --learned: ", "already given by --learned 'policy_bp'")]
    for args, start, what in cases:
        with pytest.raises(SystemExit) as e:
            ev.main(args + QUICK)
        msg = str(e.value)
        assert msg.startswith(start) and what in msg and "\n" not in msg, (args, msg)
