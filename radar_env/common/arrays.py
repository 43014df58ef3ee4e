"""The one array type the compiled kernels are compiled for (C-contiguous, writeable)."""

from __future__ import annotations

import numpy as np

__all__ = ["c_array"]


def c_array(a, dtype=None):
    """``a`` as a C-contiguous, writeable array (of ``dtype``): the one array type the kernels are compiled for
    (a read-only or strided argument would compile another specialisation). Copies only when needed."""
    a = np.asarray(a, dtype=dtype)
    if a.flags.c_contiguous and a.flags.writeable:
        return a
    return np.array(a, dtype=dtype, order="C")
