"""Automatic cages, weight transfer and skinned cage poses (rigslim.plugins.generators.cage)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.mesh import Mesh
from rigslim.model.poses import Poses
from rigslim.plugins.generators.cage import build_cage, enclosure, skinned_cage_poses, transfer_weights


def test_build_cage_encloses_the_elephant(elephant):
    cage = build_cage(elephant.mesh, 60, resolution=40)
    assert abs(cage.n_vertices - 60) <= 6
    enc = enclosure(cage, elephant.mesh.V)
    assert not enc.outside.any()
    assert enc.winding.min() > 0.99
    assert enc.clearance.min() > 0
    # closed and consistently oriented: every edge is shared by exactly two faces in opposite directions
    E = np.concatenate([cage.F[:, [0, 1]], cage.F[:, [1, 2]], cage.F[:, [2, 0]]])
    directed = {tuple(e) for e in E}
    assert len(directed) == len(E)
    assert all((b, a) in directed for a, b in E)


def test_enclosure_flags_outside_points():
    tet = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
               np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    enc = enclosure(tet, np.array([[0.1, 0.1, 0.1], [1.0, 1.0, 1.0], [0.01, 0.2, 0.2]]), min_clearance=0.05)
    assert enc.outside.tolist() == [False, True, True]
    assert enc.winding[0] == pytest.approx(1.0)
    assert enc.winding[1] == pytest.approx(0.0, abs=1e-12)


def test_build_cage_rejects_degenerate_requests(elephant):
    with pytest.raises(StepError):
        build_cage(elephant.mesh, 3)


def test_transfer_weights_at_mesh_vertices_is_identity(elephant):
    idx = np.arange(0, elephant.mesh.n_vertices, 97)
    Wt = transfer_weights(elephant.mesh, elephant.weights, elephant.mesh.V[idx])
    assert abs(Wt - elephant.weights[idx]).max() < 1e-12
    assert np.allclose(np.asarray(Wt.sum(axis=1)).ravel(), 1.0)


def test_skinned_cage_poses_follow_rigid_motion():
    cage = Mesh(np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.0]]),
                np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]]))
    W = sp.csr_matrix(np.array([[1.0, 0], [0.5, 0.5], [0, 1.0], [0.25, 0.75]]))
    c, s = np.cos(0.4), np.sin(0.4)
    R = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    T = np.zeros((2, 2, 3, 4))
    T[:, :, :, :3] = np.eye(3)
    T[1, :, :, :3] = R            # pose 1: both bones rotate alike, then translate
    T[1, :, :, 3] = [1.0, 2.0, 3.0]
    out = skinned_cage_poses(cage, W, Poses(T))
    assert out.T.shape == (2, 4, 3, 4)
    assert np.allclose(out.T[0, :, :, 3], cage.V)
    assert np.allclose(out.T[1, :, :, 3], cage.V @ R.T + [1, 2, 3])
    assert np.all(out.T[..., :3] == 0)


@pytest.mark.parametrize("extra, message", [
    ("    cage_poses: keep\n", "poses have 24 handles"),
    ("    cage_poses: from-skeleton\n", None),
])
def test_cage_poses_options(write_pipeline, extra, message):
    """Skeleton poses cannot drive a cage unless skinned; from-skeleton makes cage poses."""
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
steps:
  - generate: mean-value
    cage: auto
    cage_vertices: 30
    cage_resolution: 24
""" + extra)
    if message:
        with pytest.raises(StepError, match=message):
            run_pipeline(path)
    else:
        asset = run_pipeline(path).asset
        assert asset.poses.n_handles == asset.handles.n == 30
        assert asset.extras["skeleton"].n == 24


def test_from_skeleton_needs_a_skeleton(write_pipeline, tmp_path):
    from rigslim.runtime.run import run_pipeline

    # a regular tetrahedron far around the elephant, as a user cage
    V = 1000.0 * np.array([[1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1]])
    F = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    (tmp_path / "tet.obj").write_text("".join(f"v {x} {y} {z}\n" for x, y, z in V)
                                      + "".join(f"f {a + 1} {b + 1} {c + 1}\n" for a, b, c in F))
    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  cage: tet.obj
steps:
  - generate: mean-value
    cage_poses: from-skeleton
""")
    with pytest.raises(StepError, match="needs a skeleton"):
        run_pipeline(path)
    # without the option the user cage works, and its four coordinates are barycentric (all positive)
    path.write_text(path.read_text().replace("    cage_poses: from-skeleton\n", ""))
    asset = run_pipeline(path).asset
    assert asset.weights.shape[1] == 4 and asset.weights.min() > 0
