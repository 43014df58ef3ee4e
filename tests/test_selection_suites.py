"""The selection-only validation suites whose flights' start a tracker cannot know (agents.training.selection)."""

import numpy as np
import pytest

from agents.evaluation.suites import draw_suite
from agents.training.selection import (SELECTION_SEED_BASE, START_UNKNOWN_SUITES, SelectionSuites,
                                       draw_selection_suite)


def _first_maneuver_s(episodes):
    return np.array([e.t_s[np.argmax(e.maneuvering)] - e.t_s[0] if e.maneuvering.any() else np.inf
                     for e in episodes])


@pytest.mark.parametrize("name", sorted(START_UNKNOWN_SUITES))
def test_start_unknown_suites_turn_before_the_suites_first_leg_ends(name):
    base = START_UNKNOWN_SUITES[name]
    own = _first_maneuver_s(draw_suite(base, 40, seed=SELECTION_SEED_BASE))
    free = _first_maneuver_s(draw_selection_suite(name, 40, SELECTION_SEED_BASE))
    assert own.min() >= 90.0 - 1e-9               # the evaluation's random flights: a first leg of 90 s at least
    assert (free < 90.0).sum() >= 4               # here a maneuver can begin during the track start (70 s)
    assert free.min() >= 30.0 - 1e-9              # ... after a first leg drawn as every leg (30-300 s)


def test_start_unknown_suites_are_their_own_reproducible_flights():
    a = draw_selection_suite("random_any_start", 3, SELECTION_SEED_BASE)
    b = draw_selection_suite("random_any_start", 3, SELECTION_SEED_BASE)
    r = draw_suite("random", 3, seed=SELECTION_SEED_BASE)
    for x, y, z in zip(a, b, r):
        assert np.array_equal(x.z_m, y.z_m, equal_nan=True)
        assert x.truth.shape != z.truth.shape or not np.allclose(x.truth, z.truth)   # other seeds' flights
    # an evaluation suite is drawn as the evaluation draws it
    e = draw_selection_suite("random", 2, SELECTION_SEED_BASE)
    assert all(np.array_equal(x.z_m, y.z_m, equal_nan=True) for x, y in zip(e, r))


def test_start_unknown_seeds_stay_in_the_training_range():
    with pytest.raises(ValueError, match="training range"):
        SelectionSuites({"random_any_start": 100}, 990_000)      # 990,000 + 20,000 + i reaches 1,000,000
