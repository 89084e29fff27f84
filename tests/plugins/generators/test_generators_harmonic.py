"""Harmonic coordinates on a regular grid: non-negativity, partition of unity, hat functions on
the cage, linear precision up to the grid spacing, convergence, CG against LU."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.plugins.generators.harmonic import HarmonicGrid, conjugate_gradient, harmonic_coordinates, hat_values

TET_V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]])
TET_F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])


def barycentric(P):
    return np.column_stack([1 - P.sum(axis=1), P])


def tet_points(rng, count, margin=0.05):
    B = rng.dirichlet([1, 1, 1, 1], count)
    B = margin + (1 - 4 * margin) * B
    return B @ TET_V


def bumpy_cage():
    """A non-convex closed cage: a subdivided octahedron with a dent."""
    import igl

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(V, F, 1)
    V = V / np.linalg.norm(V, axis=1, keepdims=True) * [1.0, 1.3, 0.8]
    V[np.argmax(V[:, 2]), 2] *= 0.4
    return V, F


def test_tetrahedron_cage_gives_barycentric_coordinates(rng):
    """Linear functions are harmonic, so in a tetrahedron the harmonic coordinates are barycentric."""
    P = tet_points(rng, 300)
    errors = []
    for res in (12, 24, 48):
        W = harmonic_coordinates(P, TET_V, TET_F, resolution=res)
        errors.append(np.abs(W - barycentric(P)).max())
        assert errors[-1] < 2.0 / res       # O(h)
    assert errors[2] < errors[1] < errors[0]  # converges


@pytest.mark.parametrize("solver", ["cg", "lu"])
def test_properties_in_a_nonconvex_cage(solver, rng):
    import igl

    V, F = bumpy_cage()
    Q = rng.uniform(V.min(0), V.max(0), (3000, 3))
    P = Q[igl.winding_number(V, F, Q) > 0.5][:400]
    report = {}
    W = harmonic_coordinates(P, V, F, resolution=32, solver=solver, report=report)
    h = report["spacing"]
    assert W.min() >= -1e-9                                  # non-negative
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-8            # partition of unity
    assert np.abs(W @ V - P).max() < np.sqrt(3) * h          # linear precision up to the grid's error


def test_equal_to_hat_functions_on_the_cage(rng):
    V, F = bumpy_cage()
    f = rng.integers(0, len(F), 200)
    b = rng.dirichlet([1, 1, 1], 200)
    X = np.einsum("pi,pij->pj", b, V[F[f]])
    hats = np.zeros((200, len(V)))
    np.add.at(hats, (np.repeat(np.arange(200), 3), F[f].ravel()), b.ravel())
    assert np.abs(hat_values(X, V, F) - hats).max() < 1e-12
    errors = [np.abs(harmonic_coordinates(X, V, F, resolution=r) - hats).max() for r in (16, 48)]
    assert errors[1] < errors[0]
    assert errors[1] < 0.15


def test_cg_matches_lu_on_a_small_grid():
    V, F = bumpy_cage()
    cg = HarmonicGrid(V, F, 20, solver="cg")
    lu = HarmonicGrid(V, F, 20, solver="lu")
    assert cg.iterations > 0
    assert np.abs(cg.values - lu.values).max() < 1e-8


def test_conjugate_gradient_against_a_dense_solve(rng):
    A = sp.random(60, 60, density=0.1, random_state=1)
    A = sp.csr_matrix(A @ A.T + 5 * sp.identity(60))
    B = rng.normal(size=(60, 4))
    X, it = conjugate_gradient(A, B, tol=1e-13)
    assert np.abs(X - np.linalg.solve(A.toarray(), B)).max() < 1e-10
    assert it <= 200


def test_harmonic_pipeline_with_an_automatic_cage(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:50"}
steps:
  - generate: harmonic
    cage: auto
    cage_vertices: 40
    cage_resolution: 32
    resolution: 24
  - select: k-largest
    k: 8
  - solve: k-largest
  - evaluate: [position-rms, max-influences]
""")
    result = run_pipeline(path)
    asset = result.asset
    assert asset.handles.is_cage and asset.handles.n == asset.weights.shape[1]
    assert asset.weights.min() >= 0
    gen = result.document["steps"][1]["report"]
    assert gen["cage"]["vertices_outside"] == 0
    assert gen["cage_poses"]["source"] == "skinned to the skeleton"
    assert result.document["evaluations"][0]["metrics"]["max_influences"] == 8
