"""The registered environment ids and the arguments each fixes (:data:`ENV_VARIANTS`; no Gymnasium needed).

``radar_env`` registers every id at import (``radar_env/__init__.py``). Each id's kwargs are JSON-like (tuples
for lists and ranges, as :func:`agents.policies.checks.env_kwargs_from_json` turns a policy's ``env_config.json``
into), so ``gym.make(id)`` builds exactly the env a bundled learned tracker was trained in and observes; any
argument may still be overridden (``gym.make(id, scenario="bizup2002")``), an unknown one is a ``ValueError``
naming it. tests/test_env_ids.py checks that each bundled policy's ``env_config.json`` equals its id's kwargs
(:data:`agents.policies.bundle.BUNDLED_ENV_IDS`), so the two cannot drift, and that every id passes Gymnasium's
``check_env`` (``skip_render_check=True`` without a display, where ``render_mode="human"`` is refused at build).

``max_episode_steps`` stays ``None`` for every id: an episode is a flight, which ends by itself (the env reports
``truncated=True`` at the scenario's last look, ``terminated=True`` when the track is lost); a flight's length is
the scenario's, not the agent's, and the evaluation scores whole flights, so a time limit would only cut flights
short. ``gym.make(id, max_episode_steps=n)`` (and ``gym.make_vec``) still add Gymnasium's limit on request.
"""

from __future__ import annotations

__all__ = ["ENV_VARIANTS", "ENV_VARIANTS_DOC", "PINNED_FEATURES", "TRAINING_Q_LEVELS_G", "TRAINING_RANDOM_CONFIG"]

PINNED_FEATURES = (
    "nu_along", "nu_cross", "nis", "c_min_g", "turn_rate_alg1_deg_s", "turn_rate_alg2_deg_s", "fma_innovation_km",
    "kim_lee_q_g", "speed_m_s", "range_km", "dt_s", "pos_std_ratio", "q_prev_g", "detected", "nu_along_fm",
    "nu_cross_fm", "nis_fm", "next_nu_along", "next_nu_cross", "next_nis", "next_q_fit_g", "next_c_min_g",
    "next_los_accel_g", "next_rdot_nu", "next_dt_s", "next_meas_std_m", "next_detected")
"""The 27 observation features of the bundled learned trackers, pinned by name (today equal to
``radar_env.envs.observation.DEFAULT_FEATURES``; pinned so that a later default cannot change these ids)."""

TRAINING_Q_LEVELS_G = (0.00045, 0.000906, 0.001825, 0.003674, 0.007399, 0.014898, 0.03, 0.06041, 0.121644,
                       0.244949, 0.493242, 0.993219, 2.0, 4.027307, 8.109603)
"""The bundled policies' 15 q levels (g): 0.03 g x ~2.01^k, k = -6..8. They set the continuous action's range
(0.00045 ... 8.1 g, wider below than v0's 13 levels) and the scaling of the ``q_prev_g`` / ``next_q_fit_g``
features."""

TRAINING_RANDOM_CONFIG = {
    "random_radar_probability": 0.7, "speed_kt": (80, 1200), "speed_change_probability": 0.5,
    "speed_change_accel_g": (0.1, 5.0), "range_km": (10, 250), "first_leg_min_s": 0.0, "first_leg_s": (1, 300),
    "turn_probability": 0.85, "turn_accel_g": (0.3, 9.0), "max_turn_rate_deg_s": 30.0,
    "turn_heading_change_deg": (10, 540)}
"""The bundled learned trackers' training flights (``RandomScenarioConfig`` fields; the others at their defaults):
80-1200 kt; each maneuver a turn with probability 0.85 (0.3-9 g, up to 540 deg, at most 30 deg/s) and a speed
change with probability 0.5 (0.1-5 g); 10-250 km from the radar; a first leg of 1-300 s, so a maneuver may begin
during the track start; a random radar 70 % of the time (``scenario="random_radars"``), else the ATC radar."""

_CONTINUOUS = {"action_type": "continuous", "scenario": "random_radars", "q_levels_g": TRAINING_Q_LEVELS_G,
               "features": PINNED_FEATURES, "random_config": TRAINING_RANDOM_CONFIG}

ENV_VARIANTS = {
    "RadarTrack-v0": {},
    "RadarTrackDoppler-v0": {"radial_velocity": True},
    "RadarTrackContinuous-v0": dict(_CONTINUOUS),
    "RadarTrackContinuousDoppler-v0": {**_CONTINUOUS, "radial_velocity": True},
    "RadarTrackIMM-v0": {**_CONTINUOUS, "tracker": "imm_cv_ct"},
    "RadarTrackIMMDoppler-v0": {**_CONTINUOUS, "radial_velocity": True, "tracker": "imm_cv_ct"},
}
"""The registered environment ids and the arguments each fixes (any may still be overridden in ``gym.make``);
what each is for: :data:`ENV_VARIANTS_DOC`."""

ENV_VARIANTS_DOC = {
    "RadarTrack-v0": "the defaults: random flights seen by Adrian's ATC radar, 13 discrete q levels.",
    "RadarTrackDoppler-v0": "v0 whose filter also updates on each plot's radial velocity (the radar's Doppler "
                            "measurement); observation and reward as v0's.",
    "RadarTrackContinuous-v0": "the env of the bundled q-policy `policy_bp` (`agents/bundled/backprop`): a "
                               "continuous q over the 15 training levels' range, the 27 pinned features, the "
                               "training flights on `random_radars`. The bundled PPO `policy` was trained in it "
                               "with `action_type=\"discrete\", frame_stack=4`.",
    "RadarTrackContinuousDoppler-v0": "the same with `radial_velocity=True`: the env of `policy_bp_rdot`.",
    "RadarTrackIMM-v0": "the learned IMM's env (`policy_imm_bp`, `agents/bundled/learned_imm`): the CV / CT-EKF "
                        "IMM whose 7 per-look parameters are the action (a = 0: the tuned `imm_cv_ct`), the 27 "
                        "pinned features of a CV chain at `kf`'s q plus the IMM's 5 detectors, the training "
                        "flights. `policy_imm_ppo` has its observation (trained on earlier flights: its "
                        "`random_config`).",
    "RadarTrackIMMDoppler-v0": "the same with `radial_velocity=True`: the env of `policy_imm_bp_rdot`.",
}
"""What each id is for (Markdown; rendered on docs/env_reference.md)."""
