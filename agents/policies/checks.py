"""The one validation path of every learned-tracker loader: each file is checked before anything runs, and every
failure is a one-line ``ValueError`` naming the file and the field.

* JSON (:func:`read_json`): valid UTF-8 JSON with finite numbers only (``NaN``, ``Infinity`` and ``1e999`` refused);
  :func:`read_json_object` also requires an object.
* ``.npz`` (:func:`read_npz`): read with ``allow_pickle=False`` (no code runs), every array read in full (a
  truncated or empty file is refused here, not half-way through a run).
* weights (:func:`check_weights`): exactly the architecture's names, each of its shape, dtype float64, finite.
* env config (:func:`check_env_config`): a JSON object of known ``RadarTrack-v0`` arguments that validates.
* the file named (:func:`check_policy_file`): a tracker folder's weights are its ``policy.npz``; another name is
  refused, never swapped for the folder's own file.
* pickles (:func:`refuse_pickle`): an SB3 zip or a torch checkpoint is unpickled only with an explicit
  ``allow_pickle=True`` (``--allow-pickle``); unpickling runs whatever code the file's author put there.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

__all__ = ["POLICY_FILE", "PICKLE_OPTION", "refuse_pickle", "read_json", "read_json_object", "read_npz",
           "check_weights", "check_env_config", "check_policy_file", "check_finite_numbers", "manifest_format",
           "open_weights_folder"]

POLICY_FILE = "policy.npz"
PICKLE_OPTION = "--allow-pickle (allow_pickle=True)"


def refuse_pickle(path, what=None):
    """The one-line refusal of a pickle-bearing file loaded without the opt-in."""
    if what is None:
        what = "a stable-baselines3 zip" if Path(path).suffix == ".zip" else "a pickle-bearing file (not .npz)"
    return ValueError(f"{path}: {what} is a pickle and unpickling runs whatever code its author put there; refused "
                      f"without {PICKLE_OPTION}: pass it only for a file you trust, or run its numpy export "
                      f"(python -m agents.policies.numpy_policy --allow-pickle {path}, on a machine you trust)")


def _bad_constant(name):
    raise ValueError(f"non-finite number {name}")


def _finite_float(text):
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"non-finite number {text}")
    return v


def read_json(path):
    """The JSON value in ``path``, numbers finite; ``ValueError`` (one line, naming the file) otherwise."""
    path = Path(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"), parse_constant=_bad_constant, parse_float=_finite_float)
    except (OSError, UnicodeDecodeError, ValueError, RecursionError) as e:
        msg = str(e).splitlines()[0] if str(e) else type(e).__name__
        raise ValueError(f"{path}: not readable as JSON of finite numbers ({msg})") from None


def read_json_object(path, what="a JSON object"):
    """:func:`read_json` that must give an object (``what`` says which, in the refusal)."""
    v = read_json(path)
    if not isinstance(v, dict):
        raise ValueError(f"{path}: must hold {what}, got {type(v).__name__}")
    return v


def check_finite_numbers(path, value, field):
    """Every number in ``value`` (nested lists/dicts) must be a finite int or float (not bool); ``field`` names it."""
    if isinstance(value, dict):
        for k, v in value.items():
            check_finite_numbers(path, v, f"{field}.{k}")
    elif isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            check_finite_numbers(path, v, f"{field}[{i}]")
    elif isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise ValueError(f"{path}: field {field!r} must be a finite number, got {value!r}")


def read_npz(path):
    """``{name: array}`` of the ``.npz`` ``path`` (no pickle, every array read); ``ValueError`` (one line)."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: does not exist (or is not a regular file)")
    try:
        with np.load(path, allow_pickle=False) as z:
            if not hasattr(z, "files"):
                raise ValueError("a single .npy array, not an .npz archive")
            return {k: np.asarray(z[k]) for k in z.files}
    except Exception as e:  # noqa: BLE001 - zipfile, zlib, EOF and format errors of a damaged file: one line
        msg = str(e).splitlines()[0] if str(e) else ""
        raise ValueError(f"{path}: not a numpy .npz of plain arrays, or damaged ({type(e).__name__}: {msg})") from None


def check_weights(path, weights, shapes):
    """``weights`` must have exactly the names of ``shapes`` (``{name: shape}``), each float64, of its shape, finite."""
    if set(weights) != set(shapes):
        missing, extra = sorted(set(shapes) - set(weights)), sorted(set(weights) - set(shapes))
        raise ValueError(f"{path}: weights do not match the architecture (missing {missing}, unexpected {extra})")
    for k, s in shapes.items():
        w = weights[k]
        if w.dtype != np.float64 or w.shape != tuple(s):
            raise ValueError(f"{path}: weight {k!r} must be float64 of shape {tuple(s)}, got {w.dtype} {w.shape}")
        if not np.all(np.isfinite(w)):
            raise ValueError(f"{path}: weight {k!r} has {int(np.size(w) - np.isfinite(w).sum())} non-finite entries")


def env_kwargs_from_json(v):
    """JSON lists back to the tuples the env's arguments are (nested: range pairs inside ``random_config``)."""
    if isinstance(v, list):
        return tuple(env_kwargs_from_json(x) for x in v)
    if isinstance(v, dict):
        return {k: env_kwargs_from_json(x) for k, x in v.items()}
    return v


def check_env_config(path):
    """``(kwargs, EnvConfig)`` of the ``env_config.json`` ``path``: an object of known ``RadarTrack-v0`` arguments
    that validates; ``ValueError`` naming the file and the field otherwise."""
    from radar_env.envs.config import EnvConfig
    kw = read_json_object(path, "a JSON object of RadarTrack-v0 arguments")
    try:
        return kw, EnvConfig.from_kwargs(**env_kwargs_from_json(kw))
    except (TypeError, ValueError, KeyError, OverflowError) as e:
        raise ValueError(f"{path}: {str(e).splitlines()[0] if str(e) else type(e).__name__}") from None


def check_policy_file(path, name=POLICY_FILE):
    """A weights file given by path must be its folder's ``name`` (the manifest beside it describes that file
    only); ``ValueError`` otherwise: the file named is never swapped for a neighbour."""
    path = Path(path)
    if path.name != name:
        raise ValueError(f"{path}: a learned tracker's weights are the file {name} in its folder (its policy.json "
                         f"describes that file only); give the folder or {path.with_name(name)}")
    return path


def manifest_format(path):
    """``format`` of the ``policy.json`` in ``path``'s folder (``path``: a ``policy.npz`` or its folder), or None if
    there is none or it is unreadable: how a loader tells the ``policy.npz`` kinds apart without reading weights."""
    p = Path(path)
    try:
        return json.loads(((p if p.is_dir() else p.parent) / "policy.json").read_text()).get("format")
    except (OSError, ValueError, AttributeError):
        return None


def open_weights_folder(path, what, fmt, version):
    """The first checks of a ``policy.npz`` kind's loader (a learned IMM, a window correction): ``path`` is the
    folder or its ``policy.npz`` (:func:`check_policy_file`), the folder holds ``policy.npz``, ``policy.json`` and
    ``env_config.json``, and ``policy.json`` is an object of format ``fmt``, version ``version`` (an int, or a tuple
    of the versions the loader reads). ``what`` names the kind in the refusals (e.g. ``"a learned IMM checkpoint"``).

    Returns:
        ``(folder, config, env_file, npz)``: ``config`` the ``policy.json`` dict, the other two paths.
    """
    p = Path(path)
    d = p if p.is_dir() else check_policy_file(p, POLICY_FILE).parent
    meta_file, env_file, npz = d / "policy.json", d / "env_config.json", d / POLICY_FILE
    for f in (meta_file, env_file, npz):
        if not f.is_file():
            raise ValueError(f"{d}: not {what} (no {f.name}; it needs {POLICY_FILE}, policy.json and env_config.json)")
    config = read_json_object(meta_file, f"the config of {what} (a JSON object)")
    versions = version if isinstance(version, tuple) else (version,)
    v = config.get("version")
    if config.get("format") != fmt or isinstance(v, bool) or v not in versions:
        need = " or ".join(map(str, versions))
        raise ValueError(f"{meta_file}: format {config.get('format')!r} version {v!r}, need {fmt!r} version {need}")
    return d, config, env_file, npz
