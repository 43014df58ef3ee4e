"""The window trainer's training flights: first_leg_min_s, the broad generators and the hyperparameter checks around
them."""

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


class Drawn(Exception):
    """Raised by a fake draw: the draw's arguments are what a test checks (not StopIteration: the draws are a
    generator's, which turns it into a RuntimeError)."""


def test_training_flights_are_drawn_with_that_config(monkeypatch):
    import agents.evaluation.suites as suites
    seen = []

    def fake(name, runs, seed, random_config=None):
        seen.append((name, runs, seed, random_config))
        raise Drawn                              # enough: the draw's arguments are what is checked

    monkeypatch.setattr(suites, "draw_suite", fake)
    hp = {**load_hyperparams("window"), "first_leg_min_s": 0.0, "episodes": 7}
    with pytest.raises(Drawn):
        window.draw_training_looks(None, hp, 123)
    assert seen == [("random", 7, 123, RandomScenarioConfig(first_leg_min_s=0.0))]


@pytest.mark.parametrize("key, value, match", [
    ("first_leg_min_s", -1.0, r"first_leg_min_s: must be a number of seconds in \[0, 1e5\], got -1.0"),
    ("first_leg_min_s", True, "first_leg_min_s"),
    ("first_leg_min_s", "0", "first_leg_min_s"),
    ("eval_scenarios", "{random=100}", r"eval_scenarios: a JSON object \{suite: runs >= 1\}"),
    ("eval_scenarios", {"random": 0}, "eval_scenarios"),
    ("select_on", "random", "select_on: a list of suite names"),
    ("dtype", "float16", r"--hp dtype: the network's training precision, one of"
     r" \['float64', 'float32'\], got 'float16'"),
])
def test_bad_values_are_refused_in_one_line(key, value, match):
    hp = {**load_hyperparams("window"), key: value}
    with pytest.raises(ValueError, match=match) as e:
        window.check_hp(hp)
    assert "\n" not in str(e.value)


def test_broad_generators_draw_the_backprop_recipes_flights_at_offset_seeds(monkeypatch):
    """random_broad / random_radars_broad: the random generators with backprop.toml's broad laws (its
    random_radar_probability aside), seeds BROAD_SEED_OFFSET above the suite's own; the own suites unchanged."""
    import agents.evaluation.suites as suites
    seen = []

    def fake(name, runs, seed, random_config=None):
        seen.append((name, runs, seed, random_config))
        raise Drawn

    monkeypatch.setattr(suites, "draw_suite", fake)
    rc = dict(load_hyperparams("backprop")["env_kwargs"]["random_config"])
    assert rc.pop("random_radar_probability") == 0.7
    laws = RandomScenarioConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in rc.items()})
    assert window.broad_config() == laws and laws.speed_change_accel_g == (0.1, 5.0)
    for name, gen in window.BROAD_SCENARIOS.items():
        seen.clear()
        hp = window.check_hp({**load_hyperparams("window"), "scenarios": [name], "episodes": 7})[0]
        with pytest.raises(Drawn):
            window.draw_training_looks(None, hp, 123)
        assert seen == [(gen, 7, 123 + window.BROAD_SEED_OFFSET, laws)]


def test_broad_generators_are_checked_and_keep_their_seeds_in_the_training_range():
    hp = {**load_hyperparams("window"), "scenarios": ["random", "random_broad", "random_radars_broad"]}
    assert window.check_hp(hp)[0]["scenarios"] == hp["scenarios"]
    with pytest.raises(ValueError, match="scenarios: a list of distinct training generators from"):
        window.check_hp({**hp, "scenarios": ["random", "broad"]})
    # seed 600,000: the broad flights would reach 600,000 + 300,000 + the draws: past the selection suites' seeds
    with pytest.raises(ValueError, match=r"--seed: the training flights' seeds 600000\.\.9\d{5} must lie in"):
        window.train_window(hp, seed=600_000, out="/nonexistent")


def test_episodes_table_draws_each_suites_own_count_and_the_draws_stay_apart(monkeypatch):
    """episodes as a table {suite: flights}: each suite draws its count from the same seeds as with one number, draw
    d starts at S + d * the largest count (so no seed serves two draws), and the table is checked against scenarios."""
    import agents.evaluation.suites as suites
    seen = []

    def fake(name, runs, seed, random_config=None):
        seen.append((name, runs, seed))
        return []

    monkeypatch.setattr(suites, "draw_suite", fake)
    one = (window.np.zeros((1, 3)), window.np.ones((1, 2)), window.np.zeros((1, 2)))
    monkeypatch.setattr(window, "training_looks", lambda *a, **k: one)
    hp = {**load_hyperparams("window"), "scenarios": ["random", "random_broad"],
          "episodes": {"random": 1200, "random_broad": 300}, "epochs": 20, "fresh_flights_every": 10}
    hp = window.check_hp(hp)[0]
    assert window.suite_episodes(hp) == {"random": 1200, "random_broad": 300}
    assert window.flight_draws(hp, 100) == [100, 1300]
    F = window.draw_training_looks(None, hp, 1300, with_mirror=False)[0]
    assert len(F) == 4                          # one fake look per chunk of flights
    off = window.BROAD_SEED_OFFSET
    assert seen == [("random", 500, 1300), ("random", 500, 1800), ("random", 200, 2300),
                    ("random", 300, 1300 + off)]
    assert window.suite_episodes({**hp, "episodes": 7}) == {"random": 7, "random_broad": 7}


@pytest.mark.parametrize("episodes, match", [
    ({"random": 10}, r"episodes: a table's keys must be the scenarios \['random', 'random_broad'\], got \['random'\]"),
    ({"random": 10, "random_broad": 0},
     r"--hp episodes: random_broad's count must be an integer in \[1, 200000\], got 0"),
    ({"random": 10, "random_broad": 2.5}, "random_broad's count must be an integer"),
    (0, r"--hp episodes: must be an integer in \[1, 200000\], got 0"),
])
def test_episodes_table_is_checked_in_one_line(episodes, match):
    hp = {**load_hyperparams("window"), "scenarios": ["random", "random_broad"], "episodes": episodes}
    with pytest.raises(ValueError, match=match) as e:
        window.check_hp(hp)
    assert "\n" not in str(e.value)
