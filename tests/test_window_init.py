"""``--hp init``: a window run that starts from a saved correction's network computes that network's function at its
first step (the standardisation unfolded into the first layer and folded back on saving), and a folder of another
shape is refused in one line before anything is drawn."""
import json

import numpy as np
import pytest

from agents.training import window
from agents.training.runs import load_hyperparams

HP = {**load_hyperparams("window"), "base": "policy_bp", "window_looks": 6, "fit_looks": [4, 6], "q_looks": 3,
      "layers": [16, 16], "episodes": 6, "epochs": 1, "eval_every": 1, "fresh_flights_every": 0,
      "batch_looks": 256, "covariance_epochs": 0, "scenarios": ["random"],
      "eval_scenarios": {"random": 3, "random_radars": 3}, "select_on": ["random", "random_radars"]}


def test_a_run_started_from_a_correction_keeps_its_network_at_a_vanishing_learning_rate(tmp_path):
    first = window.train_window({**HP, "dtype": "float64"}, seed=700, out=tmp_path, verbose=0, run_name="first")
    # other flights (seed), so another standardisation: the unfolding must carry the network over exactly
    again = window.train_window({**HP, "dtype": "float64", "init": str(first), "learning_rate": 1e-12}, seed=900,
                                out=tmp_path, verbose=0, run_name="again")
    a, b = np.load(first / "policy.npz"), np.load(again / "policy.npz")
    assert sorted(a.files) == sorted(b.files)
    for k in a.files:
        np.testing.assert_allclose(b[k], a[k], rtol=1e-9, atol=1e-9)
    # a run without init records none (its config is what it was before init existed: older runs still resume)
    assert "init" not in json.loads((first / "config.json").read_text())
    assert json.loads((again / "config.json").read_text())["init"] == str(first)
    fresh = window.train_window({**HP, "dtype": "float64", "learning_rate": 1e-12}, seed=900, out=tmp_path, verbose=0,
                                run_name="fresh")
    assert not np.allclose(np.load(fresh / "policy.npz")["out.weight"], a["out.weight"])   # not by chance


@pytest.mark.parametrize("change, message", [({"layers": [8, 8]}, "must be a window correction with the run's"),
                                             ({"init": "no/such/folder"}, "holds no policy.json")])
def test_an_init_folder_that_does_not_fit_is_refused_in_one_line(tmp_path, change, message):
    first = window.train_window({**HP, "dtype": "float64"}, seed=700, out=tmp_path, verbose=0, run_name="first")
    hp = {**HP, "init": str(first), **change}
    with pytest.raises(ValueError, match=message) as e:
        window.train_window(hp, seed=701, out=tmp_path, verbose=0, run_name="bad")
    assert "\n" not in str(e.value) and "--hp init" in str(e.value)
    assert not list(tmp_path.glob("bad*"))                      # refused before a run folder was made


def test_an_init_folder_with_a_damaged_policy_json_is_refused_in_one_line(tmp_path):
    (tmp_path / "bad").mkdir()
    (tmp_path / "bad" / "policy.json").write_text("{not json")
    with pytest.raises(ValueError, match="--hp init: ") as e:
        window.check_hp({**HP, "init": str(tmp_path / "bad")})
    assert "\n" not in str(e.value) and "policy.json" in str(e.value)


def test_init_must_be_a_string():
    with pytest.raises(ValueError, match="--hp init: a window-correction folder"):
        window.check_hp({**HP, "init": 3})
