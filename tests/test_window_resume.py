"""The window trainer resumes a stopped run from its last validation's checkpoint with the numbers an unstopped run
has (weights, best epoch, history, to the bit), and refuses to resume a run of another configuration."""
import json

import numpy as np
import pytest

from agents.training import window
from agents.training.runs import RunInterrupted, load_hyperparams

HP = {**load_hyperparams("window"), "base": "policy_bp", "window_looks": 6, "fit_looks": [4, 6], "q_looks": 3,
      "layers": [16, 16], "episodes": 6, "epochs": 4, "eval_every": 1, "fresh_flights_every": 2,
      "batch_looks": 256, "covariance_epochs": 0, "scenarios": ["random", "random_broad"],
      "eval_scenarios": {"random": 3, "random_radars": 3}, "select_on": ["random", "random_radars"]}


def _stop_at_second_draw(monkeypatch):
    """Ctrl-C during the second draw of flights (epoch 3), after epoch 2's checkpoint."""
    real, calls = window.draw_training_looks, []

    def draw(*a, **k):
        calls.append(1)
        if len(calls) == 2:
            raise KeyboardInterrupt
        return real(*a, **k)
    monkeypatch.setattr(window, "draw_training_looks", draw)


def _history(run):
    s = json.loads((run / "summary.json").read_text())
    return s, [{k: v for k, v in r.items() if k != "wall_s"} for r in s["selection_history"]]


@pytest.mark.parametrize("dtype", ["float64", "float32"])
def test_a_stopped_window_run_resumes_to_the_numbers_of_one_never_stopped(tmp_path, monkeypatch, dtype):
    """In either training precision (float32: the network's weights and Adam's moments in float32, saved as float64
    as every correction's)."""
    hp = {**HP, "dtype": dtype}
    whole = window.train_window(hp, seed=700, out=tmp_path, verbose=0, run_name="whole")
    with monkeypatch.context() as m:
        _stop_at_second_draw(m)
        with pytest.raises(RunInterrupted) as e:
            window.train_window(hp, seed=700, out=tmp_path, verbose=0, run_name="stopped")
    assert e.value.resumable and "resume" in e.value.message("radar-track train --method window --seed 700")
    part = tmp_path / "stopped.partial"
    assert json.loads((part / "checkpoints" / "last.json").read_text())["epoch"] == 2
    # another configuration under this name is refused, naming what differs; the checkpoint is left as it was
    with pytest.raises(ValueError, match=r"--name: .*another configuration \(differs in \['learning_rate'\]\)"):
        window.train_window({**hp, "learning_rate": 1e-3}, seed=700, out=tmp_path, verbose=0, run_name="stopped")
    resumed = window.train_window(hp, seed=700, out=tmp_path, verbose=0, run_name="stopped")
    for f in ("policy.npz", "best/policy.npz"):
        a, b = np.load(whole / f), np.load(resumed / f)
        assert sorted(a.files) == sorted(b.files)
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k])
    (sw, hw), (sr, hr) = _history(whole), _history(resumed)
    assert hw == hr and len(hw) == 4
    assert sr["resumed_at"] == [2] and sw["resumed_at"] == [] and sr["best_epoch"] == sw["best_epoch"]
    assert not (resumed / "FAILED").exists()
    w = np.load(resumed / "policy.npz")
    assert all(w[k].dtype == np.float64 for k in w.files)


def test_a_run_stopped_after_its_last_epoch_resumes_to_its_end(tmp_path, monkeypatch):
    """Stopped during the covariance head's fit (after the last epoch's checkpoint): the same command finishes the
    run without training again, with the weights and heads of a run never stopped."""
    hp = {**HP, "covariance_epochs": 1, "epochs": 2, "fresh_flights_every": 2}      # one draw: the last is the first
    whole = window.train_window(hp, seed=701, out=tmp_path, verbose=0, run_name="whole")
    real = window._with_covariance

    def stop(*a, **k):
        raise KeyboardInterrupt
    monkeypatch.setattr(window, "_with_covariance", stop)
    with pytest.raises(RunInterrupted):
        window.train_window(hp, seed=701, out=tmp_path, verbose=0, run_name="stopped")
    monkeypatch.setattr(window, "_with_covariance", real)
    resumed = window.train_window(hp, seed=701, out=tmp_path, verbose=0, run_name="stopped")
    for f in ("policy.npz", "best/policy.npz"):
        a, b = np.load(whole / f), np.load(resumed / f)
        assert sorted(a.files) == sorted(b.files) and "cov.weight" in a.files
        for k in a.files:
            np.testing.assert_array_equal(a[k], b[k])
    (sw, hw), (sr, hr) = _history(whole), _history(resumed)
    assert hw == hr and sr["resumed_at"] == [2] and sr["training_looks"] == sw["training_looks"]


def test_a_damaged_checkpoint_is_refused_in_one_line(tmp_path, monkeypatch):
    with monkeypatch.context() as m:
        _stop_at_second_draw(m)
        with pytest.raises(RunInterrupted):
            window.train_window(HP, seed=702, out=tmp_path, verbose=0, run_name="r")
    npz = tmp_path / "r.partial" / "checkpoints" / "last.npz"
    good = npz.read_bytes()
    for damage in (good[: len(good) // 2], b"not a checkpoint"):
        npz.write_bytes(damage)
        with pytest.raises(ValueError, match=r"^--name: the checkpoint .*last\.npz cannot be resumed \(.*\); remove "):
            window.train_window(HP, seed=702, out=tmp_path, verbose=0, run_name="r")
    npz.write_bytes(good)       # intact again: it resumes
    assert json.loads((window.train_window(HP, seed=702, out=tmp_path, verbose=0, run_name="r")
                       / "summary.json").read_text())["resumed_at"] == [2]
