"""The environment reference page, docs/env_reference.md, generated from the code.

``python -m radar_env.envs.reference`` rewrites the page; ``--check`` exits 1 if the committed page differs
(tests/test_env_reference.py does the same). The page follows Gymnasium's environment pages (description, action
space, observation space, rewards, starting state, episode end, arguments, version history). What the code knows
is read from it: the registered ids and their spaces (``gym.make``), the q levels, the IMM parameters and their
ranges, the observation's names, units, scaling and bounds (the feature registry ``FEATURE_SPECS`` and each env's
``observation_space``), the arguments and their defaults (:class:`radar_env.envs.config.EnvConfig`) and every
numeric argument's valid range (:data:`NUMERIC_RANGES`, which the test checks against the validation). The prose
between them is written here.
"""

from __future__ import annotations

import argparse
import sys
from dataclasses import fields
from pathlib import Path


__all__ = ["render", "main", "PAGE", "ARGUMENTS", "NUMERIC_RANGES"]

PAGE = Path(__file__).resolve().parents[2] / "docs" / "env_reference.md"
COMMAND = "python -m radar_env.envs.reference"

NUMERIC_RANGES = {
    # argument: (low, high, integer) -- the closed interval EnvConfig.from_kwargs accepts
    "frame_stack": (1, 64, True), "warmup_scans": (1, 1000, True), "warmup_q_g": (0.0, 100.0, False),
    "reward_clip": (1e-3, 1e9, False), "reward_nees_weight": (0.0, 1e3, False),
    "track_loss_gate_sigma": (1.0, 1e6, False), "n_adrian": (1, 50, True), "window_kim_lee": (1, 1000, True),
    "fma_weight": (1e-6, 1.0, False), "imm_action_levels": (3, 101, True), "feature_q_g": (1e-6, 100.0, False),
}
"""Every numeric argument's valid interval (inclusive); anything outside is a ``ValueError`` naming it."""

ARGUMENTS = {
    "scenario": "the flights: `\"random\"`, `\"random_radars\"` (the same flights seen by a random radar), a named "
                "scenario ({scenarios}), `adsb_calibration` / `adsb_dev` / `adsb_heldout` / `adsb:<flight>`, a "
                "`.csv` trajectory (`t_s,x_m,y_m,vx_m_s,vy_m_s`), a `Setup` or a scenario object; "
                "`reset(options={{\"scenario\": ...}})` overrides it for one reset",
    "radar": "a `radar_env.sim.radar.Radar` replacing the scenario's radar",
    "random_config": "a dict of `RandomScenarioConfig` fields ({random_fields}) or a `RandomScenarioConfig`; "
                     "unknown keys refused",
    "action_type": "`\"discrete\"` or `\"continuous\"`",
    "q_levels_g": "at least 2 strictly increasing levels in (0, 100] g: the discrete actions; the first and last "
                  "bound the continuous action and scale `q_prev_g` / `next_q_fit_g`",
    "features": "observation names from the table above, no repeats",
    "frame_stack": "the observation is the last k feature vectors, newest first; 1 with `tracker=\"imm_cv_ct\"`",
    "warmup_scans": "looks filtered at `warmup_q_g` after the two-hit start, before the agent acts",
    "warmup_q_g": "q of the warm-up looks, g",
    "reward_type": "{reward_types}",
    "reward_clip": "the per-look penalty's cap",
    "reward_nees_weight": "weight of the covariance-consistency term (0: off)",
    "track_loss_gate_sigma": "the track is lost when the position error exceeds this many plot sigmas",
    "n_adrian": "looks between the headings of Adrian's turn rates",
    "window_kim_lee": "looks in Kim & Lee's sliding window",
    "fma_weight": "weight of the new plot in the fading-memory average of the innovation",
    "radial_velocity": "`True`: the filter also updates on each plot's radial velocity (an EKF update)",
    "render_mode": "`None`, {render_modes}",
    "tracker": "{trackers}: the CV filter whose q is the action, or the CV / CT-EKF IMM whose 7 per-look "
               "parameters are",
    "imm_action_levels": "levels per IMM parameter, odd (the middle one is the tuned value); discrete IMM only "
                         "(`None`: 5)",
    "imm_parameters": "a dict of IMM parameters ({imm_params}) moving the a = 0 point, and `ct_rate_1_deg_s`, "
                      "`ct_rate_2_deg_s`, `ct_rate_3_deg_s` for a bank of CT modes entered at +-each rate (the tracker "
                      "`imm_ct_bank`; a detector per mode); IMM only (`None`: the tuned values, one CT mode)",
    "feature_q_g": "q (g) of the CV chain that computes the IMM env's features; IMM only (`None`: {feature_q:.4g}, "
                   "`kf`'s tuned q)",
}
"""Every argument's meaning (``{...}``: filled from the code). tests/test_env_reference.py checks the keys are
EnvConfig's fields."""

DETECTOR_MEANINGS = {
    "mu_cv": "the IMM's CV-mode probability", "mu_ct": "the IMM's CT-mode probability",
    "mu_high": "the IMM's high-noise CV-mode probability",
    "omega_over_20deg_s": "the IMM's combined turn rate / 20 deg/s (+ = right)",
    "log10_omega_std_deg_s_over_3": "log10 of its standard deviation in deg/s, / 3",
}


def _num(v):
    return f"{float(v):.4g}"


def _rng(pair):
    return f"{pair[0]:g}-{pair[1]:g}"


def _space(sp):
    return f"`{sp}`"


def _spaces(env_id, **kw):
    import gymnasium as gym
    env = gym.make(env_id, disable_env_checker=True, **kw).unwrapped
    return env


def _kwargs_summary(kwargs):
    from .variants import PINNED_FEATURES, TRAINING_Q_LEVELS_G, TRAINING_RANDOM_CONFIG
    out = []
    for k, v in kwargs.items():
        if k == "features" and tuple(v) == PINNED_FEATURES:
            out.append("`features`: the 27 pinned (`PINNED_FEATURES`)")
        elif k == "q_levels_g" and tuple(v) == TRAINING_Q_LEVELS_G:
            out.append("`q_levels_g`: the 15 training levels")
        elif k == "random_config" and v == TRAINING_RANDOM_CONFIG:
            out.append("`random_config`: the training flights")
        else:
            out.append(f"`{k}={v!r}`")
    return ", ".join(out) if out else "(the defaults)"


def _obs_rows(layout, low, high, start=0):
    rows = []
    for i, (n, s) in enumerate(zip(layout.names, layout.specs)):
        scaling = {"linear": f"x / {s.scale:g}" if s.scale != 1 else "x", "log10p": f"log10(1 + x) / {s.scale:g}",
                   "logq": "action map"}[s.kind]
        lo, hi = (float(layout.decode(bound, n)) for bound in (low, high))
        desc = s.description.replace("|", "\\|")         # a literal bar inside a Markdown table cell
        rows.append(f"| {start + i} | `{n}` | {s.unit} | {desc} | {scaling} | {_num(low[i])} | "
                    f"{_num(high[i])} | {_num(lo)} .. {_num(hi)} |")
    return rows


def render():
    """The page's text."""
    import gymnasium as gym

    from radar_env.filters.imm_cv_ct import IMM_CV_CT_PARAMS
    from radar_env.sim.catalog import SCENARIO_NAMES
    from radar_env.sim.scenario import RandomScenarioConfig
    from .config import (EnvConfig, NEES_99_2DOF, RENDER_MODES, REWARD_SCALE_M, REWARD_TYPES, TRACKERS)
    from .imm_env import imm_action_map, imm_env_defaults
    from .observation import DEFAULT_FEATURES, DEFAULT_Q_LEVELS_G, DETECTOR_FEATURES, FEATURE_SPECS
    from .variants import ENV_VARIANTS, ENV_VARIANTS_DOC, PINNED_FEATURES, TRAINING_Q_LEVELS_G

    d = EnvConfig()
    L = [f"<!-- Generated by `{COMMAND}` from the code (radar_env/envs/reference.py): edit that, not this page; "
         "tests/test_env_reference.py fails when the two differ. -->",
         "",
         "# RadarTrack environments: reference",
         "",
         "How to use them (vector envs, wrappers, training, the bundled policies): [The environment](environment.md).",
         "This page lists what each registered id is, in the order of Gymnasium's environment pages.",
         "",
         "| | |", "|---|---|"]
    v0 = _spaces("RadarTrack-v0")
    L += [f"| Action space | {_space(v0.action_space)} (`RadarTrack-v0`; per id below) |",
          f"| Observation space | `Box(low, high, ({len(DEFAULT_FEATURES)},), float32)` (`RadarTrack-v0`; per id below) |",
          "| Import | `import gymnasium as gym, radar_env; gym.make(\"RadarTrack-v0\")` |", ""]

    L += ["## Registered ids", "",
          "Each id is `RadarTrack-v0` with some arguments fixed (`radar_env.ENV_VARIANTS`); "
          "`gym.make(id, **overrides)` changes any of them, an unknown one is a `ValueError` naming it.", "",
          "| id | action space | observation | fixed arguments | max_episode_steps |", "|---|---|---|---|---|"]
    envs = {}
    for env_id, kwargs in ENV_VARIANTS.items():
        e = envs[env_id] = _spaces(env_id)
        L.append(f"| `{env_id}` | {_space(e.action_space)} | `Box(({e.observation_space.shape[0]},))` | "
                 f"{_kwargs_summary(kwargs)} | {gym.spec(env_id).max_episode_steps} |")
    L += ["", "What they are for:", ""] + [f"* `{k}`: {v}" for k, v in ENV_VARIANTS_DOC.items()] + [""]

    L += ["## Description", "",
          "A surveillance radar looks at an aircraft every few seconds and reports range, bearing and radial "
          "velocity, each with noise. A Kalman filter with a constant-velocity (CV) model tracks it; its "
          "process-noise level q decides how much it trusts the model (low: smooth on straight legs, lagging in a "
          "turn; high: follows the turn, noisy on the legs). The agent chooses q for every look from features of the "
          "filter's innovations, never from the truth; the observation already previews the plot the chosen q will "
          "be used for. With `tracker=\"imm_cv_ct\"` (the `RadarTrackIMM` ids) the filter is a CV / coordinated-turn "
          "EKF / high-noise CV IMM and the agent sets its mode noises and switch probabilities instead. An episode "
          "(the truth, every plot's noise and detection) is drawn whole at `reset` from the seed.", ""]

    L += ["## Action space", "", "### q of the CV filter (`tracker=\"cv\"`)", "",
          f"`action_type=\"discrete\"`: `Discrete(len(q_levels_g))`; action i is q = `q_levels_g[i]` g. "
          f"`RadarTrack-v0`'s {len(DEFAULT_Q_LEVELS_G)} levels (0.03 x (2/0.03)^(j/6) g, j = -4..8):", "",
          "| action | " + " | ".join(str(i) for i in range(len(DEFAULT_Q_LEVELS_G))) + " |",
          "|---" * (len(DEFAULT_Q_LEVELS_G) + 1) + "|",
          "| q (g) | " + " | ".join(_num(q) for q in DEFAULT_Q_LEVELS_G) + " |", "",
          f"The `RadarTrackContinuous` and `RadarTrackIMM` ids use the bundled policies' {len(TRAINING_Q_LEVELS_G)} "
          f"levels ({_num(TRAINING_Q_LEVELS_G[0])} .. {_num(TRAINING_Q_LEVELS_G[-1])} g).", "",
          "`action_type=\"continuous\"`: `Box(-1, 1, (1,))`, q = q_min (q_max / q_min)^((a + 1) / 2) with q_min, q_max "
          "the first and last level (an action beyond [-1, 1] by more than 1e-6, or not finite, is refused with a "
          "`ValueError`; within that slack it is clipped).", "",
          "### IMM parameters (`tracker=\"imm_cv_ct\"`)", "",
          "`Box(-1, 1, (7,))` or `MultiDiscrete([imm_action_levels] * 7)` (level i is a = (2i - (L - 1)) / (L - 1)). "
          "Each entry is mapped piecewise linearly in log space (noises) or logit space (stay probabilities): "
          "a = -1 the low end of the range, a = 0 the tuned `imm_cv_ct` value, a = +1 the high end. "
          "**The zero action is `imm_cv_ct`.**", "",
          "| index | parameter | unit | a = -1 | a = 0 | a = +1 | space |", "|---|---|---|---|---|---|---|"]
    amap = imm_action_map(EnvConfig.from_kwargs(tracker="imm_cv_ct", action_type="continuous"))
    units = {n: u for n, u, *_ in IMM_CV_CT_PARAMS}
    logs = {n: lg for n, _, _, _, lg in IMM_CV_CT_PARAMS}
    for i, n in enumerate(amap.names):
        L.append(f"| {i} | `{n}` | {units[n] or '1'} | {_num(amap.lo[i])} | {_num(amap.base[i])} | "
                 f"{_num(amap.hi[i])} | {'log' if logs[n] else 'logit'} |")
    L.append("")

    allf = _spaces("RadarTrack-v0", features=DEFAULT_FEATURES + DETECTOR_FEATURES)
    L += ["## Observation space", "",
          "`Box(low, high, (F,), float32)`, one entry per name in `features` (`RadarTrack-v0`: the first 27 below; "
          "the `RadarTrackContinuous` and `RadarTrackIMM` ids pin the same 27 by name), each scaled and clipped to "
          "[min, max]; *physical* is the range of the value before scaling that the entry can show "
          "(`ObservationLayout.decode`; `q_prev_g` and `next_q_fit_g` follow the action map: shown for "
          f"`RadarTrack-v0`'s levels, {_num(TRAINING_Q_LEVELS_G[0])} .. {_num(TRAINING_Q_LEVELS_G[-1])} g with the "
          "15 training levels). Entries 0-16 describe the looks so far, 17-26 preview the next plot (against the q-free "
          "predicted mean). With `frame_stack=k` the observation is the last k vectors, newest first.", "",
          "| Num | Name | Unit | Meaning | Scaling | Min | Max | Physical |", "|---|---|---|---|---|---|---|---|"]
    L += _obs_rows(allf.layout, allf.observation_space.low, allf.observation_space.high)
    assert list(allf.layout.names) == list(FEATURE_SPECS)
    L += ["", f"{', '.join(f'`{n}`' for n in DETECTOR_FEATURES)} (27-29) are opt-in classical detectors (the tuned "
          "`imm_cv_ct` and `imm2` IMMs run beside the chain), only with `tracker=\"cv\"`: "
          "`features=DEFAULT_FEATURES + DETECTOR_FEATURES`.", "",
          "With `tracker=\"imm_cv_ct\"` the features (computed by a CV chain at the constant q `feature_q_g`) are "
          "followed by the IMM's detectors after the look:", "",
          "| Num | Name | Meaning | Min | Max |", "|---|---|---|---|---|"]
    imm = envs["RadarTrackIMM-v0"]
    F = len(PINNED_FEATURES)
    from radar_env.filters.imm_cv_ct import detector_names
    for j, n in enumerate(detector_names(3)):
        L.append(f"| {F + j} | `{n}` | {DETECTOR_MEANINGS[n]} | {_num(imm.observation_space.low[F + j])} | "
                 f"{_num(imm.observation_space.high[F + j])} |")
    L.append("")

    L += ["## Rewards", "",
          "With e = |estimated position - true position| / sigma_m, sigma_m = sqrt((sr^2 + (r sb)^2) / 2) the "
          "per-axis RMS noise of a plot at the true range r, the reward of a look is "
          f"-min(e^2, `reward_clip`) (`reward_type=\"squared\"`, default; `reward_clip` {d.reward_clip:g}), "
          f"-min(e, `reward_clip`) (`\"absolute\"`) or -min((error / {REWARD_SCALE_M:g} m)^2, `reward_clip`) "
          "(`\"squared_m\"`). The look where the track is lost also gets -`reward_clip` x (looks remaining). With "
          f"`reward_nees_weight` w > 0: -w min(max(NEES / {NEES_99_2DOF:.2f} - 1, 0), `reward_clip`) (the position "
          "NEES against its 2-dof 99 % bound). The terms are in `info[\"reward_terms\"]`; the evaluation's metrics "
          "do not use the reward.", ""]

    rc = RandomScenarioConfig()
    L += ["## Starting state", "",
          f"`reset(seed=s)` draws the episode from the seed (`RadarTrack-v0`: random flights, {_rng(rc.speed_kt)} kt, "
          f"{_rng(rc.n_legs)} legs, turns of {_rng(rc.turn_accel_g)} g, {_rng(rc.range_km)} km from Adrian's ATC "
          "radar, T = 5 s (`RandomScenarioConfig`'s defaults); `random_radars`: the flights seen by a "
          "random radar, 1-12 s scans, sometimes a second site). The track starts from the first two detected plots, "
          f"then `warmup_scans` looks ({d.warmup_scans}) are filtered at `warmup_q_g` ({d.warmup_q_g:g} g) before "
          "the agent acts; the first observation describes the last warm-up look. A random flight too short for "
          "that is redrawn from the same seed's stream, so the episode stays a function of the seed.", ""]

    L += ["## Episode end", "",
          f"* **Termination**: the track is lost, e > `track_loss_gate_sigma` ({d.track_loss_gate_sigma:g}); "
          "`info[\"track_lost\"]` is True.",
          "* **Truncation**: the scenario's last radar look has been processed (the flight left the radar's coverage "
          "or ended): `truncated=True`, `terminated=False`, as Gymnasium reports a time limit.",
          "* **`max_episode_steps` is `None` for every id**: the flight ends the episode by itself, its length is "
          "the scenario's (random flights differ in length, a `.csv` or ADS-B flight has its own), and the "
          "evaluation scores whole flights, so a fixed limit would only cut some of them short. "
          "`gym.make(id, max_episode_steps=n)` and `gym.make_vec(..., max_episode_steps=n)` add one on request "
          "(truncated at n steps, as Gymnasium's `TimeLimit`).", ""]

    L += ["## Arguments", "",
          "`gym.make(id, **kwargs)`; every argument is validated when the env is built: a wrong value or type, or an "
          "unknown key, is a `ValueError` naming it (and, for a number, its range).", "",
          "| argument | default | valid | meaning |", "|---|---|---|---|"]
    fill = {"scenarios": ", ".join(f"`{n}`" for n in SCENARIO_NAMES if n not in ("random", "random_radars")),
            "random_fields": ", ".join(f"`{f.name}`" for f in fields(RandomScenarioConfig)),
            "reward_types": ", ".join(f"`\"{t}\"`" for t in REWARD_TYPES),
            "render_modes": ", ".join(f"`\"{m}\"`" for m in RENDER_MODES),
            "trackers": " or ".join(f"`\"{t}\"`" for t in TRACKERS),
            "imm_params": ", ".join(f"`{n}`" for n, *_ in IMM_CV_CT_PARAMS),
            "feature_q": imm_env_defaults()["feature_q_g"]}
    for f in fields(EnvConfig):
        default = getattr(d, f.name)
        if f.name == "q_levels_g":
            dflt = f"the {len(default)} levels above"
        elif f.name == "features":
            dflt = f"the first {len(default)} features"
        else:
            dflt = f"`{default!r}`"
        if f.name in NUMERIC_RANGES:
            lo, hi, integer = NUMERIC_RANGES[f.name]
            valid = f"{'integer' if integer else 'number'} in [{lo:g}, {hi:g}]"
        else:
            valid = {"action_type": "choice", "reward_type": "choice", "render_mode": "choice", "tracker": "choice",
                     "radial_velocity": "bool"}.get(f.name, "see meaning")
        L.append(f"| `{f.name}` | {dflt} | {valid} | {ARGUMENTS[f.name].format(**fill)} |")
    L.append("")

    info = sorted(v0.reset(seed=0)[1])
    L += ["## Info", "",
          "`reset` and `step` return " + ", ".join(f"`{k}`" for k in info) + " (positions in m, velocities in m/s, "
          "`q_m_s2` in m/s^2; `q` is its deprecated alias). Details: `help(radar_env.envs.env.RadarTrackEnv)`.", ""]

    L += ["## Version history", "",
          "* v0: initial version (the next-plot preview, entries 17-26, was added before the first release). Added "
          "since, opt-in, the default env unchanged: `tracker=\"imm_cv_ct\"` and the detector features 27-29; "
          "`info[\"q\"]` renamed `info[\"q_m_s2\"]` (the old key kept as a deprecated alias).",
          "* The ids other than `RadarTrack-v0` are named argument sets of v0 (same code, same version): "
          "`RadarTrackDoppler-v0`, then `RadarTrackContinuous-v0`, `RadarTrackContinuousDoppler-v0`, "
          "`RadarTrackIMM-v0` and `RadarTrackIMMDoppler-v0`. A change of an id's arguments would be a new version "
          "of that id.", ""]
    return "\n".join(L).rstrip("\n") + "\n"


def main(argv=None):
    ap = argparse.ArgumentParser(prog=COMMAND, description=f"Write {PAGE.name} from the code.")
    ap.add_argument("--check", action="store_true", help="exit 1 if the committed page differs (write nothing)")
    args = ap.parse_args(argv)
    text = render()
    if args.check:
        if not PAGE.is_file() or PAGE.read_text() != text:
            print(f"{PAGE} is out of date: run {COMMAND}", file=sys.stderr)
            return 1
        return 0
    PAGE.write_text(text)
    print(f"wrote {PAGE}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
