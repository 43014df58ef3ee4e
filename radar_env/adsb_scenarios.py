"""Real ADS-B flights as scenarios: ``adsb:<flight>`` (or ``adsb:<flight>:<segment>``) and the pool
``adsb_calibration`` (all shipped calibration flights, one drawn per episode).

Each flight is loaded, cleaned, split and smoothed by :mod:`radar_env.adsb` (longest continuous segment by
default), turned into a :class:`radar_env.scenario.TrajectoryScenario`, and observed by Adrian's ATC radar placed
by :func:`radar_env.adsb.place_radar` (deterministic: south-west of the flight, at least 20 km from it).
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np

from . import adsb
from .catalog import Setup
from .radar import atc_radar

__all__ = ["resolve_adsb", "AdsbPool", "ADSB_SUITE"]

ADSB_SUITE = "adsb_calibration"


@lru_cache(maxsize=64)
def _setup(flight, segment):
    traj = adsb.load_trajectory(flight, segment)
    sc = traj.to_scenario(name=f"adsb:{flight}" if segment == "longest" else f"adsb:{flight}:{segment}")
    return Setup(sc, atc_radar(position_m=tuple(adsb.place_radar(traj))))


def resolve_adsb(name):
    """Setup (scenario + radar) for ``adsb:<flight>[:<segment>]``, or the :class:`AdsbPool` for
    ``adsb_calibration``. Unknown flights raise ``ValueError`` listing the shipped ones."""
    if name == ADSB_SUITE:
        return AdsbPool()
    parts = str(name).split(":")
    if len(parts) not in (2, 3) or parts[0] != "adsb" or not parts[1]:
        raise ValueError(f"ADS-B scenario names are 'adsb:<flight>' or 'adsb:<flight>:<segment>', got {name!r}")
    flights = adsb.list_flights()
    if parts[1] not in flights:
        raise ValueError(f"unknown ADS-B flight {parts[1]!r}; shipped flights: {flights}")
    segment = "longest" if len(parts) == 2 else int(parts[2])
    return _setup(parts[1], segment)


class AdsbPool:
    """All shipped flights; :meth:`draw_setup` picks one uniformly with the episode's generator."""

    name = ADSB_SUITE

    def __init__(self):
        self.flights = adsb.list_flights()

    def draw_setup(self, rng: np.random.Generator):
        return _setup(self.flights[int(rng.integers(len(self.flights)))], "longest")

    def setup(self, i):
        """Flight ``i mod n`` (used by the evaluation suite to cycle through every flight)."""
        return _setup(self.flights[i % len(self.flights)], "longest")
