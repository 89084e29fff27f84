"""rigslim.plugins.decimation.setup: the collapsible edges both collapse loops start from."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.plugins.decimation.setup import collapsible_edges, degenerate_area, seam_arrays


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


def test_boundary_and_locked_vertices_fix_their_edges():
    V, F = grid()
    m = len(V)
    on_border = (V[:, 0] == 0) | (V[:, 0] == 4) | (V[:, 1] == 0) | (V[:, 1] == 4)
    setup = collapsible_edges(F, m, keep_boundary=True)
    np.testing.assert_array_equal(setup.boundary[:m], on_border)
    assert not on_border[setup.edges].any()
    locked = np.zeros(m, bool)
    locked[12] = True                                    # the centre
    setup = collapsible_edges(F, m, keep_boundary=True, locked=locked)
    assert setup.boundary[12] and not (setup.edges == 12).any()


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
    assert not any(x in (3, 4, 5) and y not in (3, 4, 5) for x, y in edges)
    a, c = seam_arrays(None, m, len(F))
    assert not a.any() and not c.any()


def test_degenerate_area_scales_with_the_squared_diagonal():
    V, _ = grid()
    assert degenerate_area(V) == pytest.approx(1e-14 * 32.0, rel=1e-12)          # diagonal sqrt(32)
    assert degenerate_area(10 * V) == pytest.approx(1e-14 * 3200.0, rel=1e-12)
