"""Row kernels on Python threads: a compiled kernel over parts of the rows, in parallel, without ``prange``.

A numba kernel ``kernel(start, stop, *args)`` compiled with ``nogil=True`` handles the rows
``start:stop`` and releases the GIL while it runs, so Python threads that each call it on one part of
the rows run in parallel. This does what a ``prange`` loop (``parallel=True``) does for independent rows,
and costs no compilation of its own: a parallel loop adds numba's parallel-loop passes and a gufunc whose
module LLVM optimises again with everything the loop body calls, seconds per kernel on the first call.
The per-vertex kernels of the ``best-fit`` selector and of the non-negative geometric solver run this way.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

#: Parts per thread: rows of uneven cost (free sets of different sizes) balance over the threads.
PARTS_PER_THREAD = 8
#: Fewer rows than this per thread run on the calling thread alone (the threads would cost more than they save).
MIN_ROWS_PER_THREAD = 256


def over_rows(kernel: Callable[..., Any], m: int, *args: Any) -> None:
    """``kernel(start, stop, *args)`` over the rows ``0:m``, on threads when there are enough rows.

    With ``t = min(numba.get_num_threads(), m // 256)`` threads (at least one), the rows are cut into
    ``8 t`` parts of nearly equal length (``bounds = linspace(0, m, 8 t + 1)``, rounded down) that ``t``
    Python threads take in turn; with one thread the kernel runs once on ``0:m`` in the calling thread.
    ``start`` and ``stop`` are ``np.int64`` values, so the kernel compiles one specialisation for them.

    Parameters
    ----------
    kernel : numba dispatcher
        Compiled with ``nogil=True`` (else the threads take turns); writes its rows' results into arrays
        among ``args`` and touches no other row's.
    m : int
        Number of rows.
    *args
        The kernel's remaining arguments, the same for every part.
    """
    import numba

    threads = max(1, min(numba.get_num_threads(), m // MIN_ROWS_PER_THREAD))
    if threads == 1:
        kernel(np.int64(0), np.int64(m), *args)
        return
    from concurrent.futures import ThreadPoolExecutor

    bounds = np.linspace(0, m, PARTS_PER_THREAD * threads + 1).astype(np.int64)
    with ThreadPoolExecutor(threads) as pool:
        list(pool.map(lambda i: kernel(bounds[i], bounds[i + 1], *args), range(len(bounds) - 1)))
