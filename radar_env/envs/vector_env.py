"""RadarTrack-v0's native batched vector env (:class:`RadarTrackVectorEnv`): N rows of the core, same-step
autoreset."""

from __future__ import annotations

import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import VectorEnv
from gymnasium.vector.utils import batch_space
from gymnasium.vector.vector_env import AutoresetMode

from .config import EnvConfig
from .imm_core import make_core
from .env_kernels import BO_DONE
from .single_env import row_spaces
from ..common.parallel import check_num_threads
from ..common.validate import check_known_keys

__all__ = ["RadarTrackVectorEnv"]


# ---------------------------------------------------------------------------------------------------- vector env
class RadarTrackVectorEnv(VectorEnv):
    """Native batched vector version of RadarTrack-v0 (``gym.make_vec(..., vectorization_mode=
    "vector_entry_point")``): N tracks in one set of numpy arrays, same-step autoreset.

    On the step where row i ends, the returned observation is the first observation of its next episode, and
    ``info["final_obs"][i]`` / ``info["final_info"]`` hold the last observation and info of the finished one
    (``info["_final_obs"]`` is the mask of rows that ended). Seeding: ``reset(seed=s)`` seeds row i with
    ``s + i``, as Gymnasium's ``SyncVectorEnv`` does, so row i equals ``RadarTrackEnv`` reset with ``s + i``.
    Finished rows start their next tracks inside the same step (drawn straight into the tracker and started by one
    kernel call; each row's next draw is prepared from its own generator, all rows without one at once when a
    finishing row has none). An explicit ``reset()`` resets each row as Gymnasium's ``SyncVectorEnv`` does: a row
    given a seed (``seed=s``: every row, ``s + i``; a list: its entry) starts from it, a row given None continues
    its generator from where the single env's would be (a draw prepared from it is put back), so row i's episodes
    stay the single env's whatever the batch.
    ``num_threads`` (default 1): threads of the per-row step kernel and of the next episodes' draws (numba
    ``prange`` over blocks of rows; the parallel builds compile on the first use of ``num_threads > 1``, about as
    long as the serial ones). An integer in ``[1, numba.config.NUMBA_NUM_THREADS]``. Every output is
    bit-identical to ``num_threads=1`` (the rows are independent and every random draw is keyed per row;
    tests/test_vector_threads.py); the IMM tracker's own kernels and the detector features stay on one thread.
    All other arguments as :class:`RadarTrackEnv`.

    Actions: shape ``(num_envs,)`` (discrete) or ``(num_envs, 1)`` / ``(num_envs,)`` (continuous), with
    ``tracker="imm_cv_ct"`` ``(num_envs, n_par)``; other shapes raise ``ValueError``.

    Gymnasium's vector wrappers: the observation wrappers of ``gymnasium.wrappers.vector``
    (``NormalizeObservation``, ``FlattenObservation``, ...) accept only next-step autoreset and refuse this env
    (same-step); ``NormalizeReward`` and ``RecordEpisodeStatistics`` work. ``gym.make_vec(..., "sync")`` or
    ``"async"`` default to next-step autoreset, whose rows diverge from this env after their first episode end;
    with ``vector_kwargs={"autoreset_mode": AutoresetMode.SAME_STEP}`` they equal this env row for row
    (README "Use the environment"; tests/test_env_inputs.py).
    """

    metadata = {"render_modes": [], "autoreset_mode": AutoresetMode.SAME_STEP}

    def __init__(self, num_envs=1, num_threads=1, **kwargs):
        if not isinstance(num_envs, (int, np.integer)) or isinstance(num_envs, bool) or num_envs < 1:
            raise ValueError(f"num_envs must be an integer >= 1, got {num_envs!r}")
        self.num_threads = check_num_threads(num_threads)
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
        try:
            self._core = make_core(self.num_envs, self.config, autoreset=True,
                                   max_episode_steps=self.max_episode_steps)
        except MemoryError:
            raise ValueError(f"num_envs={self.num_envs:,}: the rows' arrays do not fit in this machine's memory; "
                             "give fewer rows") from None
        self._core.num_threads = self.num_threads
        self.single_action_space, self.single_observation_space = row_spaces(self._core)
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._started = False

    @property
    def layout(self):
        return self._core.layout

    def reset(self, *, seed=None, options=None):
        if options is not None and not isinstance(options, dict):
            raise ValueError(f"reset: options must be a dict (e.g. {{'scenario': 'bizup2002'}}) or None, got "
                             f"{options!r}")
        options = dict(options or {})
        scenario = options.pop("scenario", None)
        check_known_keys("reset", options, ["scenario"], noun="option")
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
            seeds = [None if s is None else int(s) for s in seeds]      # numpy integers as Python ones (gymnasium)
        if any(s is not None and s < 0 for s in seeds):
            raise ValueError(f"seed must be >= 0 (each row's), got {seed!r}"[:300])
        core = self._core
        # as Gymnasium's sync env resets each row: a seeded row gets a new generator, an unseeded one (after the
        # first reset) continues its own, from before the draw an autoreset may have prepared
        keep = np.array([s is None and self._started for s in seeds])
        core.rngs = [core.rngs[i] if keep[i] else seeding.np_random(s)[0] for i, s in enumerate(seeds)]
        (obs, fo, fs, bo), inc = core.reset(scenario, keep)
        self._started = True
        return obs, _with_masks(core.info(fo, fs, bo, inc))

    def step(self, actions):
        if not self._started:
            raise RuntimeError("RadarTrackVectorEnv: call reset() before step()")
        core = self._core
        a = np.asarray(actions)
        n = self.num_envs
        if core.action_shape:
            shapes = [(n,) + core.action_shape]
        else:
            shapes = [(n,)] if self.config.action_type == "discrete" else [(n, 1), (n,)]
        if a.shape not in shapes:
            raise ValueError(f"actions must have shape {' or '.join(map(str, shapes))} ({self.action_space}), got "
                             f"shape {a.shape}: {actions!r}")
        (obs, fo, fs, bo), rew, term, trunc, inc, final = core.step(a.reshape((n,) + core.action_shape))
        info = core.info(fo, fs, bo, inc)
        if final is not None:   # rows that ended were restarted in this step (same-step autoreset)
            rows, fobs, ffo, ffs, fbo, finc = final
            done = fbo[BO_DONE]
            final_obs = np.full(n, None, dtype=object)
            for j, r in enumerate(rows):
                final_obs[r] = fobs[j]
            info["final_obs"] = final_obs
            info["_final_obs"] = done.copy()
            info["final_info"] = _with_masks(core.info(ffo, ffs, fbo, finc), done)
            info["_final_info"] = done.copy()
        return obs, rew, term, trunc, _with_masks(info)


def _with_masks(info, mask=None):
    """``info`` with Gymnasium's ``_key`` mask beside every entry (all True, or a copy of ``mask``)."""
    out = {}
    template = None
    for k, v in info.items():
        if k.startswith("_") or k in ("final_obs", "final_info"):
            out[k] = v
            continue
        if isinstance(v, dict):
            out[k] = _with_masks(v, mask)
        else:
            out[k] = v
        if template is None:
            n = len(v[next(iter(v))]) if isinstance(v, dict) else len(v)
            template = np.ones(n, dtype=bool) if mask is None else mask
        out["_" + k] = template.copy()   # one array per key: a caller may edit one mask
    return out
