"""The source-side error (``source_distance``): thin protrusions survive the levels, in both backends."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit, Poses
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.collapse import point_triangle_distances2
from rigslim.plugins.decimation.compiled import point_triangle_distance2

FIN_HEIGHT = 1.0


def finned_ring(n_around: int = 24, n_edge: int = 3, fin: float = 0.02, R: float = 3.0):
    """A closed ring (a square profile revolved about z) with a thin wedge-shaped fin on top, ``fin`` thick at
    its foot and ``FIN_HEIGHT`` high: its two sides meet at the crest, so moving a crest vertex down the fin
    leaves every plane of its faces within ``fin / 2`` per unit of height. Returns (V, F, crest vertices)."""
    prof = [(0.0, 0.0), (2.0, 0.0), (2.0, 1.0), (1.0 + fin / 2, 1.0), (1.0, 1.0 + FIN_HEIGHT), (1.0 - fin / 2, 1.0),
            (0.0, 1.0)]
    P = np.array([(1 - t) * np.array(p) + t * np.array(q)
                  for p, q in zip(prof, prof[1:] + prof[:1], strict=True) for t in np.linspace(0, 1, n_edge, False)])
    k = len(P)
    th = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    V = np.array([[(R + x) * np.cos(t), (R + x) * np.sin(t), z] for t in th for x, z in P])
    F = []
    for i in range(n_around):
        for j in range(k):
            a, b = i * k + j, i * k + (j + 1) % k
            c, d = (i + 1) % n_around * k + j, (i + 1) % n_around * k + (j + 1) % k
            F += [[a, c, d], [a, d, b]]
    return V, np.array(F), np.flatnonzero(np.isclose(V[:, 2], 1.0 + FIN_HEIGHT))


def rigid_asset(V, F, n_poses: int = 6, seed: int = 0) -> Asset:
    """One bone turning about z: every example pose shows the same shape (the quartic error is QSlim's)."""
    rng = np.random.default_rng(seed)
    T = np.zeros((n_poses, 1, 3, 4))
    for p in range(n_poses):
        th = 0.0 if p == 0 else rng.uniform(-0.5, 0.5)
        T[p, 0, :3, :3] = [[np.cos(th), -np.sin(th), 0], [np.sin(th), np.cos(th), 0], [0, 0, 1]]
    split = FrameSplit.from_specs(list(range(0, n_poses, 2)), list(range(1, n_poses, 2)), n_poses)
    return Asset(mesh=Mesh(V, F), weights=sp.csr_matrix(np.ones((len(V), 1))), poses=Poses(T), split=split)


def fin_level(backend: str, source_distance: bool | None, target: float = 0.25, jitter: float = 0.0,
              method: str = "quartic"):
    """The finned ring simplified to ``target``; ``source_distance=None`` leaves the parameter to the default."""
    V, F, crest = finned_ring()
    V = V + jitter * np.random.default_rng(1).normal(size=V.shape)     # no ties between rotated copies
    asset = rigid_asset(V, F)
    plugin = get_host().get("articulated-decimation", method)
    params = {"targets": [target], "backend": backend}
    if source_distance is not None:
        params["source_distance"] = source_distance
    plugin.apply(asset, plugin.parse_params(params), StepContext())
    return V, crest, asset.hierarchy, asset.levels[0]


def surface_distance(points: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Distance from each point to the triangle mesh (V, F), by brute force."""
    T = V[F]
    d2 = point_triangle_distances2(points[:, None], T[None, :, 0], T[None, :, 1], T[None, :, 2])
    return np.sqrt(d2.min(axis=1))


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_thin_fin_survives_the_level(backend):
    """At 25 % of the faces the fin's crest stays where it was with the source-side error; without it the
    plane quadrics, which hardly see a vertex move down its own fin, flatten the whole fin."""
    V, crest, _, lv = fin_level(backend, True)
    lost = surface_distance(V[crest], lv.mesh.V, np.asarray(lv.mesh.F))
    assert lost.max() < 1e-3 * FIN_HEIGHT
    assert lv.mesh.V[:, 2].max() <= 1.0 + FIN_HEIGHT + 1e-6        # and no spike above it
    V, crest, _, lv = fin_level(backend, False)
    flattened = surface_distance(V[crest], lv.mesh.V, np.asarray(lv.mesh.F))
    assert flattened.min() > 0.9 * FIN_HEIGHT


def test_quartic_keeps_the_fin_by_default_and_the_baselines_do_not_add_the_term():
    """``quartic`` (and so ``rigslim lod``) adds the source-side error unless told not to; the baselines keep
    their quadric costs: the same hierarchy as with ``source_distance: false``."""
    V, crest, _, lv = fin_level("numba", None)
    assert surface_distance(V[crest], lv.mesh.V, np.asarray(lv.mesh.F)).max() < 1e-3 * FIN_HEIGHT
    _, _, by_default, _ = fin_level("numba", None, method="mohr-gleicher")
    _, _, off, _ = fin_level("numba", False, method="mohr-gleicher")
    np.testing.assert_array_equal(by_default.collapses, off.collapses)


def test_both_backends_make_the_same_collapses_with_the_source_error():
    """The source-side error requeues edges in both loops alike: the same collapses, the same errors (on a
    jittered ring, whose rotated copies of an edge do not tie)."""
    _, _, h0, _ = fin_level("numpy", True, 0.1, jitter=1e-3)
    _, _, h1, _ = fin_level("numba", True, 0.1, jitter=1e-3)
    assert h0.n_collapses == h1.n_collapses > 400
    np.testing.assert_array_equal(h1.collapses, h0.collapses)
    np.testing.assert_allclose(h1.errors, h0.errors, rtol=1e-5, atol=1e-15)


def brute_distance2(p, a, b, c):
    """Squared point-triangle distance without Voronoi regions: the plane's foot if it lies inside the
    triangle (barycentric coordinates by least squares), else the nearest of the three edges."""
    def segment(x, y):
        t = np.clip((p - x) @ (y - x) / max((y - x) @ (y - x), 1e-300), 0.0, 1.0)
        return float(np.sum((p - x - t * (y - x)) ** 2))

    best = min(segment(a, b), segment(b, c), segment(c, a))
    M = np.stack([b - a, c - a], axis=1)
    uv, *_ = np.linalg.lstsq(M, p - a, rcond=None)
    if uv.min() >= 0 and uv.sum() <= 1:
        best = min(best, float(np.sum((p - a - M @ uv) ** 2)))
    return best


def test_point_triangle_distances_match_a_brute_force_and_the_compiled_kernel():
    rng = np.random.default_rng(3)
    p, a, b, c = (rng.normal(size=(400, 3)) for _ in range(4))
    c[:20] = a[:20] + 0.5 * (b[:20] - a[:20])            # degenerate (collinear) triangles
    c[20:30], b[20:30] = a[20:30], a[20:30]             # triangles that are a point
    p[30:60] = a[30:60] + rng.uniform(0, 1, (30, 1)) * (b[30:60] - a[30:60])     # points on an edge
    ref = np.array([brute_distance2(*x) for x in zip(p, a, b, c, strict=True)])
    got = point_triangle_distances2(p, a, b, c)
    compiled = np.array([point_triangle_distance2(*x[0], *x[1], *x[2], *x[3]) for x in zip(p, a, b, c, strict=True)])
    np.testing.assert_allclose(got, ref, rtol=1e-9, atol=1e-12)
    np.testing.assert_array_equal(compiled, got)


def _face_errors(V, F, a, b, pc):
    """The compiled and the numpy face-side error of collapsing (a, b) of the mesh (V, F), no vertex merged
    before, to ``pc`` (rest position)."""
    from rigslim.plugins.decimation import compiled as cc
    from rigslim.plugins.decimation.collapse import _CollapseLoop, _vertex_faces

    F = np.asarray(F, np.int64)
    m = len(V)
    faces = [{f for f in range(len(F)) if x in F[f]} for x in range(m)]
    rem = sorted((faces[a] | faces[b]) - (faces[a] & faces[b]))
    mem = cc.new_members(m, F, _vertex_faces(F, m), V)
    z = np.zeros(1, np.int64)
    mesh = cc.LoopMesh(F.copy(), z, z, z, np.zeros(1, bool), z, z, z, z)
    pos = np.zeros((2 * m, 2, 3))
    pos[:m, 0] = pos[:m, 1] = V
    vx = cc.LoopVertices(pos[:, 0].copy(), np.ones((2 * m, 1)), np.zeros((2 * m, 1, 4, 4)), pos)
    s = cc.new_scratch(max(len(rem), 1))
    s.rem[:len(rem)] = rem
    s.pc[:] = pc
    compiled = cc.face_error(a, b, len(rem), mesh.F, vx.pos, mem, s.pc, s.rem, mem.stack)
    ref = _CollapseLoop.__new__(_CollapseLoop)          # only what face_error reads
    ref.Fm, ref.F0 = F, F
    ref.st = type("St", (), {"pos": pos})()
    ref.vf0 = faces
    ref.members = lambda x: [x]
    return compiled, ref.face_error(a, b, rem, np.tile(np.asarray(pc, float), (2, 1)))


def _unit_square_face_error(pc):
    """:func:`_face_errors` of collapsing (1, 2) of a unit square of two triangles (0, 1, 2), (0, 2, 3) to
    ``pc``: the one new face is (0, c, 3)."""
    V = np.array([[0.0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]])
    return _face_errors(V, [[0, 1, 2], [0, 2, 3]], 1, 2, pc)


def test_the_face_side_error_is_the_new_faces_distance_from_the_source():
    """(1, 2) collapses to (1, 0.5, h): the new face (0, c, 3) has its centroid (1/3, 1/2, h/3) and its new
    edge's midpoint, from c to the corner after it (3), (1/2, 3/4, h/2) above the square, so
    R = ((h/3)^2 + (h/2)^2) / 2. Placed back in the plane, R = 0."""
    for h, want in ((0.3, ((0.3 / 3) ** 2 + (0.3 / 2) ** 2) / 2), (0.0, 0.0)):
        for got in _unit_square_face_error([1.0, 0.5, h]):
            assert got == pytest.approx(want, rel=1e-12, abs=1e-15)


def test_the_face_side_error_sees_a_new_edge_that_leaves_the_source():
    """In the plane, c at (2.5, 0.2): the new face (0, c, 3) has its centroid (0.833, 0.4) on the square, but
    its new edge's midpoint (1.25, 0.6) lies 0.25 beyond the square's side x = 1. A centroid alone measured
    0; with the midpoint R = (0 + 0.25^2) / 2."""
    compiled, ref = _unit_square_face_error([2.5, 0.2, 0.0])
    assert compiled == pytest.approx(0.25 ** 2 / 2, rel=1e-12)
    assert ref == compiled


def notched_fan(n: int = 8):
    """A flat regular n-gon fan (centre 0, ring 1..n, z = 0) with the triangle (0, 1, 2) cut out: a notch."""
    th = 2 * np.pi * np.arange(n) / n
    V = np.vstack([[0.0, 0, 0], np.c_[np.cos(th), np.sin(th), np.zeros(n)]])
    F = [[0, 1 + i, 1 + (i + 1) % n] for i in range(1, n)]
    return V, np.array(F)


def test_the_face_side_error_of_a_fan_is_the_mean_over_its_samples():
    """The notched fan's centre collapses onto ring vertex 3 (at 90 degrees): of its five new faces only
    (3, 8, 1) has samples over the notch (its centroid and its new edge's midpoint, 0.10 and 0.15 from the
    source); the other eight samples lie on the source. R is the mean of the ten samples' squared distances
    to the faces of their corners' originals (a brute force here), in both backends. (The mean divides one
    face's error over a gap by the fan's size; a cost with the largest sample in it was measured on the
    sweep and dropped: docs/simplification.md, "The largest sample".)"""
    V, F = notched_fan()
    a, b = 0, 3
    c = V[b]
    rem = [f for f in range(len(F)) if (a in F[f]) != (b in F[f])]
    samples = []
    for f in rem:
        corners = np.array([c if x in (a, b) else V[x] for x in F[f]])
        after = corners[(list(F[f]).index(a if a in F[f] else b) + 1) % 3]
        owners = {a, b} | {int(x) for x in F[f]}
        S = V[F[[g for g in range(len(F)) if owners & set(F[g].tolist())]]]
        for p in (corners.mean(axis=0), 0.5 * (c + after)):
            samples.append(float(point_triangle_distances2(p[None, None], S[None, :, 0], S[None, :, 1],
                                                           S[None, :, 2]).min()))
    samples = np.array(samples)
    assert samples.max() > 0.01 and np.count_nonzero(samples > 1e-12) == 2     # one face over the notch
    compiled, ref = _face_errors(V, F, a, b, c)
    assert compiled == pytest.approx(samples.mean(), rel=1e-12)
    assert ref == pytest.approx(compiled, rel=1e-12)


def merged_members(V, F, order):
    """``new_members`` of (V, F), then the vertices merged pairwise in ``order`` (pairs of current vertex ids;
    the i-th merge makes vertex m + i), as the compiled loop's ``apply_collapse`` links them."""
    from rigslim.plugins.decimation import compiled as cc
    from rigslim.plugins.decimation.collapse import _vertex_faces

    m = len(V)
    mem = cc.new_members(m, F, _vertex_faces(F, m), V)
    for i, (a, b) in enumerate(order):
        c = m + i
        mem.head[c] = mem.head[a]
        mem.nxt[mem.tail[a]] = mem.head[b]
        mem.tail[c] = mem.tail[b]
        mem.kid[c] = a, b
        mem.size[c] = mem.size[a] + mem.size[b]
        cc.merge_ball(mem.ball, a, b, c)
    return mem


def random_merges(m: int, rng, n: int) -> list[tuple[int, int]]:
    """``n`` merges of random pairs of live vertices."""
    live, out = list(range(m)), []
    for i in range(n):
        a, b = rng.choice(len(live), 2, replace=False)
        out.append((live[a], live[b]))
        live = [x for j, x in enumerate(live) if j not in (a, b)] + [m + i]
    return out


def test_the_merge_tree_search_finds_the_nearest_source_face_of_a_brute_force():
    """Every merged vertex's ball holds its originals' faces, and the pruned depth-first search returns the
    exact minimum over them (the face-side error's nearest source face)."""
    from rigslim.plugins.decimation import compiled as cc

    rng = np.random.default_rng(5)
    V, F, _ = finned_ring(n_around=16, n_edge=2)
    m = len(V)
    mem = merged_members(V, F, random_merges(m, rng, m - 4))
    faces_of = [set() for _ in range(2 * m)]
    for p in range(m):
        faces_of[p] = {int(f) for f in mem.vf0_pool[mem.vf0_start[p]:mem.vf0_start[p] + mem.vf0_cnt[p]]}
    for c in range(m, 2 * m - 4):
        faces_of[c] = faces_of[mem.kid[c, 0]] | faces_of[mem.kid[c, 1]]
        corners = V[F[sorted(faces_of[c])]].reshape(-1, 3)
        assert np.linalg.norm(corners - mem.ball[c, :3], axis=1).max() <= mem.ball[c, 3] * (1 + 1e-12)
    for c in rng.choice(np.arange(m, 2 * m - 4), 40, replace=False):
        fs = sorted(faces_of[c])
        for g in V.min(0) + rng.uniform(size=(5, 3)) * np.ptp(V, axis=0):
            want = point_triangle_distances2(g[None], V[F[fs, 0]], V[F[fs, 1]], V[F[fs, 2]]).min()
            got = cc._nearest_source(g[0], g[1], g[2], c, mem, mem.tri0, np.inf, mem.stack)
            assert got == pytest.approx(want, rel=1e-12, abs=1e-300)


def test_a_large_source_set_enters_the_source_error_as_a_spread_sample():
    """With more than SOURCE_SAMPLES originals under a and b, every s-th of their list is measured: the
    compiled error equals the weighted mean over that sample, computed by brute force."""
    from rigslim.plugins.decimation import compiled as cc
    from rigslim.plugins.decimation.setup import SOURCE_SAMPLES

    rng = np.random.default_rng(2)
    m = 3 * SOURCE_SAMPLES + 7
    V = rng.normal(size=(m, 3))
    F = np.array([[0, 1, 2], [1, 2, 3]], np.int64)
    order, ends = [], []
    for lo, hi in ((0, m // 2), (m // 2, m)):                                # a and b: two long chains
        x = lo
        for y in range(lo + 1, hi):
            order.append((x, y))
            x = m + len(order) - 1
        ends.append(x)
    mem = merged_members(V, F, order)
    a, b = ends
    pts = []
    for x in (a, b):
        p = mem.head[x]
        while p >= 0:
            pts.append(p)
            p = mem.nxt[p]
    assert sorted(pts) == list(range(m))
    P = 2
    pos = np.zeros((2 * m, P + 1, 3))
    pos[:m, 0] = V
    for j in range(P):
        pos[:m, j + 1] = V + 0.1 * (j + 1)
    Qv = np.zeros((2 * m, P, 4, 4))
    Qv[:m, :, 0, 0] = rng.uniform(0.5, 2.0, (m, P))
    vx = cc.LoopVertices(pos[:, 0].copy(), np.ones((2 * m, 1)), Qv, pos)
    Fl = np.array([[a, 10, 11], [a, 11, 12], [b, 12, 13]], np.int64)       # faces around the merged vertex
    z = np.zeros(1, np.int64)
    mesh = cc.LoopMesh(Fl, z, z, z, np.zeros(1, bool), z, z, z, z)
    s = cc.new_scratch(P)
    s.rem[:3] = [0, 1, 2]
    s.pc[:] = rng.normal(size=(P + 1, 3))
    got = cc.source_error(a, b, 3, mesh.F, vx.pos, vx.Qv, mem, s.pc, s.rem, mem.stack, False)
    sample = np.array(pts)[::-(-m // SOURCE_SAMPLES)]
    assert 300 < len(sample) <= SOURCE_SAMPLES
    num = den = 0.0
    for p in sample:
        for j in range(P):
            T = np.where(np.isin(Fl, [a, b])[..., None], s.pc[j + 1], pos[Fl, j + 1])
            d = point_triangle_distances2(np.repeat(pos[p, j + 1][None], 3, 0), T[:, 0], T[:, 1], T[:, 2]).min()
            num += Qv[p, j, 0, 0] * d
            den += Qv[p, j, 0, 0]
    assert got == pytest.approx(num / den, rel=1e-12)
