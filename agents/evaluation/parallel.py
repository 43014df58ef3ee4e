"""Evaluations split over Ray workers (``radar-track evaluate --workers N [--address ADDR]``).

Each suite's runs are cut into ``N`` contiguous chunks; one Ray task per (suite, tracker, chunk) runs the tracker
on its chunk and returns the :class:`baselines.trackers.TrackRun`; the chunks are concatenated along the run axis
(padded to the suite's longest episode exactly as the serial run pads) before any scoring, so the scoring sees
the serial arrays bit for bit (common random numbers kept: every tracker sees the same episodes).

Tasks of the papers' named and random suites (``radar_env.sim.catalog.SCENARIO_NAMES``, where run ``i`` is a pure
function of seed ``S + i``) draw their own episodes from the suite name and seed range, so nothing but the names
travels; every task returns a digest of the episodes it drew, checked against the driver's, so a mismatch is an
error and never a silently different number. Other suites (encounter pairs, ADS-B flights, trajectory files) are
sent as episodes through the object store.

Ray is an optional extra (``pip install -e '.[scale]'``); it is imported only here and in :mod:`agents.training.sweep`.
Without ``address`` (and without ``RAY_ADDRESS``) an embedded local Ray with ``N`` CPUs is started and stopped;
with one, the tasks run on that cluster (every node needs this package installed at the same version).
"""

from __future__ import annotations

import hashlib
import os
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

from baselines.trackers import TrackRun
from radar_env.sim.catalog import SCENARIO_NAMES

from agents.evaluation.runner import failed_track_run, run_one
from agents.evaluation.suites import draw_suite
from agents.policies.loading import load_policy

__all__ = ["require_ray", "ray_session", "check_ray_address", "ray_error_line", "chunk_bounds", "concat_runs",
           "merge_chunk_runs", "episodes_digest", "run_suites_ray", "SCALE_EXTRA_HINT", "ADDRESS_TIMEOUT_S"]

SCALE_EXTRA_HINT = "pip install -e '.[scale]'"
ADDRESS_TIMEOUT_S = 25.0
"""How long :func:`check_ray_address` waits for a cluster to answer (ray.init itself retries for minutes)."""


def check_ray_address(address, timeout_s=ADDRESS_TIMEOUT_S):
    """``ValueError`` (one line, naming ``--address``) unless a Ray cluster answers at ``address`` within
    ``timeout_s``: first a TCP connection to ``host:port`` (refused or filtered ports fail at once), then a
    ``ray.init`` in a child process bounded by the timeout (a port that answers but is no Ray cluster). ``ray.init``
    in this process would retry "Failed to connect to GCS" for minutes. ``"auto"`` and ``"local"`` are not
    checked (Ray resolves them itself and fails quickly)."""
    if address in (None, "", "auto", "local"):
        return
    hostport = address[len("ray://"):] if address.startswith("ray://") else address
    host, sep, port = hostport.rpartition(":")
    if not sep or not host or not port.isdigit():
        raise ValueError(f"--address: expected HOST:PORT (e.g. 127.0.0.1:6379) or ray://HOST:PORT, got {address!r}")
    try:
        with socket.create_connection((host.strip("[]"), int(port)), timeout=min(5.0, timeout_s)):
            pass
    except OSError as e:
        raise ValueError(f"--address: no Ray cluster at {address!r}: cannot connect to {host}:{port} "
                         f"({e.strerror or type(e).__name__})") from None
    probe = ("import sys, ray; ray.init(address=sys.argv[1], include_dashboard=False, log_to_driver=False, "
             "logging_level='ERROR'); ray.shutdown()")
    try:
        r = subprocess.run([sys.executable, "-c", probe, address], capture_output=True, text=True, timeout=timeout_s)
    except subprocess.TimeoutExpired:
        raise ValueError(f"--address: {address!r} accepts connections but no Ray cluster answered within "
                         f"{timeout_s:.0f} s (is it a Ray head node's GCS port, default 6379?)") from None
    if r.returncode != 0:
        last = next((ln for ln in reversed(r.stderr.strip().splitlines()) if ln.strip()), f"exit {r.returncode}")
        raise ValueError(f"--address: cannot connect to a Ray cluster at {address!r} ({last.strip()[:300]})")


def _log_dir():
    """The Ray session's log folder, if a session is connected."""
    try:
        import ray
        node = ray._private.worker.global_worker.node      # no public API for the session's folder
        return node.get_logs_dir_path() if node is not None else None
    except Exception:  # noqa: BLE001 - best effort: the message names the default location instead
        return None


def ray_error_line(e, what="Ray"):
    """One line for a Ray exception (a task's error, a worker that died, a lost node): its type, the first line
    of its message (a task's own exception: its last line) and where Ray's logs are."""
    text = str(e).strip()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip()]
    cause = getattr(e, "cause", None)
    if cause is not None:
        first = f"{type(cause).__name__}: {str(cause).strip().splitlines()[0] if str(cause).strip() else ''}"
    else:
        first = lines[-1] if type(e).__name__ == "RayTaskError" and lines else (lines[0] if lines else "")
    logs = _log_dir() or "/tmp/ray/session_latest/logs"
    return f"{what} failed: {type(e).__name__}: {first[:300]} (Ray's logs: {logs})"


def require_ray(what="this command"):
    """Import and return ``ray``; a ``ValueError`` naming the extra to install if it is missing."""
    try:
        import ray
    except ImportError:
        raise ValueError(f"{what} needs Ray, which is not installed: {SCALE_EXTRA_HINT} "
                         "(the 'scale' extra: ray[tune], optuna)") from None
    return ray


class ray_session:
    """Context manager: the running Ray session if there is one, else ``ray.init`` on ``address`` (or
    ``RAY_ADDRESS``), else an embedded local Ray with ``num_cpus`` CPUs; shuts down only what it started."""

    def __init__(self, address=None, num_cpus=None, what="this command"):
        self.ray = require_ray(what)
        self.address, self.num_cpus, self.started = address, num_cpus, False

    def __enter__(self):
        ray = self.ray
        if not ray.is_initialized():
            address = self.address or os.environ.get("RAY_ADDRESS") or None
            kw = {"include_dashboard": False, "log_to_driver": False}
            if address is None:
                # "local": always a new embedded instance, never a cluster Ray happens to find on this machine
                address, kw["num_cpus"] = "local", self.num_cpus
            if address != "local":
                check_ray_address(address)
            try:
                ray.init(address=address, **kw)
            except ConnectionError as e:
                hint = ("" if os.environ.get("RAY_AUTH_MODE") else "; a cluster started by 'ray start' uses token "
                        "authentication: export RAY_AUTH_MODE=token (the token is read from ~/.ray/auth_token or "
                        "RAY_AUTH_TOKEN)")
                raise ValueError(f"--address: cannot connect to a Ray cluster at {address!r} ({e}){hint}") from None
            self.started = True
        return ray

    def __exit__(self, *exc):
        if self.started:
            self.ray.shutdown()
        return False


def chunk_bounds(n, chunks):
    """``[(start, stop), ...]``: ``n`` items cut into at most ``chunks`` contiguous, near-equal, non-empty pieces."""
    edges = np.linspace(0, int(n), min(int(chunks), int(n)) + 1).round().astype(int)
    return [(int(a), int(b)) for a, b in zip(edges[:-1], edges[1:]) if b > a]


def episodes_digest(episodes):
    """SHA-1 over every array of the episodes (the check that a task drew the driver's episodes)."""
    h = hashlib.sha1()
    for ep in episodes:
        for v in vars(ep).values():
            if isinstance(v, np.ndarray):
                h.update(str((v.dtype, v.shape)).encode())
                h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()


def _pad(a, K, fill):
    if a.shape[1] == K:
        return a
    out = np.full((a.shape[0], K, *a.shape[2:]), fill, dtype=a.dtype)
    out[:, :a.shape[1]] = a
    return out


def concat_runs(parts, K):
    """One :class:`TrackRun` from per-chunk runs (in run order, none failed: see :func:`merge_chunk_runs`), every
    (B, k, ...) array padded to ``K`` looks with the serial run's fill (NaN; False for declarations)."""
    first = parts[0]
    declared = None
    if first.declared is not None:
        declared = np.concatenate([_pad(p.declared, K, False) for p in parts])
    extra = {k: np.concatenate([_pad(p.extra[k], K, np.nan) for p in parts]) for k in first.extra}
    return TrackRun(first.name, np.concatenate([_pad(p.x, K, np.nan) for p in parts]),
                    np.concatenate([_pad(p.P, K, np.nan) for p in parts]),
                    np.concatenate([p.start_index for p in parts]),
                    np.concatenate([_pad(p.q_m_s2, K, np.nan) for p in parts]), declared, extra,
                    next((p.error for p in parts if p.error is not None), None))


def merge_chunk_runs(tracker, parts, episodes):
    """The suite's :class:`TrackRun` from its per-chunk runs (in run order) on ``episodes`` (the whole suite): the
    concatenation, or, if any chunk failed, what the serial run gives a tracker that raises on the suite
    (:func:`agents.evaluation.runner.failed_track_run`: NaN on every run, the first failed chunk's error, the warning on
    the driver's stderr; a worker's stderr is not forwarded)."""
    err = next((p.error for p in parts if p.error is not None), None)
    if err is not None:
        return failed_track_run(tracker, episodes, err)
    return concat_runs(parts, max(e.n_looks for e in episodes))


# ------------------------------------------------------------------------------------------------ worker side
_POLICY_CACHE = {}


def _policy_in_worker(blob, allow_pickle=False):
    """Load the policy shipped as file contents (``{file name: bytes}``, the policy file first; cached per worker
    process: Ray reuses workers). ``allow_pickle``: the driver's opt-in (``--allow-pickle``), passed on."""
    h = hashlib.sha1(b"pickle" if allow_pickle else b"")
    for name, data in blob.items():
        h.update(name.encode() + b"\0" + data)
    key = h.hexdigest()
    if key not in _POLICY_CACHE:
        with tempfile.TemporaryDirectory(prefix="radar_track_policy_") as tmp:   # the model is in memory after
            d = Path(tmp)
            for name, data in blob.items():
                (d / name).write_bytes(data)
            _POLICY_CACHE[key] = load_policy(d / next(iter(blob)), allow_pickle=allow_pickle)
    return _POLICY_CACHE[key]


def _run_chunk(tracker, episodes, policy_blobs, allow_pickle=False):
    blob = (policy_blobs or {}).get(tracker)
    choose_q, cfg = _policy_in_worker(blob, allow_pickle) if blob is not None else (None, None)
    return run_one(tracker, episodes, choose_q, cfg)


def _task_draw(suite, seed, start, stop, tracker, policy_blob, allow_pickle=False):
    eps = draw_suite(suite, stop - start, seed=seed + start)
    return episodes_digest(eps), _run_chunk(tracker, eps, policy_blob, allow_pickle)


def _task_given(episodes, tracker, policy_blob, allow_pickle=False):
    return None, _run_chunk(tracker, episodes, policy_blob, allow_pickle)


# ------------------------------------------------------------------------------------------------ driver side
def _policy_blob(policy_path):
    """``{file name: bytes}`` of a policy file and the files it is loaded with (``env_config.json``; a recurrent
    policy's ``policy.json``; an SB3 zip's numpy export, so that the workers run it without torch, SB3 or
    unpickling, as the serial evaluation does), the policy file first."""
    if policy_path is None:
        return None
    from agents.policies.numpy_policy import export_path
    p = Path(policy_path)
    blob = {p.name: p.read_bytes()}
    extra = (p.with_suffix(".json"), p.with_name("env_config.json")) + ((export_path(p),) if p.suffix == ".zip" else ())
    for f in extra:
        if f.is_file() and f != p:
            blob[f.name] = f.read_bytes()
    return blob


def _first_run_redraws(suite, episodes, seed):
    """Whether the suite's first run is what ``draw_suite(suite, 1, seed)`` draws (a trajectory file named like a
    catalog scenario is not: its episodes are sent instead)."""
    return episodes_digest(draw_suite(suite, 1, seed=seed)) == episodes_digest(episodes[:1])


def run_suites_ray(suites, trackers, policy_path=None, workers=2, address=None, seed=None, tick=None,
                   allow_pickle=False):
    """Run every tracker on every suite on Ray; returns ``{suite: {tracker: TrackRun}}`` equal to the serial runs.

    Args:
        suites: list of ``(name, episodes)`` as drawn by the driver (:func:`agents.evaluation.suites.draw_suite`).
        trackers: tracker names; ``policy`` needs ``policy_path``.
        policy_path: the ``policy`` tracker's file, or ``{policy tracker: file}`` (``policy``, ``policy_bp``).
        workers: chunks per suite (and local CPUs when Ray is started here).
        address: Ray cluster address (default ``RAY_ADDRESS``, else an embedded local Ray).
        seed: base seed the named suites were drawn with; None: send every suite's episodes.
        tick: progress callback ``tick(message)``, called once per (suite, tracker) when all its chunks are done.
        allow_pickle: the driver's opt-in to unpickle a policy zip without a current numpy export (passed to the
            workers; without it they refuse such a file, as the driver does).
    """
    workers = int(workers)
    if workers < 1:
        raise ValueError(f"workers must be >= 1, got {workers}")
    tick = tick or (lambda msg: None)
    paths = policy_path if isinstance(policy_path, dict) else {"policy": policy_path}
    blob = {t: _policy_blob(p) for t, p in paths.items() if t in trackers}
    with ray_session(address, workers, "--workers/--address") as ray:
        draw = ray.remote(num_cpus=1)(_task_draw)
        given = ray.remote(num_cpus=1)(_task_given)
        blob_ref = ray.put(blob)
        pending = {}              # ref -> (suite, tracker, chunk index)
        expect = {}               # (suite, chunk index) -> digest of the driver's episodes
        for suite, episodes in suites:
            bounds = chunk_bounds(len(episodes), workers)
            redraw = seed is not None and suite in SCENARIO_NAMES and _first_run_redraws(suite, episodes, seed)
            eps_refs = [None if redraw else ray.put(list(episodes[a:b])) for a, b in bounds]
            for c, (a, b) in enumerate(bounds):
                if redraw:
                    expect[suite, c] = episodes_digest(episodes[a:b])
                for t in trackers:
                    ref = (draw.remote(suite, int(seed), a, b, t, blob_ref, allow_pickle) if redraw
                           else given.remote(eps_refs[c], t, blob_ref, allow_pickle))
                    pending[ref] = (suite, t, c)
        n_chunks = {s: len(chunk_bounds(len(e), workers)) for s, e in suites}
        parts = {}
        try:
            while pending:
                done, _ = ray.wait(list(pending), num_returns=1)
                suite, t, c = pending.pop(done[0])
                digest, run = ray.get(done[0])
                if digest is not None and digest != expect[suite, c]:
                    raise RuntimeError(f"suite {suite!r}: a Ray task drew episodes that differ from the driver's "
                                       "(different package version on a worker node?)")
                parts.setdefault((suite, t), {})[c] = run
                if len(parts[suite, t]) == n_chunks[suite]:
                    tick(f"{suite}: {t} ({n_chunks[suite]} chunks)")
        except BaseException as e:
            for ref in pending:
                ray.cancel(ref, force=True)
            if isinstance(e, ray.exceptions.RayError):    # a worker crash, a lost node, a task's own error
                raise ValueError(ray_error_line(e, "a Ray task of the evaluation")) from None
            raise
    return {s: {t: merge_chunk_runs(t, [parts[s, t][c] for c in range(n_chunks[s])], eps) for t in trackers}
            for s, eps in suites}
