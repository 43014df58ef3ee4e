"""RadarTrack-v0: choose the Kalman filter's process-noise level every radar look.

The Gymnasium layer over the simulation and the tracking chain. :class:`RadarTrackEnv` is the single env,
:class:`RadarTrackVectorEnv` the native batched vector env; both run the same batched core (:class:`_Core`), which
runs the one tracking chain (:class:`radar_env.tracking.Tracker`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path

import gymnasium as gym
import numpy as np
from gymnasium import spaces
from gymnasium.utils import seeding
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from .catalog import SCENARIO_NAMES, Setup
from .draws import MAX_EPISODE_DRAWS, draw_episodes  # noqa: F401 (MAX_EPISODE_DRAWS: public here)
from .observation import DEFAULT_FEATURES, FEATURE_SPECS, ObservationLayout, measurement_sigma_m
from .radar import Radar
from .scenario import RADAR_PLACEMENT_RANGE_M, RandomScenarioConfig, SegmentScenario, TrajectoryScenario
from .tracking import Tracker
from .units import G0_M_S2
from .validate import check_choice, check_known_keys, check_number, is_real_number

__all__ = ["RadarTrackEnv", "RadarTrackVectorEnv", "EnvConfig", "DEFAULT_Q_LEVELS_G"]

RENDER_MODES = ("rgb_array", "human")
"""Render modes of the single env: a radar-scope picture (radar_env/render.py, needs matplotlib)."""

DEFAULT_Q_LEVELS_G = tuple(float(0.03 * (2.0 / 0.03) ** (j / 6.0)) for j in range(-4, 9))
"""13 levels, g: ``0.03 * (2/0.03)^(j/6)``, j = -4..8, i.e. a ratio of ~2.01 between neighbours, exactly 0.03 g
(j = 0) and 2 g (j = 6), from 0.00182 g to 8.11 g."""


REWARD_TYPES = ("squared", "absolute", "squared_m")
REWARD_SCALE_M = 100.0
"""Error scale of ``reward_type="squared_m"``: the reward is ``-min((error / 100 m)^2, reward_clip)``."""


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
    warmup_scans: int = 12
    warmup_q_g: float = 0.03
    reward_type: str = "squared"
    reward_clip: float = 100.0
    track_loss_gate_sigma: float = 30.0
    n_adrian: int = 4
    window_kim_lee: int = 12
    fma_weight: float = 0.1
    render_mode: object = None

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
        check_number(p + "warmup_scans", self.warmup_scans, 1, 1000, integer=True)
        check_number(p + "warmup_q_g", self.warmup_q_g, 0.0, 100.0)
        check_choice(p + "reward_type", self.reward_type, REWARD_TYPES)
        check_number(p + "reward_clip", self.reward_clip, 1e-3, 1e9)
        check_number(p + "track_loss_gate_sigma", self.track_loss_gate_sigma, 1.0, 1e6)
        check_number(p + "n_adrian", self.n_adrian, 1, 50, integer=True)
        check_number(p + "window_kim_lee", self.window_kim_lee, 1, 1000, integer=True)
        check_number(p + "fma_weight", self.fma_weight, 1e-6, 1.0)
        check_choice(p + "render_mode", self.render_mode, (None, *RENDER_MODES))
        if self.radar is not None and not isinstance(self.radar, Radar):
            raise ValueError(f"{p}radar must be a radar_env.radar.Radar or None, got {type(self.radar).__name__}")
        if self.random_config is not None and not isinstance(self.random_config, (dict, RandomScenarioConfig)):
            raise ValueError(f"{p}random_config must be a dict or RandomScenarioConfig, got "
                             f"{type(self.random_config).__name__}")
        self.random_scenario_config  # noqa: B018 - builds (validates) a dict's RandomScenarioConfig
        resolve_scenario(self.scenario)  # raises for unknown names / bad files

    @property
    def random_scenario_config(self):
        rc = self.random_config
        return RandomScenarioConfig.from_dict(rc) if isinstance(rc, dict) else rc


def resolve_scenario(scenario):
    """Normalise the ``scenario`` argument: a name in ``SCENARIO_NAMES``, a CSV path, a :class:`Setup`, or a
    scenario object. Returns a name (str), a Setup, or a scenario object."""
    if isinstance(scenario, (Setup, SegmentScenario, TrajectoryScenario)) or hasattr(scenario, "draw_setup"):
        return scenario
    if isinstance(scenario, Path) or (isinstance(scenario, str) and scenario.endswith(".csv")):
        return TrajectoryScenario.from_csv(scenario)
    if isinstance(scenario, str):
        if scenario.startswith("adsb:") or scenario == "adsb_calibration":
            from .adsb_scenarios import resolve_adsb
            return resolve_adsb(scenario)
        if scenario not in SCENARIO_NAMES:
            raise ValueError(f"RadarTrack-v0: unknown scenario {scenario!r}; valid: {list(SCENARIO_NAMES)}, "
                             "'adsb_calibration', 'adsb:<flight>', a "
                             "'.csv' trajectory file (columns t_s,x_m,y_m,vx_m_s,vy_m_s), a Setup or a scenario "
                             "object")
        return scenario
    raise ValueError(f"RadarTrack-v0: scenario must be a name, a .csv path, a Setup or a scenario object, got "
                     f"{type(scenario).__name__}")


def draw_setup_and_episode(scenario, radar, random_config, rng, warmup_scans=EnvConfig.warmup_scans,
                           radar_range_m=RADAR_PLACEMENT_RANGE_M):
    """The episode of one reset: the truth (if random) and all plots, from ``rng`` only (a batch of one of
    :func:`radar_env.draws.draw_episodes`, whose docstring gives the random stream).

    A trajectory scenario with ``radar=None`` is seen by Adrian's ATC radar placed as
    :func:`radar_env.scenario.place_radar_site` does with ``range_m=radar_range_m`` (m).

    An episode too short for the track start (two hits, ``warmup_scans`` warm-up looks, then at least one look
    for the policy; e.g. a short random flight seen by a slow radar, or missed plots) is redrawn from the same
    stream, at most ``MAX_EPISODE_DRAWS`` times. Only draws that could not be run are replaced. A fixed scenario
    whose looks, all detected, are still too few raises ``ValueError`` at once (the env checks this when it is
    built)."""
    return draw_episodes(resolve_scenario(scenario), radar, random_config, [rng], warmup_scans,
                         radar_range_m).episode(0)


def actions_to_q_m_s2(actions, action_type, levels_m_s2):
    """The action map (no validation): discrete index -> ``levels_m_s2[i]``; continuous ``a`` in [-1, 1] (clipped)
    -> ``q_min (q_max / q_min)^((a + 1) / 2)`` with ``q_min, q_max`` the first and last level. Returns (n,)."""
    levels = np.asarray(levels_m_s2, dtype=np.float64)
    a = np.asarray(actions)
    if action_type == "discrete":
        return levels[a.reshape(-1).astype(np.int64)]
    a = np.clip(a.astype(np.float64).reshape(a.shape[0] if a.ndim else 1, -1)[:, 0], -1.0, 1.0)
    l0, l1 = math.log10(levels[0]), math.log10(levels[-1])
    return 10.0 ** (l0 + 0.5 * (a + 1.0) * (l1 - l0))


# ---------------------------------------------------------------------------------------------------- batched core
class _Core:
    """N tracks stepped together: actions -> q -> tracking chain -> observation, reward, end flags, info."""

    def __init__(self, n, cfg: EnvConfig):
        self.n, self.cfg = n, cfg
        self.levels_m_s2 = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
        self.q_min, self.q_max = self.levels_m_s2[0], self.levels_m_s2[-1]
        self.layout = ObservationLayout(cfg.features, self.q_min, self.q_max)
        self.tracker = Tracker(n, warmup_scans=cfg.warmup_scans, warmup_q_m_s2=cfg.warmup_q_g * G0_M_S2,
                               n_adrian=cfg.n_adrian, window_kim_lee=cfg.window_kim_lee, fma_weight=cfg.fma_weight)
        self.q_prev = np.full(n, cfg.warmup_q_g * G0_M_S2)
        self.rngs = [None] * n
        # resolved once: a CSV trajectory is read here, not at every reset
        self.scenario = resolve_scenario(cfg.scenario)
        self.random_config = cfg.random_scenario_config
        self._lq0, self._lq1 = math.log10(self.q_min), math.log10(self.q_max)
        # Refuse at build what would fail at a reset (a scenario too short for warmup_scans, a random_config whose
        # flights never stay in range): one probe draw from a throwaway generator; no row's stream is touched.
        draw_setup_and_episode(self.scenario, cfg.radar, self.random_config, np.random.default_rng(0),
                               cfg.warmup_scans)

    # ---- actions
    def action_to_q(self, action):
        a = np.asarray(action)
        # bool, complex, str and object actions are refused, not cast: True would silently be level 1
        if a.dtype.kind not in "iuf":
            raise ValueError(f"action must be {'integer' if self.cfg.action_type == 'discrete' else 'real'} "
                             f"number(s), got {action!r} (dtype {a.dtype})")
        if self.cfg.action_type == "discrete":
            a = a.reshape(self.n) if a.size == self.n else a
            if a.shape != (self.n,) or not np.all(np.isfinite(a.astype(np.float64))) or np.any(a != np.round(a)):
                raise ValueError(f"action must be {self.n} integer(s) in [0, {len(self.levels_m_s2) - 1}], got "
                                 f"{action!r}")
            ai = a.astype(np.int64)
            if np.any(ai < 0) or np.any(ai >= len(self.levels_m_s2)):
                raise ValueError(f"action must be in [0, {len(self.levels_m_s2) - 1}] (Discrete("
                                 f"{len(self.levels_m_s2)})), got {action!r}")
            return actions_to_q_m_s2(ai, "discrete", self.levels_m_s2)
        a = a.astype(np.float64).reshape(-1)
        if a.size != self.n or not np.all(np.isfinite(a)) or np.any(np.abs(a) > 1.0 + 1e-6):
            raise ValueError(f"action must be {self.n} finite value(s) in [-1, 1] (Box(-1, 1)), got {action!r}")
        return actions_to_q_m_s2(a, "continuous", self.levels_m_s2)

    # ---- episodes
    def _draw(self, rows, scenario=None):
        # all rows in one batched draw; row r's episode comes from its own generator only (radar_env.draws)
        sc = self.scenario if scenario is None else resolve_scenario(scenario)
        batch = draw_episodes(sc, self.cfg.radar, self.random_config, [self.rngs[r] for r in rows],
                              self.cfg.warmup_scans)
        return [batch.episode(i) for i in range(batch.batch_size)]

    def enable_prefetch(self):
        """Start the next episode of rows in batches (vector env autoreset). A row's next episode is drawn from its
        own generator exactly as it would be at its reset, so results do not change; only the warm-up of many
        rows runs as one batched call instead of one small call per finishing row."""
        self._pf = Tracker(self.n, warmup_scans=self.cfg.warmup_scans, warmup_q_m_s2=self.cfg.warmup_q_g * G0_M_S2,
                           n_adrian=self.cfg.n_adrian, window_kim_lee=self.cfg.window_kim_lee,
                           fma_weight=self.cfg.fma_weight)
        self._pf_ready = np.zeros(self.n, dtype=bool)
        self._pf_out = None

    def invalidate_prefetch(self):
        if getattr(self, "_pf", None) is not None:
            self._pf_ready[:] = False

    def _next_from_prefetch(self, rows):
        stale = np.flatnonzero(~self._pf_ready)
        if np.any(~self._pf_ready[rows]):
            out = self._pf.load(stale, self._draw(stale))
            if self._pf_out is None:
                self._pf_out = _empty_like_rows(out, self.n)
            _scatter_rows(self._pf_out, out, stale)
            self._pf_ready[stale] = True
        self.tracker.copy_rows_from(self._pf, rows, rows)
        self._pf_ready[rows] = False
        return _gather_rows(self._pf_out, rows)

    def reset_rows(self, rows, scenario=None, use_prefetch=False):
        if use_prefetch and scenario is None and getattr(self, "_pf", None) is not None:
            out = self._next_from_prefetch(rows)
        else:
            self.invalidate_prefetch()
            out = self.tracker.load(rows, self._draw(rows, scenario))
        self.q_prev[rows] = self.cfg.warmup_q_g * G0_M_S2
        obs = self.layout.encode(out, self.q_prev[rows])
        info = self._info(out, self._reward_terms(out, np.zeros(len(rows), dtype=bool), np.zeros(len(rows))))
        return obs, info, out

    def step(self, action):
        q = self.action_to_q(action)
        out = self.tracker.step(q)
        self.q_prev = q.copy()
        err_norm = self._normalised_error(out)
        lost = err_norm > self.cfg.track_loss_gate_sigma
        remaining = (self.tracker.n_looks - self.tracker.k).astype(np.float64)
        terms = self._reward_terms(out, lost, remaining, err_norm)
        reward = sum(terms.values())
        terminated = lost
        truncated = out.done & ~lost
        obs = self.layout.encode(out, q)
        info = self._info(out, terms)
        info["track_lost"] = lost
        return obs, reward, terminated, truncated, info

    # ---- reward
    def _normalised_error(self, out):
        r = np.hypot(out.truth[:, 0] - out.site_xy_m[:, 0], out.truth[:, 1] - out.site_xy_m[:, 1])
        sig = measurement_sigma_m(r, out.range_noise_std_m, out.bearing_noise_std_rad)
        return np.hypot(out.x[:, 0] - out.truth[:, 0], out.x[:, 1] - out.truth[:, 1]) / sig

    def _reward_terms(self, out, lost, remaining, err_norm=None):
        e = self._normalised_error(out) if err_norm is None else err_norm
        clip, kind = self.cfg.reward_clip, self.cfg.reward_type
        if kind == "squared_m":   # metres, not sigmas: weighs looks as the pooled position RMSE does
            e = np.hypot(out.x[:, 0] - out.truth[:, 0], out.x[:, 1] - out.truth[:, 1]) / REWARD_SCALE_M
        pos = -np.minimum(e if kind == "absolute" else e * e, clip)
        return {"position_error": pos, "track_lost": np.where(lost, -clip * remaining, 0.0)}

    # ---- info
    def _info(self, out, terms):
        # StepOutput arrays are new every step (gathered or computed), so the info can hold them without copies.
        x = out.x
        return {
            "truth": out.truth,
            "estimate": x,
            "covariance": out.P,
            "measurement": out.z_m,
            "measurement_covariance": out.R_m2,
            "polar": np.stack([out.range_m, out.bearing_rad, out.radial_velocity_m_s], axis=-1),
            "q_m_s2": out.q_m_s2,
            "q": out.q_m_s2,      # deprecated alias of q_m_s2 (m/s^2, not g), removed in the next version
            "dt": out.dt_s,
            "detected": out.detected,
            "maneuvering": out.maneuvering,
            "time_s": out.t_s,
            "reward_terms": dict(terms),
            "track_lost": np.zeros(x.shape[0], dtype=bool),
        }



def _empty_like_rows(out, n):
    """A StepOutput-shaped store with n rows."""
    vals = []
    for v in out:
        if isinstance(v, dict):
            vals.append({k: np.zeros((n,) + a.shape[1:], dtype=a.dtype) for k, a in v.items()})
        else:
            vals.append(np.zeros((n,) + v.shape[1:], dtype=v.dtype))
    return type(out)(*vals)


def _scatter_rows(store, out, rows):
    for sv, v in zip(store, out):
        if isinstance(v, dict):
            for k, a in v.items():
                sv[k][rows] = a
        else:
            sv[rows] = v


def _gather_rows(store, rows):
    return type(store)(*[({k: a[rows] for k, a in v.items()} if isinstance(v, dict) else v[rows]) for v in store])


# ---------------------------------------------------------------------------------------------------- single env
class RadarTrackEnv(gym.Env):
    r"""Choose a tracking Kalman filter's process-noise level at every radar look.

    ## Description

    A surveillance radar looks at an aircraft every few seconds and reports range, bearing and radial velocity,
    each with noise. A Kalman filter with a constant-velocity model tracks it. Its process-noise level ``q``
    decides how much it trusts the model: a low ``q`` gives a smooth track on straight legs but lags in a turn;
    a high ``q`` follows the turn but is noisy on the legs. The agent chooses ``q`` for every prediction, from
    features of the filter's innovations (never from the truth). Each step runs the chain once::

        q = action -> dt = t_k - t_{k-1} -> F(dt), Q(dt, q) -> predict -> update with plot k (or predict through
        a missed look) -> features, preview of plot k+1 -> observation, reward

    The observation that the action answers already previews plot k (its innovation against the predicted mean
    ``F x``, which does not depend on q): like an IMM, which weighs its modes with the plot itself, the agent
    chooses q knowing the plot it will be used for. The estimate at look k still uses plots up to k only.

    The episode (truth trajectory, every plot's noise and detection) is drawn whole at ``reset`` from the env's
    seeded generator, so a seed fixes the episode bit for bit and the evaluation replays the same plots through
    classical trackers (common random numbers).

    ## Action Space

    ``action_type="discrete"`` (default): ``Discrete(13)``; action ``i`` selects ``q = q_levels_g[i]`` g with
    the default levels ``0.03 * (2/0.03)^(j/6)`` g, ``j = -4 .. 8``:

    | action | 0 | 1 | 2 | 3 | 4 | 5 | 6 | 7 | 8 | 9 | 10 | 11 | 12 |
    |---|---|---|---|---|---|---|---|---|---|---|---|---|---|
    | q (g) | 0.0018 | 0.0037 | 0.0074 | 0.0149 | **0.03** | 0.060 | 0.122 | 0.245 | 0.494 | 0.994 | **2.0** | 4.03 | 8.11 |

    (0.03 g and 2 g are Bizup's low and high levels.) ``action_type="continuous"``: ``Box(-1, 1, (1,))`` mapped
    to ``log10 q`` linearly over the same range, ``q = q_min (q_max/q_min)^((a+1)/2)``.

    ## Observation Space

    ``Box(low, high, (F,), float32)``, one entry per name in ``features`` (default: all 27 below), scaled and
    clipped. Physical value = the inverse of the scaling (``ObservationLayout.decode``). Entries 0-16 describe
    the looks processed so far, 17-26 preview the next plot (``radar_env.observation.PAST_FEATURES`` leaves them
    out: q then has to be chosen before the plot is seen).

    | Num | Name | Unit | Scaling | Min | Max |
    |---|---|---|---|---|---|
    | 0 | nu_along: innovation along the predicted track / its std | 1 | x/5 | -1 | 1 |
    | 1 | nu_cross: innovation across the track (+ = right) / its std | 1 | x/5 | -1 | 1 |
    | 2 | nis: normalised innovation squared | 1 | log10(1+x)/3 | 0 | 1 |
    | 3 | c_min_g: Bizup's minimum centripetal acceleration | g | x/8 | 0 | 1 |
    | 4 | turn_rate_alg1_deg_s: Adrian algorithm 1 (n = 4) | deg/s | x/20 | -1 | 1 |
    | 5 | turn_rate_alg2_deg_s: Adrian algorithm 2 (n = 4) | deg/s | x/20 | -1 | 1 |
    | 6 | fma_innovation_km: fading-memory average of abs(innovation), weight 0.1 | km | x/20 | 0 | 1 |
    | 7 | kim_lee_q_g: sqrt of Kim & Lee's phi over a 12-look window | g | x/8 | 0 | 1 |
    | 8 | speed_m_s: estimated speed | m/s | x/400 | 0 | 1 |
    | 9 | range_km: estimated range | km | x/200 | 0 | 1 |
    | 10 | dt_s: time since the previous look | s | x/20 | 0 | 1 |
    | 11 | pos_std_ratio: filter position std / measurement std | 1 | x/3 | 0 | 1 |
    | 12 | q_prev_g: q of the last prediction | g | action map | -1 | 1 |
    | 13 | detected: the last look gave a plot | 1 | x | 0 | 1 |
    | 14 | nu_along_fm: fading-memory mean of nu_along (weight 0.2 on the new plot) | 1 | x/3 | -1 | 1 |
    | 15 | nu_cross_fm: fading-memory mean of nu_cross | 1 | x/3 | -1 | 1 |
    | 16 | nis_fm: fading-memory mean of the NIS (Bar-Shalom's alpha = 0.8) | 1 | log10(1+x)/3 | 0 | 1 |
    | 17 | next_nu_along: next plot's innovation along track / its std at q = 0 | 1 | x/10 | -1 | 1 |
    | 18 | next_nu_cross: next plot's innovation across track / its std at q = 0 | 1 | x/10 | -1 | 1 |
    | 19 | next_nis: next plot's NIS at q = 0 | 1 | log10(1+x)/3 | 0 | 1 |
    | 20 | next_q_fit_g: q explaining the next innovation (Kim & Lee with one plot) | g | action map | -1 | 1 |
    | 21 | next_c_min_g: Bizup's c_min from the next plot | g | x/8 | 0 | 1 |
    | 22 | next_los_accel_g: (next plot's radial velocity - that of F x) / dt | g | x/4 | -1 | 1 |
    | 23 | next_rdot_nu: next plot's radial-velocity innovation / its std at q = 0 | 1 | x/10 | -1 | 1 |
    | 24 | next_dt_s: time to the next look | s | x/20 | 0 | 1 |
    | 25 | next_meas_std_m: per-axis RMS noise of the next plot | m | log10(1+x)/3 | 0 | 1 |
    | 26 | next_detected: the next look gives a plot | 1 | x | 0 | 1 |

    Measurement-based features hold their last value through a missed look.

    ## Rewards

    With ``e = |estimated position - true position| / sigma_m``, where ``sigma_m = sqrt((sr^2 + (r sb)^2)/2)``
    is the per-axis RMS noise of a plot at the true range ``r``, the reward per step is
    ``-min(e^2, reward_clip)`` (``reward_type="squared"``, default; aligned with position RMSE) or
    ``-min(e, reward_clip)`` (``"absolute"``), or ``-min((error / 100 m)^2, reward_clip)`` (``"squared_m"``: in
    metres, so looks weigh as in the pooled position RMSE whatever the radar's noise). When the track is lost (below), the step also gets
    ``-reward_clip * (looks remaining)``, the worst case of finishing the episode. The terms are in
    ``info["reward_terms"]`` (``position_error``, ``track_lost``). Evaluation metrics do not use the reward.

    ## Starting State

    At ``reset`` an episode is drawn (a random scenario by default: 100-600 kt, 3-6 legs, 0.5-7 g turns,
    ranges 10-150 km, Adrian's ATC radar: T = 5 s, 0.04 NM, 0.07 deg). The track starts from the first two
    detected plots (two-hit start), then ``warmup_scans`` looks are filtered at ``warmup_q_g`` (Bizup: 12 at
    0.03 g). The first observation describes the last warm-up look.

    ## Episode End

    * Termination: the track is lost, ``e > track_loss_gate_sigma`` (default 30); ``info["track_lost"]`` is True.
    * Truncation: the scenario's last radar look has been processed.

    ## Arguments

    ``gym.make("RadarTrack-v0", **kwargs)``; every argument is validated and an unknown one raises ``ValueError``.

    * ``scenario``: ``"random"`` (default), ``"random_radars"`` (the same flights seen by a random radar: 1-12 s
      scan period, noise, detection probability, sometimes a second site), a name from
      ``radar_env.catalog.SCENARIO_NAMES`` (``bizup2002``,
      ``adrian_flower``, ``kim_lee_accel``, ``seed002_course_changes``, ``seed002_two_radars``), a path to a
      ``.csv`` trajectory (``t_s,x_m,y_m,vx_m_s,vy_m_s``), a ``Setup`` or a scenario object. ``reset(options=
      {"scenario": ...})`` overrides it for that reset only.
    * ``radar``: a ``radar_env.radar.Radar`` replacing the scenario's radar (default: the paper's radar; for a
      user trajectory, the ATC radar placed by ``place_radar_site``).
    * ``random_config``: dict or ``RandomScenarioConfig`` for the random scenarios (unknown keys raise).
    * ``action_type``: ``"discrete"`` or ``"continuous"``; ``q_levels_g``: increasing levels in (0, 100] g.
    * ``features``: tuple of observation names (table above).
    * ``warmup_scans`` (12, in [1, 1000]), ``warmup_q_g`` (0.03). A random episode with fewer looks than the track
      start needs (two hits, the warm-up, one look to act on) is redrawn from the same generator; a fixed scenario
      too short for ``warmup_scans`` is refused when the env is built.
    * ``reward_type`` (``"squared"``), ``reward_clip`` (100), ``track_loss_gate_sigma`` (30).
    * ``n_adrian`` (4), ``window_kim_lee`` (12), ``fma_weight`` (0.1): feature parameters.
    * ``render_mode``: ``None`` (default), ``"rgb_array"`` (``render()`` returns an RGB frame of
      ``radar_env.render.FRAME_SHAPE``) or ``"human"`` (a matplotlib window updated every step; refused with a
      ``ValueError`` when matplotlib has no interactive backend, e.g. on a machine without a display).

    Numbers must be real numbers (not strings, ``None``, booleans or complex); every wrong value raises
    ``ValueError`` naming the argument. Actions likewise: an index (or a value in [-1, 1]) as int/float, never
    bool, str or complex.

    ## Info

    ``truth``, ``estimate``, ``covariance``, ``measurement`` and ``measurement_covariance`` (NaN at a missed look),
    ``polar`` (measured range m, bearing rad, radial velocity m/s), ``q_m_s2`` (q of the last prediction, m/s^2),
    ``dt`` (s), ``time_s``, ``detected``, ``maneuvering`` (truth), ``track_lost``, ``reward_terms``. ``q`` is a
    deprecated alias of ``q_m_s2`` (m/s^2, not g), kept for one version.

    ## Version History

    * v0: initial version (the next-plot preview entries 17-26 were added before the first release; ``info["q"]``
      renamed ``info["q_m_s2"]``, the old key kept as a deprecated alias).
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 10}

    def __init__(self, **kwargs):
        self.config = EnvConfig.from_kwargs(**kwargs)
        self.render_mode = self.config.render_mode
        if self.render_mode == "human":
            from .render import human_display_problem  # lazy: matplotlib only when rendering
            problem = human_display_problem()
            if problem is not None:
                raise ValueError(f"RadarTrack-v0: render_mode='human' needs a window, but {problem}; use "
                                 "render_mode='rgb_array' (frames as arrays, e.g. for gymnasium.wrappers.RecordVideo)")
        self._core = _Core(1, self.config)
        n_act = len(self.config.q_levels_g)
        self.action_space = (spaces.Discrete(n_act) if self.config.action_type == "discrete"
                             else spaces.Box(-1.0, 1.0, (1,), dtype=np.float32))
        lay = self._core.layout
        self.observation_space = spaces.Box(lay.low, lay.high, dtype=np.float32)
        self.q_levels_m_s2 = self._core.levels_m_s2.copy()
        self._needs_reset = True

    @property
    def layout(self):
        """The :class:`radar_env.observation.ObservationLayout` of this env's observations."""
        return self._core.layout

    def reset(self, *, seed=None, options=None):
        if seed is not None and not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool)):
            raise ValueError(f"reset: seed must be None or an integer, got {seed!r}")   # True would be seed 1
        super().reset(seed=seed)
        options = dict(options or {})
        scenario = options.pop("scenario", None)
        if options:
            raise ValueError(f"reset: unknown option(s) {sorted(options)}; valid: ['scenario']")
        self._core.rngs[0] = self.np_random
        obs, info, _ = self._core.reset_rows(np.array([0]), scenario)
        self._needs_reset = False
        info = _row(info, 0)
        self._history = [(info["estimate"], info["covariance"], info["q_m_s2"], info["time_s"], obs[0])]
        if self.render_mode == "human":
            self.render()
        return obs[0], info

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("RadarTrack-v0: call reset() before step() (and after an episode ends)")
        a = np.asarray(action)
        if a.size != 1:
            raise ValueError(f"action must be a single value ({self.action_space}), got {action!r}")
        obs, rew, term, trunc, info = self._core.step(a.reshape(1))
        self._needs_reset = bool(term[0] or trunc[0])
        info = _row(info, 0)
        if self.render_mode is not None:
            self._history.append((info["estimate"], info["covariance"], info["q_m_s2"], info["time_s"], obs[0]))
        if self.render_mode == "human":
            self.render()
        return obs[0], float(rew[0]), bool(term[0]), bool(trunc[0]), info

    def episode(self):
        """The current episode's stored looks (``Tracker.look_data`` views for row 0)."""
        return {f: self._core.tracker.look_data(f)[0, : self._core.tracker.n_looks[0]]
                for f in ("t_s", "truth", "z_m", "detected")}

    def _render_state(self):
        """What the scope shows: looks processed so far, the track history and the latest features."""
        tr = self._core.tracker
        k = int(tr.k[0])
        det = tr.look_data("detected")[0, :k]
        est, P, q, t, obs = self._history[-1]
        feats = {n: float(self.layout.decode(obs, n)) for n in ("c_min_g", "nis", "turn_rate_alg1_deg_s",
                                                                 "turn_rate_alg2_deg_s") if n in self.layout}
        return {"truth": tr.look_data("truth")[0, :k, :2], "plots": tr.look_data("z_m")[0, :k][det],
                "sites": np.unique(tr.look_data("site_xy_m")[0, :k], axis=0),
                "estimates": np.array([h[0] for h in self._history]), "P": P, "q_m_s2": q, "time_s": t,
                "features": feats}

    def render(self):
        """A radar-scope frame: RGB array ``radar_env.render.FRAME_SHAPE`` (``rgb_array``) or a window (``human``)."""
        if self.render_mode is None:
            gym.logger.warn("RadarTrack-v0: render() called without a render_mode; pass render_mode to gym.make")
            return None
        from .render import render_frame  # lazy: matplotlib only when rendering
        return render_frame(self)


_SCALAR_INFO = ("q_m_s2", "q", "dt", "detected", "maneuvering", "track_lost", "time_s")


def _row(info, i):
    """Row ``i`` of a batched info dict, with Python scalars for the scalar keys and reward terms."""
    out = {k: v[i] for k, v in info.items() if not isinstance(v, dict)}
    for k in _SCALAR_INFO:
        out[k] = out[k].item()
    out["reward_terms"] = {k: float(v[i]) for k, v in info["reward_terms"].items()}
    return out


# ---------------------------------------------------------------------------------------------------- vector env
class RadarTrackVectorEnv(VectorEnv):
    """Native batched vector version of RadarTrack-v0 (``gym.make_vec(..., vectorization_mode=
    "vector_entry_point")``): N tracks in one set of numpy arrays, same-step autoreset.

    On the step where row i ends, the returned observation is the first observation of its next episode, and
    ``info["final_obs"][i]`` / ``info["final_info"]`` hold the last observation and info of the finished one
    (``info["_final_obs"]`` is the mask of rows that ended). Seeding: ``reset(seed=s)`` seeds row i with
    ``s + i``, as Gymnasium's ``SyncVectorEnv`` does, so row i equals ``RadarTrackEnv`` reset with ``s + i``.
    Finished rows start their next tracks in batches (each row's next episode drawn ahead from its own generator,
    so autoreset results are unchanged); an explicit ``reset()`` without a seed discards those prepared episodes,
    so after it the rows continue from their generators' advanced state.
    All other arguments as :class:`RadarTrackEnv`.

    Actions: shape ``(num_envs,)`` (discrete) or ``(num_envs, 1)`` / ``(num_envs,)`` (continuous); other shapes
    raise ``ValueError``.

    Gymnasium's vector wrappers: the observation wrappers of ``gymnasium.wrappers.vector``
    (``NormalizeObservation``, ``FlattenObservation``, ...) accept only next-step autoreset and refuse this env
    (same-step); ``NormalizeReward`` and ``RecordEpisodeStatistics`` work. ``gym.make_vec(..., "sync")`` or
    ``"async"`` default to next-step autoreset, whose rows diverge from this env after their first episode end;
    with ``vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}`` they equal this env row for row
    (README "Use the environment"; tests/test_env_inputs.py).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs=1, **kwargs):
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        # gym.make_vec passes the spec's / caller's max_episode_steps; apply it as gym.make's TimeLimit does
        # (truncated once a row has taken that many steps) rather than dropping it silently.
        max_steps = kwargs.pop("max_episode_steps", None)
        if max_steps is not None and (not isinstance(max_steps, (int, np.integer)) or isinstance(max_steps, bool)
                                      or max_steps < 1):
            raise ValueError(f"max_episode_steps must be None or an integer >= 1, got {max_steps!r}")
        self.max_episode_steps = None if max_steps is None else int(max_steps)
        self.config = EnvConfig.from_kwargs(**kwargs)
        if self.config.render_mode is not None:
            raise ValueError("RadarTrackVectorEnv does not render; use the single env")
        self.num_envs = int(num_envs)
        self._core = _Core(self.num_envs, self.config)
        self._core.enable_prefetch()
        n_act = len(self.config.q_levels_g)
        self.single_action_space = (spaces.Discrete(n_act) if self.config.action_type == "discrete"
                                    else spaces.Box(-1.0, 1.0, (1,), dtype=np.float32))
        lay = self._core.layout
        self.single_observation_space = spaces.Box(lay.low, lay.high, dtype=np.float32)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._all = np.arange(self.num_envs)
        self._elapsed = np.zeros(self.num_envs, dtype=np.int64)
        self._started = False

    @property
    def layout(self):
        return self._core.layout

    def reset(self, *, seed=None, options=None):
        options = dict(options or {})
        scenario = options.pop("scenario", None)
        if options:
            raise ValueError(f"reset: unknown option(s) {sorted(options)}; valid: ['scenario']")
        if seed is None:
            seeds = [None] * self.num_envs
        elif isinstance(seed, (int, np.integer)) and not isinstance(seed, bool):
            seeds = [int(seed) + i for i in range(self.num_envs)]
        else:
            ok_one = lambda s: s is None or (isinstance(s, (int, np.integer)) and not isinstance(s, bool))  # noqa: E731
            seeds = list(seed) if np.iterable(seed) and not isinstance(seed, (str, bytes)) else None
            if seeds is None or not all(ok_one(s) for s in seeds):
                raise ValueError(f"seed must be None, an integer or a list of num_envs integers / None, got {seed!r}")
            if len(seeds) != self.num_envs:
                raise ValueError(f"seed list must have num_envs={self.num_envs} entries, got {len(seeds)}")
        if seed is not None or not self._started:
            self._core.rngs = [seeding.np_random(s)[0] for s in seeds]
        obs, info, _ = self._core.reset_rows(self._all, scenario)
        self._elapsed[:] = 0
        self._started = True
        return obs, _with_masks(info)

    def step(self, actions):
        if not self._started:
            raise RuntimeError("RadarTrackVectorEnv: call reset() before step()")
        core = self._core
        a = np.asarray(actions)
        n = self.num_envs
        shapes = [(n,)] if self.config.action_type == "discrete" else [(n, 1), (n,)]
        if a.shape not in shapes:
            raise ValueError(f"actions must have shape {' or '.join(map(str, shapes))} ({self.action_space}), got "
                             f"shape {a.shape}: {actions!r}")
        obs, rew, term, trunc, info = core.step(a.reshape(n))
        self._elapsed += 1
        if self.max_episode_steps is not None:
            trunc = trunc | (self._elapsed >= self.max_episode_steps)
        done = term | trunc
        self._elapsed[done] = 0
        if np.any(done):
            rows = np.flatnonzero(done)
            final_obs = np.full(self.num_envs, None, dtype=object)
            for r in rows:
                final_obs[r] = obs[r].copy()
            final_info = _with_masks(info, done)
            new_obs, new_info, _ = core.reset_rows(rows, use_prefetch=True)
            obs = obs.copy()
            obs[rows] = new_obs
            info = _merge_rows(info, new_info, rows)
            info["final_obs"] = final_obs
            info["_final_obs"] = done.copy()
            info["final_info"] = final_info
            info["_final_info"] = done.copy()
        return obs, rew, term, trunc, _with_masks(info)


def _merge_rows(info, new, rows):
    out = {}
    for k, v in info.items():
        if isinstance(v, dict):
            out[k] = _merge_rows(v, new[k], rows)
        else:
            a = np.array(v, copy=True)
            a[rows] = new[k]
            out[k] = a
    return out


def _with_masks(info, mask=None):
    out = {}
    for k, v in info.items():
        if k.startswith("_") or k in ("final_obs", "final_info"):
            out[k] = v
            continue
        if isinstance(v, dict):
            out[k] = _with_masks(v, mask)
        else:
            out[k] = v
        n = len(v[next(iter(v))]) if isinstance(v, dict) else len(v)
        out["_" + k] = np.ones(n, dtype=bool) if mask is None else mask.copy()
    return out
