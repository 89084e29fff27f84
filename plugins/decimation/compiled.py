"""The compiled (numba) greedy collapse loop of the articulated simplifier, in named phases.

The numpy reference is :func:`rigslim.plugins.decimation.collapse.simplify`
with ``backend="numpy"``; tests check that both make the same collapses.
Like meshoptimizer's simplifier, the loop is a sequence of small phases,
each a function over named groups of arrays:

- :func:`evaluate_edge`: when a dirty edge reaches the top of the queue,
  it gets its true cost (:func:`rigslim.plugins.decimation.edge_costs.edge_cost`)
  and is queued again;
- :func:`link_ok`: the faces around the edge and the link condition (exactly
  two common neighbours, so the result stays manifold);
- :func:`folds`: the new vertex in the rest pose and every example pose, and
  the fold-over guard (no surviving face's normal turns by more than
  ``arccos(min_normal_cos)``);
- :func:`apply_collapse`: the new vertex, the faces and the vertex-face lists;
- :func:`requeue`: the new edges with the lower bound
  ``max(cost(a, x), cost(b, x), cost(a, b))``, marked dirty, and the blocked
  edges around them released.
- :func:`speculate`: when an attempt must judge its edge (the fold-over guard
  and the measured error :func:`source_error`, the loop's costliest work), the
  next entries of the queue that would do work are judged, or evaluated if
  dirty, with it, one thread each. Their results are kept with the edge's stamp
  and the collapse count, and a later turn uses them only while nothing around
  the edge has changed, the rule by which an attempt already reuses the error
  in an edge's cost. The queue's order is total, so the collapses are the same
  as one at a time (``ahead=1``).

The arrays are grouped in named tuples (:class:`LoopMesh`, :class:`LoopVertices`,
:class:`LoopEdges`, :class:`LoopQueue`, :class:`LoopRecord`, :class:`Scratch`);
:func:`collapse_chunk` runs a given number of collapses per call so that the
caller can report progress between chunks. The mesh setup (collapsible edges,
locked vertices, seams) is shared with the numpy reference
(:mod:`rigslim.plugins.decimation.setup`); the queue is :mod:`rigslim.plugins.decimation.edge_queue`.
"""

from __future__ import annotations

from collections import namedtuple

import numpy as np
from numba import njit, prange

from rigslim.numerics.point_mesh_distance import point_triangle_distance2
from rigslim.plugins.decimation.edge_costs import collapse_cost, quadric_floor, quadric_weight
from rigslim.plugins.decimation.edge_queue import (
    C_AHEAD,
    C_COLLAPSES,
    C_COSTED,
    C_EVALS,
    C_FACES,
    C_HEAP,
    C_MEASURED,
    C_POOL,
    C_POPS,
    C_TAG,
    C_TRIES,
    edge_add,
    edge_kill,
    edge_of,
    pop,
    push,
)
from rigslim.plugins.decimation.setup import (
    BEST,
    BLOCKED,
    BORDER,
    CLEAN,
    DEAD,
    DIRTY,
    FREE,
    KEEP_A,
    KEEP_B,
    MAX_EDGE_FACES,
    NONE,
    SEAM,
    SOURCE_SAMPLES,
)

__all__ = ["EVALUATE", "JUDGE", "CostModel", "LoopAhead", "LoopEdges", "LoopMembers", "LoopMesh", "LoopQueue",
           "LoopRecord", "LoopVertices", "Scratch", "apply_collapse", "collapse_chunk", "evaluate_edge", "folded",
           "folds", "link_ok", "new_ahead", "new_members", "new_scratch", "point_triangle_distance2", "posed_point",
           "requeue", "source_error", "speculate", "surviving_faces"]

#: The mesh as the loop edits it: faces (vertices renamed as they merge), vertex-face lists (``pool`` slices
#: ``vf_start[x]:vf_start[x] + vf_cnt[x]``), fixed and seam vertices, face charts, a marker array, and
#: ``changed[x]``: the number of collapses made when x's faces last changed (0: never).
LoopMesh = namedtuple("LoopMesh", ["F", "vf_start", "vf_cnt", "pool", "boundary", "along", "charts", "mark",
                                   "changed"])
#: Per-vertex tables (2m rows: the originals, then one per collapse): rest position, weights, quadrics,
#: positions in the rest pose and every example pose.
LoopVertices = namedtuple("LoopVertices", ["V", "W", "Qv", "pos"])
#: Edge slots (ends, cost, the new vertex and weights, stamp, state), the free list, the key hash, the
#: source-side error already in each edge's cost (:func:`source_error`) and ``stime``, the number of collapses
#: made when it was added (-1: not since the edge's last evaluation).
LoopEdges = namedtuple("LoopEdges", ["ea", "eb", "ecost", "ev", "ew", "estamp", "estate", "free", "hk", "hv", "esrc",
                                     "stime"])
#: The heap of ``(cost, stamp, edge)`` entries.
LoopQueue = namedtuple("LoopQueue", ["hc", "hs", "he"])
#: Counters (:mod:`rigslim.plugins.decimation.edge_queue`) and the recorded collapses, errors and face counts.
LoopRecord = namedtuple("LoopRecord", ["cnt", "col", "errs", "nfaces"])
#: The edge cost model (:func:`rigslim.plugins.decimation.edge_costs.edge_cost`) and the example poses. ``fp``
#: ends with the loop's settings: ``fp[2]`` the zero cost, ``fp[3]`` normalised (0/1), ``fp[4]`` the source-side
#: error (0/1), ``fp[5]`` the face-side error's factor (0: off; else the squared rest scale).
CostModel = namedtuple("CostModel", ["method", "ip", "fp", "T"])
#: The original vertices each vertex stands for (the merge tree's leaves), as linked lists: ``head[x]`` the first,
#: ``nxt[p]`` the one after original p (-1: the last), ``tail[x]`` the last.
#: ``kid[c]``: the two vertices merged into c (-1 for an original); ``ball[x]``: a sphere (centre, radius) holding
#: every source face of x's originals, so the merge tree is a bounding-volume hierarchy (:func:`_nearest_source`).
LoopMembers = namedtuple("LoopMembers", ["head", "nxt", "tail", "size", "tri0", "vf0_start", "vf0_cnt",
                                         "vf0_pool", "kid", "ball", "stack"])
#: Work arrays of one collapse attempt: neighbours of a and b, the union, the surviving and the removed
#: faces, the new vertex in every pose, and 3x4 / 3x3 temporaries.
Scratch = namedtuple("Scratch", ["Na", "Nb", "nbr", "uni", "rem", "fab", "pc", "Xw", "q", "o"])
#: The work of the queue's next entries, done ahead of their turn, several at once (:func:`speculate`): per edge
#: slot the measured error (``val``) and whether the collapse folds a face (``fold``, :func:`folds`), with the
#: edge's stamp and the number of collapses made when they were measured (``time``, -1: never); the true cost
#: of a dirty edge (``cost``; its new vertex and weights are in the edge table) with the stamp it was computed
#: at (``cstamp``); the candidates (``cand``), what each needs (``kind``: :data:`JUDGE` or :data:`EVALUATE`)
#: and their work arrays (one row each); the heap entries held while the candidates are found.
LoopAhead = namedtuple("LoopAhead", ["val", "fold", "stamp", "time", "cost", "cstamp", "cand", "kind", "out", "bent",
                                     "rem", "pc", "Xw", "q", "o", "stack", "hc", "hs", "he"])


def new_scratch(n_poses: int) -> Scratch:
    """Work arrays for a loop over ``n_poses`` example poses."""
    return Scratch(np.empty(4096, np.int64), np.empty(4096, np.int64), np.empty(4096, np.int64),
                   np.empty(8192, np.int64), np.empty(8192, np.int64), np.empty(MAX_EDGE_FACES, np.int64),
                   np.empty((n_poses + 1, 3)), np.empty((3, 4)), np.empty((3, 3)), np.empty((3, 3)))


#: What a candidate of :func:`speculate` needs: its guard and measured error (a clean edge about to be attempted)
#: or its true cost (a dirty edge about to be evaluated, :func:`evaluate_edge`).
JUDGE, EVALUATE = 0, 1


def new_ahead(cap: int, width: int, n_poses: int, m: int) -> LoopAhead:
    """Room to measure ``width`` candidates at once (:func:`speculate`) over ``cap`` edge slots of a mesh of m
    vertices; ``width`` 1 measures each attempt alone."""
    width = max(1, int(width))
    held = 4 * width
    return LoopAhead(np.zeros(cap), np.zeros(cap, np.bool_), np.zeros(cap, np.int64), np.full(cap, -1, np.int64),
                     np.zeros(cap), np.full(cap, -1, np.int64),
                     np.zeros(width, np.int64), np.zeros(width, np.int8), np.zeros(width), np.zeros(width, np.bool_),
                     np.empty((width, 8192), np.int64), np.empty((width, n_poses + 1, 3)), np.empty((width, 3, 4)),
                     np.empty((width, 3, 3)), np.empty((width, 3, 3)), np.empty((width, 2 * m + 8), np.int64),
                     np.zeros(held), np.zeros(held, np.int64), np.zeros(held, np.int64))


def new_members(m: int, F0: np.ndarray, vf0: tuple[np.ndarray, np.ndarray, np.ndarray],
                V0: np.ndarray) -> LoopMembers:
    """Every original vertex stands for itself; rows m.. are the merged vertices' lists. ``F0`` and ``vf0``
    (``vf_start``, ``vf_cnt``, ``pool``): the source faces and each original vertex's faces, kept unchanged
    for the face-side error (:func:`face_error`): ``tri0`` holds each source face in the rest pose ``V0`` as
    one row ``(A, reach, B, C)``, its corners and its reach from the first, ``max(|B - A|, |C - A|)``.
    An original's ``ball`` is centred on it, with the radius of its farthest face corner."""
    head = np.full(2 * m, -1, np.int64)
    head[:m] = np.arange(m)
    F0 = np.asarray(F0, np.int64)
    V0 = np.asarray(V0, np.float64)
    A, B, C = V0[F0[:, 0]], V0[F0[:, 1]], V0[F0[:, 2]]
    reach = np.maximum(np.linalg.norm(B - A, axis=1), np.linalg.norm(C - A, axis=1))
    tri0 = np.ascontiguousarray(np.concatenate([A, reach[:, None], B, C], axis=1))
    vf_start, vf_cnt, pool = (np.ascontiguousarray(x, np.int64) for x in vf0)
    ball = np.zeros((2 * m, 4))
    ball[:m, :3] = V0[:m]
    owner = np.repeat(np.arange(m), vf_cnt[:m])
    faces = np.concatenate([pool[s:s + c] for s, c in zip(vf_start[:m], vf_cnt[:m], strict=True)]) if m else pool[:0]
    if len(faces):
        corner = np.linalg.norm(V0[F0[faces]] - V0[owner][:, None, :], axis=2).max(axis=1)
        np.maximum.at(ball[:, 3], owner, corner)
    return LoopMembers(head, np.full(m, -1, np.int64), head.copy(), np.ones(2 * m, np.int64), tri0, vf_start,
                       vf_cnt, pool,
                       np.full((2 * m, 2), -1, np.int64), ball, np.empty(2 * m + 8, np.int64))


@njit(cache=True)
def merge_ball(ball, a, b, c):
    """``ball[c]``: the smallest sphere holding the spheres of a and b."""
    d0, d1, d2 = ball[b, 0] - ball[a, 0], ball[b, 1] - ball[a, 1], ball[b, 2] - ball[a, 2]
    d = np.sqrt(d0 * d0 + d1 * d1 + d2 * d2)
    ra, rb = ball[a, 3], ball[b, 3]
    if d + rb <= ra:
        ball[c] = ball[a]
    elif d + ra <= rb:
        ball[c] = ball[b]
    else:
        r = 0.5 * (d + ra + rb)
        t = (r - ra) / d
        ball[c, 0], ball[c, 1], ball[c, 2] = ball[a, 0] + t * d0, ball[a, 1] + t * d1, ball[a, 2] + t * d2
        ball[c, 3] = r


@njit(cache=True)
def _posed_new_faces(a, b, nrem, F, pos, pc, rem):
    """The new faces around the merged vertex (``rem``, with a and b at ``pc``) in every example pose j, as rows
    ``(A, reach, B, C)`` of a ``(poses, nrem, 10)`` array: corners and ``max(|B - A|, |C - A|)``."""
    P = pos.shape[1] - 1
    out = np.empty((P, nrem, 10))
    for i in range(nrem):
        f = rem[i]
        for j in range(P):
            for c in range(3):
                x = F[f, c]
                X = pc[j + 1] if (x == a or x == b) else pos[x, j + 1]
                o = 0 if c == 0 else 1 + 3 * c
                out[j, i, o], out[j, i, o + 1], out[j, i, o + 2] = X[0], X[1], X[2]
            out[j, i, 3] = _reach(out[j, i])
    return out


@njit(cache=True)
def _reach(t):
    """``max(|B - A|, |C - A|)`` of a row ``(A, reach, B, C)``: the triangle lies within it of A."""
    b0, b1, b2 = t[4] - t[0], t[5] - t[1], t[6] - t[2]
    c0, c1, c2 = t[7] - t[0], t[8] - t[1], t[9] - t[2]
    return max(np.sqrt(b0 * b0 + b1 * b1 + b2 * b2), np.sqrt(c0 * c0 + c1 * c1 + c2 * c2))


@njit(cache=True)
def _nearest2(q0, q1, q2, tri, n, first):
    """The squared distance from q to the nearest of the triangles ``tri[:n]`` (rows ``(A, reach, B, C)``) and
    its index, trying ``first`` first. A triangle is skipped when it cannot be nearer than the nearest so far:
    its distance is at least ``|q - A| - reach``, so the minimum is the same as without the test."""
    if n == 0:
        return np.inf, first
    t = tri[first]
    best = point_triangle_distance2(q0, q1, q2, t[0], t[1], t[2], t[4], t[5], t[6], t[7], t[8], t[9])
    far = np.sqrt(best)
    arg = first
    for i in range(n):
        if i == first:
            continue
        t = tri[i]
        e0, e1, e2 = q0 - t[0], q1 - t[1], q2 - t[2]
        lim = (1.0 + 1e-9) * (far + t[3])
        if e0 * e0 + e1 * e1 + e2 * e2 > lim * lim:
            continue
        d = point_triangle_distance2(q0, q1, q2, t[0], t[1], t[2], t[4], t[5], t[6], t[7], t[8], t[9])
        if d < best:
            best = d
            far = np.sqrt(d)
            arg = i
    return best, arg


@njit(cache=True)
def source_error(a, b, nrem, F, pos, Qv, mem, pc, rem, stack, face):
    """The source-side error of collapsing (a, b): the mean squared distance, weighted by their planes' areas,
    of the original vertices that a and b stand for from the new faces around the merged vertex; with
    ``face`` non-zero, plus ``face`` times the face-side error (:func:`face_error`, measured at rest: ``face``
    is the squared :func:`rigslim.plugins.decimation.setup.rest_scale`, the posed units of a rest unit).

    ``S = sum_p sum_j w_p^j d_pj^2 / sum_p sum_j w_p^j`` over the originals p of a and b (``mem``) and the
    example poses j, ``w_p^j = tr Q_p^j[:3, :3]`` (the area of p's planes in pose j; DeCoro's one rest-frame
    quadric weighs every pose alike), ``d_pj`` the distance
    from p in pose j to the nearest face of ``rem[:nrem]`` (the faces left around a and b, :func:`link_ok`) with
    a and b at the new vertex (``pc``: at rest and in every example pose, :func:`posed_vertex`). The new faces
    are posed once (:func:`_posed_new_faces`), and the search starts from the face nearest to the previous
    original (:func:`_nearest2`): the same minima, so the same sum, as a search of every face.

    When a and b stand for more than :data:`SOURCE_SAMPLES` originals together, every s-th of their list
    enters, ``s = ceil(n / SOURCE_SAMPLES)``: a mean over a spread sample (the list follows the merge tree,
    so it is spatially ordered). That happens only far down a large mesh's hierarchy (below about 750 faces
    of the 193k-face elephant), where each collapse would otherwise measure thousands of originals.

    ``stack``: work space of the merge-tree search (:func:`_nearest_source`; ``mem.stack`` in the loop, one per
    candidate in :func:`speculate`). Only reads the loop's state, so several candidates may be measured at once.
    """
    posed = _posed_new_faces(a, b, nrem, F, pos, pc, rem)
    stride = -(-(mem.size[a] + mem.size[b]) // SOURCE_SAMPLES)
    sw = 0.0
    sd = 0.0
    near = 0
    i = -1
    for start in (mem.head[a], mem.head[b]):
        p = start
        while p >= 0:
            i += 1
            if i % stride != 0:
                p = mem.nxt[p]
                continue
            for j in range(pos.shape[1] - 1):
                jq = j if Qv.shape[1] > 1 else 0        # one rest-frame quadric (DeCoro): the same weight
                best, near = _nearest2(pos[p, j + 1, 0], pos[p, j + 1, 1], pos[p, j + 1, 2], posed[j], nrem, near)
                w = Qv[p, jq, 0, 0] + Qv[p, jq, 1, 1] + Qv[p, jq, 2, 2]
                sw += w
                sd += w * best
            p = mem.nxt[p]
    out = sd / sw if sw > 0 else 0.0
    if face != 0.0:
        out += face * face_error(a, b, nrem, F, pos, mem, pc, rem, stack)
    return out


@njit(cache=True)
def _nearest_source(g0, g1, g2, root, mem, tri, best, stack):
    """``min(best, d(g, S)^2)``, S the source faces of the originals under ``root`` in the merge tree.

    Depth first, the nearer child first; a subtree is skipped when g is farther from its ball than the
    nearest face so far (``|g - centre| - radius > sqrt(best)``, with a relative margin of 1e-9 for round-off),
    a face when ``|g - A| - reach`` is (``tri`` rows ``(A, reach, B, C)``). No face that could be nearer is
    skipped, so the minimum is exact.
    """
    ball, kid, m = mem.ball, mem.kid, len(mem.nxt)
    far = np.sqrt(best)
    top = 0
    stack[0] = root
    while top >= 0:
        x = stack[top]
        top -= 1
        e0, e1, e2 = g0 - ball[x, 0], g1 - ball[x, 1], g2 - ball[x, 2]
        if far < np.inf:
            lim = (1.0 + 1e-9) * (far + ball[x, 3])
            if e0 * e0 + e1 * e1 + e2 * e2 > lim * lim:
                continue
        if x >= m:
            u, v = kid[x, 0], kid[x, 1]
            du = (g0 - ball[u, 0]) ** 2 + (g1 - ball[u, 1]) ** 2 + (g2 - ball[u, 2]) ** 2
            dv = (g0 - ball[v, 0]) ** 2 + (g1 - ball[v, 1]) ** 2 + (g2 - ball[v, 2]) ** 2
            if du < dv:
                u, v = v, u
            stack[top + 1], stack[top + 2] = u, v            # the nearer (v) on top
            top += 2
            continue
        for k in range(mem.vf0_start[x], mem.vf0_start[x] + mem.vf0_cnt[x]):
            t = tri[mem.vf0_pool[k]]
            e0, e1, e2 = g0 - t[0], g1 - t[1], g2 - t[2]
            if far < np.inf:
                lim = (1.0 + 1e-9) * (far + t[3])
                if e0 * e0 + e1 * e1 + e2 * e2 > lim * lim:
                    continue
            d = point_triangle_distance2(g0, g1, g2, t[0], t[1], t[2], t[4], t[5], t[6], t[7], t[8], t[9])
            if d < best:
                best = d
                far = np.sqrt(d)
    return best


@njit(cache=True)
def face_error(a, b, nrem, F, pos, mem, pc, rem, stack):
    """The face-side error of collapsing (a, b): the mean squared distance of the new faces from the source.

    ``R = (1 / 2|rem|) sum_f (d(g_f, S_f)^2 + d(h_f, S_f)^2)`` over the new faces f around the merged vertex
    c (``rem[:nrem]``, with a and b at ``pc[0]``), ``g_f`` the centroid of f in the rest pose, ``h_f`` the
    midpoint of f's new edge from c to the corner that follows c in f (each edge of c's fan is that edge of
    one face), and ``S_f`` the source faces of the original vertices that f's three corners stand for
    (``mem``: a's and b's, and the two others'). The quadrics measure the new vertex against unbounded planes
    and ``S`` the source against the new faces; neither sees a new face that spreads within its plane over
    empty space (a grip's opening covered), ``R`` does: at its centre, and along the new edges, where a face
    whose centre stays on the source still cuts across a notch or a gap. The rest pose only: the example
    poses would multiply its cost by their number. A source face is skipped when it cannot be nearer than the
    nearest so far: a triangle lies within ``reach`` of its first corner A, so its distance is at least
    ``|g - A| - reach``, and a whole subtree of the merge tree when g is farther than ``best`` from its ball
    (:func:`_nearest_source`): the minimum is the same as without the tests.
    """
    tri = mem.tri0
    found = np.empty(2 * nrem)
    count = 0
    for i in range(nrem):
        f = rem[i]
        x, y, z = F[f, 0], F[f, 1], F[f, 2]
        X = pc[0] if (x == a or x == b) else pos[x, 0]
        Y = pc[0] if (y == a or y == b) else pos[y, 0]
        Z = pc[0] if (z == a or z == b) else pos[z, 0]
        N = Y if (x == a or x == b) else (Z if (y == a or y == b) else X)     # the corner after c
        g0 = (X[0] + Y[0] + Z[0]) / 3.0
        g1 = (X[1] + Y[1] + Z[1]) / 3.0
        g2 = (X[2] + Y[2] + Z[2]) / 3.0
        h0 = 0.5 * (pc[0, 0] + N[0])
        h1 = 0.5 * (pc[0, 1] + N[1])
        h2 = 0.5 * (pc[0, 2] + N[2])
        best = np.inf
        edge = np.inf
        for root in (a, b, -1 if (x == a or x == b) else x, -1 if (y == a or y == b) else y,
                     -1 if (z == a or z == b) else z):
            if root >= 0:
                best = _nearest_source(g0, g1, g2, root, mem, tri, best, stack)
                edge = _nearest_source(h0, h1, h2, root, mem, tri, edge, stack)
        if best < np.inf:
            found[count] = best
            found[count + 1] = edge
            count += 2
    if count == 0:
        return 0.0
    found = np.sort(found[:count])          # summed smallest first: the same sum in any order of the faces
    total = 0.0
    for i in range(count):
        total += found[i]
    return total / count


@njit(cache=True)
def surviving_faces(a, b, F, vf_start, vf_cnt, pool, rem):
    """``rem[:n]``: the faces of a without b, then those of b without a, as :func:`link_ok` lists them; returns n."""
    n = 0
    for i in range(vf_start[a], vf_start[a] + vf_cnt[a]):
        f = pool[i]
        if not (F[f, 0] == b or F[f, 1] == b or F[f, 2] == b):
            rem[n] = f
            n += 1
    for i in range(vf_start[b], vf_start[b] + vf_cnt[b]):
        f = pool[i]
        if not (F[f, 0] == a or F[f, 1] == a or F[f, 2] == a):
            rem[n] = f
            n += 1
    return n


@njit(parallel=True, cache=True)
def _measure(n, cand, kind, out, bent, rem, pc, Xw, q, o, stack, ea, eb, ev, ew, method, ip, fp, T, V, W, Qv, fixed,
             along, F, vf_start, vf_cnt, pool, pos, mem, face, tiny, min_normal_cos):
    """The body of :func:`speculate`, one candidate a thread. Its arrays are arguments: with numba 0.68,
    writes inside a parallel loop to an array reached through a named tuple were lost."""
    for i in prange(n):
        e = cand[i]
        a, b = ea[e], eb[e]
        if kind[i] == EVALUATE:
            out[i] = collapse_cost(method, a, b, placement(fixed[a], fixed[b], along[a], along[b]), V, W, Qv, T, ip,
                                   fp, ev[e], ew[e])
            continue
        nrem = surviving_faces(a, b, F, vf_start, vf_cnt, pool, rem[i])
        posed_point(ev[e], ew[e], T, pc[i], Xw[i])
        bent[i] = folded(a, b, nrem, F, pos, pc[i], rem[i], q[i], o[i], tiny, min_normal_cos)
        out[i] = 0.0 if bent[i] else source_error(a, b, nrem, F, pos, Qv, mem, pc[i], rem[i], stack[i], face)


@njit(cache=True)
def speculate(n, cm, mesh, vx, ed, mem, ah, cnt, tiny, min_normal_cos):
    """Do the work of the candidate edges ``ah.cand[:n]`` at once, one thread each: a dirty edge's true cost
    (:func:`evaluate_edge`), or a clean edge's fold-over guard (:func:`folds`) and, where it passes, its measured
    error (:func:`source_error`).

    Each gets its own work arrays (the faces left around it, :func:`surviving_faces`, and its new vertex posed,
    :func:`posed_point`), and nothing here writes the loop's state but a dirty edge's new vertex and weights,
    which only its evaluation reads: so each finds what its turn would find. ``ah`` keeps the results with e's
    stamp and, for a guard and error, the collapses made so far (``cnt``, which also counts the measured errors
    and the costs computed ahead): a cost holds while the stamp does
    (it depends on a and b alone), a guard and an error while neither changes around the edge either.
    """
    _measure(n, ah.cand, ah.kind, ah.out, ah.bent, ah.rem, ah.pc, ah.Xw, ah.q, ah.o, ah.stack, ed.ea, ed.eb, ed.ev,
             ed.ew, cm.method, cm.ip, cm.fp, cm.T, vx.V, vx.W, vx.Qv, mesh.boundary, mesh.along, mesh.F, mesh.vf_start,
             mesh.vf_cnt, mesh.pool, vx.pos, mem, cm.fp[5], tiny, min_normal_cos)
    for i in range(n):
        e = ah.cand[i]
        if ah.kind[i] == EVALUATE:
            ah.cost[e], ah.cstamp[e] = ah.out[i], ed.estamp[e]
            cnt[C_COSTED] += 1
        else:
            ah.val[e], ah.fold[e], ah.stamp[e], ah.time[e] = ah.out[i], ah.bent[i], ed.estamp[e], cnt[C_COLLAPSES]
            if not ah.bent[i]:
                cnt[C_MEASURED] += 1


@njit(cache=True)
def _unchanged(t, a, b, changed):
    """Whether a and b's faces are as they were after ``t`` collapses (``t`` -1: never measured)."""
    return t >= 0 and changed[a] <= t and changed[b] <= t


@njit(cache=True)
def _judged(e, mesh, ed, ah):
    """Whether ``ah`` holds the guard and measured error of clean edge e as its attempt would find them."""
    return ah.stamp[e] == ed.estamp[e] and _unchanged(ah.time[e], ed.ea[e], ed.eb[e], mesh.changed)


@njit(cache=True)
def _candidates(e, kind, mesh, ed, qu, cnt, ah):
    """``ah.cand[:n]``: e (needing ``kind``), then the next entries of the queue whose turn would do work, as many
    as ``ah`` has rows; returns n.

    A current dirty entry without its cost in ``ah`` is evaluated; a current clean one whose measured error is
    neither in its cost (``stime``) nor in ``ah`` is judged. The entries looked at (at most ``len(ah.hc)``) are
    queued again as they were, so the queue pops what it would have popped: its order is total (cost, stamp,
    edge)."""
    width = len(ah.cand)
    ah.cand[0], ah.kind[0] = e, kind
    n = 1
    held = 0
    while n < width and held < len(ah.hc) and cnt[C_HEAP] > 0:
        c, st, x = pop(qu.hc, qu.hs, qu.he, cnt)
        ah.hc[held], ah.hs[held], ah.he[held] = c, st, x
        held += 1
        if st != ed.estamp[x]:
            continue
        if ed.estate[x] == DIRTY:
            if ah.cstamp[x] == st:
                continue
            need = EVALUATE
        elif ed.estate[x] == CLEAN:
            if _unchanged(ed.stime[x], ed.ea[x], ed.eb[x], mesh.changed) or _judged(x, mesh, ed, ah):
                continue
            need = JUDGE
        else:
            continue
        new = True
        for k in range(n):
            if ah.cand[k] == x:
                new = False
        if new:
            ah.cand[n], ah.kind[n] = x, need
            n += 1
    for k in range(held):
        push(qu.hc, qu.hs, qu.he, cnt, ah.hc[k], ah.hs[k], ah.he[k], ed.estamp, ed.estate)
    return n


@njit(cache=True)
def _remove_face(v, f, vf_start, vf_cnt, pool):
    s, c = vf_start[v], vf_cnt[v]
    for i in range(s, s + c):
        if pool[i] == f:
            pool[i] = pool[s + c - 1]
            vf_cnt[v] = c - 1
            return


@njit(cache=True)
def _neighbours(x, F, vf_start, vf_cnt, pool, mark, tag, out):
    """Vertices sharing a face with x (marked with ``tag``) into ``out``; returns their count."""
    n = 0
    for i in range(vf_start[x], vf_start[x] + vf_cnt[x]):
        f = pool[i]
        for c in range(3):
            y = F[f, c]
            if y != x and mark[y] != tag:
                mark[y] = tag
                out[n] = y
                n += 1
    return n


@njit(cache=True)
def _seam_edge(x, y, F, vf_start, vf_cnt, pool, charts):
    """Whether edge (x, y) has exactly two faces and they lie in different charts."""
    f1 = -1
    f2 = -1
    n = 0
    s0 = vf_start[y]
    for i in range(vf_cnt[y]):
        f = pool[s0 + i]
        if F[f, 0] == x or F[f, 1] == x or F[f, 2] == x:
            if n == 0:
                f1 = f
            else:
                f2 = f
            n += 1
    return n == 2 and charts[f1] != charts[f2]


@njit(cache=True)
def placement(fixed_a, fixed_b, along_a, along_b):
    """:func:`rigslim.plugins.decimation.setup.placement` (the same rule, compiled)."""
    if not fixed_a and not fixed_b:
        return FREE
    if not fixed_b:
        return KEEP_A
    if not fixed_a:
        return KEEP_B
    if along_a == SEAM and along_b == SEAM:
        return FREE
    if along_a == BORDER and along_b == BORDER:
        return BEST
    if along_a != 0 and along_b == 0:
        return KEEP_B
    if along_a == 0 and along_b != 0:
        return KEEP_A
    return NONE


@njit(cache=True)
def _collapsible(x, y, boundary, along, F, vf_start, vf_cnt, pool, charts):
    """Whether edge (x, y) may collapse: :func:`placement` allows it and, with two fixed ends, it lies on
    their curve (a seam edge for seam vertices, a border edge, with one face, for border vertices)."""
    if placement(boundary[x], boundary[y], along[x], along[y]) == NONE:
        return False
    if not (boundary[x] and boundary[y]):
        return True
    n = 0
    f1 = -1
    f2 = -1
    s0 = vf_start[y]
    for i in range(vf_cnt[y]):
        f = pool[s0 + i]
        if F[f, 0] == x or F[f, 1] == x or F[f, 2] == x:
            if n == 0:
                f1 = f
            else:
                f2 = f
            n += 1
    if max(along[x], along[y]) == BORDER:
        return n == 1
    return n == 2 and charts[f1] != charts[f2]


@njit(cache=True)
def evaluate_edge(e, cm, vx, ed, qu, cnt, fixed, along, ah):
    """Give the dirty edge e its true cost (:func:`collapse_cost` with the edge's :func:`placement`; computed
    ahead by :func:`speculate` when ``ah`` holds it at e's stamp) and queue it again."""
    a, b = ed.ea[e], ed.eb[e]
    cnt[C_EVALS] += 1
    if ah.cstamp[e] == ed.estamp[e]:
        ed.ecost[e] = ah.cost[e]
    else:
        ed.ecost[e] = collapse_cost(cm.method, a, b, placement(fixed[a], fixed[b], along[a], along[b]), vx.V, vx.W,
                                    vx.Qv, cm.T, cm.ip, cm.fp, ed.ev[e], ed.ew[e])
    ed.estate[e] = CLEAN
    ed.esrc[e] = 0.0
    ed.stime[e] = -1
    ed.estamp[e] += 1
    push(qu.hc, qu.hs, qu.he, cnt, ed.ecost[e], ed.estamp[e], e, ed.estamp, ed.estate)


@njit(cache=True)
def link_ok(a, b, mesh, cnt, s):
    """Faces around edge (a, b) and the link condition.

    Fills ``s.fab`` (the faces of the edge), ``s.rem`` (the faces that survive, around a or b) and
    ``s.uni`` (the union of the neighbours of a and b, without them). Returns ``(ok, nrem, nu, nfab)``: ok
    when the edge has two faces and a and b have exactly two common neighbours (or, for a collapse along
    a border, both ends fixed: one face and one common neighbour; or, at a non-manifold edge, 3 to
    ``MAX_EDGE_FACES`` faces and as many common neighbours: Dey et al. 1999's link condition), the union has
    three or more vertices and at least four faces would be left.
    """
    F, vf_start, vf_cnt, pool, mark = mesh.F, mesh.vf_start, mesh.vf_cnt, mesh.pool, mesh.mark
    fab, rem, uni, Na, Nb = s.fab, s.rem, s.uni, s.Na, s.Nb
    nfab, nrem, nu = 0, 0, 0
    for i in range(vf_start[a], vf_start[a] + vf_cnt[a]):
        f = pool[i]
        if F[f, 0] == b or F[f, 1] == b or F[f, 2] == b:
            if nfab < len(fab):
                fab[nfab] = f
            nfab += 1
        else:
            rem[nrem] = f
            nrem += 1
    border = nfab == 1 and mesh.boundary[a] and mesh.boundary[b]
    junction = 2 < nfab <= len(fab)                 # a non-manifold edge: a fin or flap meeting a body
    if nfab != 2 and not border and not junction:
        return False, nrem, nu, nfab
    for i in range(vf_start[b], vf_start[b] + vf_cnt[b]):
        f = pool[i]
        if not (F[f, 0] == a or F[f, 1] == a or F[f, 2] == a):
            rem[nrem] = f
            nrem += 1
    cnt[C_TAG] += 1
    ta = cnt[C_TAG]
    na = _neighbours(a, F, vf_start, vf_cnt, pool, mark, ta, Na)
    cnt[C_TAG] += 1
    tb = cnt[C_TAG]
    nb = _neighbours(b, F, vf_start, vf_cnt, pool, mark, tb, Nb)
    # mark now says tb for Nb's vertices; Na's vertices not in Nb keep ta
    common = 0
    for i in range(nb):
        y = Nb[i]
        if y != a and y != b:
            uni[nu] = y
            nu += 1
    for i in range(na):
        y = Na[i]
        if y == a or y == b:
            continue
        if mark[y] == tb:
            common += 1
        else:
            uni[nu] = y
            nu += 1
    return common == nfab and nu >= 3 and cnt[C_FACES] - nfab >= 4, nrem, nu, nfab


@njit(cache=True)
def posed_vertex(v, w, T, s):
    """``s.pc``: the new vertex at rest (v) and in each example pose j, ``sum_k w_k T_k^j [v; 1]``."""
    posed_point(v, w, T, s.pc, s.Xw)


@njit(cache=True)
def posed_point(v, w, T, pc, Xw):
    """:func:`posed_vertex` into ``pc`` ((poses + 1, 3)), ``Xw`` a 3 x 4 work array."""
    P, n = T.shape[0], T.shape[1]
    for t in range(3):
        pc[0, t] = v[t]
    for j in range(P):
        for r in range(3):
            for c in range(4):
                acc = 0.0
                for k in range(n):
                    acc += w[k] * T[j, k, r, c]
                Xw[r, c] = acc
        for r in range(3):
            pc[j + 1, r] = Xw[r, 0] * v[0] + Xw[r, 1] * v[1] + Xw[r, 2] * v[2] + Xw[r, 3]


@njit(cache=True)
def folds(a, b, v, w, nrem, mesh, vx, cm, s, tiny, min_normal_cos):
    """Whether moving a and b to the new vertex folds a surviving face, in the rest pose or any example pose.

    Fills ``s.pc`` with the new vertex's positions (:func:`posed_vertex`). A face
    folds when its normal turns by more than ``arccos(min_normal_cos)``, or degenerates (``|n| <= tiny``).
    """
    posed_vertex(v, w, cm.T, s)
    return folded(a, b, nrem, mesh.F, vx.pos, s.pc, s.rem, s.q, s.o, tiny, min_normal_cos)


@njit(cache=True)
def folded(a, b, nrem, F, pos, pc, rem, q, o, tiny, min_normal_cos):
    """:func:`folds` with the new vertex already posed (``pc``) and explicit work arrays (3 x 3 ``q``, ``o``)."""
    P1 = pos.shape[1]
    for i in range(nrem):
        f = rem[i]
        for j in range(P1):
            for c in range(3):
                x = F[f, c]
                for t in range(3):
                    o[c, t] = pos[x, j, t]
                    q[c, t] = pc[j, t] if (x == a or x == b) else pos[x, j, t]
            u0, u1, u2 = o[1, 0] - o[0, 0], o[1, 1] - o[0, 1], o[1, 2] - o[0, 2]
            w0, w1, w2 = o[2, 0] - o[0, 0], o[2, 1] - o[0, 1], o[2, 2] - o[0, 2]
            no0, no1, no2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
            u0, u1, u2 = q[1, 0] - q[0, 0], q[1, 1] - q[0, 1], q[1, 2] - q[0, 2]
            w0, w1, w2 = q[2, 0] - q[0, 0], q[2, 1] - q[0, 1], q[2, 2] - q[0, 2]
            nn0, nn1, nn2 = u1 * w2 - u2 * w1, u2 * w0 - u0 * w2, u0 * w1 - u1 * w0
            lo = np.sqrt(no0 * no0 + no1 * no1 + no2 * no2)
            ln = np.sqrt(nn0 * nn0 + nn1 * nn1 + nn2 * nn2)
            dot = no0 * nn0 + no1 * nn1 + no2 * nn2
            if lo > tiny and (ln <= tiny or dot < min_normal_cos * lo * ln):
                return True
    return False


@njit(cache=True)
def apply_collapse(e, a, b, nrem, nfab, mesh, vx, ed, cnt, s, mem):
    """Collapse edge e = (a, b) into a new vertex c; returns ``(c, cost of e)``.

    The new vertex takes the edge's position, weights and poses (``s.pc``) and the sum of the quadrics;
    the edge's two faces go, the surviving faces (``s.rem``) point at c, and c's face list is appended
    to the pool (compacted when full). A collapse along a seam makes c a seam vertex; a half-edge
    collapse onto a fixed end makes c fixed, of that end's class.
    """
    F, vf_start, vf_cnt, pool = mesh.F, mesh.vf_start, mesh.vf_cnt, mesh.pool
    boundary, along, fab, rem = mesh.boundary, mesh.along, s.fab, s.rem
    N = len(vx.V)
    m = N // 2
    c = m + cnt[C_COLLAPSES]
    vx.V[c] = ed.ev[e]
    vx.W[c] = ed.ew[e]
    vx.pos[c] = s.pc
    vx.Qv[c] = vx.Qv[a] + vx.Qv[b]
    mem.head[c] = mem.head[a]             # c stands for the originals of a, then those of b
    mem.nxt[mem.tail[a]] = mem.head[b]
    mem.tail[c] = mem.tail[b]
    mem.kid[c, 0], mem.kid[c, 1] = a, b
    mem.size[c] = mem.size[a] + mem.size[b]
    merge_ball(mem.ball, a, b, c)
    # along its curve c stays on it; onto a corner or a fixed end it takes that end's class
    if boundary[a] and boundary[b]:
        along[c] = along[a] if along[a] == along[b] else 0
    elif boundary[a] or boundary[b]:
        along[c] = along[a] if boundary[a] else along[b]
    boundary[c] = boundary[a] or boundary[b]
    for i in range(nfab):
        f = fab[i]
        for t in range(3):
            x = F[f, t]
            if x != a and x != b:
                _remove_face(x, f, vf_start, vf_cnt, pool)
    for i in range(nrem):
        f = rem[i]
        for t in range(3):
            if F[f, t] == a or F[f, t] == b:
                F[f, t] = c
    vf_cnt[a] = 0
    vf_cnt[b] = 0
    if cnt[C_POOL] + nrem > len(pool):    # compact the vertex-face lists
        tmp = pool.copy()
        k = 0
        for x in range(N):
            if vf_cnt[x] > 0:
                s0 = vf_start[x]
                for i in range(vf_cnt[x]):
                    pool[k + i] = tmp[s0 + i]
                vf_start[x] = k
                k += vf_cnt[x]
        cnt[C_POOL] = k
    vf_start[c] = cnt[C_POOL]
    vf_cnt[c] = nrem
    for i in range(nrem):
        pool[cnt[C_POOL] + i] = rem[i]
    cnt[C_POOL] += nrem
    cnt[C_FACES] -= nfab
    cost_ab = ed.ecost[e]
    edge_kill(e, N, ed.ea, ed.eb, ed.estate, ed.free, cnt, ed.hk, ed.hv)
    return c, cost_ab


@njit(cache=True)
def requeue(a, b, c, cost_ab, nu, mesh, ed, qu, cnt, s, Qv, normalised, zero):
    """Replace the edges (a, x) and (b, x) by (c, x) for every neighbour x, in increasing order of x.

    Each new edge is queued with the lower bound ``max(cost(a, x), cost(b, x), cost(a, b), floor(c, x))``
    (normalised costs: ``max(E(a, x), E(b, x), E(a, b), floor) / (w_a + w_b + w_x)``, the unnormalised errors
    ``E`` over the new edge's weight; ``floor``: the sum of its summed quadrics' per-pose minima,
    :func:`rigslim.plugins.decimation.edge_costs.quadric_floor`, 0 below the zero cost ``zero``) and marked
    dirty (unless both c and x are fixed and the edge is no seam edge); edges at x that a guard blocked earlier
    are queued again.
    """
    F, vf_start, vf_cnt, pool, mark = mesh.F, mesh.vf_start, mesh.vf_cnt, mesh.pool, mesh.mark
    boundary, along, charts = mesh.boundary, mesh.along, mesh.charts
    ea, eb, ecost, estamp, estate, free, hk, hv = ed.ea, ed.eb, ed.ecost, ed.estamp, ed.estate, ed.free, ed.hk, ed.hv
    uni, nbr = s.uni, s.nbr
    N = len(mark)
    # union in increasing order (the Python loop does the same)
    for i in range(1, nu):
        y = uni[i]
        k = i - 1
        while k >= 0 and uni[k] > y:
            uni[k + 1] = uni[k]
            k -= 1
        uni[k + 1] = y
    wa = quadric_weight(Qv, a) if normalised else 1.0
    wb = quadric_weight(Qv, b) if normalised else 1.0
    for i in range(nu):
        x = uni[i]
        mesh.changed[x] = cnt[C_COLLAPSES] + 1       # x's faces now have c for a or b
        wx = quadric_weight(Qv, x) if normalised else 0.0
        lb = cost_ab * (wa + wb) if normalised else cost_ab
        for y in (a, b):
            eo = edge_of(x, y, N, hk, hv)
            if eo >= 0:
                wy = wa if y == a else wb
                lb = max(lb, ecost[eo] * (wy + wx) if normalised else ecost[eo])
                edge_kill(eo, N, ea, eb, estate, free, cnt, hk, hv)
        if not _collapsible(x, c, boundary, along, F, vf_start, vf_cnt, pool, charts):
            continue
        lb = max(lb, quadric_floor(Qv, c, x))
        if normalised:
            lb = lb / (wa + wb + wx) if wa + wb + wx > 0 else lb
        if lb < zero:
            lb = 0.0
        en = edge_add(x, c, N, ea, eb, estamp, free, cnt, hk, hv)
        ed.stime[en] = -1
        ecost[en] = lb
        estate[en] = DIRTY
        push(qu.hc, qu.hs, qu.he, cnt, lb, estamp[en], en, estamp, estate)
        # edges at x blocked earlier may collapse now
        cnt[C_TAG] += 1
        k = _neighbours(x, F, vf_start, vf_cnt, pool, mark, cnt[C_TAG], nbr)
        for t in range(k):
            eb_ = edge_of(x, nbr[t], N, hk, hv)
            if eb_ >= 0 and estate[eb_] == BLOCKED:
                estate[eb_] = CLEAN
                push(qu.hc, qu.hs, qu.he, cnt, ecost[eb_], estamp[eb_], eb_, estamp, estate)


@njit(cache=True)
def collapse_chunk(max_steps, min_faces, min_normal_cos, tiny, cm, mesh, vx, ed, qu, rec, s, mem, ah):
    """Run up to ``max_steps`` greedy collapses; returns True when the simplification has finished.

    Every array is the loop's state and is updated in place (see
    :func:`rigslim.plugins.decimation.collapse.simplify`): pop the cheapest edge, skip stale entries,
    re-evaluate a dirty edge, else try the collapse (:func:`link_ok`,
    :func:`folds`), block the edge if a guard refuses it, or :func:`apply_collapse`, :func:`requeue`
    and record it.
    """
    cnt = rec.cnt
    measured = cm.fp[4] != 0.0
    for _ in range(max_steps):
        if cnt[C_FACES] <= min_faces:
            return True
        done = False
        while cnt[C_HEAP] > 0:
            cost, stamp, e = pop(qu.hc, qu.hs, qu.he, cnt)
            cnt[C_POPS] += 1
            state = ed.estate[e]
            if stamp != ed.estamp[e] or state == DEAD or state == BLOCKED:
                continue
            if state == DIRTY:               # its true cost, queued again
                evaluate_edge(e, cm, vx, ed, qu, cnt, mesh.boundary, mesh.along, ah)
                continue
            cnt[C_TRIES] += 1
            a, b = ed.ea[e], ed.eb[e]
            ok, nrem, nu, nfab = link_ok(a, b, mesh, cnt, s)
            # S was added with nothing around a and b changed since: the guards and S would give what they gave
            same = _unchanged(ed.stime[e], a, b, mesh.changed)
            # judged ahead (speculate) with nothing around a and b changed since: its guard and S as they were
            ahead = ok and not same and _judged(e, mesh, ed, ah)
            if ahead:
                cnt[C_AHEAD] += 1
            elif ok and not same and measured and len(ah.cand) > 1:   # judge it and the next candidates at once
                n = _candidates(e, JUDGE, mesh, ed, qu, cnt, ah)
                speculate(n, cm, mesh, vx, ed, mem, ah, cnt, tiny, min_normal_cos)
                ahead = True
            if ahead:
                posed_vertex(ed.ev[e], ed.ew[e], cm.T, s)
                ok = not ah.fold[e]
            elif ok and not same:            # fold-over guard in the rest pose and every example pose
                ok = not folds(a, b, ed.ev[e], ed.ew[e], nrem, mesh, vx, cm, s, tiny, min_normal_cos)
            elif ok:
                posed_vertex(ed.ev[e], ed.ew[e], cm.T, s)
            if not ok:
                ed.estate[e] = BLOCKED
                continue
            if measured and not same:        # the source-side error S, added to the quadric cost when first seen
                if ahead:
                    h = ah.val[e]
                else:
                    h = source_error(a, b, nrem, mesh.F, vx.pos, vx.Qv, mem, s.pc, s.rem, mem.stack,
                                     cm.fp[5])
                    cnt[C_MEASURED] += 1
                if h < cm.fp[2]:
                    h = 0.0
                if h > ed.esrc[e]:           # not yet in its cost: add it and queue the edge again
                    ed.ecost[e] += h - ed.esrc[e]
                    ed.esrc[e] = h
                    ed.stime[e] = cnt[C_COLLAPSES]
                    ed.estamp[e] += 1
                    push(qu.hc, qu.hs, qu.he, cnt, ed.ecost[e], ed.estamp[e], e, ed.estamp, ed.estate)
                    continue
            c, cost_ab = apply_collapse(e, a, b, nrem, nfab, mesh, vx, ed, cnt, s, mem)
            requeue(a, b, c, cost_ab, nu, mesh, ed, qu, cnt, s, vx.Qv, cm.fp[3] != 0.0, cm.fp[2])
            i = cnt[C_COLLAPSES]
            rec.col[i, 0], rec.col[i, 1] = a, b
            rec.errs[i] = cost_ab
            rec.nfaces[i] = cnt[C_FACES]
            cnt[C_COLLAPSES] += 1
            done = True
            break
        if not done:
            return True
    return cnt[C_FACES] <= min_faces
