"""The batched core of RadarTrack-v0 (no Gymnasium needed): N tracks stepped together.

:class:`_Core` maps actions to q (:func:`actions_to_q_m_s2`), runs the one tracking chain
(:class:`radar_env.tracking.Tracker`), and builds observations, rewards, end flags and the info dict. Episodes come
from :func:`draw_setup_and_episode`. The single env and the vector env are thin Gymnasium layers over it.
"""

from __future__ import annotations

import math

import numpy as np

from .config import NEES_99_2DOF, REWARD_SCALE_M, EnvConfig, resolve_scenario
from .draws import MAX_EPISODE_DRAWS, draw_episodes
from .observation import FrameStack, ObservationLayout, measurement_sigma_m
from .scenario import RADAR_PLACEMENT_RANGE_M
from .units import G0_M_S2

__all__ = ["draw_setup_and_episode", "actions_to_q_m_s2", "MAX_EPISODE_DRAWS"]


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
        self.frames = FrameStack(n, cfg.frame_stack, len(cfg.features)) if cfg.frame_stack > 1 else None
        self.tracker = cfg.track_start.tracker(n)
        self.q_prev = np.full(n, cfg.warmup_q_g * G0_M_S2)
        self.rngs = [None] * n
        # resolved once: a CSV trajectory is read here, not at every reset
        self.scenario = resolve_scenario(cfg.scenario)
        self.random_config = cfg.random_scenario_config
        # Refuse at build what would fail at a reset (a scenario too short for warmup_scans, a random_config whose
        # flights never stay in range): one probe draw from a throwaway generator; no row's stream is touched.
        draw_setup_and_episode(self.scenario, cfg.radar, self.random_config, np.random.default_rng(0),
                               cfg.warmup_scans)

    # ---- actions
    def action_to_q(self, action):
        """Validated action -> (n,) q in m/s^2 (:func:`actions_to_q_m_s2`); ``ValueError`` naming the valid range.
        Cheap checks on small arrays: this runs every step."""
        a = np.asarray(action)
        kind = a.dtype.kind
        # bool, complex, str and object actions are refused, not cast: True would silently be level 1
        if kind not in "iuf":
            raise ValueError(f"action must be {'integer' if self.cfg.action_type == 'discrete' else 'real'} "
                             f"number(s), got {action!r} (dtype {a.dtype})")
        n, n_levels = self.n, self.levels_m_s2.size
        if self.cfg.action_type == "discrete":
            if a.size != n or (kind == "f" and not (np.isfinite(a) & (a == np.round(a))).all()):
                raise ValueError(f"action must be {n} integer(s) in [0, {n_levels - 1}], got {action!r}")
            if kind == "f":   # range checked before the cast, which is undefined for huge values
                ok = ((a >= 0) & (a < n_levels)).all()
                ai = a.reshape(n).astype(np.int64)
            else:
                ai = a.reshape(n).astype(np.int64, copy=False)
                ok = not (ai.view(np.uint64) >= n_levels).any()   # a negative index wraps to a huge unsigned one
            if not ok:
                raise ValueError(f"action must be in [0, {n_levels - 1}] (Discrete({n_levels})), got {action!r}")
            return self.levels_m_s2[ai]
        a = a.astype(np.float64).reshape(-1)
        if a.size != n or not (np.abs(a) <= 1.0 + 1e-6).all():   # False for NaN / inf
            raise ValueError(f"action must be {n} finite value(s) in [-1, 1] (Box(-1, 1)), got {action!r}")
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
        self._pf = self.cfg.track_start.tracker(self.n)
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
        if self.frames is not None:
            obs = self.frames.reset(rows, obs)
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
        if self.frames is not None:
            obs = self.frames.push(slice(None), obs)
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
        terms = {"position_error": pos, "track_lost": np.where(lost, -clip * remaining, 0.0)}
        w = self.cfg.reward_nees_weight
        if w > 0:   # overconfidence: the position NEES beyond its 99 % bound, in units of the bound
            d0, d1 = out.x[:, 0] - out.truth[:, 0], out.x[:, 1] - out.truth[:, 1]
            a, b, c = out.P[:, 0, 0], out.P[:, 0, 1], out.P[:, 1, 1]
            det = a * c - b * b
            # the 2 x 2 closed form, never a LinAlgError: the update keeps P positive definite on every radar the
            # env accepts (radar_env.kernels._pd_floor); a block that is not (det <= 0) would count as maximally
            # inconsistent (the clipped penalty), never as a number from a singular solve
            ok = (det > 0.0) & (a > 0.0)
            nees = np.divide(c * d0 * d0 - 2.0 * b * d0 * d1 + a * d1 * d1, det, out=np.full(det.shape, np.inf),
                             where=ok)
            terms["inconsistency"] = -w * np.minimum(np.maximum(nees / NEES_99_2DOF - 1.0, 0.0), clip)
        return terms

    # ---- info
    def _info(self, out, terms):
        # StepOutput arrays are new every step (gathered or computed), so the info can hold them without copies.
        x = out.x
        polar = np.empty((x.shape[0], 3))   # np.stack costs more than the three copies at these sizes
        polar[:, 0], polar[:, 1], polar[:, 2] = out.range_m, out.bearing_rad, out.radial_velocity_m_s
        return {
            "truth": out.truth,
            "estimate": x,
            "covariance": out.P,
            "measurement": out.z_m,
            "measurement_covariance": out.R_m2,
            "polar": polar,
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


_SCALAR_INFO = frozenset(("q_m_s2", "q", "dt", "detected", "maneuvering", "track_lost", "time_s"))


def _row(info, i):
    """Row ``i`` of a batched info dict, with Python scalars for the scalar keys and reward terms."""
    out = {k: (v[i].item() if k in _SCALAR_INFO else v[i]) for k, v in info.items() if k != "reward_terms"}
    out["reward_terms"] = {k: v[i].item() for k, v in info["reward_terms"].items()}
    return out
