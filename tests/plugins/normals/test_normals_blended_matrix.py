"""Blended-matrix normals: inverse transpose of sum_l w_l R_l, against explicit inverses."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.handles import Handles
from rigslim.model.mesh import Mesh
from rigslim.numerics.blend import blended_matrices, per_vertex_normals
from rigslim.numerics.blended_normals import blended_matrix_normals, cofactor_apply
from rigslim.numerics.largest_entries import k_largest
from rigslim.numerics.normal_error import normal_rms_angle
from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals
from rigslim.plugins.solvers.renormalised import renormalised_weights


def angles(N, M):
    return np.arctan2(np.linalg.norm(np.cross(N, M), axis=1), np.einsum("ij,ij->i", N, M))


def test_cofactor_is_det_times_inverse_transpose(rng):
    R = rng.standard_normal((20, 3, 3))
    n = rng.standard_normal((20, 3))
    expected = np.linalg.det(R)[:, None] * np.einsum("vji,vj->vi", np.linalg.inv(R), n)
    np.testing.assert_allclose(cofactor_apply(R, n), expected, atol=1e-10)


def test_identity_at_rest_and_rigid_motion_exact(elephant, rng):
    mesh, W = elephant.mesh, elephant.weights
    N0 = per_vertex_normals(mesh.V, mesh.F)
    T = elephant.handles.rest_transforms()
    assert angles(blended_matrix_normals(N0, W, T), N0).max() < 1e-12
    Q, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    Q *= np.sign(np.linalg.det(Q))
    T[:, :, :3] = Q                                       # every bone the same rotation: rigid motion
    T[:, :, 3] = rng.standard_normal((T.shape[0], 3))
    assert angles(blended_matrix_normals(N0, W, T), N0 @ Q.T).max() < 1e-12


def test_matches_explicit_inverse_transpose_on_animation(elephant):
    mesh, W = elephant.mesh, elephant.weights
    reduced = renormalised_weights(W, k_largest(W, 4))
    N0 = per_vertex_normals(mesh.V, mesh.F)
    for weights in (W, reduced):
        for j in (50, 300):
            T = elephant.poses.T[j]
            R = blended_matrices(weights, T)[:, :, :3]
            expected = np.einsum("vji,vj->vi", np.linalg.inv(R), N0)
            expected /= np.linalg.norm(expected, axis=1, keepdims=True)
            assert angles(blended_matrix_normals(N0, weights, T), expected).max() < 1e-9


def test_reflection_keeps_inverse_transpose_direction(rng):
    N0 = rng.standard_normal((10, 3))
    N0 /= np.linalg.norm(N0, axis=1, keepdims=True)
    W = sp.csr_matrix(np.ones((10, 1)))
    T = np.zeros((1, 3, 4))
    T[0, :, :3] = np.diag([-1.0, 2.0, 1.0])
    expected = N0 @ np.linalg.inv(T[0, :, :3])           # R^{-T} n, as rows
    expected /= np.linalg.norm(expected, axis=1, keepdims=True)
    assert angles(blended_matrix_normals(N0, W, T), expected).max() < 1e-12


def test_plugin_close_to_recomputed_on_elephant(elephant):
    """Skinning normals against normals recomputed from the deformed mesh (report the RMS angle)."""
    from rigslim.numerics.blend import linear_blend

    est = BlendedMatrixNormals()
    mesh, W = elephant.mesh, elephant.weights
    N0 = per_vertex_normals(mesh.V, mesh.F)
    rms, rms_rest = [], []
    for j in elephant.split.test[:5]:
        T = elephant.poses.T[j]
        P = linear_blend(mesh.V, W, T)
        recomputed = per_vertex_normals(P, mesh.F)
        N = est.estimate(mesh, W, elephant.handles, T, P, est.Params())
        rms.append(normal_rms_angle(N, recomputed))
        rms_rest.append(normal_rms_angle(N0, recomputed))
    print(f"\nblended-matrix vs recomputed normals, elephant full weights, 5 test frames: RMS {np.mean(rms):.4f} rad "
          f"(rest normals left unchanged: {np.mean(rms_rest):.4f} rad)")
    assert np.mean(rms) < 0.5 * np.mean(rms_rest)


def test_plugin_rejects_cages():
    cage = Mesh(np.eye(4, 3), np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]]))
    handles = Handles.from_cage(cage)
    est = BlendedMatrixNormals()
    with pytest.raises(StepError, match="approximate-affine"):
        est.estimate(cage, sp.identity(4, format="csr"), handles, handles.rest_transforms(), cage.V, est.Params())
