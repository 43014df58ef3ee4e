"""Old import paths kept working for one release: each old module name is an alias of its new module.

Issue 37 moved the flat modules into sub-packages (``radar_env.episode`` is now ``radar_env.sim.episode``, ...).
One meta-path finder, registered by ``radar_env/__init__.py``, answers the old names: importing one returns the
*same* module object as the new path (``radar_env.episode.Episode is radar_env.sim.episode.Episode``) and emits
one DeprecationWarning naming the new path (:func:`warn_moved`; ``baselines/imm_cv_ct.py``, the old name of the
renamed runner, is a one-file shim that uses it: an alias registered from ``baselines/__init__.py`` would import
radar_env with every ``import baselines``). :func:`forward_attributes` does the same for names read from a package
whose module became it (``radar_env.filters.transition_ct``, formerly of the module ``radar_env/filters.py``).
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import warnings
from pathlib import Path

__all__ = ["MOVED", "install", "forward_attributes", "warn_moved"]

MOVED = {f"radar_env.{old}": f"radar_env.{new}" for old, new in {
    # shared utilities
    "units": "common.units", "validate": "common.validate", "numba_cache": "common.numba_cache",
    # simulation
    "scenario": "sim.scenario", "radar": "sim.radar", "episode": "sim.episode", "draws": "sim.draws",
    "adsb": "sim.adsb", "adsb_scenarios": "sim.adsb_scenarios", "catalog": "sim.catalog",
    # filters (the module radar_env/filters.py became radar_env.filters.kalman: see forward_attributes)
    "kernels": "filters.kernels", "tracking": "filters.tracking", "features": "filters.features",
    "imm_cv_ct": "filters.imm_cv_ct", "torch_chain": "filters.torch_chain", "torch_imm": "filters.torch_imm",
    # the Gymnasium layer
    "config": "envs.config", "core": "envs.core", "env_kernels": "envs.env_kernels",
    "observation": "envs.observation", "imm_env": "envs.imm_env", "imm_core": "envs.imm_core",
    "detectors": "envs.detectors", "single_env": "envs.single_env", "vector_env": "envs.vector_env",
    "env": "envs.env",
}.items()}
"""Old module name -> new module name (radar_env's own moves; others join through :func:`install`)."""

_WHEN = "the old path goes away in the next release"


def _stacklevel(skip=()):
    """The ``stacklevel`` for a warning raised in :func:`warn_moved` that points it at the code that asked for the
    old name: past this module's frames, ``importlib.import_module`` and the files ``skip``; ``warnings`` itself
    skips (and does not count) the import system's ``<frozen importlib._bootstrap...>`` frames."""
    def internal(f):
        return "importlib" in f.f_code.co_filename and "_bootstrap" in f.f_code.co_filename

    files = {__file__, importlib.__file__, *skip}
    frame, level = sys._getframe(1), 1            # warn_moved's frame is level 1
    while frame is not None and (internal(frame) or frame.f_code.co_filename in files):
        frame = frame.f_back
        if frame is not None and not internal(frame):
            level += 1
    return level


def warn_moved(old, new, skip=()):
    """The one DeprecationWarning of an old path ``old``, naming ``new``, attributed to the importing code (past
    the frames of the files ``skip``: a shim module calling this)."""
    warnings.warn(f"{old} moved to {new}; {_WHEN}", DeprecationWarning, stacklevel=_stacklevel(skip))


class _AliasLoader(importlib.abc.Loader):
    """Loads an old name as the new module itself (imported if need be); executes nothing."""

    def __init__(self, new):
        self.new = new
        self._spec = None

    def create_module(self, spec):
        module = importlib.import_module(self.new)
        self._spec = module.__spec__
        return module

    def exec_module(self, module):
        module.__spec__ = self._spec     # the import system gave the shared module the alias' spec: restore its own


class _MovedFinder(importlib.abc.MetaPathFinder):
    """Answers the old names of :data:`MOVED`, before any other finder (a stale copy of the old layout on the path,
    e.g. an editable install of another checkout, must not shadow the alias); it answers nothing else."""

    def __init__(self):
        self.moved = {}

    def find_spec(self, name, path=None, target=None):
        new = self.moved.get(name)
        if new is None:
            return None
        warn_moved(name, new)
        return importlib.machinery.ModuleSpec(name, _AliasLoader(new))


def install(moved):
    """Make each old module name of ``moved`` (``{old: new}``) an alias of its new module; one finder for all."""
    finder = next((f for f in sys.meta_path if type(f).__name__ == "_MovedFinder"), None)
    if finder is None:
        finder = _MovedFinder()
        sys.meta_path.insert(0, finder)
    finder.moved.update(moved)


def forward_attributes(package, module):
    """A module ``__getattr__`` for ``package`` that serves the public names (``__all__``) of ``module`` with one
    DeprecationWarning each: the old ``package.name`` of a module that became the package ``package``. Names of
    the package's own sub-modules are left to the import system."""
    folder = None

    def __getattr__(name):
        nonlocal folder
        pkg = sys.modules[package]
        folder = folder or Path(pkg.__file__).parent
        if name.startswith("_") or (folder / f"{name}.py").is_file() or (folder / name).is_dir():
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        mod = importlib.import_module(module)
        if name not in getattr(mod, "__all__", ()):
            raise AttributeError(f"module {package!r} has no attribute {name!r}")
        warnings.warn(f"{package}.{name} moved to {module}.{name}; {_WHEN}", DeprecationWarning, stacklevel=2)
        value = getattr(mod, name)
        setattr(pkg, name, value)        # once: later reads find the attribute
        return value

    return __getattr__
