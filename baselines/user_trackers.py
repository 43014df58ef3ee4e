"""Your own tracker in the comparison: the protocol, the common track start, and loading a tracker module.

A user tracker is a function of one episode's looks (plots only, no truth)::

    def my_tracker(looks: Looks, start: TrackStart) -> tuple[np.ndarray, np.ndarray]:
        ...
        return x, P          # (K, 4) estimates [x, y, vx, vy] (m, m/s) and (K, 4, 4) covariances, one per look

registered by name with :func:`baselines.registry.register_tracker` (``register_tracker("mine", my_tracker)``),
after which ``run_tracker("mine", episodes)`` and ``radar-track evaluate --tracker-module my_module --trackers
mine,imm2`` run it on the same plots as every other tracker. ``--tracker-module`` takes a dotted module name
(looked up in the current directory, then among installed modules) or a ``.py`` file; importing it must call
``register_tracker``. Importing a module runs its code: use only modules you trust.

* ``looks`` (:class:`Looks`): per look ``t_s``, the site that looked (``site_index``, ``site_xy_m``), ``detected``,
  the converted plot ``z_m`` (NaN where missed) and its covariance ``R_m2``, the polar measurements and the sites'
  noise sigmas.
* ``start`` (:class:`TrackStart`): the common track start every built-in tracker uses (two-hit initialisation,
  then ``warmup_scans`` looks of a CV KF at 0.03 g): ``index`` is the first look the metrics score, ``x``/``P``
  the estimate after look ``index - 1`` (time ``t_s``). Use it or start your own way: the metrics score looks
  ``>= start.index`` whatever the tracker did before, so every tracker is scored on the same looks.
* Return NaN where you have no estimate; a NaN or infinite estimate at a scored look makes that run count as
  failed (reported, never scored as zero). Wrong shapes raise ``ValueError``.

A batch tracker ``fn(episodes, cfg) -> TrackRun`` (the built-ins' form) can be registered with ``batch=True``.
"""

from __future__ import annotations

import importlib
import importlib.machinery
import importlib.util
import sys
from pathlib import Path
from typing import NamedTuple, Protocol

import numpy as np


from .trackers import TrackRun, _start

__all__ = ["Looks", "TrackStart", "UserTracker", "looks_of", "common_track_start", "per_episode_runner",
           "batch_runner", "import_tracker_module"]


class Looks(NamedTuple):
    """The looks of one episode as a tracker may see them (K looks, time order; no truth)."""

    t_s: np.ndarray                 # (K,) look times
    site_index: np.ndarray          # (K,) int, which radar site looked
    site_xy_m: np.ndarray           # (K, 2) that site's position
    detected: np.ndarray            # (K,) bool, the look produced a plot
    z_m: np.ndarray                 # (K, 2) converted plot position (NaN where missed)
    R_m2: np.ndarray                # (K, 2, 2) its covariance (NaN where missed)
    range_m: np.ndarray             # (K,) measured range (NaN where missed)
    bearing_rad: np.ndarray         # (K,) measured bearing (NaN where missed)
    radial_velocity_m_s: np.ndarray  # (K,) measured radial velocity (NaN where missed)
    range_noise_std_m: np.ndarray   # (K,) sigmas of the site that looked
    bearing_noise_std_rad: np.ndarray
    radial_velocity_noise_std_m_s: np.ndarray


class TrackStart(NamedTuple):
    """The common track start of one episode (see the module docstring)."""

    index: int          # first look the metrics score
    x: np.ndarray       # (4,) estimate after look index - 1
    P: np.ndarray       # (4, 4) its covariance
    t_s: float          # time of look index - 1


class UserTracker(Protocol):
    """``tracker(looks, start) -> (x (K, 4), P (K, 4, 4))``: one estimate and covariance per look."""

    def __call__(self, looks: Looks, start: TrackStart) -> tuple[np.ndarray, np.ndarray]: ...


def looks_of(episode) -> Looks:
    """The :class:`Looks` of an :class:`radar_env.sim.episode.Episode` (copies: a tracker cannot alter the episode)."""
    return Looks(**{f: np.array(getattr(episode, f)) for f in Looks._fields})


def common_track_start(episodes, cfg=None):
    """The common track start of each episode (list of :class:`TrackStart`), computed by the tracking chain
    (:meth:`radar_env.filters.tracking.Tracker.load`) exactly as for the built-in trackers."""
    episodes = list(episodes)
    tr = _start(cfg).tracker(len(episodes))
    out = tr.load(np.arange(len(episodes)), episodes)
    return [TrackStart(int(k) + 1, out.x[b].copy(), out.P[b].copy(), float(out.t_s[b]))
            for b, k in enumerate(out.look_index)]


def per_episode_runner(name, fn):
    """The registry runner ``run(episodes, cfg) -> TrackRun`` of a per-episode :class:`UserTracker` ``fn``."""
    def run(episodes, cfg):
        episodes = list(episodes)
        starts = common_track_start(episodes, cfg)
        B, K = len(episodes), max(e.n_looks for e in episodes)
        x_all, P_all = np.full((B, K, 4), np.nan), np.full((B, K, 4, 4), np.nan)
        for b, (e, s) in enumerate(zip(episodes, starts)):
            res = fn(looks_of(e), s)
            if not (isinstance(res, tuple) and len(res) == 2):
                raise ValueError(f"tracker {name!r} must return (x, P), got {type(res).__name__}")
            x, P = (np.asarray(a, dtype=np.float64) for a in res)
            k = e.n_looks
            if x.shape != (k, 4) or P.shape != (k, 4, 4):
                raise ValueError(f"tracker {name!r} must return x of shape ({k}, 4) and P of shape ({k}, 4, 4) for "
                                 f"episode {b} ({k} looks), got {x.shape} and {P.shape}")
            x_all[b, :k], P_all[b, :k] = x, P
        return TrackRun(name, x_all, P_all, np.array([s.index for s in starts], dtype=np.int64),
                        np.full((B, K), np.nan))
    return run


def batch_runner(name, fn):
    """The registry runner of a batch tracker ``fn(episodes, cfg) -> TrackRun``: shapes checked, and the scored
    looks set to the common start's (whatever ``start_index`` the tracker returned)."""
    def run(episodes, cfg):
        episodes = list(episodes)
        res = fn(episodes, cfg)
        if not isinstance(res, TrackRun):
            raise ValueError(f"tracker {name!r} (batch=True) must return a baselines.trackers.TrackRun, got "
                             f"{type(res).__name__}")
        B, K = len(episodes), max(e.n_looks for e in episodes)
        if res.x.shape != (B, K, 4) or res.P.shape != (B, K, 4, 4):
            raise ValueError(f"tracker {name!r} must return x of shape ({B}, {K}, 4) and P of shape ({B}, {K}, 4, 4),"
                             f" got {res.x.shape} and {res.P.shape}")
        starts = common_track_start(episodes, cfg)
        res.start_index = np.array([s.index for s in starts], dtype=np.int64)
        res.name = name
        if res.q_m_s2 is None or np.shape(res.q_m_s2) != (B, K):
            res.q_m_s2 = np.full((B, K), np.nan)
        return res
    return run


def import_tracker_module(spec):
    """Import a user tracker module: a ``.py`` file path, or a dotted module name (looked up in the current
    directory first, then among the installed modules). Importing it is expected to call
    :func:`baselines.registry.register_tracker`. Returns the module; ``ValueError`` (one line, naming the module) if
    it cannot be found or raises on import.

    Only the named module is imported from the current directory (its top-level package, for a dotted name): the
    directory is not put on ``sys.path``, so another file there (a stray ``tqdm.py``) cannot shadow a library
    later; ``sys.path`` is restored to what it was, whatever the module did to it. (A module that imports its
    siblings in the directory should be a package, or a file given by path that adds its own folder.)"""
    spec = str(spec)
    if spec.endswith(".py"):
        path = Path(spec)
        if not path.is_file():
            raise ValueError(f"tracker module file {spec!r} does not exist")
        name = f"_radar_track_user_{path.stem}"
        if name in sys.modules:
            return sys.modules[name]
    saved_path = list(sys.path)
    try:
        if spec.endswith(".py"):
            return _exec_module(name, importlib.util.spec_from_file_location(name, path))
        top = spec.split(".")[0]
        if top not in sys.modules:
            found = importlib.machinery.PathFinder.find_spec(top, [str(Path.cwd())])
            if found is not None:
                _exec_module(top, found)
        return importlib.import_module(spec)
    except ModuleNotFoundError as e:
        raise ValueError(f"tracker module {spec!r} cannot be imported: {e}") from None
    except Exception as e:  # noqa: BLE001 - the user's module raised on import: one line naming it
        msg = str(e).splitlines()[0] if str(e) else ""
        raise ValueError(f"tracker module {spec!r} raised on import: {type(e).__name__}: {msg}") from None
    finally:
        sys.path[:] = saved_path


def _exec_module(name, found):
    """Create, register and execute the module of spec ``found`` as ``sys.modules[name]`` (removed if it raises)."""
    mod = importlib.util.module_from_spec(found)
    sys.modules[name] = mod
    try:
        found.loader.exec_module(mod)
    except BaseException:
        del sys.modules[name]
        raise
    return mod
