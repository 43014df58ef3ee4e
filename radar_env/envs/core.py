"""The batched core of RadarTrack-v0 (no Gymnasium needed): N tracks stepped together.

:class:`_Core` runs the env's step for all rows in one compiled call (:mod:`radar_env.envs.env_kernels`: action -> q,
the one tracking chain of :class:`radar_env.filters.tracking.Tracker`, observation, reward, end flags) and builds the info
dict from its output arrays. Episodes are drawn straight into the tracker (:class:`radar_env.sim.draws.LookDrawer`).
The single env and the vector env are thin Gymnasium layers over it.
"""

from __future__ import annotations

import math

import numpy as np

from . import env_kernels as _ek
from ..filters import kernels as _k
from .config import NEES_99_2DOF, REWARD_SCALE_M, EnvConfig, resolve_scenario
from .detectors import DetectorBank
from ..common.parallel import run as _run_rows
from ..sim.draws import MAX_EPISODE_DRAWS, LookDrawer, _keys, draw_episodes
from .observation import FrameStack, ObservationLayout
from ..sim.scenario import RADAR_PLACEMENT_RANGE_M
from ..common.units import G0_M_S2

__all__ = ["draw_setup_and_episode", "actions_to_q_m_s2", "MAX_EPISODE_DRAWS"]


def draw_setup_and_episode(scenario, radar, random_config, rng, warmup_scans=EnvConfig.warmup_scans,
                           radar_range_m=RADAR_PLACEMENT_RANGE_M):
    """The episode of one reset: the truth (if random) and all plots, from ``rng`` only (a batch of one of
    :func:`radar_env.sim.draws.draw_episodes`, whose docstring gives the random stream).

    A trajectory scenario with ``radar=None`` is seen by Adrian's ATC radar placed as
    :func:`radar_env.sim.scenario.place_radar_site` does with ``range_m=radar_range_m`` (m).

    An episode too short for the track start (two hits, ``warmup_scans`` warm-up looks, then at least one look
    for the policy; e.g. a short random flight seen by a slow radar, or missed plots) is redrawn from the same
    stream, at most ``MAX_EPISODE_DRAWS`` times. Only draws that could not be run are replaced. A fixed scenario
    whose looks, all detected, are still too few raises ``ValueError`` at once (the env checks this when it is
    built)."""
    return draw_episodes(resolve_scenario(scenario), radar, random_config, [rng], warmup_scans,
                         radar_range_m).episode(0)


def actions_to_q_m_s2(actions, action_type, levels_m_s2):
    """The action map (no validation): discrete index -> ``levels_m_s2[i]``; continuous ``a`` in [-1, 1] (clipped)
    -> ``q_min (q_max / q_min)^((a + 1) / 2)`` with ``q_min, q_max`` the first and last level (the env's step
    kernel computes the same, :func:`radar_env.envs.env_kernels._continuous_q`). Returns (n,)."""
    levels = np.asarray(levels_m_s2, dtype=np.float64)
    a = np.asarray(actions)
    if action_type == "discrete":
        return levels[a.reshape(-1).astype(np.int64)]
    a = _k.c_array(a.astype(np.float64).reshape(a.shape[0] if a.ndim else 1, -1)[:, 0], np.float64)
    q = np.empty(a.shape[0])
    _ek.k_continuous_q(a, math.log10(levels[0]), math.log10(levels[-1]), q)
    return q


_NO_ROWS = np.zeros(0, dtype=np.int64)
_NO_ACTIONS = np.zeros(0)


# ---------------------------------------------------------------------------------------------------- batched core
class _Core:
    """N tracks stepped together: actions -> q -> tracking chain -> observation, reward, end flags, info; every
    step one call of :func:`radar_env.envs.env_kernels.k_env` (the reward's NEES term, when weighted, in numpy).

    Episodes are drawn straight into the tracker's looks (:class:`radar_env.sim.draws.LookDrawer`; a pool through
    :func:`radar_env.sim.draws.draw_episodes`) and started by the same kernel. With
    ``autoreset`` (the vector env) rows that end are restarted in the same ``step``: their next draw is prepared
    from their own generator as before (all rows without one prepared take it when a finishing row has none), so
    each row's episodes are those of a single env with its seed."""

    def __init__(self, n, cfg: EnvConfig, autoreset=False, max_episode_steps=None):
        self.n, self.cfg, self.autoreset = n, cfg, bool(autoreset)
        self.levels_m_s2 = np.asarray(cfg.q_levels_g, dtype=np.float64) * G0_M_S2
        self.q_min, self.q_max = self.levels_m_s2[0], self.levels_m_s2[-1]
        self.layout = ObservationLayout(cfg.features, self.q_min, self.q_max)
        self.frames = FrameStack(n, cfg.frame_stack, len(cfg.features))   # the kernels stack into frames.buf
        self.tracker = cfg.track_start.tracker(n)
        # the optional detector features (radar_env.envs.detectors): their IMMs step before the chain, and the kernel
        # reads their values from ``_ext`` (no columns without them)
        self.detectors = DetectorBank(n) if self.layout.uses_detectors else None
        self._ext = self.detectors.values if self.detectors is not None else np.zeros((n, 0))
        self.rngs = [None] * n
        # resolved once: a CSV trajectory is read here, not at every reset
        self.scenario = resolve_scenario(cfg.scenario)
        self.random_config = cfg.random_scenario_config
        # Refuse at build what would fail at a reset (a fixed scenario too short for warmup_scans, a random
        # configuration whose longest flight has too few looks) without drawing: LookDrawer checks it in closed
        # form. A pool is probed with one draw from a throwaway generator; no row's stream is touched.
        self.drawer = LookDrawer.of(self.scenario, cfg.radar, self.random_config, cfg.warmup_scans)
        if self.drawer is None:
            draw_setup_and_episode(self.scenario, cfg.radar, self.random_config, np.random.default_rng(0),
                                   cfg.warmup_scans)
        self.ep = self._env_parameters(max_episode_steps)
        _ek.announce_compilation()
        self.elapsed = np.zeros(n, dtype=np.int64)
        self.obs_width = cfg.frame_stack * len(cfg.features)
        self._all = np.arange(n, dtype=np.int64)
        self._ready = np.zeros(n, dtype=bool)          # rows whose next draw is prepared (autoreset)
        self._keys = np.zeros(n, dtype=np.uint64)      # ... as the drawer's key
        self._prepared = [None] * n                    # ... or, for a pool, as an episode
        self._rng_state = [None] * n                   # ... and the row's generator state before it

    action_shape = ()
    """The shape of one row's action."""

    num_threads = 1
    """Threads of the per-row step and autoreset-draw kernels (:mod:`radar_env.common.parallel`; the vector env's
    ``num_threads``): 1 runs the serial kernels, more their parallel builds, with the same outputs."""

    def observation_bounds(self):
        """``(low, high)`` of one row's observation."""
        return self.cfg.observation_bounds(self.layout)

    def _env_parameters(self, max_episode_steps):
        cfg, lay = self.cfg, self.layout
        plan = lay.env_plan
        head = np.zeros(_ek.W_EP_HEAD)
        head[_ek.EP_ACT_CONT] = cfg.action_type == "continuous"
        head[_ek.EP_NLEV] = self.levels_m_s2.size
        head[_ek.EP_L0], head[_ek.EP_L1] = math.log10(self.levels_m_s2[0]), math.log10(self.levels_m_s2[-1])
        head[_ek.EP_LQ0], head[_ek.EP_LQ1] = lay._lq0, lay._lq1
        head[_ek.EP_WARM_Q], head[_ek.EP_WARM_N] = cfg.warmup_q_g * G0_M_S2, cfg.warmup_scans
        head[_ek.EP_GATE], head[_ek.EP_CLIP] = cfg.track_loss_gate_sigma, cfg.reward_clip
        head[_ek.EP_RKIND], head[_ek.EP_SCALE_M] = _ek.REWARD_KINDS[cfg.reward_type], REWARD_SCALE_M
        head[_ek.EP_MAX_STEPS] = 0 if max_episode_steps is None else max_episode_steps
        head[_ek.EP_NFEAT], head[_ek.EP_NSTACK] = plan.shape[0], cfg.frame_stack
        head[_ek.EP_LEVELS] = _ek.W_EP_HEAD
        head[_ek.EP_PLAN] = _ek.W_EP_HEAD + self.levels_m_s2.size
        return np.concatenate([head, self.levels_m_s2, plan.reshape(-1)])

    # ---- actions
    def _actions(self, action):
        """The actions as (n,) float64 for the kernels, after the checks that need the Python object (dtype,
        size); the kernels check the values (:meth:`_refuse`)."""
        a = np.asarray(action)
        kind = a.dtype.kind
        # bool, complex, str and object actions are refused, not cast: True would silently be level 1
        if kind not in "iuf":
            raise ValueError(f"action must be {'integer' if self.cfg.action_type == 'discrete' else 'real'} "
                             f"number(s), got {action!r} (dtype {a.dtype})")
        if a.size != self.n:
            self._refuse(_ek.ST_ACTION_SHAPE, action)
        return a.astype(np.float64).reshape(self.n)

    def _refuse(self, status, action):
        n, n_levels = self.n, self.levels_m_s2.size
        if self.cfg.action_type == "continuous":
            raise ValueError(f"action must be {n} finite value(s) in [-1, 1] (Box(-1, 1)), got {action!r}")
        if status == _ek.ST_ACTION_SHAPE:
            raise ValueError(f"action must be {n} integer(s) in [0, {n_levels - 1}], got {action!r}")
        if status == _ek.ST_ACTION_RANGE:
            raise ValueError(f"action must be in [0, {n_levels - 1}] (Discrete({n_levels})), got {action!r}")
        raise ValueError("step() called on a row whose episode has ended; load a new episode first")

    def action_to_q(self, action):
        """Validated action -> (n,) q in m/s^2 (:func:`actions_to_q_m_s2`); ``ValueError`` naming the valid range."""
        a = self._actions(action)
        q = np.empty(self.n)
        status = _ek.k_action_q(a, self.ep, q)
        if status != _ek.ST_OK:
            self._refuse(status, action)
        return q

    # ---- output blocks and info
    def _blocks(self):
        """Fresh output arrays of one call (the info holds views of them, so they are new every step)."""
        n = self.n
        return (np.empty((n, self.obs_width), dtype=np.float32), np.empty((n, _ek.W_FO)),
                np.empty((_ek.W_FS, n)), np.empty((_ek.W_BO, n), dtype=bool))

    def _kernel_args(self):
        tr, b = self.tracker, self.tracker.bank
        return (self.ep, tr._st, tr._it, tr._looks, b._f, b._i, b._b, b._par, self.frames.buf, self.elapsed,
                self._ext)

    def info(self, fo, fs, bo, inconsistency=None):
        """The batched info dict: views of the output blocks."""
        n = fo.shape[0]
        terms = {"position_error": fs[_ek.FS_POS], "track_lost": fs[_ek.FS_LOST]}
        if inconsistency is not None:
            terms["inconsistency"] = inconsistency
        q = fs[_ek.FS_Q]
        return {
            "truth": fo[:, _ek.FO_TRUTH:_ek.FO_TRUTH + 4],
            "estimate": fo[:, _ek.FO_X:_ek.FO_X + 4],
            "covariance": fo[:, _ek.FO_P:_ek.FO_P + 16].reshape(n, 4, 4),
            "measurement": fo[:, _ek.FO_Z:_ek.FO_Z + 2],
            "measurement_covariance": fo[:, _ek.FO_R:_ek.FO_R + 4].reshape(n, 2, 2),
            "polar": fo[:, _ek.FO_POLAR:_ek.FO_POLAR + 3],
            "q_m_s2": q,
            "q": q,      # deprecated alias of q_m_s2 (m/s^2, not g), removed in the next version
            "dt": fs[_ek.FS_DT],
            "detected": bo[_ek.BO_DET],
            "maneuvering": bo[_ek.BO_MAN],
            "time_s": fs[_ek.FS_T],
            "reward_terms": terms,
            "track_lost": bo[_ek.BO_LOST],
        }

    def info_row(self, fo, fs, bo, inconsistency=None, i=0):
        """Row ``i``'s info with Python scalars for the scalar keys and reward terms (the single env's info)."""
        f = fo[i]
        s = fs[:, i].tolist()
        b = bo[:, i].tolist()
        terms = {"position_error": s[_ek.FS_POS], "track_lost": s[_ek.FS_LOST]}
        if inconsistency is not None:
            terms["inconsistency"] = inconsistency[i].item()
        q = s[_ek.FS_Q]
        return {"truth": f[_ek.FO_TRUTH:_ek.FO_TRUTH + 4], "estimate": f[_ek.FO_X:_ek.FO_X + 4],
                "covariance": f[_ek.FO_P:_ek.FO_P + 16].reshape(4, 4), "measurement": f[_ek.FO_Z:_ek.FO_Z + 2],
                "measurement_covariance": f[_ek.FO_R:_ek.FO_R + 4].reshape(2, 2),
                "polar": f[_ek.FO_POLAR:_ek.FO_POLAR + 3], "q_m_s2": q, "q": q, "dt": s[_ek.FS_DT],
                "detected": b[_ek.BO_DET], "maneuvering": b[_ek.BO_MAN], "time_s": s[_ek.FS_T],
                "reward_terms": terms, "track_lost": b[_ek.BO_LOST]}

    # ---- episodes
    def _draw(self, rows, scenario=None):
        # all rows in one batched draw; row r's episode comes from its own generator only (radar_env.sim.draws)
        sc = self.scenario if scenario is None else resolve_scenario(scenario)
        batch = draw_episodes(sc, self.cfg.radar, self.random_config, [self.rngs[r] for r in rows],
                              self.cfg.warmup_scans)
        return [batch.episode(i) for i in range(batch.batch_size)]

    def _start(self, rows, blocks, scenario=None, prepared=False):
        """Draw (or take the prepared draws of) ``rows``, start their tracks and write their first observation and
        info at their indices of ``blocks``."""
        drawer = self.drawer
        if scenario is not None:
            drawer = LookDrawer.of(resolve_scenario(scenario), self.cfg.radar, self.random_config,
                                   self.cfg.warmup_scans)
        if drawer is not None:
            keys = self._keys[rows] if prepared else _keys([self.rngs[r] for r in rows])
            drawer.draw(keys, rows, self.tracker, self.num_threads)
        else:
            eps = [self._prepared[r] for r in rows] if prepared else self._draw(rows, scenario)
            self.tracker._put(rows, eps)
        det = self.detectors
        if det is not None:
            det.values[rows] = det.initial    # the first observation's detector values (before any IMM look)
        status = _run_rows(self.num_threads, rows.size, _ek.k_env, rows, _NO_ACTIONS, *self._kernel_args(), *blocks)
        if status != _ek.ST_OK:   # drawn episodes always start (the draws check it); a bug otherwise
            raise RuntimeError(f"track start failed for row {rows[-1 - status]}")
        if det is not None:
            det.start(rows, self.tracker._st)  # the IMMs start where the chain's track starts

    def _prepare(self, rows):
        """Take the next draw of ``rows`` from their generators now (the draw of their next reset), keeping each
        generator's state before it (an explicit reset puts it back: :meth:`reset`)."""
        for r in rows:
            self._rng_state[r] = self.rngs[r].bit_generator.state
        if self.drawer is not None:
            self._keys[rows] = _keys([self.rngs[r] for r in rows])
        else:
            for r, e in zip(rows, self._draw(rows)):
                self._prepared[r] = e
        self._ready[rows] = True

    def reset(self, scenario=None, keep=None):
        """Every row draws a new episode from its generator and starts it. Returns the output blocks ``(obs, fo, fs,
        bo)`` and the reward's inconsistency term (None unless weighted). A row whose next draw an autoreset already
        took (:meth:`_prepare`) has its generator put back to the state before that draw where ``keep`` (bool (n,):
        the rows whose generator the caller did not replace), so it draws what a single env with its generator
        draws now, whatever the batch and whatever ``scenario``; elsewhere the prepared draw is dropped."""
        if keep is not None:
            for r in np.flatnonzero(self._ready & np.asarray(keep, dtype=bool)):
                self.rngs[r].bit_generator.state = self._rng_state[r]
        self._ready[:] = False
        blocks = self._blocks()
        self._start(self._all, blocks, scenario)
        return blocks, (self._inconsistency(blocks[1]) if self.cfg.reward_nees_weight > 0 else None)

    def step(self, action):
        """One step of every row. Returns ``(blocks, reward, terminated, truncated, inconsistency, final)``: the
        output blocks after any autoreset, and ``final = None`` or ``(rows, obs, fo, fs, bo, inconsistency)`` of
        the rows that ended (their last step's outputs; the blocks then hold their new episodes' first)."""
        a = self._actions(action)
        blocks = obs, fo, fs, bo = self._blocks()
        self._advance(a, action, blocks)
        inc = self._inconsistency(fo) if self.cfg.reward_nees_weight > 0 else None
        if not self.autoreset or not bo[_ek.BO_DONE].any():
            rew = fs[_ek.FS_REWARD] if inc is None else fs[_ek.FS_REWARD] + inc
            return blocks, rew, bo[_ek.BO_LOST], bo[_ek.BO_TRUNC], inc, None
        rows = np.flatnonzero(bo[_ek.BO_DONE])
        final = (rows, obs[rows], fo.copy(), fs.copy(), bo.copy(), inc)
        ffs, fbo = final[3], final[4]
        rew = ffs[_ek.FS_REWARD] if inc is None else ffs[_ek.FS_REWARD] + inc
        if np.any(~self._ready[rows]):
            self._prepare(np.flatnonzero(~self._ready))
        self._start(rows, blocks, prepared=True)
        self._ready[rows] = False
        if inc is not None:
            inc = inc.copy()
            inc[rows] = self._inconsistency(fo[rows])
        return blocks, rew, fbo[_ek.BO_LOST], fbo[_ek.BO_TRUNC], inc, final

    def _advance(self, a, action, blocks):
        """Every row's next look with the checked actions ``a`` into ``blocks`` (``ValueError`` for a refused one)."""
        if self.detectors is not None:   # the detectors' IMMs take the look the chain takes next (actions checked)
            status = self.detectors.step(self.tracker._looks, self.tracker._it, self._all, a, self.ep)
            if status != _ek.ST_OK:
                self._refuse(status, action)
        status = _run_rows(self.num_threads, self.n, _ek.k_env, _NO_ROWS, a, *self._kernel_args(), *blocks)
        if status != _ek.ST_OK:
            self._refuse(status, action)

    # ---- reward
    def _inconsistency(self, fo):
        """The reward's ``inconsistency`` term of ``reward_nees_weight`` (the other terms are in the step kernel:
        ``position_error`` = -min(e^2 or e, reward_clip) with e the error over the plot noise at the true range, or
        in units of REWARD_SCALE_M; ``track_lost`` = -reward_clip * (looks remaining) when e > the gate)."""
        n = fo.shape[0]
        x = fo[:, _ek.FO_X:_ek.FO_X + 4]
        P = fo[:, _ek.FO_P:_ek.FO_P + 16].reshape(n, 4, 4)
        truth = fo[:, _ek.FO_TRUTH:_ek.FO_TRUTH + 4]
        w, clip = self.cfg.reward_nees_weight, self.cfg.reward_clip
        # overconfidence: the position NEES beyond its 99 % bound, in units of the bound
        d0, d1 = x[:, 0] - truth[:, 0], x[:, 1] - truth[:, 1]
        a, b, c = P[:, 0, 0], P[:, 0, 1], P[:, 1, 1]
        det = a * c - b * b
        # the 2 x 2 closed form, never a LinAlgError: the update keeps P positive definite on every radar the env
        # accepts (radar_env.filters.kernels._pd_floor); a block that is not (det <= 0) would count as maximally
        # inconsistent (the clipped penalty), never as a number from a singular solve
        ok = (det > 0.0) & (a > 0.0)
        nees = np.divide(c * d0 * d0 - 2.0 * b * d0 * d1 + a * d1 * d1, det, out=np.full(det.shape, np.inf), where=ok)
        return -w * np.minimum(np.maximum(nees / NEES_99_2DOF - 1.0, 0.0), clip)


_SCALAR_INFO = frozenset(("q_m_s2", "q", "dt", "detected", "maneuvering", "track_lost", "time_s"))


def _row(info, i):
    """Row ``i`` of a batched info dict, with Python scalars for the scalar keys and reward terms."""
    out = {k: (v[i].item() if k in _SCALAR_INFO else v[i]) for k, v in info.items() if k != "reward_terms"}
    out["reward_terms"] = {k: v[i].item() for k, v in info["reward_terms"].items()}
    return out
