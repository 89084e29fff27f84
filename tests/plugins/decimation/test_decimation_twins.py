"""Double-sided sheets (plugins/decimation/twins.py): one side simplified, the other following it."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from support.synthetic import tube_asset

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.twins import back_faces, face_deaths, with_back_faces


def test_back_faces_pairs_opposite_windings_only():
    F = np.array([[0, 1, 2],      # front
                  [3, 4, 5],
                  [2, 1, 0],      # 0's back
                  [4, 5, 3],      # 1 again, same winding (a rotation): not a back
                  [1, 0, 2],      # a second back of 0's triangle, with no front left for it
                  [6, 7, 8]])
    assert back_faces(F).tolist() == [False, False, True, False, False, False]
    # with two fronts, both backs pair
    F2 = np.vstack([F, [[1, 2, 0]]])
    assert back_faces(F2).tolist() == [False, False, True, False, True, False, False]
    assert not back_faces(np.zeros((0, 3), np.int64)).any()
    # faces that repeat a vertex have no winding: never a pair
    assert not back_faces(np.array([[0, 0, 1], [0, 1, 0], [1, 0, 0]])).any()


def finned_tube(back_first: bool = False) -> Asset:
    """:func:`tube_asset` with a double-sided fin beside it: a 6 x 16 grid in the plane y = 0, every face
    stored twice with opposite winding (the backs after the fronts, or before them), skinned by z like the
    tube."""
    base = tube_asset(rings=16, segments=10, bones=4, poses=8, seed=1)
    V0, F0 = base.mesh.V, base.mesh.F
    xs, zs = np.linspace(0.5, 1.5, 6), np.linspace(0.0, 4.0, 16)
    X, Z = np.meshgrid(xs, zs, indexing="ij")
    Vs = np.stack([X.ravel(), np.zeros(X.size), Z.ravel()], 1)
    idx = np.arange(X.size).reshape(X.shape) + len(V0)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    front = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    back = front[:, ::-1]
    sheet = np.vstack([back, front] if back_first else [front, back])
    V = np.vstack([V0, Vs])
    W = np.exp(-((V[:, 2:3] - (np.arange(4) + 0.5)[None]) ** 2) / 0.5)
    W /= W.sum(axis=1, keepdims=True)
    return Asset(mesh=Mesh(V, np.vstack([F0, sheet])), handles=base.handles, weights=sp.csr_matrix(W),
                 poses=base.poses, split=base.split)


def decimate(asset, **params):
    plugin = get_host().get("articulated-decimation", "quartic")
    asset.extras.clear()
    plugin.apply(asset, plugin.parse_params(params), StepContext())
    return asset.hierarchy, asset.levels


def _sheet_faces(F: np.ndarray) -> int:
    return int(back_faces(F).sum())


@pytest.mark.parametrize("back_first", [False, True])
def test_a_double_sided_fin_simplifies_and_stays_double_sided(back_first):
    asset = finned_tube(back_first)
    n = asset.mesh.n_faces
    hier, levels = decimate(asset, targets=[0.25], max_bones=3)
    lv = levels[0]
    # reached (without twins.py: 306 faces; the fin holds 300 of the 600)
    assert abs(lv.n_faces - round(0.25 * n)) <= 2
    assert len(hier.F) == n and hier.faces_after(0) == n
    # every face of the level's fin is there twice, once per side
    key = np.sort(lv.mesh.F, axis=1)
    uniq, counts = np.unique(key, axis=0, return_counts=True)
    fin = lv.mesh.V[uniq][:, :, 0].min(axis=1) > 0.4       # the tube's radius is 0.3; parts never merge
    assert fin.any() and (counts[fin] == 2).all() and (counts[~fin] == 1).all()
    assert back_faces(lv.mesh.F).sum() == fin.sum()
    assert 0 < fin.sum() < 75                               # the fin itself was simplified
    # the recorded face counts are the faces of every prefix, back faces included
    for t in np.linspace(0, hier.n_collapses, 9).astype(int):
        assert hier.prefix(t).n_faces == hier.faces_after(t)


def test_both_backends_make_the_same_collapses_on_a_double_sided_fin():
    h_np, _ = decimate(finned_tube(), targets=[0.25], max_bones=3, backend="numpy")
    h_nb, _ = decimate(finned_tube(), targets=[0.25], max_bones=3, backend="numba")
    assert np.array_equal(h_np.collapses, h_nb.collapses)
    assert np.array_equal(h_np.n_faces, h_nb.n_faces)


def test_face_deaths_agree_with_the_prefixes():
    asset = finned_tube()
    hier, _ = decimate(asset, targets=[0.2], max_bones=3)
    F = hier.F
    death = face_deaths(F, hier.collapses, hier.n_original)
    m = hier.n_original
    for t in range(0, hier.n_collapses + 1, 7):
        applied = np.zeros(hier.n_collapses, bool)
        applied[:t] = True
        R = hier._ancestors(applied)[F]
        alive = (R[:, 0] != R[:, 1]) & (R[:, 1] != R[:, 2]) & (R[:, 2] != R[:, 0])
        assert np.array_equal(alive, death >= t), t
    assert (death <= hier.n_collapses).all() and m == len(hier.V) - hier.n_collapses


def test_with_back_faces_only_counts_them():
    asset = finned_tube()
    hier, _ = decimate(asset, targets=[0.25], max_bones=3)
    back = back_faces(hier.F)
    again = with_back_faces(hier, hier.F, np.zeros(len(hier.F), bool))   # no back face: the same counts
    assert np.array_equal(again.n_faces, hier.n_faces)
    assert _sheet_faces(hier.F) == back.sum() == 150
