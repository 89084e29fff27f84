"""Non-manifold edges (collapse.py ``_topology``, compiled.py ``link_ok``): where a single-sided fin meets a body.

An edge with three or more faces may collapse when the link condition holds in its general form, the vertices
common to both ends' neighbourhoods being exactly the apexes of the edge's faces (Dey et al. 1999). Before, such
edges never collapsed, so the line where a fin meets a body kept every one of its edges."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from support.synthetic import tube_asset

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host


def finned_tube() -> Asset:
    """:func:`tube_asset` (16 rings of 10, open at both ends) with a single-sided fin along its line at angle 0:
    a 4 x 16 grid in the plane y = 0 whose first column is the tube's own vertices, so that the tube's 15 edges
    along that line have three faces each (two of the tube, one of the fin)."""
    base = tube_asset(rings=16, segments=10, bones=4, poses=8, seed=2)
    V0, F0 = base.mesh.V, base.mesh.F
    zs = V0[::10, 2]                                        # ring heights; vertex r * 10 is at angle 0
    xs = np.array([0.5, 0.7, 0.9])
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    Vf = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    idx = np.vstack([np.arange(16) * 10, len(V0) + np.arange(X.size).reshape(3, 16)])    # (4, 16)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    fin = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    V = np.vstack([V0, Vf])
    W = np.exp(-((V[:, 2:3] - (np.arange(4) + 0.5)[None]) ** 2) / 0.5)
    W /= W.sum(axis=1, keepdims=True)
    return Asset(mesh=Mesh(V, np.vstack([F0, fin])), handles=base.handles, weights=sp.csr_matrix(W),
                 poses=base.poses, split=base.split)


def _edges(F):
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    return np.unique(E, axis=0, return_counts=True)


def decimate(asset, **params):
    plugin = get_host().get("articulated-decimation", "quartic")
    asset.extras.clear()
    plugin.apply(asset, plugin.parse_params(params), StepContext())
    return asset.hierarchy, asset.levels


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_line_where_a_fin_meets_a_body_collapses(backend):
    asset = finned_tube()
    n = asset.mesh.n_faces
    hier, levels = decimate(asset, targets=[0.3], max_bones=3, backend=backend)
    lv = levels[0]
    assert abs(lv.n_faces - round(0.3 * n)) <= 2
    # the fin stays attached along a shorter line (before: all 15 of its edges, whatever the target)
    _, counts = _edges(lv.mesh.F)
    assert 1 <= (counts == 3).sum() < 15 and (counts <= 3).all()
    # no collapse makes a new non-manifold edge or a duplicate face; face counts are the prefixes' own
    for t in np.linspace(0, hier.n_collapses, 9).astype(int):
        mesh = hier.prefix(t).mesh
        _, c = _edges(mesh.F)
        assert (c == 3).sum() <= 15 and (c <= 3).all()
        assert len(np.unique(np.sort(mesh.F, axis=1), axis=0)) == mesh.n_faces == hier.faces_after(t)


def test_both_backends_make_the_same_collapses_along_a_fin_line():
    h_np, _ = decimate(finned_tube(), targets=[0.3], max_bones=3, backend="numpy")
    h_nb, _ = decimate(finned_tube(), targets=[0.3], max_bones=3, backend="numba")
    assert np.array_equal(h_np.collapses, h_nb.collapses)
