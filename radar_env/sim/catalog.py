"""Named scenarios, each paired with its paper's radar, and the random-scenario setup.

``make_setup(name, rng)`` returns a :class:`Setup` (scenario + radar). Names:

=========================  ==========================================================================================
``random``                 :func:`radar_env.sim.scenario.random_scenario` with Adrian's ATC radar placed by the draw
``random_radars``          the same flights seen by a random radar (:func:`random_radar`): scan period 1-12 s,
                           noise, detection probability and, in 30 % of draws, a second site (irregular looks)
``bizup2002``              Bizup (seed 000) fig. 6: 350 kt, starts 120 NM out, two 2 g turns (40 s at ~290 s, 30 s
                           at ~610 s), 930 s; Bizup's radar (T = 10 s, 100 ft, 0.1 deg, 2 kt) at the origin
``adrian_flower``          Adrian (seed 003): 12-leaf flower, 200 kt, 15 NM legs, 180 deg left / 150 deg right turns
                           at 3 deg/s, radar at the flower's centre, ATC radar (T = 5 s, 0.04 NM, 0.07 deg)
``kim_lee_accel``          Kim & Lee (seed 004): radial outbound flight, 120 m/s, CV 25 s, +5 g 10 s, CV 30 s,
                           -5 g 10 s, CV 25 s; T = 1 s, range sigma 150 m
``seed002_course_changes`` seed 002's maneuvering case: straight legs joined by course changes; ATC radar
``seed002_two_radars``     seed 002's two-radar case: two sites 60 km apart with scan periods 5 s and 4 s
=========================  ==========================================================================================

Held-out families (:data:`FAMILIES`): random flights of one kind, seen by the ATC radar of ``random`` and drawn by
:func:`radar_env.sim.scenario.random_scenario` with the family's :class:`RandomScenarioConfig` (default values
otherwise). They are evaluation suites: each has its own random stream (suite key = its name), and no training,
tuning or selection run uses them (training may cover such flights through its own ``random_config``).

=========================  ==========================================================================================
``start_maneuver``         the first maneuver (a 2-7 g turn of 30-270 deg) begins 5-45 s after the first look, i.e.
                           during the track start (two hits + 12 warm-up looks = 70 s at T = 5 s); turns only
``short_tracks``           flights cut at 190 s: 24-39 looks at T = 5 s; first leg 20-120 s, legs 20-90 s
``sharp_turns``            350-600 kt, every turn 6-9 g (turn rate up to 30 deg/s)
``slow_orbits``            100-180 kt, turns of 360-720 deg at 0.3-1 g, no speed changes
``speed_changes``          every maneuver a pure speed change at 0.1-1 g, no turns
=========================  ==========================================================================================

Choices the papers leave open (start position and heading, turn directions, the seed-002 numbers, which the
paper does not give) are stated in each factory's docstring.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from .radar import Radar, RadarSite, atc_radar, bizup_radar
from .scenario import RandomScenarioConfig, ScenarioBuilder, Segment, SegmentScenario, random_scenario
from ..common.units import DEG, G0_M_S2, KNOT_M_S, NM_M

__all__ = ["Setup", "SCENARIO_NAMES", "FAMILIES", "family_config", "make_setup", "random_radar", "RANDOM_RADAR_RANGES"]


@dataclass(frozen=True)
class Setup:
    """A scenario (truth) and the radar that observes it."""

    scenario: object
    radar: Radar

    @property
    def name(self):
        return self.scenario.name


def bizup2002():
    """350 kt; start 120 NM from the radar at bearing 60 deg, heading 270 deg (crossing); straight 290 s, right 2 g
    turn for 40 s (250 deg), straight 280 s, left 2 g turn for 30 s (187 deg), straight 290 s (930 s, 94 looks).
    Turn directions and start heading are not given in the paper (its fig. 6 is not reproduced in the text)."""
    v = 350 * KNOT_M_S
    w = 2 * G0_M_S2 / v
    r0 = 120 * NM_M
    start = (r0 * np.sin(60 * DEG), r0 * np.cos(60 * DEG))
    b = ScenarioBuilder(position_m=start, speed_m_s=v, heading_deg=270.0)
    b.segments += [Segment(290.0), Segment(40.0, w), Segment(280.0), Segment(30.0, -w), Segment(290.0)]
    return Setup(b.build("bizup2002"), bizup_radar())


def adrian_flower():
    """12 leaves: each is a 15 NM leg, a 180 deg left turn, a 15 NM leg and a 150 deg right turn (net 30 deg left
    per leaf, 360 deg over the flower), 200 kt, 3 deg/s, start heading 45 deg. The radar sits at the centre of the
    flower (mean position of the path), so that every leg passes near it as in Adrian's fig. 2."""
    b = ScenarioBuilder(position_m=(0.0, 0.0), speed_kt=200, heading_deg=45.0)
    leg_s = 15 * NM_M / (200 * KNOT_M_S)
    for _ in range(12):
        b.straight(leg_s).turn(-180, rate_deg_s=3).straight(leg_s).turn(150, rate_deg_s=3)
    sc = b.build("adrian_flower")
    t = np.linspace(0, sc.duration_s, 4001)
    centre = sc.states_at(t)[:, :2].mean(axis=0)
    return Setup(sc, atc_radar(position_m=tuple(centre)))


def kim_lee_accel():
    """Straight radial flight away from the radar (east, starting 20 km out), 120 m/s: CV 25 s, +5 g 10 s, CV 30 s,
    -5 g 10 s, CV 25 s (100 s). Radar: T = 1 s, range sigma 150 m (the paper's 1-D sigma); the paper is 1-D, so
    the bearing sigma is set to give 150 m cross-range at 30 km (0.286 deg); radial velocity 2 kt."""
    g5 = 5 * G0_M_S2
    segs = [Segment(25.0), Segment(10.0, accel_m_s2=g5), Segment(30.0), Segment(10.0, accel_m_s2=-g5),
            Segment(25.0)]
    sc = SegmentScenario([20e3, 0.0, 120.0, 0.0], segs, name="kim_lee_accel")
    radar = Radar((RadarSite(position_m=(0.0, 0.0), scan_period_s=1.0, range_noise_std_m=150.0,
                             bearing_noise_std_rad=150.0 / 30e3, radial_velocity_noise_std_m_s=2 * KNOT_M_S,
                             name="kim_lee"),))
    return Setup(sc, radar)


def seed002_course_changes():
    """Seed 002 gives no numbers for its maneuvering case; ours: 300 kt, start 60 km south-west of the radar heading
    north-east, legs of 120 s joined by course changes of +90, -60 and +120 deg at 3 deg/s; ATC radar."""
    b = ScenarioBuilder(position_m=(-42.4e3, -42.4e3), speed_kt=300, heading_deg=45.0)
    b.straight(120).turn(90, rate_deg_s=3).straight(120).turn(-60, rate_deg_s=3).straight(120)
    b.turn(120, rate_deg_s=3).straight(120)
    return Setup(b.build("seed002_course_changes"), atc_radar())


def seed002_two_radars():
    """Seed 002's two-radar case: sites at (0, 0) and (60 km, 0), ATC noise, scan periods 5 s and 4 s (irregular
    update times); 300 kt flight from west to east passing between them with one 90 deg course change."""
    b = ScenarioBuilder(position_m=(-20e3, 30e3), speed_kt=300, heading_deg=100.0)
    b.straight(200).turn(90, rate_deg_s=3).straight(100)
    s1 = atc_radar((0.0, 0.0)).sites[0]
    s2 = s1.replace(position_m=(60e3, 0.0), scan_period_s=4.0, first_scan_s=1.5, name="atc2")
    return Setup(b.build("seed002_two_radars"), Radar((s1, s2)))


RANDOM_RADAR_RANGES = {
    "scan_period_s": (1.0, 12.0),            # log-uniform
    "range_noise_std_m": (10.0, 250.0),      # log-uniform
    "bearing_noise_std_deg": (0.03, 0.3),    # log-uniform
    "radial_velocity_noise_std_m_s": (0.5, 2.0),  # log-uniform
    "detection_probability": (0.8, 1.0),     # uniform
    "second_site_probability": 0.3,
    "second_site_offset_km": (20.0, 80.0),   # uniform distance, uniform direction
}
"""Ranges of :func:`random_radar`. They cover the papers' radars (Kim & Lee T = 1 s / 150 m, the ATC radar
T = 5 s / 74 m / 0.07 deg, Bizup T = 10 s / 30 m / 0.1 deg) and what lies between, so that a policy trained on
``random_radars`` is not tied to one radar."""


def random_radar(rng, site_xy_m):
    """A radar drawn from ``RANDOM_RADAR_RANGES`` with its first site at ``site_xy_m`` (fixed draw order: per site
    period, range, bearing and radial-velocity noise, detection probability, first-scan offset; then whether a
    second site exists and where)."""
    R = RANDOM_RADAR_RANGES

    def logu(key):
        lo, hi = R[key]
        return float(np.exp(rng.uniform(np.log(lo), np.log(hi))))

    def site(pos, name):
        period = logu("scan_period_s")
        return RadarSite(position_m=tuple(pos), scan_period_s=period, range_noise_std_m=logu("range_noise_std_m"),
                         bearing_noise_std_rad=logu("bearing_noise_std_deg") * DEG,
                         radial_velocity_noise_std_m_s=logu("radial_velocity_noise_std_m_s"),
                         detection_probability=float(rng.uniform(*R["detection_probability"])),
                         first_scan_s=float(rng.uniform(0.0, period)) * (name != "site1"), name=name)

    sites = [site(site_xy_m, "site1")]
    if rng.uniform() < R["second_site_probability"]:
        d, a = rng.uniform(*R["second_site_offset_km"]) * 1e3, rng.uniform(0.0, 2 * np.pi)
        sites.append(site(np.asarray(site_xy_m) + d * np.array([np.sin(a), np.cos(a)]), "site2"))
    return Radar(tuple(sites))


FAMILIES = {
    "start_maneuver": dict(first_leg_min_s=0.0, first_leg_s=(5.0, 45.0), turn_accel_g=(2.0, 7.0),
                           turn_heading_change_deg=(30.0, 270.0), speed_change_probability=0.0),
    "short_tracks": dict(max_duration_s=190.0, first_leg_min_s=0.0, first_leg_s=(20.0, 120.0),
                         leg_duration_s=(20.0, 90.0)),
    "sharp_turns": dict(speed_kt=(350.0, 600.0), turn_accel_g=(6.0, 9.0), max_turn_rate_deg_s=30.0),
    "slow_orbits": dict(speed_kt=(100.0, 180.0), turn_accel_g=(0.3, 1.0), turn_heading_change_deg=(360.0, 720.0),
                        n_legs=(2, 4), speed_change_probability=0.0),
    "speed_changes": dict(speed_change_probability=1.0, turn_probability=0.0, speed_change_accel_g=(0.1, 1.0)),
}
"""Held-out family suites: name -> the :class:`RandomScenarioConfig` arguments of its flights (module docstring)."""


@lru_cache(maxsize=None)
def family_config(name):
    """The :class:`RandomScenarioConfig` of family ``name`` (a key of :data:`FAMILIES`; built once)."""
    return RandomScenarioConfig(**FAMILIES[name])


_NAMED = {f.__name__: f for f in (bizup2002, adrian_flower, kim_lee_accel, seed002_course_changes,
                                   seed002_two_radars)}
SCENARIO_NAMES = ("random", "random_radars") + tuple(_NAMED) + tuple(FAMILIES)


@lru_cache(maxsize=None)
def _named_setup(name):
    """Named setups are deterministic and immutable: built once (the flower has 48 segments), not at every reset."""
    return _NAMED[name]()


def make_setup(name, rng=None, random_config: RandomScenarioConfig | None = None, radar: Radar | None = None):
    """Scenario and radar by name (see module docstring).

    Args:
        name: one of ``SCENARIO_NAMES``.
        rng: numpy Generator, required for ``random``, ``random_radars`` and the families (named scenarios are
            deterministic).
        random_config: :class:`RandomScenarioConfig` for ``random`` / ``random_radars`` (a family has its own).
        radar: overrides the radar (for ``random`` its first site is moved to the drawn position).
    """
    if name in ("random", "random_radars"):
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"scenario {name!r} needs rng, a numpy.random.Generator")
        sc, site = random_scenario(rng, random_config)
        if radar is not None:
            return Setup(sc, radar.moved_to(site))
        if name == "random":
            return Setup(sc, atc_radar(position_m=tuple(site)))
        p = (random_config or RandomScenarioConfig()).random_radar_probability
        return Setup(sc, random_radar(rng, site) if rng.uniform() < p else atc_radar(position_m=tuple(site)))
    if name in FAMILIES:
        if not isinstance(rng, np.random.Generator):
            raise ValueError(f"scenario {name!r} needs rng, a numpy.random.Generator")
        sc, site = random_scenario(rng, family_config(name), name=name)
        return Setup(sc, (radar.moved_to(site) if radar is not None else atc_radar(position_m=tuple(site))))
    if name not in _NAMED:
        raise ValueError(f"unknown scenario {name!r}; valid names: {list(SCENARIO_NAMES)}")
    s = _named_setup(name)
    return Setup(s.scenario, radar) if radar is not None else s
