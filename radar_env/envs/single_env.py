"""RadarTrack-v0, the single env (:class:`RadarTrackEnv`): a Gymnasium layer over the batched core of one row."""

from __future__ import annotations

import math

import gymnasium as gym
import numpy as np
from gymnasium import spaces

from .config import RENDER_MODES, EnvConfig
from .imm_core import make_core
from .env_kernels import BO_TRUNC
from ..common.validate import check_known_keys

__all__ = ["RadarTrackEnv", "row_spaces"]


def row_spaces(core):
    """``(action_space, observation_space)`` of one row of ``core``: the q action (``Discrete(len(q_levels_g))`` or
    ``Box(-1, 1, (1,))``), or with ``tracker="imm_cv_ct"`` the IMM's parameters (``MultiDiscrete([L] * n_par)`` or
    ``Box(-1, 1, (n_par,))``)."""
    cfg = core.cfg
    discrete = cfg.action_type == "discrete"
    if cfg.tracker == "imm_cv_ct":
        m = core.action_map
        act = (spaces.MultiDiscrete([m.levels] * m.n_par) if discrete
               else spaces.Box(-1.0, 1.0, (m.n_par,), dtype=np.float32))
    else:
        act = spaces.Discrete(len(cfg.q_levels_g)) if discrete else spaces.Box(-1.0, 1.0, (1,), dtype=np.float32)
    return act, spaces.Box(*core.observation_bounds(), dtype=np.float32)


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

    ``Box(low, high, (F,), float32)``, one entry per name in ``features`` (default: the first 27 below), scaled
    and clipped. Physical value = the inverse of the scaling (``ObservationLayout.decode``). Entries 0-16 describe
    the looks processed so far, 17-26 preview the next plot (``radar_env.envs.observation.PAST_FEATURES`` leaves them
    out: q then has to be chosen before the plot is seen). 27-29 are opt-in classical maneuver detectors
    (``radar_env.envs.observation.DETECTOR_FEATURES``, in no default list): the tuned imm_cv_ct and imm2 IMMs run beside
    the chain on the same looks (``radar_env.envs.detectors``; ``tracker="cv"`` only).

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
    | 27 | imm_ct_prob: imm_cv_ct's CT-mode probability (opt-in) | 1 | x | 0 | 1 |
    | 28 | imm_omega_deg_s: imm_cv_ct's turn-rate estimate, + = right (opt-in) | deg/s | x/20 | -1 | 1 |
    | 29 | imm2_high_prob: imm2's high-noise-mode probability (opt-in) | 1 | x | 0 | 1 |

    Measurement-based features hold their last value through a missed look.

    ## Rewards

    With ``e = |estimated position - true position| / sigma_m``, where ``sigma_m = sqrt((sr^2 + (r sb)^2)/2)``
    is the per-axis RMS noise of a plot at the true range ``r``, the reward per step is
    ``-min(e^2, reward_clip)`` (``reward_type="squared"``, default; aligned with position RMSE) or
    ``-min(e, reward_clip)`` (``"absolute"``), or ``-min((error / 100 m)^2, reward_clip)`` (``"squared_m"``: in
    metres, so looks weigh as in the pooled position RMSE whatever the radar's noise). When the track is lost (below), the step also gets
    ``-reward_clip * (looks remaining)``, the worst case of finishing the episode. The terms are in
    ``info["reward_terms"]`` (``position_error``, ``track_lost``). With ``reward_nees_weight`` w > 0 a third term
    ``inconsistency`` = ``-w * min(max(NEES / 9.21 - 1, 0), reward_clip)`` penalises a covariance that is too small
    for the error (NEES of the position against its 2-dof 99 % bound 9.21). Evaluation metrics do not use the
    reward.

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
    The other registered ids fix some of them (``radar_env.ENV_VARIANTS``; docs/env_reference.md lists each id).

    * ``scenario``: ``"random"`` (default), ``"random_radars"`` (the same flights seen by a random radar: 1-12 s
      scan period, noise, detection probability, sometimes a second site), a name from
      ``radar_env.sim.catalog.SCENARIO_NAMES`` (``bizup2002``,
      ``adrian_flower``, ``kim_lee_accel``, ``seed002_course_changes``, ``seed002_two_radars``; the held-out
      families ``start_maneuver``, ``short_tracks``, ``sharp_turns``, ``slow_orbits``, ``speed_changes``, which take
      no ``random_config``), ``adsb_calibration`` / ``adsb_dev`` / ``adsb_heldout`` / ``adsb:<flight>``, a path to a
      ``.csv`` trajectory (``t_s,x_m,y_m,vx_m_s,vy_m_s``), a ``Setup`` or a scenario object. ``reset(options=
      {"scenario": ...})`` overrides it for that reset only.
    * ``radar``: a ``radar_env.sim.radar.Radar`` replacing the scenario's radar (default: the paper's radar; for a
      user trajectory, the ATC radar placed by ``place_radar_site``).
    * ``random_config``: dict or ``RandomScenarioConfig`` for the random scenarios (unknown keys raise).
    * ``action_type``: ``"discrete"`` or ``"continuous"``; ``q_levels_g``: increasing levels in (0, 100] g.
    * ``features``: tuple of observation names (table above).
    * ``frame_stack`` (1, in [1, 64]): the observation is the last ``frame_stack`` feature vectors, newest first
      (``(frame_stack * F,)``; at an episode's first look the older frames repeat it); the evaluation stacks them
      the same way for a policy trained so (its ``env_config.json``).
    * ``warmup_scans`` (12, in [1, 1000]), ``warmup_q_g`` (0.03). A random episode with fewer looks than the track
      start needs (two hits, the warm-up, one look to act on) is redrawn from the same generator; a fixed scenario
      too short for ``warmup_scans`` is refused when the env is built.
    * ``reward_type`` (``"squared"``), ``reward_clip`` (100), ``reward_nees_weight`` (0, in [0, 1000]),
      ``track_loss_gate_sigma`` (30).
    * ``n_adrian`` (4), ``window_kim_lee`` (12), ``fma_weight`` (0.1): feature parameters.
    * ``radial_velocity`` (False): the filter also updates on each detected plot's radial velocity after its
      position (an EKF update, the radar's noise; warm-up included), with ``tracker="imm_cv_ct"`` every IMM mode
      too; the observation's features are computed from that filter. ``RadarTrackDoppler-v0`` is this env with
      ``radial_velocity=True``.
    * ``tracker``: ``"cv"`` (default: this env) or ``"imm_cv_ct"``: the filter is the CV / CT-EKF IMM of the
      ``imm_cv_ct`` tracker and the action its per-look parameters, ``Box(-1, 1, (7,))`` or
      ``MultiDiscrete([imm_action_levels] * 7)`` (a = 0: the tuned ``imm_cv_ct``); the observation appends the IMM's
      mode probabilities, turn rate and its std to the features (computed by this env's chain at the constant q
      ``feature_q_g``); info estimate / covariance, reward and track loss are the IMM's. With it:
      ``imm_action_levels`` (odd, default 5), ``imm_parameters`` (dict, default the tuned values), ``feature_q_g``
      (default ``kf``'s tuned q); ``frame_stack`` must be 1. Reference: :mod:`radar_env.envs.imm_env`,
      docs/environment.md.
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

    * v0 (``tracker="imm_cv_ct"`` and the detector features 27-29 added later, both opt-in: the default env is
      unchanged): initial version (the next-plot preview entries 17-26 were added before the first release;
      ``info["q"]`` renamed ``info["q_m_s2"]``, the old key kept as a deprecated alias).
    """

    metadata = {"render_modes": list(RENDER_MODES), "render_fps": 10}

    def __init__(self, **kwargs):
        self.config = EnvConfig.from_kwargs(**kwargs)
        self.render_mode = self.config.render_mode
        if self.render_mode == "human":
            from ..render import human_display_problem  # lazy: matplotlib only when rendering
            problem = human_display_problem()
            if problem is not None:
                raise ValueError(f"RadarTrack-v0: render_mode='human' needs a window, but {problem}; use "
                                 "render_mode='rgb_array' (frames as arrays, e.g. for gymnasium.wrappers.RecordVideo)")
        self._core = make_core(1, self.config)
        self.action_space, self.observation_space = row_spaces(self._core)
        self.q_levels_m_s2 = self._core.levels_m_s2.copy()
        self._needs_reset = True

    @property
    def layout(self):
        """The :class:`radar_env.envs.observation.ObservationLayout` of this env's observations."""
        return self._core.layout

    def reset(self, *, seed=None, options=None):
        if seed is not None and not (isinstance(seed, (int, np.integer)) and not isinstance(seed, bool)):
            raise ValueError(f"reset: seed must be None or an integer, got {seed!r}")   # True would be seed 1
        if seed is not None and seed < 0:
            raise ValueError(f"reset: seed must be >= 0, got {seed}")
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset: options must be a dict (e.g. {{'scenario': 'bizup2002'}}) or None, got "
                             f"{options!r}")
        super().reset(seed=None if seed is None else int(seed))
        options = dict(options or {})
        scenario = options.pop("scenario", None)
        check_known_keys("reset", options, ["scenario"], noun="option")
        core = self._core
        core.rngs[0] = self.np_random
        (obs, fo, fs, bo), inc = core.reset(scenario)
        self._needs_reset = False
        info = core.info_row(fo, fs, bo, inc)
        self._history = [(info["estimate"], info["covariance"], info["q_m_s2"], info["time_s"], obs[0])]
        if self.render_mode == "human":
            self.render()
        return obs[0], info

    def step(self, action):
        if self._needs_reset:
            raise RuntimeError("RadarTrack-v0: call reset() before step() (and after an episode ends)")
        a = np.asarray(action)
        core = self._core
        size = math.prod(core.action_shape)
        if a.shape != self.action_space.shape and not (size == 1 and a.shape == ()):
            what = (f"shape {self.action_space.shape}" if size != 1 else
                    "a single number or shape (1,)" if self.action_space.shape else "a single number")
            raise ValueError(f"action must be {what} ({self.action_space}), got shape {a.shape}")
        (obs, fo, fs, bo), rew, _, _, inc, _ = core.step(a.reshape((1,) + core.action_shape))
        info = core.info_row(fo, fs, bo, inc)
        term, trunc = info["track_lost"], bool(bo[BO_TRUNC, 0])
        self._needs_reset = term or trunc
        if self.render_mode is not None:
            self._history.append((info["estimate"], info["covariance"], info["q_m_s2"], info["time_s"], obs[0]))
        if self.render_mode == "human":
            self.render()
        return obs[0], rew[0].item(), term, trunc, info

    def episode(self):
        """The current episode's stored looks (``Tracker.look_data`` views for row 0): ``t_s``, ``truth``, ``z_m``,
        ``R_m2`` (NaN at a missed look) and ``detected``, every look of the episode, the future ones too (the agent's
        observation never includes them; a caller that must stay causal reads up to the current look)."""
        return {f: self._core.tracker.look_data(f)[0, : self._core.tracker.n_looks[0]]
                for f in ("t_s", "truth", "z_m", "R_m2", "detected")}

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

    def close(self):
        """Close the ``human`` window and release the render figures (if rendered); the env may be reset again."""
        if getattr(self, "_fig", None) is not None or getattr(self, "_human_fig", None) is not None:
            from ..render import close_render
            close_render(self)
        super().close()

    def render(self):
        """A radar-scope frame: RGB array ``radar_env.render.FRAME_SHAPE`` (``rgb_array``) or a window (``human``)."""
        if self.render_mode is None:
            gym.logger.warn("RadarTrack-v0: render() called without a render_mode; pass render_mode to gym.make")
            return None
        from ..render import render_frame  # lazy: matplotlib only when rendering
        return render_frame(self)
