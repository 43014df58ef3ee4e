"""The window trainer's training flights: first_leg_min_s and the hyperparameter checks around it."""

import pytest

from agents.training import window
from agents.training.runs import load_hyperparams
from radar_env.sim.scenario import RandomScenarioConfig


def test_training_config_is_the_suites_own_unless_first_leg_min_s_differs():
    hp = load_hyperparams("window")
    assert hp["first_leg_min_s"] == 0.0                             # the bundled eighth recipe's
    assert window.training_config(hp) == RandomScenarioConfig(first_leg_min_s=0.0)
    own = RandomScenarioConfig().first_leg_min_s                    # the suites' own 90 s: their own config
    assert window.training_config({**hp, "first_leg_min_s": own}) is None
    assert window.training_config({k: v for k, v in hp.items() if k != "first_leg_min_s"}) is None   # older runs


def test_training_flights_are_drawn_with_that_config(monkeypatch):
    import agents.evaluation.suites as suites
    seen = []

    def fake(name, runs, seed, random_config=None):
        seen.append((name, runs, seed, random_config))
        raise StopIteration                      # enough: the draw's arguments are what is checked

    monkeypatch.setattr(suites, "draw_suite", fake)
    hp = {**load_hyperparams("window"), "first_leg_min_s": 0.0, "episodes": 7}
    with pytest.raises(StopIteration):
        window.draw_training_looks(None, hp, 123)
    assert seen == [("random", 7, 123, RandomScenarioConfig(first_leg_min_s=0.0))]


@pytest.mark.parametrize("key, value, match", [
    ("first_leg_min_s", -1.0, r"first_leg_min_s: must be a number of seconds in \[0, 1e5\], got -1.0"),
    ("first_leg_min_s", True, "first_leg_min_s"),
    ("first_leg_min_s", "0", "first_leg_min_s"),
    ("eval_scenarios", "{random=100}", r"eval_scenarios: a JSON object \{suite: runs >= 1\}"),
    ("eval_scenarios", {"random": 0}, "eval_scenarios"),
    ("select_on", "random", "select_on: a list of suite names"),
])
def test_bad_values_are_refused_in_one_line(key, value, match):
    hp = {**load_hyperparams("window"), key: value}
    with pytest.raises(ValueError, match=match) as e:
        window.check_hp(hp)
    assert "\n" not in str(e.value)
