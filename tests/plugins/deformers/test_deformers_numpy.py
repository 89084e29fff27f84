"""The numpy reference deformer and the shared bound-deformer machinery (layouts, checks)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import InputError, StepError
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import linear_blend, per_vertex_normals
from rigslim.numerics.blended_normals import blended_matrix_normals
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.deformers.base import fixed_k_arrays, handle_data, pack_weights, resolve_normals
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.solvers.renormalised import renormalised_weights


def test_callable_positions_and_normals(elephant):
    mesh, W = elephant.mesh, elephant.weights
    T = elephant.poses.T[120]
    bound = NumpyDeformer().bind(mesh, W, NumpyDeformer.Params(), handles=elephant.handles)
    np.testing.assert_array_equal(bound(T), linear_blend(mesh.V, W, T))
    P, N = bound.deform(T, normals=True)
    np.testing.assert_array_equal(P, linear_blend(mesh.V, W, T))
    np.testing.assert_allclose(N, blended_matrix_normals(per_vertex_normals(mesh.V, mesh.F), W, T), atol=1e-14)
    assert bound.normals_mode == "blended-matrix" and bound.last_seconds > 0


def test_bad_transforms_and_missing_normals_are_one_line_errors(elephant):
    bound = NumpyDeformer().bind(elephant.mesh, elephant.weights, NumpyDeformer.Params(normals="none"))
    with pytest.raises(InputError, match=r"expected \(24, 3, 4\)"):
        bound(np.zeros((23, 3, 4)))
    bad = elephant.poses.T[0].copy()
    bad[0, 0, 0] = np.nan
    with pytest.raises(InputError, match="NaN"):
        bound(bad)
    with pytest.raises(StepError, match="without normals"):
        bound.deform(elephant.poses.T[0], normals=True)
    with pytest.raises(InputError, match="rows"):
        NumpyDeformer().bind(elephant.mesh, elephant.weights[:10], NumpyDeformer.Params())


def test_resolve_normals(elephant):
    assert resolve_normals("auto", None) == "blended-matrix"
    assert resolve_normals("auto", elephant.handles) == "blended-matrix"
    assert resolve_normals("none", elephant.handles) is None
    with pytest.raises(StepError, match="cage"):
        resolve_normals("approximate-affine", elephant.handles)


def test_fixed_k_arrays_and_layouts_keep_the_weights(elephant):
    W = elephant.weights
    idx, val = fixed_k_arrays(W)
    assert idx.shape[1] == np.diff(W.indptr).max()
    back = ReducedWeights(idx, val, W.shape[1]).to_sparse()
    assert abs(back - W).max() == 0
    with pytest.raises(StepError, match="influences"):
        fixed_k_arrays(W, k=3)
    csr = pack_weights(W, "auto", W.shape[1])
    assert csr.layout == "csr" and csr.indptr.dtype == np.int32 and csr.values.dtype == np.float32
    reduced = renormalised_weights(W, k_largest(W, 4))
    fixed = pack_weights(reduced, "auto", W.shape[1])
    assert fixed.layout == "fixed" and fixed.indices.dtype == np.int32 and fixed.k == 4
    compact = pack_weights(reduced, "compact", W.shape[1])
    assert compact.indices.dtype == np.uint16 and compact.values.dtype == np.float16
    assert compact.nbytes == fixed.nbytes // 2
    # float16 keeps 11 significant bits: weights in [0, 1] move by at most 2^-12
    assert np.abs(compact.effective.values - reduced.values).max() <= 2.0 ** -12
    with pytest.raises(StepError, match="layout"):
        pack_weights(reduced, "dense", W.shape[1])


def test_handle_records_hold_transform_rows_and_handle_positions(rng):
    T = rng.standard_normal((5, 3, 4))
    C0 = rng.standard_normal((5, 3))
    rec = handle_data(T, C0)
    assert rec.shape == (5, 5, 4) and rec.dtype == np.float32
    np.testing.assert_allclose(rec[:, :3], T, rtol=1e-6, atol=1e-6)
    chat = np.einsum("nij,nj->ni", T[:, :, :3], C0) + T[:, :, 3]
    np.testing.assert_allclose(rec[:, 3, :3], chat - chat.mean(axis=0), rtol=1e-6, atol=1e-6)   # centred
    np.testing.assert_allclose(rec[:, 4, :3], C0 - C0.mean(axis=0), rtol=1e-6, atol=1e-6)
    assert not handle_data(T, None)[:, 3:].any()


def test_sparse_input_rows_of_any_width(rng):
    """A hand-made sparse matrix with empty-ish rows (one weight) and wide rows."""
    from rigslim.model.mesh import Mesh

    m, n = 30, 7
    W = sp.random(m, n, density=0.4, random_state=1, format="csr") + sp.eye(m, n, format="csr")
    W = sp.csr_matrix(sp.diags(1.0 / np.asarray(W.sum(axis=1)).ravel()) @ W)
    V = rng.standard_normal((m, 3))
    mesh = Mesh(V, np.array([[0, 1, 2]]))
    T = rng.standard_normal((n, 3, 4))
    bound = NumpyDeformer().bind(mesh, W, NumpyDeformer.Params(normals="none"))
    idx, val = fixed_k_arrays(W)
    np.testing.assert_allclose(bound(T), linear_blend(V, ReducedWeights(idx, val, n), T), atol=1e-12)
