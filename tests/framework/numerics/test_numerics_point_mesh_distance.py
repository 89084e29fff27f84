"""The compiled bounding-volume hierarchy's point-to-mesh distances against libigl's and a brute force."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.numerics.point_mesh_distance import (
    build_tree,
    distances_to_other_parts,
    point_mesh_squared_distances,
    point_triangle_distance2,
    refit_tree,
)


def _sphere(n: int = 3):
    import igl

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(V, F, n)
    return V / np.linalg.norm(V, axis=1, keepdims=True), np.asarray(F, np.int64)


def _brute(P, V, F):
    return np.array([min(point_triangle_distance2(*p, *V[a], *V[b], *V[c]) for a, b, c in F) for p in P])


def test_distances_match_libigl_and_a_brute_force():
    """Points inside, outside, far away and on the surface; a mesh with degenerate triangles (a collinear
    one, one that is a point) and one triangle alone."""
    import igl

    rng = np.random.default_rng(0)
    V, F = _sphere(3)
    V = V * [1.0, 0.5, 2.0]
    F = np.vstack([F, [[0, 1, 1], [2, 2, 2]]])                      # degenerate: a segment and a point
    P = np.vstack([rng.normal(size=(300, 3)) * s for s in (0.3, 1.0, 10.0)] + [V[F[:40, 0]]])
    got = point_mesh_squared_distances(P, V, F)
    ref = igl.point_mesh_squared_distance(P, V, F)[0]
    np.testing.assert_allclose(got, ref, rtol=1e-12, atol=1e-14)
    np.testing.assert_allclose(got[::17], _brute(P[::17], V, F), rtol=1e-12, atol=1e-14)
    one = np.array([[0, 1, 2]])
    np.testing.assert_allclose(point_mesh_squared_distances(P, V, one), _brute(P, V, one), rtol=1e-12, atol=1e-14)


def test_a_refitted_tree_measures_new_positions_exactly():
    """The tree of the rest positions, refitted to a bent and stretched pose, gives that pose's distances
    (the order is kept, the boxes follow): the same as a tree built on the pose."""
    import igl

    rng = np.random.default_rng(1)
    V, F = _sphere(4)
    tree = build_tree(V, F)
    X = V.copy()
    X[:, 2] += 0.8 * X[:, 0] ** 2
    X[:, 0] *= 3.0
    P = rng.normal(size=(2000, 3)) * [3.0, 1.0, 1.0]
    got = point_mesh_squared_distances(P, X, F, refit_tree(tree, X, F))
    np.testing.assert_allclose(got, igl.point_mesh_squared_distance(P, X, F)[0], rtol=1e-12, atol=1e-14)
    assert np.array_equal(got, point_mesh_squared_distances(P, X, F, build_tree(X, F)))
    with pytest.raises(AssertionError):       # the unrefitted tree prunes with the rest pose's boxes
        np.testing.assert_allclose(point_mesh_squared_distances(P, X, F, tree), got, rtol=1e-12)


def test_the_tree_holds_every_triangle_once_and_its_boxes_hold_their_triangles():
    V, F = _sphere(3)
    tree = build_tree(V, F)
    leaves = tree.kid < 0
    assert np.array_equal(np.sort(tree.perm), np.arange(len(F)))
    assert tree.count[leaves].sum() == len(F) and tree.count[leaves].max() <= 4
    for x in np.flatnonzero(leaves):
        corners = V[F[tree.perm[tree.first[x]:tree.first[x] + tree.count[x]]]].reshape(-1, 3)
        assert (corners >= tree.lo[x]).all() and (corners <= tree.hi[x]).all()
    inner = np.flatnonzero(~leaves)
    for k in (tree.kid[inner], tree.kid[inner] + 1):
        assert (tree.lo[k] >= tree.lo[inner]).all() and (tree.hi[k] <= tree.hi[inner]).all()


def test_first_guesses_change_no_distance_and_stale_ones_are_ignored():
    """Guesses found on the same mesh, and guesses of another, larger mesh (indices beyond these triangles),
    give the same distances as no guess; the guesses are overwritten with the nearest triangles."""
    rng = np.random.default_rng(2)
    V, F = _sphere(3)
    P = rng.normal(size=(200, 3))
    ref = point_mesh_squared_distances(P, V, F)
    found = np.full(len(P), -1, np.int64)
    np.testing.assert_array_equal(point_mesh_squared_distances(P, V, F, nearest=found), ref)
    assert found.min() >= 0 and found.max() < len(F)
    np.testing.assert_array_equal(point_mesh_squared_distances(P, V, F, nearest=found), ref)
    stale = np.full(len(P), len(F) + 1000, np.int64)
    np.testing.assert_array_equal(point_mesh_squared_distances(P, V, F, nearest=stale), ref)
    assert stale.max() < len(F)


def test_distances_to_other_parts_match_a_brute_force_over_the_allowed_triangles():
    """Each point measured against the triangles of the other live parts only: its own part's triangles and a
    removed part's are skipped (every point of the part lies on them), one hierarchy for all; a point with no
    allowed triangle gets inf."""
    rng = np.random.default_rng(1)
    V, F = _sphere(2)
    part = rng.integers(0, 5, len(F))
    alive = np.array([True, True, False, True, True])
    P = np.vstack([V[F[:60, 0]], rng.normal(size=(40, 3))])
    owner = np.concatenate([part[:60], rng.integers(0, 5, 40)])
    tree = build_tree(V, F)
    got = distances_to_other_parts(P, owner, V, F, part, alive, tree)
    for p, o, g in zip(P, owner, got, strict=True):
        allowed = F[(part != o) & alive[part]]
        assert g == pytest.approx(_brute([p], V, allowed)[0], rel=1e-12, abs=1e-15)
    guess = np.full(len(P), -1, np.int64)
    np.testing.assert_array_equal(distances_to_other_parts(P, owner, V, F, part, alive, tree, guess), got)
    assert (part[guess] != owner).all() and alive[part[guess]].all()      # each point's nearest allowed triangle
    np.testing.assert_array_equal(distances_to_other_parts(P, owner, V, F, part, alive, tree, guess), got)
    alive2 = alive.copy()
    alive2[part[guess[0]]] = False                                         # a guess on a removed part is none
    np.testing.assert_array_equal(distances_to_other_parts(P, owner, V, F, part, alive2, tree, guess.copy()),
                                  distances_to_other_parts(P, owner, V, F, part, alive2, tree))
    only = np.array([True, False, False, False, False])
    alone = distances_to_other_parts(P[:3], np.zeros(3, np.int64), V, F, part, only, tree)
    assert np.isinf(alone).all()
    np.testing.assert_allclose(point_mesh_squared_distances(P, V, F, tree), _brute(P, V, F), rtol=1e-12,
                               atol=1e-15)                                     # the unmasked query counts all
