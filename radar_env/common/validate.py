"""Argument checks shared by the env, its configs and the radar (written once, reused everywhere).

Every check raises ``ValueError`` naming the parameter, its valid range or type, and the value given. Numbers
must be real numbers (``int``/``float``/numpy scalars): strings, ``None``, booleans and complex numbers are
refused rather than converted, so ``scan_period_s='5'`` fails where it is given, not many steps later.
"""

from __future__ import annotations

import math
import numbers

import numpy as np

__all__ = ["check_number", "check_pair", "check_choice", "check_known_keys", "check_probabilities", "is_real_number"]


def is_real_number(v):
    """True for int/float and numpy integer/floating scalars; False for bool, str, complex, None, arrays."""
    return isinstance(v, numbers.Real) and not isinstance(v, (bool, np.bool_))


def _interval(lo, hi, lo_open, hi_open):
    return f"{'(' if lo_open else '['}{lo}, {hi}{')' if hi_open else ']'}"


def check_number(name, value, lo=-math.inf, hi=math.inf, *, integer=False, lo_open=False, hi_open=False):
    """``value`` as a float (or int if ``integer``), if it is a finite real number in the interval; else
    ``ValueError`` naming ``name``."""
    ok = is_real_number(value)
    if ok:
        v = float(value)
        ok = (math.isfinite(v) and (v > lo if lo_open else v >= lo) and (v < hi if hi_open else v <= hi)
              and (not integer or v == int(v)))
    if not ok:
        kind = "an integer" if integer else "a finite number"
        raise ValueError(f"{name} must be {kind} in {_interval(lo, hi, lo_open, hi_open)}, got {value!r}"
                         + ("" if is_real_number(value) else f" ({type(value).__name__})"))
    return int(v) if integer else v


def check_pair(name, value, lo, hi, *, integer=False):
    """A ``(low, high)`` pair (tuple or list) of numbers with ``lo <= low <= high <= hi``; returns a tuple."""
    kind = "integers" if integer else "numbers"
    if not (isinstance(value, (tuple, list)) and len(value) == 2 and all(is_real_number(x) for x in value)):
        raise ValueError(f"{name} must be a (low, high) pair of {kind} in [{lo}, {hi}], got {value!r}")
    a, b = (check_number(name, x, lo, hi, integer=integer) for x in value)
    if a > b:
        raise ValueError(f"{name} must satisfy {lo} <= low <= high <= {hi}, got {value!r}")
    return (a, b)


def check_choice(name, value, choices):
    """``value`` if it is one of ``choices`` (compared only among objects of the same type); else ``ValueError``."""
    if not any(isinstance(value, type(c)) and value == c for c in choices):
        raise ValueError(f"{name} must be one of {list(choices)}, got {value!r}")
    return value


def check_known_keys(what, given, valid, noun="key"):
    """``ValueError`` listing the unknown names of ``given`` (a mapping or names) and the valid ones, e.g.
    ``unknown RandomScenarioConfig key(s) ['speed']; valid: [...]``.
    ``what`` may be empty (``unknown feature(s) [...]``)."""
    unknown = sorted(set(given) - set(valid), key=str)
    if unknown:
        raise ValueError(f"unknown {what + ' ' if what else ''}{noun}(s) {unknown}; valid: {list(valid)}")


def check_probabilities(name, value, shape=None):
    """``value`` as a float array of probabilities (finite, >= 0) summing to 1 along the last axis (to
    ``np.allclose``), of ``shape`` if given (e.g. ``(M, M)`` for a transition matrix whose rows are
    distributions); else ``ValueError`` naming ``name`` and the value."""
    try:
        p = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        p = None
    ok = p is not None and p.ndim >= 1 and (shape is None or p.shape == tuple(shape))
    ok = ok and bool(np.all(np.isfinite(p)) and np.all(p >= 0) and np.allclose(p.sum(axis=-1), 1.0))
    if not ok:
        what = "rows of probabilities" if (shape is not None and len(shape) > 1) else "probabilities"
        raise ValueError(f"{name} must be {what} (finite, >= 0) summing to 1"
                         + (f" with shape {tuple(shape)}" if shape is not None else "") + f", got {value!r}")
    return p
