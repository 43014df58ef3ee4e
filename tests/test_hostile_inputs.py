"""Hostile and mistaken files: nothing silently wrong, nothing written where it should not be.

* policies: a model whose stored observation bounds or recorded training env differ from the env config it is
  given is refused naming the field; the help texts say a policy file is code;
* paths: ``--json`` never replaces an input or writes through a link, plots replace links in ``--out`` instead of
  following them, sweep and run names are plain folder names, ``--tracker-module`` imports only what it names and
  restores ``sys.path``;
* inputs: a truncated, corrupt or binary ADS-B file and a ``.csv.gz`` given as a scenario are one-line errors naming
  the file and the reason; swapped latitude/longitude is refused by the loader's own speed check; a flight far
  outside its radar's range warns; a CSV too short for any warm-up does not suggest ``warmup_scans <= 0``;
* metrics: ANEES only from looks whose covariance is positive definite (never negative), flagged where few; a
  bound tracker worse than a real one is flagged in the table.
"""

from __future__ import annotations

import gzip
import json
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from agents.evaluation import evaluate as ev
from agents.evaluation.metrics import nees_values
from agents.policies.bundle import BUNDLED_POLICY, embed_env_config, policy_env_kwargs
from agents.policies.loading import load_policy
from baselines.user_trackers import import_tracker_module
from radar_env.sim import adsb
from radar_env.envs.env import RadarTrackEnv
from test_cli_errors import _write_flight

QUICK = ["--no-plots", "--quiet"]
BASE = ["--scenario", "kim_lee_accel", "--runs", "2", "--trackers", "kf_low"]


def _one_line(excinfo, *words):
    msg = str(excinfo.value)
    assert "\n" not in msg, msg
    for w in words:
        assert w in msg, (w, msg)
    return msg


# ------------------------------------------------------------------------------------------------ policy files
needs_bundle = pytest.mark.skipif(not BUNDLED_POLICY.is_file(), reason="no bundled policy")


def _copy_policy(tmp_path, with_record=False):
    d = tmp_path / "pol"
    d.mkdir()
    shutil.copy(BUNDLED_POLICY, d / "policy.zip")
    shutil.copy(BUNDLED_POLICY.with_suffix(".npz"), d / "policy.npz")      # its numpy export: no unpickling
    shutil.copy(BUNDLED_POLICY.with_name("env_config.json"), d / "env_config.json")
    if with_record:
        shutil.copy(BUNDLED_POLICY.with_name("training.json"), d / "training.json")
    return d


def _edit_env_config(d, **changes):
    kw = json.loads((d / "env_config.json").read_text())
    kw.update(changes)
    (d / "env_config.json").write_text(json.dumps(kw))


@needs_bundle
def test_reordered_features_are_refused_by_the_stored_observation_bounds(tmp_path):
    """Same feature count, another order: the model's stored Box bounds differ entry by entry from the env's."""
    d = _copy_policy(tmp_path)
    feats = list(policy_env_kwargs(d / "policy.zip")["features"])
    feats[0], feats[2] = feats[2], feats[0]            # nu_along [-1, 1] <-> nis [0, 1]
    _edit_env_config(d, features=feats)
    with pytest.raises(ValueError) as e:
        load_policy(d / "policy.zip")
    _one_line(e, "observation bounds", "'features'", "entry 0", feats[0])


@needs_bundle
@pytest.mark.parametrize("record", ["train_config", "embedded"])
def test_other_q_levels_of_the_same_count_are_refused_by_the_training_record(tmp_path, record):
    """The bounds cannot see the q levels; the record of the training env can (the bundle's training.json, or
    the copy training embeds in the zip)."""
    d = _copy_policy(tmp_path, with_record=record == "train_config")
    if record == "embedded":
        embed_env_config(d / "policy.zip", json.loads((d / "env_config.json").read_text()))
    load_policy(d / "policy.zip", allow_pickle=True)    # unchanged: loads (the embedding made the export stale)
    levels = [2.0 * v for v in json.loads((d / "env_config.json").read_text())["q_levels_g"]]
    levels[-1] = min(levels[-1], 100.0)
    _edit_env_config(d, q_levels_g=levels)
    with pytest.raises(ValueError) as e:
        load_policy(d / "policy.zip")
    _one_line(e, "q_levels_g", "trained with")


def test_evaluate_and_train_help_say_policy_files_run_code():
    from agents.training.train import build_parser as train_parser
    for text in (ev.build_parser().format_help(), train_parser().format_help()):
        flat = " ".join(text.split())
        assert "pickle" in flat and "runs the code" in flat and "trust" in flat, flat


# ------------------------------------------------------------------------------------------------ output paths
def test_json_never_replaces_an_input_file(tmp_path):
    f = _write_flight(tmp_path / "flight.csv")
    before = f.read_bytes()
    with pytest.raises(SystemExit) as e:
        ev.main(["--trajectory", str(f), "--runs", "2", "--trackers", "kf_low", "--json", str(f), *QUICK])
    _one_line(e, "--json", "input")
    assert f.read_bytes() == before


def test_json_through_a_symbolic_link_is_refused(tmp_path):
    target = tmp_path / "outside.txt"
    target.write_text("keep")
    link = tmp_path / "out" / "m.json"
    link.parent.mkdir()
    link.symlink_to(target)
    with pytest.raises(SystemExit) as e:
        ev.main([*BASE, "--json", str(link), *QUICK])
    _one_line(e, "--json", "symbolic link")
    assert target.read_text() == "keep"


def test_plots_replace_links_in_out_and_never_follow_them(tmp_path):
    out = tmp_path / "plots"
    out.mkdir()
    target = tmp_path / "outside.png"
    target.write_text("keep")
    res = ev.main([*BASE, "--out", str(out), "--quiet", "--json", str(tmp_path / "m.json")])
    names = sorted(p.name for p in out.iterdir())
    assert names and res
    for n in names:                                     # plant links where the plots go, then run again
        (out / n).unlink()
        (out / n).symlink_to(target)
    ev.main([*BASE, "--out", str(out), "--quiet"])
    assert target.read_text() == "keep"
    assert sorted(p.name for p in out.iterdir()) == names
    assert all(not (out / n).is_symlink() and (out / n).stat().st_size > 1000 for n in names)


@pytest.mark.parametrize("name", ["../x", "/tmp/abs_sweep", "a/b", ".."])
def test_sweep_name_must_be_a_plain_folder_name(tmp_path, name):
    from agents.training.sweep import load_sweep_config
    cfg = tmp_path / "s.toml"
    cfg.write_text(f'[sweep]\nname = "{name}"\n[space]\nseed = [0]\n')
    with pytest.raises(ValueError) as e:
        load_sweep_config(cfg)
    _one_line(e, "[sweep] name", "plain folder name")


def test_tracker_module_imports_only_what_it_names_and_restores_sys_path(tmp_path, monkeypatch):
    """A stray module beside the tracker module (say a tqdm.py) must not become importable: the current directory
    is not left on sys.path, and what the module did to sys.path is undone."""
    (tmp_path / "stray_shadow_module.py").write_text("raise RuntimeError('the stray module ran')\n")
    (tmp_path / "my_rel_trackers.py").write_text(
        "import sys\nsys.path.insert(0, '/nonexistent/added_by_module')\n"
        "from baselines.registry import register_tracker\n"
        "register_tracker('rel_mine', lambda looks, start: (None, None), overwrite=True)\n")
    monkeypatch.chdir(tmp_path)
    before = list(sys.path)
    mod = import_tracker_module("my_rel_trackers")
    assert mod.__name__ == "my_rel_trackers" and Path(mod.__file__).parent == tmp_path
    assert sys.path == before
    import importlib.util
    assert importlib.util.find_spec("stray_shadow_module") is None
    sys.modules.pop("my_rel_trackers", None)


# ------------------------------------------------------------------------------------------------ input files
def _shipped_gz():
    return adsb.flight_path("brussels_vor")


@pytest.mark.parametrize("kind, reason", [("truncated", "truncated gzip"), ("garbage", "not a readable gzip"),
                                          ("binary", "not UTF-8 text")])
def test_bad_adsb_files_are_one_line_errors_naming_file_and_reason(tmp_path, kind, reason):
    raw = _shipped_gz().read_bytes()
    if kind == "truncated":
        f = tmp_path / "flight.csv.gz"
        f.write_bytes(raw[: len(raw) // 2])
    elif kind == "garbage":
        f = tmp_path / "flight.csv.gz"
        f.write_bytes(b"this is not gzip at all\n" * 10)
    else:
        f = tmp_path / "flight.csv"
        f.write_bytes(b"t_s,lat_deg,lon_deg\n\xff\xfe\x00\x01")
    with pytest.raises(ValueError) as e:
        adsb.load_trajectory(f)
    _one_line(e, str(f), reason)
    with pytest.raises(SystemExit) as e:                # through the evaluation: the same message, one line
        ev.main(["--scenario", f"adsb:{f}", "--runs", "1", "--trackers", "kf_low", *QUICK])
    _one_line(e, str(f), reason)


def test_a_csv_gz_given_as_a_scenario_names_the_file(tmp_path):
    f = tmp_path / "flight.csv.gz"
    f.write_bytes(_shipped_gz().read_bytes()[:100])
    with pytest.raises(SystemExit) as e:
        ev.main(["--scenario", str(f), "--runs", "1", "--trackers", "kf_low", *QUICK])
    msg = _one_line(e, str(f), "adsb:")
    assert "unknown scenario" not in msg


def test_swapped_latitude_and_longitude_are_refused(tmp_path):
    lines = gzip.decompress(_shipped_gz().read_bytes()).decode().splitlines()
    head = lines[0].split(",")
    i, j = head.index("lat_deg"), head.index("lon_deg")
    out = [lines[0]]
    for ln in lines[1:]:
        c = ln.split(",")
        c[i], c[j] = c[j], c[i]
        out.append(",".join(c))
    f = tmp_path / "swapped.csv"
    f.write_text("\n".join(out) + "\n")
    assert adsb.load_trajectory(_shipped_gz()).check["speed_rms_m_s"] < 5.0      # the file as shipped: 2.8 m/s
    with pytest.raises(ValueError) as e:
        adsb.load_trajectory(f)
    _one_line(e, str(f), "lat_deg and lon_deg look swapped")


@pytest.mark.parametrize("flight", adsb.list_flights())
def test_shipped_flights_pass_the_swap_check(flight):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        adsb.load_trajectory(flight)


def test_a_flight_far_outside_its_radars_range_warns(tmp_path):
    """A 10-hour straight flight at 220 m/s: 7,900 km from a radar placed 10-150 km from its start."""
    f = _write_flight(tmp_path / "long.csv", speed_m_s=220.0, duration_s=36000.0)
    with pytest.warns(UserWarning, match=r"beyond 463 km from its radar \(250 NM\).*up to [0-9,]+ km"):
        RadarTrackEnv(scenario=str(f)).reset(seed=0)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        RadarTrackEnv(scenario=str(_write_flight(tmp_path / "short.csv"))).reset(seed=0)


def test_a_csv_too_short_for_any_warmup_does_not_suggest_warmup_zero(tmp_path):
    f = _write_flight(tmp_path / "tiny.csv", duration_s=12.0)          # 3 looks of a 5 s radar
    with pytest.raises(ValueError) as e:
        RadarTrackEnv(scenario=str(f), warmup_scans=1)
    msg = _one_line(e, "no warm-up fits")
    assert "<= 0" not in msg and "<= -" not in msg


# ------------------------------------------------------------------------------------------------ metrics
def test_nees_only_from_positive_definite_covariances_and_never_negative():
    rng = np.random.default_rng(0)
    d = rng.normal(size=(6, 4)) * 10
    good = np.diag([4.0, 9.0, 1.0, 2.0])
    indefinite = np.diag([4.0, -1e-9, 1.0, 2.0])
    tiny_neg = np.diag([1e12, 1e12, 1e-3, 1e-3])
    tiny_neg[2, 3] = tiny_neg[3, 2] = 1e-3 + 1e-9       # eigenvalues 2e-3 and -1e-9: indefinite
    asym = good.copy()
    asym[0, 1] = 1.0
    P = np.stack([good, indefinite, tiny_neg, asym, np.full((4, 4), np.nan), good])
    nees = nees_values(d, P)
    ref = np.einsum("i,ij,j", d[0], np.linalg.inv(good), d[0])
    assert nees[0] == pytest.approx(ref) and nees[5] > 0
    assert np.isnan(nees[1:5]).all()


def test_anees_is_flagged_where_few_looks_are_valid_and_a_beaten_bound_is_flagged():
    from agents.evaluation.evaluate import bounds_beaten, format_table, table_notes
    from agents.evaluation.metrics import evaluate_run
    from agents.evaluation.suites import draw_suite
    from baselines.registry import run_tracker
    from radar_env.sim.episode import stack_episodes
    eps = draw_suite("kim_lee_accel", 3)
    batch = stack_episodes(eps)
    run = run_tracker("kf_tuned", eps)
    m = evaluate_run(batch, run)
    assert m["nees_invalid_looks"] == 0 and not m["anees_few_valid_looks"]
    bad = run_tracker("kf_tuned", eps)
    bad.P[:, :, 1, 1] = -1.0                            # no look has a covariance: ANEES undefined, flagged
    half = run_tracker("kf_tuned", eps)
    half.P[0, :, 1, 1] = -1.0                           # a third of the runs
    mb, mh = evaluate_run(batch, bad), evaluate_run(batch, half)
    assert np.isnan(mb["anees"]) and mb["nees_valid_looks"] == 0 and "anees" in mb["undefined"]
    assert mh["anees_few_valid_looks"] and mh["nees_valid_looks"] > 0 and mh["anees"] > 0
    trackers = {"imm2": {**m, "pos_rmse_m": 70.0}, "clairvoyant": {**m, "pos_rmse_m": 648e3},
                "kf_half": mh}
    beaten = bounds_beaten(trackers)
    assert list(beaten) == ["clairvoyant"] and beaten["clairvoyant"]["beaten_by"] == "imm2"
    res = {"runs": 3, "looks_per_run_mean": 100.0, "trackers": trackers, "bounds_beaten": beaten}
    notes = " ".join(table_notes(res))
    assert "clairvoyant: NOT A BOUND" in notes and "imm2's 70.0 m" in notes
    assert "kf_half: ANEES from only" in notes
    table = format_table({"s": res})
    assert f"{mh['anees']:.2f}*" in table
