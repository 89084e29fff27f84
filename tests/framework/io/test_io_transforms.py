"""rigslim.io.transforms: quaternions and TRS matrices of glTF nodes, both directions."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigslim.errors import InputError
from rigslim.io.transforms import matrix_quaternion, quaternion_matrix, rigid_parts, slerp, trs_matrix


def test_matrix_quaternion_inverts_quaternion_matrix(rng):
    R = Rotation.random(200, random_state=1).as_matrix()
    q = matrix_quaternion(R)
    assert (q[:, 3] >= 0).all()
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0, atol=1e-14)
    np.testing.assert_allclose(quaternion_matrix(q), R, atol=1e-12)
    # and the other way round, up to the sign of q
    q0 = rng.standard_normal((50, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    q1 = matrix_quaternion(quaternion_matrix(q0))
    np.testing.assert_allclose(np.abs(np.einsum("ij,ij->i", q0, q1)), 1.0, atol=1e-12)


def test_trs_matrix_splits_back_into_rigid_parts():
    q = Rotation.from_euler("xyz", [0.3, -0.2, 1.1]).as_quat()
    M = trs_matrix(np.array([1.0, 2.0, 3.0]), q, np.ones(3))
    R, t = rigid_parts(M[:3])
    np.testing.assert_allclose(R, quaternion_matrix(q), atol=1e-14)
    np.testing.assert_allclose(t, [1, 2, 3])


@pytest.mark.parametrize("bad", [np.diag([1.0, 1.0, 2.0]), np.diag([1.0, 1.0, -1.0])])
def test_rigid_parts_refuses_scale_and_reflection(bad):
    T = np.concatenate([bad, np.zeros((3, 1))], axis=1)[None]
    with pytest.raises(InputError, match="not a rotation plus translation"):
        rigid_parts(T)


def test_slerp_is_a_geodesic():
    a = Rotation.from_euler("z", 0.0).as_quat()
    b = Rotation.from_euler("z", 1.2).as_quat()
    for u in (0.0, 0.25, 1.0):
        angle = Rotation.from_quat(slerp(a, b, u)).as_euler("xyz")[2]
        assert angle == pytest.approx(1.2 * u, abs=1e-12)
