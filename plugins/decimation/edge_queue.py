"""The compiled loop's priority queue and edge table: a binary heap and an open-addressing hash of edge keys.

- the heap holds ``(cost, stamp, edge)`` entries ordered like Python's tuples
  (:func:`_less`), as ``heapq`` does in the numpy reference
  (:func:`rigslim.plugins.decimation.collapse.simplify`);
- the hash maps an edge key ``min(x, y) * N + max(x, y)`` to its slot
  (Fibonacci hashing, linear probing, backward-shift deletion);
- edge slots are reused through a free list; a slot's ``stamp`` grows with
  every change, so heap entries of an older state are skipped when popped.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from rigslim.plugins.decimation.setup import BLOCKED, DEAD

__all__ = ["C_AHEAD", "C_COLLAPSES", "C_COSTED", "C_EVALS", "C_FACES", "C_FREE", "C_HEAP", "C_MEASURED", "C_POOL",
           "C_POPS", "C_SIZE", "C_TAG", "C_TRIES", "N_COUNTERS", "edge_add", "edge_kill", "edge_of", "init_table",
           "pop", "push"]

#: Counters of the loop state (one int64 array, ``cnt``): faces left, collapses made, heap size, free edge
#: slots, edge slots used, vertex-face pool use, marker tag, heap pops, collapse attempts, edge evaluations,
#: measured errors (source- and face-side, :func:`rigslim.plugins.decimation.compiled.source_error`), attempts
#: that found their guard and error judged ahead of them and costs computed ahead
#: (:func:`rigslim.plugins.decimation.compiled.speculate`).
(C_FACES, C_COLLAPSES, C_HEAP, C_FREE, C_SIZE, C_POOL, C_TAG, C_POPS, C_TRIES, C_EVALS, C_MEASURED, C_AHEAD,
 C_COSTED) = range(13)
N_COUNTERS = 13


@njit(cache=True)
def _hslot(key, hmask):
    h = np.uint64(key) * np.uint64(0x9E3779B97F4A7C15)
    return np.int64((h >> np.uint64(20)) & np.uint64(hmask))


@njit(cache=True)
def _hfind(hk, hv, key):
    hmask = len(hk) - 1
    i = _hslot(key, hmask)
    while hk[i] != -1:
        if hk[i] == key:
            return i
        i = (i + 1) & hmask
    return -1


@njit(cache=True)
def _hinsert(hk, hv, key, val):
    hmask = len(hk) - 1
    i = _hslot(key, hmask)
    while hk[i] != -1:
        i = (i + 1) & hmask
    hk[i], hv[i] = key, val


@njit(cache=True)
def _hdelete(hk, hv, i):
    """Delete slot i of the linear-probing table (backward shift, Knuth's algorithm R)."""
    hmask = len(hk) - 1
    hk[i] = -1
    j = i
    while True:
        j = (j + 1) & hmask
        if hk[j] == -1:
            return
        k = _hslot(hk[j], hmask)
        if (i <= j and i < k <= j) or (i > j and (i < k or k <= j)):
            continue
        hk[i], hv[i] = hk[j], hv[j]
        hk[j] = -1
        i = j


@njit(cache=True)
def _less(c1, s1, e1, c2, s2, e2):
    return c1 < c2 or (c1 == c2 and (s1 < s2 or (s1 == s2 and e1 < e2)))


@njit(cache=True)
def _sift_down(hc, hs, he, size, i):
    while True:
        l, r, m = 2 * i + 1, 2 * i + 2, i
        if l < size and _less(hc[l], hs[l], he[l], hc[m], hs[m], he[m]):
            m = l
        if r < size and _less(hc[r], hs[r], he[r], hc[m], hs[m], he[m]):
            m = r
        if m == i:
            return
        hc[i], hc[m] = hc[m], hc[i]
        hs[i], hs[m] = hs[m], hs[i]
        he[i], he[m] = he[m], he[i]
        i = m


@njit(cache=True)
def push(hc, hs, he, cnt, cost, stamp, e, estamp, estate):
    size = cnt[C_HEAP]
    if size == len(hc):                          # drop stale entries (they would be skipped anyway)
        k = 0
        for i in range(size):
            if hs[i] == estamp[he[i]] and estate[he[i]] != DEAD and estate[he[i]] != BLOCKED:
                hc[k], hs[k], he[k] = hc[i], hs[i], he[i]
                k += 1
        size = k
        for i in range(size // 2 - 1, -1, -1):
            _sift_down(hc, hs, he, size, i)
    i = size
    hc[i], hs[i], he[i] = cost, stamp, e
    while i > 0:
        p = (i - 1) // 2
        if _less(hc[i], hs[i], he[i], hc[p], hs[p], he[p]):
            hc[i], hc[p] = hc[p], hc[i]
            hs[i], hs[p] = hs[p], hs[i]
            he[i], he[p] = he[p], he[i]
            i = p
        else:
            break
    cnt[C_HEAP] = size + 1


@njit(cache=True)
def pop(hc, hs, he, cnt):
    size = cnt[C_HEAP] - 1
    c, s, e = hc[0], hs[0], he[0]
    hc[0], hs[0], he[0] = hc[size], hs[size], he[size]
    cnt[C_HEAP] = size
    _sift_down(hc, hs, he, size, 0)
    return c, s, e


@njit(cache=True)
def edge_add(x, y, N, ea, eb, estamp, free, cnt, hk, hv):
    if cnt[C_FREE] > 0:
        cnt[C_FREE] -= 1
        e = free[cnt[C_FREE]]
    else:
        e = cnt[C_SIZE]
        cnt[C_SIZE] += 1
    if x > y:
        x, y = y, x
    ea[e], eb[e] = x, y
    estamp[e] += 1
    _hinsert(hk, hv, x * N + y, e)
    return e


@njit(cache=True)
def edge_kill(e, N, ea, eb, estate, free, cnt, hk, hv):
    estate[e] = DEAD
    _hdelete(hk, hv, _hfind(hk, hv, ea[e] * N + eb[e]))
    free[cnt[C_FREE]] = e
    cnt[C_FREE] += 1


@njit(cache=True)
def edge_of(x, y, N, hk, hv):
    if x > y:
        x, y = y, x
    i = _hfind(hk, hv, x * N + y)
    return -1 if i < 0 else hv[i]


@njit(cache=True)
def init_table(edges, N, ea, eb, estamp, hk, hv):
    """Edge slots 0..E-1 for the sorted unique edges, registered in the key hash (stamp 1, as after one add)."""
    for e in range(len(edges)):
        ea[e], eb[e] = edges[e, 0], edges[e, 1]
        estamp[e] = 1
        _hinsert(hk, hv, edges[e, 0] * N + edges[e, 1], e)
