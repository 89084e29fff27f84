"""Approximate-affine normals ([P10] sec. 5): identity at rest, exact for k = 4 under affine cage
motion, close to recomputed normals on a real (bending) cage deformation."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.handles import Handles, cage_transforms
from rigslim.model.mesh import Mesh
from rigslim.numerics.affine_normals import affine_fit_rest, approximate_affine_normals
from rigslim.numerics.blend import linear_blend, per_vertex_normals
from rigslim.numerics.largest_entries import k_largest
from rigslim.numerics.normal_error import normal_rms_angle
from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
from rigslim.plugins.solvers.renormalised import renormalised_weights


def box_cage(mesh: Mesh, margin: float = 0.15, levels: int = 1, jitter: float = 0.0, seed: int = 0) -> Handles:
    """A box around the mesh, midpoint-subdivided ``levels`` times (26 vertices for 1).

    ``jitter`` moves each cage vertex randomly by up to that fraction of the
    box size, so that a vertex's nearest cage vertices are not coplanar.
    """
    import igl

    lo, hi = mesh.V.min(axis=0), mesh.V.max(axis=0)
    pad = margin * (hi - lo)
    lo, hi = lo - pad, hi + pad
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    V = lo + corners * (hi - lo)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    if levels:
        V, F = igl.upsample(V, F, levels)
    if jitter:
        V = V + jitter * (hi - lo) * np.random.default_rng(seed).uniform(-1, 1, V.shape)
    return Handles.from_cage(Mesh(V, F, source="box cage"))


def idw_weights(V: np.ndarray, C: np.ndarray, power: float = 2.0, linear_precision: bool = False) -> sp.csr_matrix:
    """Normalised inverse-distance weights to cage vertices (a stand-in for mean value coordinates).

    With ``linear_precision`` the weights are projected (least-squares change)
    onto ``sum_i w_i = 1, sum_i w_i c_i = v``, so the rest cage reproduces the
    mesh, as generalized barycentric coordinates do.
    """
    D = np.linalg.norm(V[:, None, :] - C[None, :, :], axis=2)
    W = 1.0 / np.maximum(D, 1e-12) ** power
    W /= W.sum(axis=1, keepdims=True)
    if linear_precision:
        G = np.vstack([C.T, np.ones(len(C))])                     # (4, n)
        target = np.hstack([V, np.ones((len(V), 1))])              # (m, 4)
        residual = W @ G.T - target
        W = W - residual @ np.linalg.solve(G @ G.T, G)
    return sp.csr_matrix(W)


def angles(N: np.ndarray, M: np.ndarray) -> np.ndarray:
    return np.arctan2(np.linalg.norm(np.cross(N, M), axis=1), np.einsum("ij,ij->i", N, M))


@pytest.fixture(scope="module")
def cage_case(elephant):
    mesh = elephant.mesh
    handles = box_cage(mesh, jitter=0.1)
    W = idw_weights(mesh.V, handles.cage.V)
    return mesh, handles, W


def reduce_to(W, k):
    return renormalised_weights(W, k_largest(W, k))


def test_identity_at_rest_full_and_reduced(cage_case):
    mesh, handles, W = cage_case
    N0 = per_vertex_normals(mesh.V, mesh.F)
    T = handles.rest_transforms()
    for weights in (W, reduce_to(W, 4), reduce_to(W, 2)):
        N = approximate_affine_normals(weights, handles.cage.V, T, affine_fit_rest(weights, handles.cage.V, N0))
        assert angles(N, N0).max() < 1e-9


@pytest.mark.parametrize("reflect", [False, True])
def test_exact_for_k4_under_affine_cage_motion(cage_case, rng, reflect):
    mesh, handles, W = cage_case
    reduced = reduce_to(W, 4)
    N0 = per_vertex_normals(mesh.V, mesh.F)
    rest = affine_fit_rest(reduced, handles.cage.V, N0)
    ok = ~rest.degenerate                     # influences affinely independent (cond(P) < 1e4)
    assert ok.mean() > 0.95
    for _ in range(3):
        A = rng.standard_normal((3, 3)) + 2 * np.eye(3)
        if (np.linalg.det(A) < 0) != reflect:
            A[:, 0] *= -1
        C = handles.cage.V @ A.T + rng.standard_normal(3)
        N = approximate_affine_normals(reduced, handles.cage.V, cage_transforms(C[None])[0], rest)
        expected = N0 @ np.linalg.inv(A)       # rows: (A^{-T} n)^T
        expected /= np.linalg.norm(expected, axis=1, keepdims=True)
        assert angles(N[ok], expected[ok]).max() < 1e-8


def test_degenerate_influences_get_the_ridge_and_stay_unit(elephant, rng):
    """On an axis-aligned box cage a vertex's 4 largest weights sit on one face: the fit is undetermined."""
    mesh = elephant.mesh
    handles = box_cage(mesh)
    reduced = reduce_to(idw_weights(mesh.V, handles.cage.V), 4)
    N0 = per_vertex_normals(mesh.V, mesh.F)
    rest = affine_fit_rest(reduced, handles.cage.V, N0)
    assert rest.degenerate.mean() > 0.5 and (rest.ridge[rest.degenerate] > 0).all()
    R, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    R *= np.sign(np.linalg.det(R))
    C = handles.cage.V @ R.T
    N = approximate_affine_normals(reduced, handles.cage.V, cage_transforms(C[None])[0], rest)
    np.testing.assert_allclose(np.linalg.norm(N, axis=1), 1.0, atol=1e-12)
    # a rotation keeps the in-plane fit exact; the ridge pulls only the undetermined direction to identity
    assert np.median(angles(N, N0 @ R.T)) < 0.5 * np.median(angles(N0, N0 @ R.T))


def bend(C0: np.ndarray, amount: float) -> np.ndarray:
    """Bend points around an axis parallel to y: +-amount/2 rad at the two ends along x."""
    lo, hi = C0.min(axis=0), C0.max(axis=0)
    s = (C0[:, 0] - lo[0]) / (hi[0] - lo[0]) - 0.5
    theta = amount * s
    radius = (hi[0] - lo[0]) / amount
    C = C0.copy()
    C[:, 0] = lo[0] + (hi[0] - lo[0]) / 2 + (radius + C0[:, 2]) * np.sin(theta)
    C[:, 2] = (radius + C0[:, 2]) * np.cos(theta) - radius
    return C


def test_close_to_recomputed_on_bending_cage(elephant):
    """A real deformation: bend the cage by +-0.8 rad; IDW weights (power 4) with linear precision."""
    mesh = elephant.mesh
    handles = box_cage(mesh)
    C0 = handles.cage.V
    W = idw_weights(mesh.V, C0, power=4, linear_precision=True)
    np.testing.assert_allclose(W @ C0, mesh.V, atol=1e-9)
    T = cage_transforms(bend(C0, 1.6)[None])[0]
    N0 = per_vertex_normals(mesh.V, mesh.F)
    recomputed = per_vertex_normals(linear_blend(mesh.V, W, T), mesh.F)
    rms_rest = normal_rms_angle(N0, recomputed)                 # doing nothing
    rms = {}
    for label, weights in (("full", W), ("k=8", reduce_to(W, 8)), ("k=4", reduce_to(W, 4))):
        est = approximate_affine_normals(weights, C0, T, affine_fit_rest(weights, C0, N0))
        rms[label] = normal_rms_angle(est, recomputed)
    print("\napproximate-affine vs recomputed normals (elephant, bent 26-vertex box cage, IDW power 4 with "
          "linear precision): RMS " + ", ".join(f"{k} {v:.4f} rad" for k, v in rms.items()) +
          f"; rest normals left unchanged: {rms_rest:.4f} rad")
    assert rms["full"] < 0.6 * rms_rest
    assert rms["k=4"] < 0.8 * rms_rest


def test_plugin_rejects_skeletons_and_caches_rest_fit(elephant, cage_case):
    est = ApproximateAffineNormals()
    params = est.Params()
    with pytest.raises(StepError, match="blended-matrix"):
        est.estimate(elephant.mesh, elephant.weights, elephant.handles, elephant.poses.T[3], elephant.mesh.V, params)
    mesh, handles, W = cage_case
    T = handles.rest_transforms()
    N = est.estimate(mesh, W, handles, T, mesh.V, params)
    first = est._rest
    est.estimate(mesh, W, handles, T, mesh.V, params)
    assert est._rest is first
    assert angles(N, per_vertex_normals(mesh.V, mesh.F)).max() < 1e-9


MVC_PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:40"}
steps:
  - generate: mean-value
    cage: auto
    cage_vertices: 60
    cage_resolution: 40
  - select: k-largest
    k: 8
  - solve: k-largest
  - evaluate: [normal-deviation]
    name: recomputed
  - normals: approximate-affine
  - evaluate: [normal-deviation]
    name: approximate-affine
"""


def test_mean_value_cage_pipeline_real_deformation(write_pipeline):
    """The elephant's motion carried by an automatic 60-vertex cage with mean value coordinates:
    approximate-affine normals against normals recomputed from the deformed mesh."""
    from rigslim.runtime.run import run_pipeline

    result = run_pipeline(write_pipeline(MVC_PIPELINE))
    asset = result.asset
    assert asset.handles.is_cage
    W, C0, mesh = asset.weights, asset.handles.cage.V, asset.mesh
    N0 = per_vertex_normals(mesh.V, mesh.F)
    rest = affine_fit_rest(W, C0, N0)
    rms, rms_rest = [], []
    for j in asset.split.test:
        T = asset.poses.T[j]
        recomputed = per_vertex_normals(linear_blend(mesh.V, W, T), mesh.F)
        rms.append(normal_rms_angle(approximate_affine_normals(W, C0, T, rest), recomputed))
        rms_rest.append(normal_rms_angle(N0, recomputed))
    ev = {e["name"]: e["metrics"]["normal_rms_rad"]["mean"] for e in result.document["evaluations"]}
    print(f"\nMVC elephant ({len(asset.split.test)} test frames): approximate-affine vs recomputed normals, full "
          f"weights: RMS {np.mean(rms):.4f} rad (rest normals unchanged: {np.mean(rms_rest):.4f} rad); k=8 "
          f"pipeline normal-deviation: approximate-affine {ev['approximate-affine']:.4f} rad, recomputed "
          f"{ev['recomputed']:.4f} rad")
    assert np.mean(rms) < 0.5 * np.mean(rms_rest)
    assert ev["approximate-affine"] < 0.5 * np.mean(rms_rest)
