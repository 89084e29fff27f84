"""Per-pose quadrics and the alternating quartic solves (rigslim.plugins.decimation.quadrics)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.model.mesh import Mesh
from rigslim.plugins.decimation.quadrics import (
    alternate,
    bone_limit,
    per_pose_quadrics,
    position_step,
    quadric_error,
    quartic_error,
    vertex_quadrics,
    weight_step,
)


def bumpy_sphere(n=8, seed=1):
    """A small closed mesh: an octahedron midpoint-subdivided, projected to a bumpy sphere."""
    import igl

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(V, F, 2)
    V = V / np.linalg.norm(V, axis=1, keepdims=True)
    V *= 1.0 + 0.15 * np.random.default_rng(seed).random((len(V), 1))
    return Mesh(V, F)


def rigid(rng):
    A = rng.normal(size=(3, 3))
    R, _ = np.linalg.qr(A)
    R *= np.sign(np.linalg.det(R))
    return np.hstack([R, rng.normal(size=(3, 1))])


def test_vertex_quadrics_match_a_direct_sum_of_plane_distances():
    mesh = bumpy_sphere()
    Q = vertex_quadrics(mesh.V, mesh.F)
    p = np.array([0.3, -0.2, 0.5])
    for v in (0, 7, 30):
        d2 = 0.0
        for f in np.flatnonzero((mesh.F == v).any(axis=1)):
            a, b, c = mesh.V[mesh.F[f]]
            n = np.cross(b - a, c - a)
            area = 0.5 * np.linalg.norm(n)
            d2 += area * (np.dot(n / np.linalg.norm(n), p - a)) ** 2
        assert quadric_error(Q[v], p) == pytest.approx(d2, rel=1e-10)


def qslim_cost(Q, a, b, V):
    """Textbook QSlim edge cost: minimiser of v^T (Qa + Qb) v, else best of endpoints/midpoint."""
    q = Q[a] + Q[b]
    A, rhs = q[:3, :3], -q[:3, 3]
    if abs(np.linalg.det(A)) > 1e-10 * (np.trace(A) / 3) ** 3:
        return quadric_error(q, np.linalg.solve(A, rhs))
    return min(quadric_error(q, p) for p in (V[a], V[b], 0.5 * (V[a] + V[b])))


def test_one_bone_reduces_to_plain_qslim():
    """With one bone (rigid poses), the quartic cost is P times the rest-pose QSlim cost of every edge."""
    from rigslim.plugins.decimation.collapse import SimplifyState
    from rigslim.plugins.decimation.models import QuarticModel

    mesh = bumpy_sphere()
    rng = np.random.default_rng(3)
    T = np.stack([np.eye(3, 4)] + [rigid(rng) for _ in range(3)])[:, None]      # (P=4, n=1, 3, 4)
    W = sp.csr_matrix(np.ones((mesh.n_vertices, 1)))
    Q, X = per_pose_quadrics(mesh.V, mesh.F, W, T)
    st = SimplifyState(mesh.V, mesh.F, W.toarray(), T, X)
    E = mesh.edges
    v, w, cost = QuarticModel(Q).costs(st, E[:, 0], E[:, 1])
    Qrest = vertex_quadrics(mesh.V, mesh.F)
    direct = np.array([qslim_cost(Qrest, a, b, mesh.V) for a, b in E])
    assert np.allclose(cost, len(T) * direct, rtol=1e-7, atol=1e-12)
    assert np.allclose(w, 1.0)
    # and the first collapse of the hierarchy is QSlim's cheapest edge
    from rigslim.plugins.decimation.collapse import simplify

    hier = simplify(mesh.V, mesh.F, W.toarray(), T, X, QuarticModel(Q), min_faces=mesh.n_faces - 2)
    assert set(hier.collapses[0]) == set(E[np.argmin(direct)])


@pytest.fixture(scope="module")
def elephant_edges(elephant):
    """Per-pose quadrics of the elephant and a few of its edges as solver inputs."""
    T = elephant.example_poses().T
    Q, _ = per_pose_quadrics(elephant.mesh.V, elephant.mesh.F, elephant.weights, T)
    W = elephant.weights.toarray()
    E = elephant.mesh.edges[::997][:12]
    return elephant, Q, W, T, E


def edge_inputs(Q, W, T, V, E):
    mask_full = (W[E[:, 0]] != 0) | (W[E[:, 1]] != 0)
    K = int(mask_full.sum(axis=1).max())
    bones = np.argsort(~mask_full, axis=1, kind="stable")[:, :K]
    mask = np.take_along_axis(mask_full, bones, axis=1)
    a0 = np.take_along_axis(0.5 * (W[E[:, 0]] + W[E[:, 1]]), bones, axis=1) * mask
    Tb = np.ascontiguousarray(np.transpose(T[:, bones], (1, 2, 0, 3, 4)))       # (B, K, P, 3, 4)
    Qe = Q[E[:, 0]] + Q[E[:, 1]]
    fb = np.stack([V[E[:, 0]], V[E[:, 1]], 0.5 * (V[E[:, 0]] + V[E[:, 1]])], axis=1)
    return Qe, Tb, a0, mask, fb, bones


def test_alternation_never_increases_the_error(elephant_edges):
    asset, Q, W, T, E = elephant_edges
    Qe, Tb, a0, mask, fb, _ = edge_inputs(Q, W, T, asset.mesh.V, E)
    a = a0
    v, _ = position_step(Qe, Tb, a, fb)
    prev = quartic_error(Qe, Tb, a, v)
    for _ in range(8):
        a = weight_step(Qe, Tb, v, a0, mask)
        e_w = quartic_error(Qe, Tb, a, v)
        assert (e_w <= prev * (1 + 1e-9) + 1e-12).all()
        v, _ = position_step(Qe, Tb, a, fb)
        e_v = quartic_error(Qe, Tb, a, v)
        assert (e_v <= e_w * (1 + 1e-9) + 1e-12).all()
        prev = e_v
        assert np.allclose(a.sum(axis=1), 1.0)
        assert (a[~mask] == 0).all()


@pytest.mark.parametrize("method", ["pinv", "tikhonov"])
def test_exact_poses_recover_a_vertexs_own_position_and_weights(elephant_edges, method):
    asset, Q, W, T, _ = elephant_edges
    V = asset.mesh.V
    verts = np.array([5, 500, 1500, 3000, 4500])
    E = np.stack([verts, verts], axis=1)
    Qe, Tb, a_true, mask, fb, _ = edge_inputs(Q, W, T, V, E)
    Qv = Qe / 2                                        # the vertex's own quadrics
    v, _ = position_step(Qv, Tb, a_true, fb + 0.01)
    assert np.allclose(v, V[verts], atol=1e-7 * asset.mesh.bbox_diagonal)
    a = weight_step(Qv, Tb, V[verts], a_true, mask, method=method)
    assert np.allclose(a, a_true, atol=1e-6)
    # from perturbed weights the weight step finds zero error again (and, with enough poses, a itself)
    rng = np.random.default_rng(0)
    noise = rng.normal(scale=0.05, size=a_true.shape) * mask
    noise -= mask * (noise.sum(axis=1, keepdims=True) / mask.sum(axis=1, keepdims=True))
    a2 = weight_step(Qv, Tb, V[verts], a_true + noise, mask, method=method)
    assert (quartic_error(Qv, Tb, a2, V[verts]) < 1e-10 * asset.mesh.bbox_diagonal ** 2).all()
    v3, a3, e3 = alternate(Qv, Tb, a_true, mask, fb, iterations=5)
    assert np.allclose(v3, V[verts], atol=1e-7 * asset.mesh.bbox_diagonal) and np.allclose(a3, a_true, atol=1e-6)


def test_weight_step_matches_the_pseudo_inverse_and_a_general_solver(elephant_edges):
    """Tikhonov and pinv agree; both are constrained minimisers (checked with scipy's SLSQP)."""
    from scipy.optimize import minimize

    asset, Q, W, T, E = elephant_edges
    Qe, Tb, a0, mask, fb, _ = edge_inputs(Q, W, T, asset.mesh.V, E[:4])
    v, _ = position_step(Qe, Tb, a0, fb)
    ap = weight_step(Qe, Tb, v, a0, mask, method="pinv")
    at = weight_step(Qe, Tb, v, a0, mask, method="tikhonov")
    ep, et = quartic_error(Qe, Tb, ap, v), quartic_error(Qe, Tb, at, v)
    assert np.allclose(et, ep, rtol=1e-5, atol=1e-12)
    for b in range(len(v)):
        k = np.flatnonzero(mask[b])

        def f(x, b=b, k=k):
            a = np.zeros(mask.shape[1])
            a[k] = x
            return quartic_error(Qe[b:b + 1], Tb[b:b + 1], a[None], v[b:b + 1])[0]

        res = minimize(f, a0[b, k], constraints=[{"type": "eq", "fun": lambda x: x.sum() - 1}], method="SLSQP",
                       options={"ftol": 1e-14, "maxiter": 500})
        assert ep[b] <= res.fun * (1 + 1e-4) + 1e-10


def test_converged_alternation_is_stationary(elephant_edges):
    """At the alternation's end, v is a minimiser for a and a for v (each a convex subproblem)."""
    asset, Q, W, T, E = elephant_edges
    Qe, Tb, a0, mask, fb, _ = edge_inputs(Q, W, T, asset.mesh.V, E[:4])
    v, a, e = alternate(Qe, Tb, a0, mask, fb, iterations=200, tol=1e-12)
    v2, _ = position_step(Qe, Tb, a, fb)
    assert np.allclose(quartic_error(Qe, Tb, a, v2), e, rtol=1e-6)
    a2 = weight_step(Qe, Tb, v, a0, mask, method="pinv")
    assert np.allclose(quartic_error(Qe, Tb, a2, v), e, rtol=1e-4)


def test_bone_limit_keeps_the_largest_and_renormalises():
    a = np.array([[0.5, 0.3, 0.15, 0.05], [0.7, -0.1, 0.4, 0.0]])
    mask = a != 0
    out, keep = bone_limit(a, mask, 2)
    assert np.allclose(out, [[0.625, 0.375, 0, 0], [0.7 / 1.1, 0, 0.4 / 1.1, 0]])
    assert (keep.sum(axis=1) == 2).all()
    same, _ = bone_limit(a[:, :2], mask[:, :2], 2)
    assert np.array_equal(same, a[:, :2])


def test_alternate_with_bone_limit_restricts_the_result(elephant_edges):
    asset, Q, W, T, E = elephant_edges
    Qe, Tb, a0, mask, fb, _ = edge_inputs(Q, W, T, asset.mesh.V, E)
    v, a, e = alternate(Qe, Tb, a0, mask, fb, max_bones=3)
    assert (np.count_nonzero(a, axis=1) <= 3).all()
    assert np.allclose(a.sum(axis=1), 1.0)
    assert np.allclose(quartic_error(Qe, Tb, a, v), e)


def test_nonnegative_weight_step_matches_a_general_qp_solver(elephant_edges):
    """The non-negative weight step is the optimum of its QP (checked against Clarabel)."""
    import clarabel

    asset, Q, W, T, E = elephant_edges
    Qe, Tb, a0, mask, fb, _ = edge_inputs(Q, W, T, asset.mesh.V, E[:6])
    v, _ = position_step(Qe, Tb, a0, fb)
    ridge = 1e-9
    a = weight_step(Qe, Tb, v, a0, mask, nonnegative=True, ridge=ridge)
    assert (a >= 0).all() and np.allclose(a.sum(axis=1), 1.0) and (a[~mask] == 0).all()
    for b in range(len(v)):
        k = np.flatnonzero(mask[b])
        # H of the edge on its bones, from the error at feasible points (weights summing to one):
        # E(e_i) = H_ii and E((e_i + e_j) / 2) = (H_ii + 2 H_ij + H_jj) / 4.
        def err(a, b=b):
            return quartic_error(Qe[b:b + 1], Tb[b:b + 1], a[None], v[b:b + 1])[0]

        unit = np.eye(mask.shape[1])[k]
        diag = np.array([err(e) for e in unit])
        H = np.array([[2 * err(0.5 * (x + y)) - 0.5 * (diag[i] + diag[j]) for j, y in enumerate(unit)]
                      for i, x in enumerate(unit)])
        H /= np.trace(H) / len(k)
        P = sp.csc_matrix(2 * (H + ridge * np.eye(len(k))))
        q = -2 * ridge * a0[b, k]
        A = sp.csc_matrix(np.vstack([np.ones((1, len(k))), -np.eye(len(k))]))
        rhs = np.r_[1.0, np.zeros(len(k))]
        cones = [clarabel.ZeroConeT(1), clarabel.NonnegativeConeT(len(k))]
        settings = clarabel.DefaultSettings()
        settings.verbose = False
        settings.tol_gap_abs = settings.tol_gap_rel = 1e-12
        sol = clarabel.DefaultSolver(P, q, A, rhs, cones, settings).solve()
        x = np.array(sol.x)
        def obj(z, H=H, k=k, b=b):
            return z @ (H + ridge * np.eye(len(k))) @ z - 2 * ridge * a0[b, k] @ z
        assert obj(a[b, k]) <= obj(x) + 1e-8 * max(1.0, abs(obj(x)))


def _sheet(n=8):
    """A flat open n x n grid in z = 0 (an L-shaped outline: the top-right quarter removed)."""
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    F = []
    for i in range(n):
        for j in range(n):
            if i >= n // 2 and j >= n // 2:
                continue
            a, b, c, d = ids[i, j], ids[i, j + 1], ids[i + 1, j], ids[i + 1, j + 1]
            F += [[a, b, d], [a, d, c]]
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    F = np.array(F, dtype=np.int64)
    used = np.unique(F)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    return V[used], remap[F]


def test_border_quadrics_measure_the_distance_off_the_border_line():
    from rigslim.plugins.decimation.quadrics import border_quadrics

    V, F = _sheet()
    Q = border_quadrics(V[None], F, weight=2.0)[:, 0]
    i = int(np.flatnonzero((V[:, 1] == 0) & (V[:, 0] == 3))[0])       # on the bottom border, two unit edges
    for p, expect in (([5.0, 0.0, 0.0], 0.0), ([3.0, 0.5, 0.0], 2 * 2 * 1.0 * 0.25), ([3.0, 0.0, 7.0], 0.0)):
        ph = np.r_[p, 1.0]
        assert ph @ Q[i] @ ph == pytest.approx(expect, abs=1e-12)
    inner = int(np.flatnonzero((V[:, 0] == 2) & (V[:, 1] == 2))[0])
    assert not Q[inner].any()


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_a_flat_sheet_keeps_its_outline(backend):
    """Guard: the border planes keep a planar part's outline (without them, and without the source-side error,
    which also sees it, its border is eaten for free)."""
    import scipy.sparse as sp

    from rigslim.asset import Asset
    from rigslim.host import get_host
    from rigslim.mesh import Mesh
    from rigslim.plugin import StepContext
    from rigslim.poses import FrameSplit, Poses

    V, F = _sheet()
    T = np.zeros((4, 1, 3, 4))
    T[..., :3, :3] = np.eye(3)
    asset = Asset(mesh=Mesh(V, F), weights=sp.csr_matrix(np.ones((len(V), 1))), poses=Poses(T),
                  split=FrameSplit.from_specs([0, 2], [1, 3], 4))
    plugin = get_host().get("articulated-decimation", "quartic")
    area = 0.5 * np.abs(np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])[:, 2]).sum()
    for border_weight, keeps in ((1.0, True), (0.0, False)):
        asset.extras.clear()
        plugin.apply(asset, plugin.parse_params({"targets": [12], "backend": backend, "source_distance": False,
                                                 "border_weight": border_weight}), StepContext())
        lv = asset.levels[0]
        P, G = lv.mesh.V, np.asarray(lv.mesh.F)
        got = 0.5 * np.abs(np.cross(P[G[:, 1]] - P[G[:, 0]], P[G[:, 2]] - P[G[:, 0]])[:, 2]).sum()
        assert lv.n_faces <= 14
        assert (got == pytest.approx(area, rel=1e-9)) == keeps, (border_weight, got, area)


@pytest.mark.parametrize("area_weighted", [True, False])
def test_compiled_vertex_quadrics_equal_the_numpy_reference(area_weighted):
    """The compiled pass over the faces and the numpy formula (planes, outer products, incidence product) give
    the same quadrics, for one pose and for a stack of poses, degenerate faces included."""
    from rigslim.plugins.decimation.quadrics import vertex_quadrics_reference

    mesh = bumpy_sphere()
    rng = np.random.default_rng(3)
    X = mesh.V[None] + 0.05 * rng.normal(size=(4,) + mesh.V.shape)
    F = np.vstack([mesh.F, [[0, 0, 1], [2, 3, 2]]])          # two faces with a repeated corner: zero area
    for pos in (mesh.V, X):
        got = vertex_quadrics(pos, F, area_weighted)
        want = vertex_quadrics_reference(pos, F, area_weighted)
        assert got.shape == want.shape
        np.testing.assert_allclose(got, want, rtol=1e-12, atol=1e-12 * np.abs(want).max())
