"""Exact point-to-mesh distances through a bounding-volume hierarchy of the triangles, compiled and threaded.

The distance of a point q to a triangle mesh is ``min_f d(q, f)`` over its triangles, ``d`` the Euclidean
distance to the closest point of the triangle (:func:`point_triangle_distance2`, Ericson 2005, sec. 5.1.5;
a degenerate triangle is its segment or point). A bounding-volume hierarchy of axis-aligned boxes prunes
the search: a subtree is skipped when the box distance ``d(q, box) >= best``, the nearest so far, and the
nearer child is searched first, so the minimum is the one of a search of every triangle.

The hierarchy is built once per triangle list (:func:`build_tree`: the triangles sorted by the Morton code
of their centroids, each node split where its codes' highest differing bit changes, the linear BVH of
Lauterbach et al. 2009 as Karras 2012 splits it; equal codes are halved by count) and refitted for new
vertex positions (:func:`refit_tree`: the boxes recomputed bottom up, the order kept), so the posed frames
of one mesh share one build. The queries run in numba's threads, blocks of points at a time.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

__all__ = ["TriangleTree", "build_tree", "distances_to_other_parts", "point_mesh_squared_distances",
           "point_triangle_distance2", "refit_tree"]

#: The hierarchy: node boxes ``lo``, ``hi`` (n, 3); ``kid[x]`` the first of x's two children (the second is
#: ``kid[x] + 1``; -1: a leaf); a leaf holds the triangles ``perm[first[x]:first[x] + count[x]]``.
TriangleTree = namedtuple("TriangleTree", ["lo", "hi", "kid", "first", "count", "perm"])

#: Triangles per leaf at most.
LEAF = 4
#: Points per block of a threaded query.
BLOCK = 256
#: Depth-first stack: the tree is at most 63 Morton bits plus log2(triangles) deep, and a search holds at most
#: one node per level plus one.
STACK = 160


@njit(cache=True)
def point_triangle_distance2(p0, p1, p2, a0, a1, a2, b0, b1, b2, c0, c1, c2):
    """Squared distance from point p to triangle (a, b, c): the closest point by Voronoi regions
    (Ericson 2005, *Real-Time Collision Detection*, sec. 5.1.5)."""
    ab0, ab1, ab2 = b0 - a0, b1 - a1, b2 - a2
    ac0, ac1, ac2 = c0 - a0, c1 - a1, c2 - a2
    ap0, ap1, ap2 = p0 - a0, p1 - a1, p2 - a2
    d1 = ab0 * ap0 + ab1 * ap1 + ab2 * ap2
    d2 = ac0 * ap0 + ac1 * ap1 + ac2 * ap2
    if d1 <= 0.0 and d2 <= 0.0:
        return ap0 * ap0 + ap1 * ap1 + ap2 * ap2
    bp0, bp1, bp2 = p0 - b0, p1 - b1, p2 - b2
    d3 = ab0 * bp0 + ab1 * bp1 + ab2 * bp2
    d4 = ac0 * bp0 + ac1 * bp1 + ac2 * bp2
    if d3 >= 0.0 and d4 <= d3:
        return bp0 * bp0 + bp1 * bp1 + bp2 * bp2
    vc = d1 * d4 - d3 * d2
    if vc <= 0.0 and d1 >= 0.0 and d3 <= 0.0:
        t = d1 / (d1 - d3)
        q0, q1, q2 = ap0 - t * ab0, ap1 - t * ab1, ap2 - t * ab2
        return q0 * q0 + q1 * q1 + q2 * q2
    cp0, cp1, cp2 = p0 - c0, p1 - c1, p2 - c2
    d5 = ab0 * cp0 + ab1 * cp1 + ab2 * cp2
    d6 = ac0 * cp0 + ac1 * cp1 + ac2 * cp2
    if d6 >= 0.0 and d5 <= d6:
        return cp0 * cp0 + cp1 * cp1 + cp2 * cp2
    vb = d5 * d2 - d1 * d6
    if vb <= 0.0 and d2 >= 0.0 and d6 <= 0.0:
        t = d2 / (d2 - d6)
        q0, q1, q2 = ap0 - t * ac0, ap1 - t * ac1, ap2 - t * ac2
        return q0 * q0 + q1 * q1 + q2 * q2
    va = d3 * d6 - d5 * d4
    if va <= 0.0 and (d4 - d3) >= 0.0 and (d5 - d6) >= 0.0:
        t = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        q0, q1, q2 = bp0 - t * (c0 - b0), bp1 - t * (c1 - b1), bp2 - t * (c2 - b2)
        return q0 * q0 + q1 * q1 + q2 * q2
    den = va + vb + vc
    if den == 0.0:                   # a degenerate triangle: the nearest of its corners
        return min(ap0 * ap0 + ap1 * ap1 + ap2 * ap2, min(bp0 * bp0 + bp1 * bp1 + bp2 * bp2,
                                                         cp0 * cp0 + cp1 * cp1 + cp2 * cp2))
    v = vb / den
    w = vc / den
    q0, q1, q2 = ap0 - v * ab0 - w * ac0, ap1 - v * ab1 - w * ac1, ap2 - v * ab2 - w * ac2
    return q0 * q0 + q1 * q1 + q2 * q2


@njit(cache=True)
def _spread(x):
    """The low 21 bits of x spread to every third bit (a Morton code's one axis)."""
    x &= 0x1FFFFF
    x = (x | (x << 32)) & 0x1F00000000FFFF
    x = (x | (x << 16)) & 0x1F0000FF0000FF
    x = (x | (x << 8)) & 0x100F00F00F00F00F
    x = (x | (x << 4)) & 0x10C30C30C30C30C3
    x = (x | (x << 2)) & 0x1249249249249249
    return x


@njit(cache=True)
def _morton_order(V, F):
    """The triangles ordered by the Morton code of their centroids (21 bits per axis over their box)."""
    nf = F.shape[0]
    cen = np.empty((nf, 3))
    for f in range(nf):
        for k in range(3):
            cen[f, k] = (V[F[f, 0], k] + V[F[f, 1], k] + V[F[f, 2], k]) / 3.0
    lo = np.empty(3)
    scale = np.empty(3)
    for k in range(3):
        lo[k] = cen[:, k].min()
        ext = cen[:, k].max() - lo[k]
        scale[k] = 2097151.0 / ext if ext > 0.0 else 0.0
    code = np.empty(nf, np.int64)
    for f in range(nf):
        c = np.int64(0)
        for k in range(3):
            c |= _spread(np.int64((cen[f, k] - lo[k]) * scale[k])) << k
        code[f] = c
    order = np.argsort(code, kind="mergesort")
    return order, code[order]


@njit(cache=True)
def _split(code, s, c):
    """Where the sorted Morton codes ``code[s:s + c]`` first have their highest differing bit set (Karras
    2012), as a count from s; the middle when they are all equal."""
    a, b = code[s], code[s + c - 1]
    if a == b:
        return c // 2
    bit = np.int64(1) << np.int64(63 - _leading_zeros(a ^ b))
    lo, hi = s, s + c - 1                  # the first index whose code has the bit: code[hi] has it
    while lo < hi:
        mid = (lo + hi) // 2
        if code[mid] & bit:
            hi = mid
        else:
            lo = mid + 1
    return lo - s


@njit(cache=True)
def _leading_zeros(x):
    n = 0
    while n < 64 and not (x & (np.int64(1) << np.int64(63 - n))):
        n += 1
    return n


@njit(cache=True)
def _build(V, F):
    nf = F.shape[0]
    perm, code = _morton_order(V, F)
    cap = max(1, 2 * nf)
    kid = np.full(cap, -1, np.int64)
    first = np.zeros(cap, np.int64)
    count = np.zeros(cap, np.int64)
    count[0] = nf
    n = 1
    x = 0
    while x < n:                     # breadth first: children after their parent
        c = count[x]
        if c > LEAF:
            h = _split(code, first[x], c)
            kid[x] = n
            first[n], count[n] = first[x], h
            first[n + 1], count[n + 1] = first[x] + h, c - h
            n += 2
        x += 1
    lo, hi = np.empty((n, 3)), np.empty((n, 3))
    _bounds(V, F, kid[:n], first[:n], count[:n], perm, lo, hi)
    return lo, hi, kid[:n].copy(), first[:n].copy(), count[:n].copy(), perm


@njit(cache=True)
def _bounds(V, F, kid, first, count, perm, lo, hi):
    """Every node's box, children before parents (nodes are numbered breadth first)."""
    for x in range(len(kid) - 1, -1, -1):
        k = kid[x]
        if k >= 0:
            for d in range(3):
                lo[x, d] = min(lo[k, d], lo[k + 1, d])
                hi[x, d] = max(hi[k, d], hi[k + 1, d])
            continue
        for d in range(3):
            lo[x, d] = np.inf
            hi[x, d] = -np.inf
        for i in range(first[x], first[x] + count[x]):
            t = perm[i]
            for c in range(3):
                for d in range(3):
                    v = V[F[t, c], d]
                    lo[x, d] = min(lo[x, d], v)
                    hi[x, d] = max(hi[x, d], v)


def build_tree(V: np.ndarray, F: np.ndarray) -> TriangleTree:
    """The hierarchy of the triangles ``F`` (f, 3) over the vertices ``V`` (at least one triangle)."""
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    return TriangleTree(*_build(V, F))


def refit_tree(tree: TriangleTree, V: np.ndarray, F: np.ndarray) -> TriangleTree:
    """``tree``'s triangles over new vertex positions ``V``: the same order, every box recomputed."""
    lo, hi = np.empty_like(tree.lo), np.empty_like(tree.hi)
    _bounds(np.ascontiguousarray(V, np.float64), np.ascontiguousarray(F, np.int64), tree.kid, tree.first,
            tree.count, tree.perm, lo, hi)
    return tree._replace(lo=lo, hi=hi)


@njit(inline="always")
def _box2(q0, q1, q2, lo, hi, x):
    """Squared distance from q to node x's box (0 inside)."""
    a = max(lo[x, 0] - q0, 0.0, q0 - hi[x, 0])
    b = max(lo[x, 1] - q1, 0.0, q1 - hi[x, 1])
    c = max(lo[x, 2] - q2, 0.0, q2 - hi[x, 2])
    return a * a + b * b + c * c


@njit(cache=True)
def _nearest2(q0, q1, q2, V, F, lo, hi, kid, first, count, perm, stack, hint, part, own, alive):
    """The squared distance from q to the nearest triangle and that triangle, starting from the distance to
    triangle ``hint`` (-1: none): a near first guess prunes more, and the minimum is the same.

    With ``own >= 0`` only triangles of other parts that are alive count (``part[t] != own`` and
    ``alive[part[t]]``; :func:`distances_to_other_parts`); ``own`` -1 counts every triangle."""
    best = np.inf
    arg = -1
    if own >= 0 and hint >= 0 and (part[hint] == own or not alive[part[hint]]):
        hint = -1
    if hint >= 0:
        a, b, c = F[hint, 0], F[hint, 1], F[hint, 2]
        best = point_triangle_distance2(q0, q1, q2, V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                                        V[c, 0], V[c, 1], V[c, 2])
        arg = hint
    top = 0
    stack[0] = 0
    while top >= 0:
        x = stack[top]
        top -= 1
        if _box2(q0, q1, q2, lo, hi, x) >= best:
            continue
        k = kid[x]
        if k < 0:
            for i in range(first[x], first[x] + count[x]):
                t = perm[i]
                if own >= 0 and (part[t] == own or not alive[part[t]]):
                    continue
                a, b, c = F[t, 0], F[t, 1], F[t, 2]
                d = point_triangle_distance2(q0, q1, q2, V[a, 0], V[a, 1], V[a, 2], V[b, 0], V[b, 1], V[b, 2],
                                             V[c, 0], V[c, 1], V[c, 2])
                if d < best:
                    best = d
                    arg = t
            continue
        d0, d1 = _box2(q0, q1, q2, lo, hi, k), _box2(q0, q1, q2, lo, hi, k + 1)
        near, far, dn, df = (k, k + 1, d0, d1) if d0 <= d1 else (k + 1, k, d1, d0)
        if df < best:
            top += 1
            stack[top] = far
        if dn < best:
            top += 1
            stack[top] = near
    return best, arg


@njit(cache=True, parallel=True)
def _query(P, V, F, lo, hi, kid, first, count, perm, out, nearest, part, owner, alive):
    n = P.shape[0]
    for blk in prange((n + BLOCK - 1) // BLOCK):
        stack = np.empty(STACK, np.int64)
        for p in range(blk * BLOCK, min(n, (blk + 1) * BLOCK)):
            out[p], nearest[p] = _nearest2(P[p, 0], P[p, 1], P[p, 2], V, F, lo, hi, kid, first, count, perm, stack,
                                           nearest[p], part, owner[p] if len(owner) else -1, alive)


def point_mesh_squared_distances(P: np.ndarray, V: np.ndarray, F: np.ndarray,
                                 tree: TriangleTree | None = None, nearest: np.ndarray | None = None) -> np.ndarray:
    """(n,) squared distances of the points ``P`` (n, 3) to the mesh (V, F) (at least one triangle).

    ``tree``: the hierarchy of ``F`` (:func:`build_tree`), refitted to ``V`` (:func:`refit_tree`) when its
    boxes came from other positions; built here when None. ``nearest``: (n,) int64, each point's first guess
    of its nearest triangle (-1: none), overwritten with the nearest found (the same points in the previous
    frame of an animation are good guesses). Exact: the same minima as a search of every triangle (module
    docstring).
    """
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    P = np.ascontiguousarray(P, np.float64).reshape(-1, 3)
    tree = build_tree(V, F) if tree is None else tree
    out = np.empty(len(P))
    nearest = _guesses(nearest, len(P), len(F))
    none = np.zeros(0, np.int64)
    _query(P, V, F, tree.lo, tree.hi, tree.kid, tree.first, tree.count, tree.perm, out, nearest, none, none,
           np.zeros(0, np.bool_))
    return out


def distances_to_other_parts(P: np.ndarray, owner: np.ndarray, V: np.ndarray, F: np.ndarray, part: np.ndarray,
                             alive: np.ndarray, tree: TriangleTree | None = None,
                             nearest: np.ndarray | None = None) -> np.ndarray:
    """(n,) squared distances of the points ``P`` to the triangles of the other parts that are alive: point p's
    is ``min d(p, t)^2`` over the triangles t with ``part[t] != owner[p]`` and ``alive[part[t]]`` (inf when
    there is none). One hierarchy of every triangle serves every part (``tree``, as for
    :func:`point_mesh_squared_distances`); the excluded triangles are skipped where the search reaches them,
    so the minimum is the one of a search of the allowed triangles. ``nearest``: (n,) int64 first guesses
    (-1: none; an excluded triangle is none), overwritten with the triangles found, as for
    :func:`point_mesh_squared_distances`."""
    V = np.ascontiguousarray(V, np.float64)
    F = np.ascontiguousarray(F, np.int64)
    P = np.ascontiguousarray(P, np.float64).reshape(-1, 3)
    tree = build_tree(V, F) if tree is None else tree
    out = np.empty(len(P))
    nearest = _guesses(nearest, len(P), len(F))
    _query(P, V, F, tree.lo, tree.hi, tree.kid, tree.first, tree.count, tree.perm, out, nearest,
           np.ascontiguousarray(part, np.int64), np.ascontiguousarray(owner, np.int64),
           np.ascontiguousarray(alive, np.bool_))
    return out


def _guesses(nearest: np.ndarray | None, n: int, n_faces: int) -> np.ndarray:
    """``nearest`` as first guesses of n points' nearest triangles among ``n_faces`` (a new array of -1 when
    it is None or not (n,) int64; a guess beyond the triangles, another mesh's, is no guess)."""
    if nearest is None or len(nearest) != n or nearest.dtype != np.int64:
        return np.full(n, -1, np.int64)
    nearest[nearest >= n_faces] = -1
    return nearest
