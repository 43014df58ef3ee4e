"""What every trainer shares (``radar-track train --method ppo`` in :mod:`agents.training.train`, ``--method
backprop`` in :mod:`agents.training.backprop`): the hyperparameter files, ``--hp`` parsing, the training scenarios
and the run folder.

A run is written into ``<out>/<name>.partial/`` and renamed to ``<out>/<name>/`` only when complete
(:func:`run_paths`, :func:`open_run_folder`, :func:`write_run_files`, :func:`mark_failed`, :func:`finish_run`); a
finished ``<out>/<name>/`` is never overwritten.
"""

from __future__ import annotations

import json
import shutil
import tomllib
import traceback
from importlib import resources
from pathlib import Path

__all__ = ["ENV_ID", "TRAIN_SCENARIOS", "HP_DIR", "HP_NAMES", "load_hyperparams", "parse_hp", "run_paths",
           "open_run_folder", "write_run_files", "mark_failed", "finish_run"]

ENV_ID = "RadarTrack-v0"
TRAIN_SCENARIOS = ("random", "random_radars")
"""The random generators training may use (named scenarios, trajectories and flights are for evaluation only)."""
HP_DIR = Path(__file__).with_name("hyperparams")
HP_NAMES = ("ppo", "dqn", "sac", "backprop")
"""The hyperparameter files shipped in ``agents/training/hyperparams/``."""


def load_hyperparams(algo, path=None):
    """The ``RadarTrack-v0`` table of ``agents/training/hyperparams/<algo>.toml`` (package data, read through
    ``importlib.resources`` so it works from a wheel install) or of the TOML file ``path``; ``algo`` ``"backprop"``
    reads ``backprop.toml`` (``--method backprop``)."""
    if path:
        path = Path(path)
        if not path.is_file():
            raise ValueError(f"--hyperparams: file {str(path)!r} does not exist")
        text, where = path.read_bytes(), str(path)
    else:
        if algo not in HP_NAMES:
            raise ValueError(f"algo must be one of {HP_NAMES}, got {algo!r}")
        res = resources.files(__package__).joinpath("hyperparams", f"{algo}.toml")
        text, where = res.read_bytes(), f"agents/training/hyperparams/{algo}.toml"
    try:
        table = tomllib.loads(text.decode())
    except (tomllib.TOMLDecodeError, UnicodeDecodeError) as e:
        raise ValueError(f"--hyperparams: {where} is not TOML ({e})") from None
    if ENV_ID not in table:
        raise ValueError(f"--hyperparams: {where}: no [\"{ENV_ID}\"] table")
    return table[ENV_ID]


def parse_hp(items):
    """``--hp KEY=VALUE`` items -> ``{KEY: value}`` (the value parsed as JSON, else kept as a string); a one-line
    ``SystemExit`` for an item without ``=``."""
    out = {}
    for it in items or []:
        if "=" not in it:
            raise SystemExit(f"error: --hp expects KEY=VALUE, got {it!r}")
        k, v = it.split("=", 1)
        try:
            out[k] = json.loads(v)
        except json.JSONDecodeError:
            out[k] = v
    return out


# ------------------------------------------------------------------------------------------------ run folders
def run_paths(out, run_name, default_name):
    """``(run, part)``: the run folder ``<out>/<name>`` and its ``<name>.partial`` (``name`` = ``run_name`` or
    ``default_name``). ``ValueError`` naming ``--name`` / ``--out`` for a name that is not a plain folder name, a
    finished run of that name (never overwritten) or an ``--out`` that is not a directory."""
    if run_name is not None and (not isinstance(run_name, str) or run_name in ("", ".", "..")
                                 or Path(run_name).name != run_name or "\\" in run_name):
        raise ValueError(f"--name: must be a plain folder name inside --out (no '/', '..'), got {run_name!r}")
    run = Path(out) / (run_name or default_name)
    part = run.with_name(run.name + ".partial")
    if run.exists():        # a finished run is never overwritten (an unfinished <name>.partial is, in open_run_folder)
        raise ValueError(f"--name: run folder {str(run)!r} already exists; choose another name (or remove it)")
    if Path(out).exists() and not Path(out).is_dir():
        raise ValueError(f"--out: {str(out)!r} exists and is not a directory")
    return run, part


def open_run_folder(part, keep=False):
    """Create ``part`` (``<name>.partial``); an earlier attempt under this name that failed or was killed is removed
    first, unless ``keep`` (a resumed run)."""
    try:
        if part.exists() and not keep:
            shutil.rmtree(part)
        part.mkdir(parents=True, exist_ok=keep)
    except OSError as e:
        raise ValueError(f"--out: cannot create the run folder {str(part)!r} ({e.strerror or e})") from None


def write_run_files(part, config, args, command, env_kwargs):
    """``config.json``, ``args.json``, ``command.txt`` and ``env_config.json`` of a run."""
    (part / "config.json").write_text(json.dumps(config, indent=1))
    (part / "args.json").write_text(json.dumps(args or {}, indent=1))
    (part / "command.txt").write_text((command or "") + "\n")
    (part / "env_config.json").write_text(json.dumps(env_kwargs, indent=1))


def mark_failed(part):
    """Write the current exception's traceback to ``<part>/FAILED`` (call it in an ``except`` block)."""
    (part / "FAILED").write_text(traceback.format_exc())


def finish_run(part, run):
    """The run is complete: ``<name>.partial`` becomes ``<name>``."""
    part.rename(run)
