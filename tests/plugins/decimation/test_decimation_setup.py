"""rigslim.plugins.decimation.setup: the collapsible edges both collapse loops start from."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.plugins.decimation.setup import (
    BEST,
    BORDER,
    FREE,
    KEEP_A,
    KEEP_B,
    NONE,
    SEAM,
    collapsible_edges,
    degenerate_area,
    placement,
    placements,
    seam_arrays,
)


def grid(n: int = 4):
    """An open n x n grid of squares, two triangles each."""
    ids = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    F = []
    for i in range(n):
        for j in range(n):
            a, b, c, d = ids[i, j], ids[i, j + 1], ids[i + 1, j], ids[i + 1, j + 1]
            F += [[a, b, d], [a, d, c]]
    x, y = np.meshgrid(np.arange(n + 1.0), np.arange(n + 1.0))
    V = np.stack([x.ravel(), y.ravel(), np.zeros(x.size)], axis=1)
    return V, np.array(F, dtype=np.int64)


def unique_edges(F):
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return np.unique(E, axis=0)


def test_every_edge_is_collapsible_without_fixed_vertices():
    V, F = grid()
    setup = collapsible_edges(F, len(V), keep_boundary=False)
    np.testing.assert_array_equal(setup.edges, unique_edges(F))
    assert setup.boundary.shape == (2 * len(V),) and not setup.boundary.any()


def test_border_vertices_slide_along_the_border_and_free_vertices_collapse_onto_them():
    V, F = grid()
    m = len(V)
    on_border = (V[:, 0] == 0) | (V[:, 0] == 4) | (V[:, 1] == 0) | (V[:, 1] == 4)
    setup = collapsible_edges(F, m, keep_boundary=True)
    np.testing.assert_array_equal(setup.boundary[:m], on_border)
    np.testing.assert_array_equal(setup.along[:m], np.where(on_border, BORDER, 0))
    edges = {tuple(e) for e in setup.edges.tolist()}
    E = unique_edges(F)
    n_faces = {tuple(e): int(((F == e[0]).any(axis=1) & (F == e[1]).any(axis=1)).sum()) for e in E.tolist()}
    for e in E.tolist():
        both = on_border[e[0]] and on_border[e[1]]
        # two border ends: only along the border (one face); otherwise every edge may collapse
        assert (tuple(e) in edges) == (not both or n_faces[tuple(e)] == 1), e
    fixed = setup.boundary
    place = placements(fixed[E[:, 0]], fixed[E[:, 1]], setup.along[E[:, 0]], setup.along[E[:, 1]])
    np.testing.assert_array_equal(place[~on_border[E[:, 0]] & on_border[E[:, 1]]], KEEP_B)
    assert (place[on_border[E[:, 0]] & on_border[E[:, 1]]] == BEST).all()
    assert (place[~on_border[E[:, 0]] & ~on_border[E[:, 1]]] == FREE).all()


def test_fixed_borders_and_locked_vertices_take_half_edge_collapses_only():
    V, F = grid()
    m = len(V)
    setup = collapsible_edges(F, m, keep_boundary=True, border_collapses=False)
    fixed = setup.boundary[:m]
    assert not setup.along.any()
    assert not (fixed[setup.edges[:, 0]] & fixed[setup.edges[:, 1]]).any()      # two fixed ends: never
    locked = np.zeros(m, bool)
    locked[12] = True                                    # the centre
    setup = collapsible_edges(F, m, keep_boundary=True, locked=locked)
    at12 = setup.edges[(setup.edges == 12).any(axis=1)]
    assert setup.boundary[12] and len(at12) == 6         # its six edges: half-edge collapses onto it
    for a, b in at12.tolist():
        assert placement(bool(setup.boundary[a]), bool(setup.boundary[b]), 0, 0) == (KEEP_A if a == 12 else KEEP_B)
    for fa in (False, True):                             # the scalar rule and the array rule agree
        for fb in (False, True):
            for ca in (0, SEAM, BORDER):
                for cb in (0, SEAM, BORDER):
                    got = placements(np.array([fa]), np.array([fb]), np.array([ca]), np.array([cb]))[0]
                    assert got == placement(fa, fb, ca, cb)
    assert placement(True, True, 0, 0) == NONE and placement(True, True, SEAM, BORDER) == NONE
    assert placement(True, True, SEAM, 0) == KEEP_B and placement(True, True, 0, BORDER) == KEEP_A


def test_a_seam_edge_between_two_charts_stays_collapsible():
    V, F = grid(2)
    m = len(V)
    along = np.zeros(m, bool)
    along[[3, 4, 5]] = True                              # the middle row of vertices
    charts = (F.min(axis=1) >= 3).astype(np.int64)       # faces above the row are chart 1
    locked = along.copy()
    setup = collapsible_edges(F, m, keep_boundary=False, locked=locked, seams=(along, charts))
    edges = {tuple(e) for e in setup.edges.tolist()}
    assert (3, 4) in edges and (4, 5) in edges           # along the seam, between the two charts
    seam = {3, 4, 5}
    # off the seam: half-edge collapses of the free vertices onto the seam, never a seam-to-seam chord
    for x, y in edges:
        if x in seam and y in seam:
            assert (x, y) in {(3, 4), (4, 5)}
    assert (0, 3) in edges and (1, 4) in edges
    a, c = seam_arrays(None, m, len(F))
    assert not a.any() and not c.any()


def test_degenerate_area_scales_with_the_squared_diagonal():
    V, _ = grid()
    assert degenerate_area(V) == pytest.approx(1e-14 * 32.0, rel=1e-12)          # diagonal sqrt(32)
    assert degenerate_area(10 * V) == pytest.approx(1e-14 * 3200.0, rel=1e-12)
