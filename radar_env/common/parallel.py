"""Row kernels on several threads: the same Python function compiled a second time with ``parallel=True``.

A row kernel written for this (:func:`radar_env.envs.env_kernels.k_env`, :func:`radar_env.sim.draws._random_rows`,
:func:`radar_env.sim.draws.k_fill_random_looks`) takes a last argument ``chunks`` and loops ``for blk in
prange(chunks)`` over contiguous blocks of rows, each block with its own scratch arrays, so that no two blocks write
the same memory. Its ordinary ``@njit`` build (``prange`` is ``range`` there) is called with ``chunks = 1``: the
serial kernel. :func:`run` with ``num_threads > 1`` (and at least two rows per thread) calls the parallel build of
the *same* function (its ``py_func``, compiled lazily on first use, cached on disk under its own name) with
``chunks = num_threads`` on that many of numba's threads. Each row's numbers do not depend on the block it is in
(the rows are independent and every random draw is keyed per row), so the outputs are bit-identical to the serial
build's.
"""

from __future__ import annotations

import types

import numba
import numpy as np

__all__ = ["check_num_threads", "run", "parallel_build"]

_BUILDS = {}


def check_num_threads(num_threads):
    """``num_threads`` as an int in ``[1, numba.config.NUMBA_NUM_THREADS]``; ``ValueError`` naming the range
    otherwise."""
    top = int(numba.config.NUMBA_NUM_THREADS)
    if (not isinstance(num_threads, (int, np.integer)) or isinstance(num_threads, bool)
            or not 1 <= num_threads <= top):
        raise ValueError(f"num_threads must be an integer in [1, {top}] (numba.config.NUMBA_NUM_THREADS), got "
                         f"{num_threads!r}")
    return int(num_threads)


def parallel_build(dispatcher):
    """The ``parallel=True`` build of an ``@njit`` function's ``py_func`` (made once per process). The copy of the
    function is named ``<name>_parallel`` so that numba's disk cache keeps it apart from the serial build (numba
    keys cache entries by the function's qualified name and signature, not by its flags)."""
    f = dispatcher.py_func
    p = _BUILDS.get(f)
    if p is None:
        g = types.FunctionType(f.__code__, f.__globals__, f.__name__ + "_parallel", f.__defaults__, f.__closure__)
        g.__qualname__ = f.__qualname__ + "_parallel"
        g.__module__ = f.__module__
        g.__doc__ = f.__doc__
        # only the explicit prange loops run in parallel: numba's other conversions (np.zeros, array expressions,
        # ...) would each become a parallel region of its own, with its own start and barrier, in every call
        options = dict(prange=True, comprehension=False, reduction=False, inplace_binop=False, setitem=False,
                       numpy=False, stencil=False, fusion=False)
        p = _BUILDS[f] = numba.njit(parallel=options, cache=True)(g)
    return p


def run(num_threads, n_rows, dispatcher, *args):
    """``dispatcher(*args, 1)`` for ``num_threads == 1`` or fewer than ``2 * num_threads`` rows (``n_rows``: a
    parallel region's start and barrier cost more than a block of one row saves); else its parallel build with
    ``chunks = num_threads`` on ``num_threads`` of numba's threads (numba's thread count is per calling thread and
    restored after the call). The outputs are the same either way."""
    if num_threads == 1 or n_rows < 2 * num_threads:
        return dispatcher(*args, 1)
    kernel = parallel_build(dispatcher)
    before = numba.get_num_threads()
    numba.set_num_threads(num_threads)
    try:
        return kernel(*args, num_threads)
    finally:
        numba.set_num_threads(before)
