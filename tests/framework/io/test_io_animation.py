import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.io import read_dmat, read_mesh, read_stacked_animation
from rigslim.io.animation import stacked_to_transforms, transforms_to_stacked
from rigslim.numerics.blend import linear_blend


def test_stacked_round_trip(rng):
    T = rng.standard_normal((5, 3, 3, 4))
    np.testing.assert_array_equal(stacked_to_transforms(transforms_to_stacked(T)), T)


def test_elephant_animation_matches_libigl_convention(data_dir):
    poses = read_stacked_animation(data_dir / "elephant-anim.dmat", n_handles=24)
    assert poses.T.shape == (457, 24, 3, 4)
    rest = np.zeros((24, 3, 4))
    rest[:, :, :3] = np.eye(3)
    np.testing.assert_allclose(poses.T[0], rest, atol=1e-12)
    R = poses.T[100, :, :, :3]
    np.testing.assert_allclose(R @ R.transpose(0, 2, 1), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    # DATA.md's formula: sum_b W[:, b] * ([V, 1] @ T[4b:4b+4]) with the column read as (96, 3) F-order.
    mesh = read_mesh(data_dir / "elephant.obj")
    W = read_dmat(data_dir / "elephant-weights.dmat")
    col = read_dmat(data_dir / "elephant-anim.dmat")[:, 100].reshape(96, 3, order="F")
    V1 = np.hstack([mesh.V, np.ones((mesh.n_vertices, 1))])
    expected = sum(W[:, [b]] * (V1 @ col[4 * b:4 * b + 4]) for b in range(24))
    np.testing.assert_allclose(linear_blend(mesh.V, W, poses.T[100]), expected, atol=1e-9)


def test_wrong_bone_count(data_dir):
    with pytest.raises(InputError, match="24 bones"):
        read_stacked_animation(data_dir / "elephant-anim.dmat", n_handles=20)
