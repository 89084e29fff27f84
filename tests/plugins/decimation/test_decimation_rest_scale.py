"""The rest scale (``setup.rest_scale``): a collapse costs the same whatever units the rest pose is in.

glTF files from gltfpack (KHR_mesh_quantization: integer rest positions, dequantised by the inverse bind
matrices) and FBX conversions (a rest mesh in centimetres under a 0.01 armature) have rest positions in other
units than their poses. The face-side error and the round-off thresholds are measured at rest; without the
scale, gltfpack's wolf (rest diagonal 20,107 for 4.2 m) had costs 1,349 times the original's, and
``rigslim lod`` said that its first collapse already exceeded ``--max-error 1%``.
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp
from test_decimation_source_error import finned_ring, rigid_asset

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.model.poses import Poses
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.setup import degenerate_area, rest_scale, zero_cost


def rotations(n: int, seed: int = 0) -> np.ndarray:
    """(n, 3, 3) random rotations (QR of Gaussian matrices, determinant +1)."""
    q, r = np.linalg.qr(np.random.default_rng(seed).normal(size=(n, 3, 3)))
    q = q * np.sign(np.diagonal(r, axis1=1, axis2=2))[:, None, :]
    return q * np.sign(np.linalg.det(q))[:, None, None]


def poses(P: int, n: int, scale=1.0, seed: int = 0) -> np.ndarray:
    T = np.zeros((P, n, 3, 4))
    T[..., :3] = rotations(P * n, seed).reshape(P, n, 3, 3) * np.asarray(scale, float)[..., None, None]
    T[..., 3] = np.random.default_rng(seed + 1).normal(size=(P, n, 3))
    return T


def test_rigid_transforms_give_exactly_one():
    """Rotations with float32 round-off (a glTF file's) give 1.0 exactly, so that ordinary files are untouched."""
    T = poses(7, 5).astype(np.float32).astype(np.float64)
    W = np.random.default_rng(2).random((40, 5))
    assert rest_scale(W, T) == 1.0


@pytest.mark.parametrize("s", [0.01, 1 / 64, 100.0, 0.000208143])
def test_a_uniform_scale_is_found(s):
    assert rest_scale(np.ones((10, 3)), poses(4, 3, s)) == pytest.approx(s, rel=1e-6)


def test_joints_count_by_their_use_and_singular_ones_not_at_all():
    """The weighted median: joint 0 (scale 2) carries 3/4 of the weight, joint 1 (scale 1/2) 1/4, so s = 2, and
    with the weights the other way s = 1/2; joint 2, used as much as both, is scaled to nothing (a hidden part)
    and does not count."""
    T = poses(3, 3, np.array([2.0, 0.5, 0.0]))
    W = np.array([[0.75, 0.25, 1.0]] * 4)
    assert rest_scale(W, T) == 2.0
    assert rest_scale(W[:, [1, 0, 2]], T) == 0.5
    assert rest_scale(sp.csr_matrix(W), T) == rest_scale(W, T)
    assert rest_scale(W, np.zeros((2, 3, 3, 4))) == 1.0               # nothing to measure: no scale


def test_a_part_hidden_in_some_poses_does_not_move_the_scale():
    """A weapon hidden by scaling its joint to 1e-4 in two of five poses, and a joint that squashes to 0.8 in one:
    the medians keep s = 0.01 (a centimetre rest), where the mean of the logs would not."""
    T = poses(5, 3, 0.01)
    T[1:3, 2, :, :3] *= 1e-4
    T[4, 1, :, :3] *= 0.8
    W = np.array([[0.2, 0.3, 0.5]] * 6)
    assert rest_scale(W, T) == pytest.approx(0.01, rel=1e-5)


def test_the_thresholds_are_in_posed_units():
    V = np.random.default_rng(0).random((30, 3))
    F = np.array([[0, 1, 2], [2, 3, 4]])
    for normalised in (False, True):
        assert zero_cost(64 * V, F, 5, normalised, 1 / 64) == pytest.approx(zero_cost(V, F, 5, normalised))
    assert degenerate_area(64 * V, 1 / 64) == pytest.approx(degenerate_area(V))


def scaled(asset: Asset, c: float) -> Asset:
    """The same animation with the rest mesh in units ``c`` times smaller: V' = c V, A' = A / c."""
    T = asset.poses.T.copy()
    T[..., :3] /= c
    return Asset(mesh=Mesh(asset.mesh.V * c, asset.mesh.F), weights=asset.weights, poses=Poses(T),
                 split=asset.split)


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_the_hierarchy_does_not_depend_on_the_rest_units(backend):
    """The finned ring with its rest in units 64 times smaller (a power of two: every posed position is the
    same float) makes the same collapses with the same errors, in both loops; its rest positions are 64 times
    the original's. The face-side error (on for ``quartic``) is what the scale corrects: unscaled it is 4,096
    times larger and the collapses differ."""
    V, F, _ = finned_ring()
    V = V + 1e-3 * np.random.default_rng(1).normal(size=V.shape)       # no ties between rotated copies
    plugin = get_host().get("articulated-decimation", "quartic")
    params = plugin.parse_params({"targets": [0.1], "backend": backend})
    assert params.face_distance and params.source_distance
    hiers = []
    for c in (1.0, 64.0):
        asset = scaled(rigid_asset(V, F), c)
        plugin.apply(asset, params, StepContext())
        hiers.append(asset.hierarchy)
    h1, h64 = hiers
    assert h1.n_collapses > 400
    np.testing.assert_array_equal(h64.collapses, h1.collapses)
    np.testing.assert_array_equal(h64.errors, h1.errors)
    np.testing.assert_array_equal(h64.V, 64.0 * h1.V)
