"""Real ADS-B flights as scenarios: ``adsb:<flight>`` (or ``adsb:<flight>:<segment>``; ``<flight>`` a shipped id or
a flight file ``<path>.csv[.gz]`` in :mod:`radar_env.sim.adsb`'s format) and the pools
``adsb_calibration`` (all shipped calibration flights, one drawn per episode), ``adsb_dev`` and ``adsb_heldout``.

The split (:data:`ADSB_SPLIT`), stated before any policy of issue 20 was trained: the shipped flights in
alphabetical order, ``adsb_dev`` the 1st, 3rd, 5th, ... (may be looked at while developing and choosing a policy),
``adsb_heldout`` the 2nd, 4th, ... (12 flights each; used only to report). Every flight has been in the README's
per-flight table since an earlier round, so ``adsb_heldout`` is held out from training and choosing, not unseen.

Each flight is loaded, cleaned, split and smoothed by :mod:`radar_env.sim.adsb` (longest continuous segment by
default), turned into a :class:`radar_env.sim.scenario.TrajectoryScenario`, and observed by Adrian's ATC radar placed
by :func:`radar_env.sim.adsb.place_radar` (deterministic: south-west of the flight, at least 20 km from it).
"""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np

from . import adsb
from .catalog import Setup
from .radar import atc_radar

__all__ = ["resolve_adsb", "AdsbPool", "ADSB_SUITE", "ADSB_SPLIT", "split_flights"]

ADSB_SUITE = "adsb_calibration"
ADSB_SPLIT = ("adsb_dev", "adsb_heldout")
"""The two halves of the shipped flights (module docstring)."""


def split_flights(name):
    """The flights of pool ``name`` (``adsb_calibration``: all; ``adsb_dev`` / ``adsb_heldout``: every other one)."""
    flights = adsb.list_flights()
    if name == ADSB_SUITE:
        return flights
    return flights[ADSB_SPLIT.index(name)::2]


@lru_cache(maxsize=64)
def _setup(flight, segment):
    traj = adsb.load_trajectory(flight, segment)
    sc = traj.to_scenario(name=f"adsb:{flight}" if segment == "longest" else f"adsb:{flight}:{segment}")
    return Setup(sc, atc_radar(position_m=tuple(adsb.place_radar(traj))))


def resolve_adsb(name):
    """Setup (scenario + radar) for ``adsb:<flight>[:<segment>]`` (a shipped flight id or a flight file path), or
    the :class:`AdsbPool` for ``adsb_calibration``. Unknown flights raise ``ValueError`` listing the shipped ones;
    a bad file, the loader's one-line error naming it (:func:`radar_env.sim.adsb.load_trajectory`)."""
    if name == ADSB_SUITE or name in ADSB_SPLIT:
        return AdsbPool(name)
    parts = str(name).split(":")
    if len(parts) not in (2, 3) or parts[0] != "adsb" or not parts[1]:
        raise ValueError(f"ADS-B scenario names are 'adsb:<flight>' or 'adsb:<flight>:<segment>', got {name!r}")
    flights = adsb.list_flights()
    if parts[1] not in flights:
        if not parts[1].endswith((".csv", ".csv.gz")):
            raise ValueError(f"unknown ADS-B flight {parts[1]!r}; shipped flights: {flights}, or a flight file "
                             "'adsb:<path>.csv[.gz]'")
        if not Path(parts[1]).is_file():
            raise ValueError(f"ADS-B flight file {parts[1]!r} does not exist")
    segment = "longest" if len(parts) == 2 else int(parts[2])
    return _setup(parts[1], segment)


class AdsbPool:
    """The flights of a pool (default all shipped ones); :meth:`draw_setup` picks one uniformly with the episode's
    generator."""

    def __init__(self, name=ADSB_SUITE):
        self.name = name
        self.flights = split_flights(name)

    def draw_setup(self, rng: np.random.Generator):
        return _setup(self.flights[int(rng.integers(len(self.flights)))], "longest")

    def setup(self, i):
        """Flight ``i mod n`` (used by the evaluation suite to cycle through every flight)."""
        return _setup(self.flights[i % len(self.flights)], "longest")
