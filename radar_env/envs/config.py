"""RadarTrack-v0's configuration: every argument, its defaults and its validation (no Gymnasium needed).

:class:`EnvConfig` is built and checked by :meth:`EnvConfig.from_kwargs`; :func:`resolve_scenario` normalises the
``scenario`` argument.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import numpy as np

from ..sim.catalog import SCENARIO_NAMES, Setup
from .observation import DEFAULT_FEATURES, DEFAULT_Q_LEVELS_G, FrameStack, ObservationLayout
from ..sim.radar import Radar
from ..sim.scenario import RandomScenarioConfig, SegmentScenario, TrajectoryScenario
from ..filters.tracking import TrackStart
from ..common.validate import check_choice, check_known_keys, check_number, is_real_number

__all__ = ["EnvConfig", "DEFAULT_Q_LEVELS_G", "RENDER_MODES", "REWARD_TYPES", "REWARD_SCALE_M", "TRACKERS",
           "resolve_scenario"]

RENDER_MODES = ("rgb_array", "human")
"""Render modes of the single env: a radar-scope picture (radar_env/render.py, needs matplotlib)."""

REWARD_TYPES = ("squared", "absolute", "squared_m")
TRACKERS = ("cv", "imm_cv_ct")
"""The env's filter: ``"cv"`` (the CV Kalman filter whose q is the action) or ``"imm_cv_ct"`` (the CV / CT-EKF IMM
whose per-look parameters are the action, :mod:`radar_env.envs.imm_env`)."""
IMM_ONLY_ARGUMENTS = ("imm_action_levels", "imm_parameters", "feature_q_g")
REWARD_SCALE_M = 100.0
"""Error scale of ``reward_type="squared_m"``: the reward is ``-min((error / 100 m)^2, reward_clip)``."""
NEES_99_2DOF = -2.0 * math.log(0.01)
"""chi2_2(0.99) = -2 ln(0.01) = 9.21 (the 2-dof chi-square quantile in closed form): the position NEES above which
``reward_nees_weight`` penalises a look."""


# ---------------------------------------------------------------------------------------------------- config
@dataclass(frozen=True)
class EnvConfig:
    """Every argument of RadarTrack-v0 (see the env docstring). Built by :meth:`from_kwargs`, which validates."""

    scenario: object = "random"
    radar: object = None
    random_config: object = None
    action_type: str = "discrete"
    q_levels_g: tuple = DEFAULT_Q_LEVELS_G
    features: tuple = DEFAULT_FEATURES
    frame_stack: int = 1
    warmup_scans: int = 12
    warmup_q_g: float = 0.03
    reward_type: str = "squared"
    reward_clip: float = 100.0
    reward_nees_weight: float = 0.0
    track_loss_gate_sigma: float = 30.0
    n_adrian: int = 4
    window_kim_lee: int = 12
    fma_weight: float = 0.1
    radial_velocity: bool = False
    render_mode: object = None
    tracker: str = "cv"
    imm_action_levels: object = None
    imm_parameters: object = None
    feature_q_g: object = None

    @classmethod
    def from_kwargs(cls, **kwargs):
        check_known_keys("RadarTrack-v0", kwargs, [f.name for f in fields(cls)], noun="argument")
        cfg = cls(**kwargs)
        cfg._validate()
        return cfg

    def _validate(self):
        p = "RadarTrack-v0: "   # every message names the argument after this prefix
        check_choice(p + "action_type", self.action_type, ("discrete", "continuous"))
        lv = self.q_levels_g
        ok = isinstance(lv, (tuple, list, np.ndarray)) and np.ndim(lv) == 1 and len(lv) >= 2
        ok = ok and all(is_real_number(v) and math.isfinite(float(v)) and 0 < float(v) <= 100 for v in lv)
        if not ok or np.any(np.diff(np.asarray(lv, dtype=np.float64)) <= 0):
            raise ValueError(f"{p}q_levels_g must be a tuple of >= 2 strictly increasing numbers in (0, 100] g, got "
                             f"{self.q_levels_g!r}")
        if not (isinstance(self.features, (tuple, list)) and all(isinstance(f, str) for f in self.features)):
            raise ValueError(f"{p}features must be a tuple of feature names (e.g. ('nis', 'c_min_g')), got "
                             f"{self.features!r}")
        try:
            ObservationLayout(self.features)
        except ValueError as e:   # unknown / repeated names: say which argument they came from
            raise ValueError(f"{p}features: {e}") from None
        check_number(p + "frame_stack", self.frame_stack, 1, 64, integer=True)
        self.track_start.checked(p)   # warmup_scans, warmup_q_g, n_adrian, window_kim_lee, fma_weight, radial_velocity
        for name in ("frame_stack", "warmup_scans", "n_adrian", "window_kim_lee"):   # 2.0 -> 2 (checked integral)
            object.__setattr__(self, name, int(getattr(self, name)))
        check_choice(p + "reward_type", self.reward_type, REWARD_TYPES)
        check_number(p + "reward_clip", self.reward_clip, 1e-3, 1e9)
        check_number(p + "reward_nees_weight", self.reward_nees_weight, 0.0, 1e3)
        check_number(p + "track_loss_gate_sigma", self.track_loss_gate_sigma, 1.0, 1e6)
        check_choice(p + "render_mode", self.render_mode, (None, *RENDER_MODES))
        if self.radar is not None and not isinstance(self.radar, Radar):
            raise ValueError(f"{p}radar must be a radar_env.sim.radar.Radar or None, got {type(self.radar).__name__}")
        if self.random_config is not None and not isinstance(self.random_config, (dict, RandomScenarioConfig)):
            raise ValueError(f"{p}random_config must be a dict or RandomScenarioConfig, got "
                             f"{type(self.random_config).__name__}")
        self.random_scenario_config  # noqa: B018 - builds (validates) a dict's RandomScenarioConfig
        resolve_scenario(self.scenario)  # raises for unknown names / bad files
        check_choice(p + "tracker", self.tracker, TRACKERS)
        if self.tracker == "cv":
            for name in IMM_ONLY_ARGUMENTS:
                if getattr(self, name) is not None:
                    raise ValueError(f"{p}{name} applies only with tracker='imm_cv_ct' (the IMM's action map and "
                                     f"feature chain), got {name}={getattr(self, name)!r} with tracker='cv'")
        else:
            from .imm_env import check_imm_config   # the IMM env's own arguments and refusals
            check_imm_config(self, p)

    @property
    def track_start(self):
        """The track-start and feature parameters (:class:`radar_env.filters.tracking.TrackStart`) the env and every tracker
        share."""
        return TrackStart(self.warmup_scans, self.warmup_q_g, self.n_adrian, self.window_kim_lee, self.fma_weight,
                          self.radial_velocity)

    def observation_bounds(self, layout):
        """``(low, high)`` of the observation Box: ``layout``'s bounds, tiled ``frame_stack`` times."""
        return FrameStack.bounds(layout, self.frame_stack)

    @property
    def random_scenario_config(self):
        rc = self.random_config
        return RandomScenarioConfig.from_dict(rc) if isinstance(rc, dict) else rc


def resolve_scenario(scenario):
    """Normalise the ``scenario`` argument: a name in ``SCENARIO_NAMES``, a CSV path, a :class:`Setup`, or a
    scenario object. Returns a name (str), a Setup, or a scenario object."""
    if isinstance(scenario, (Setup, SegmentScenario, TrajectoryScenario)) or hasattr(scenario, "draw_setup"):
        return scenario
    if isinstance(scenario, Path) or (isinstance(scenario, str) and scenario.endswith(".csv")
                                      and not scenario.startswith("adsb:")):
        return TrajectoryScenario.from_csv(scenario)
    if isinstance(scenario, str):
        if scenario.startswith("adsb:") or scenario in ("adsb_calibration", "adsb_dev", "adsb_heldout"):
            from ..sim.adsb_scenarios import resolve_adsb
            return resolve_adsb(scenario)
        if scenario.endswith((".gz", ".zip", ".json", ".txt", ".tsv")) or (
                Path(scenario).suffix and Path(scenario).is_file()):
            raise ValueError(f"RadarTrack-v0: scenario {scenario!r} names a file that is not a trajectory .csv "
                             "(plain text, columns t_s,x_m,y_m,vx_m_s,vy_m_s); an ADS-B flight file "
                             f"(t_s,lat_deg,lon_deg,..., .csv or .csv.gz) is given as 'adsb:{scenario}'")
        if scenario not in SCENARIO_NAMES:
            raise ValueError(f"RadarTrack-v0: unknown scenario {scenario!r}; valid: {list(SCENARIO_NAMES)}, "
                             "'adsb_calibration', 'adsb_dev', 'adsb_heldout', 'adsb:<flight>', a "
                             "'.csv' trajectory file (columns t_s,x_m,y_m,vx_m_s,vy_m_s), a Setup or a scenario "
                             "object")
        return scenario
    raise ValueError(f"RadarTrack-v0: scenario must be a name, a .csv path, a Setup or a scenario object, got "
                     f"{type(scenario).__name__}")
