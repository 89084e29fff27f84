"""Row kernels on threads: every row handled exactly once, in parts, on as many threads as numba's count
allows, and a nogil kernel's results the same as on one thread."""

import threading

import numba
import numpy as np
import pytest
from numba import njit

from rigslim.numerics.row_threads import MIN_ROWS_PER_THREAD, PARTS_PER_THREAD, over_rows


@njit(cache=True, nogil=True)
def _row_norms(start, stop, X, out):  # pragma: no cover - numba
    for v in range(start, stop):
        s = 0.0
        for j in range(X.shape[1]):
            s += X[v, j] * X[v, j]
        out[v] = s


def _recording(calls):
    lock = threading.Lock()

    def kernel(start, stop, seen):
        assert isinstance(start, np.int64) and isinstance(stop, np.int64)
        with lock:
            calls.append((int(start), int(stop), threading.get_ident()))
        seen[start:stop] += 1

    return kernel


@pytest.mark.parametrize("m", [0, 5, MIN_ROWS_PER_THREAD - 1, 3 * MIN_ROWS_PER_THREAD + 17])
def test_every_row_once(m):
    calls = []
    seen = np.zeros(m, dtype=np.int64)
    over_rows(_recording(calls), m, seen)
    assert (seen == 1).all()
    threads = max(1, min(numba.get_num_threads(), m // MIN_ROWS_PER_THREAD))
    if threads == 1:
        assert [c[:2] for c in calls] == [(0, m)]
        assert calls[0][2] == threading.get_ident()   # on the calling thread, no pool
    else:
        assert len(calls) == PARTS_PER_THREAD * threads
        assert sorted(c[:2] for c in calls)[0][0] == 0 and max(c[1] for c in calls) == m


def test_one_thread_when_numba_has_one():
    m = 4 * MIN_ROWS_PER_THREAD
    before = numba.get_num_threads()
    numba.set_num_threads(1)
    try:
        calls = []
        over_rows(_recording(calls), m, np.zeros(m, dtype=np.int64))
    finally:
        numba.set_num_threads(before)
    assert [c[:2] for c in calls] == [(0, m)]


def test_nogil_kernel_matches_numpy(rng):
    X = rng.normal(size=(5 * MIN_ROWS_PER_THREAD + 3, 7))
    out = np.full(len(X), np.nan)
    over_rows(_row_norms, len(X), X, out)
    np.testing.assert_array_equal(out, np.array([sum(x * x for x in row) for row in X]))
