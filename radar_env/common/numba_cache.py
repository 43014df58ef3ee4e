"""numba's on-disk kernel cache kept consistent with the sources it was compiled from.

numba (``@njit(cache=True)``) keys a function's cache entry on its own source file's time stamp and size only. A
kernel that calls a function of another module (``envs.env_kernels`` and ``filters.imm_cv_ct`` call
``filters.kernels``, which calls ``sim.motion``), or reads a module constant (``sim.looks``), therefore keeps
running the *old* compiled callee after that other module changed, e.g. after an update of the package: silently
wrong numbers, not an error. (Seen: an update of the covariance update in
``kernels.py`` left the env's cached step kernel on the previous update.)

:func:`drop_stale_kernels` stamps a package's cache folder with a digest of the sources its kernels depend on and,
when the digest differs, deletes that package's cached kernels first, so that they recompile once (the cold-cache
notice of :func:`radar_env.envs.env_kernels.announce_compilation` then says so). numba keeps one cache folder per
source folder, so the first kernel module of each sub-package (``sim.motion``, ``filters.kernels``,
``envs.env_kernels``) calls it at import with the sources of the whole ``radar_env`` package, before any kernel of
that folder can load from the cache.
"""

from __future__ import annotations

import hashlib
from pathlib import Path

__all__ = ["drop_stale_kernels", "package_sources", "sources_digest", "STAMP_NAME"]

STAMP_NAME = "radar-track-sources.sha256"
"""The stamp file in a cache folder: the digest of the sources the cached kernels were compiled from."""

_checked = set()


def sources_digest(files):
    """SHA-256 over the names and bytes of ``files`` (sorted by path)."""
    h = hashlib.sha256()
    for f in sorted(Path(p) for p in files):
        h.update(f.name.encode())
        h.update(f.read_bytes())
    return h.hexdigest()


def drop_stale_kernels(dispatcher, sources):
    """Delete the cached kernels of the modules among ``sources`` that live in ``dispatcher``'s cache folder when
    the digest of ``sources`` differs from the folder's stamp; then stamp it. ``dispatcher``: any cached
    ``@njit`` function of the package (it only tells where numba keeps the package's cache, whichever locator
    numba chose: ``__pycache__``, ``NUMBA_CACHE_DIR`` or the user-wide folder). Once per folder and process; a
    read-only cache folder or a change of numba's internals leaves everything as it is."""
    try:
        cache_dir = Path(dispatcher._cache._cache_path)
    except AttributeError:   # numba internals changed, or caching is off
        return
    if cache_dir in _checked:
        return
    _checked.add(cache_dir)
    sources = [Path(s) for s in sources]
    digest = sources_digest(sources)
    stamp = cache_dir / STAMP_NAME
    stems = {s.stem for s in sources}
    try:
        if stamp.is_file() and stamp.read_text().strip() == digest:
            return
        if cache_dir.is_dir():
            for f in cache_dir.iterdir():
                if f.suffix in (".nbi", ".nbc") and f.name.split(".", 1)[0] in stems:
                    f.unlink(missing_ok=True)
        cache_dir.mkdir(parents=True, exist_ok=True)
        stamp.write_text(digest + "\n")
    except OSError:          # read-only install: numba caches elsewhere or not at all
        pass


def package_sources(*packages):
    """Every ``.py`` file of the given package folders, their sub-packages included."""
    return [f for p in packages for f in sorted(Path(p).rglob("*.py"))]
