"""Rotations of glTF nodes: quaternions ``(x, y, z, w)``, TRS matrices, slerp, and rigid parts of 3x4 transforms.

The reader (:mod:`rigslim.io.gltf`) turns node TRS and animation channels into matrices; the writer
(:mod:`rigslim.io.gltf.write`) turns rigid 3x4 handle transforms back into rotations and translations.
Both directions live here so that they stay each other's inverse (glTF 2.0 specification, section 3.5.2
"Transformations", and Appendix C for spherical linear interpolation).
"""

from __future__ import annotations

import numpy as np

from rigslim.errors import InputError

__all__ = ["matrix_quaternion", "quaternion_matrix", "rigid_parts", "slerp", "trs_matrix"]


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices of unit quaternions in glTF order ``(x, y, z, w)``.

    Parameters
    ----------
    q : (..., 4) array

    Returns
    -------
    (..., 3, 3) array

    Notes
    -----
    ``R = I + 2 w [u]_x + 2 [u]_x^2`` for ``q = (u, w)`` normalised first.
    """
    q = np.asarray(q, dtype=np.float64)
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    x, y, z, w = np.moveaxis(q, -1, 0)
    R = np.empty(q.shape[:-1] + (3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def trs_matrix(t: np.ndarray, r: np.ndarray, s: np.ndarray) -> np.ndarray:
    """(..., 4, 4) matrices ``T @ R @ S`` from translations, quaternions (x, y, z, w) and scales."""
    t, r, s = (np.asarray(x, dtype=np.float64) for x in (t, r, s))
    shape = np.broadcast_shapes(t.shape[:-1], r.shape[:-1], s.shape[:-1])
    M = np.zeros(shape + (4, 4))
    M[..., :3, :3] = quaternion_matrix(r) * s[..., None, :]
    M[..., :3, 3] = t
    M[..., 3, 3] = 1.0
    return M


def slerp(q0: np.ndarray, q1: np.ndarray, u: np.ndarray) -> np.ndarray:
    """Spherical linear interpolation of unit quaternions along the shorter arc.

    Notes
    -----
    ``slerp(q0, q1, u) = sin((1-u) a) / sin a * q0 + sin(u a) / sin a * q1``
    with ``cos a = |q0 . q1|`` and ``q1`` negated when ``q0 . q1 < 0``
    (glTF 2.0 Appendix C); falls back to normalised lerp when ``a`` is tiny.
    """
    q0 = np.asarray(q0, float)
    q1 = np.asarray(q1, float)
    u = np.asarray(u, float)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.abs(d)
    a = np.arccos(np.clip(d, -1.0, 1.0))
    sa = np.sin(a)
    small = sa < 1e-6
    sa_safe = np.where(small, 1.0, sa)
    w0 = np.where(small, 1 - u, np.sin((1 - u) * a) / sa_safe)
    w1 = np.where(small, u, np.sin(u * a) / sa_safe)
    q = w0 * q0 + w1 * q1
    return q / np.linalg.norm(q, axis=-1, keepdims=True)


def matrix_quaternion(R: np.ndarray) -> np.ndarray:
    """Unit quaternions ``(x, y, z, w)`` of rotation matrices (Shepperd's method).

    Parameters
    ----------
    R : (..., 3, 3) rotation matrices

    Returns
    -------
    (..., 4) array with ``w >= 0``

    Notes
    -----
    Picks the largest of ``4w^2 = 1 + tr R`` and ``4x^2 = 1 + R_00 - R_11 - R_22``
    (and y, z alike) for stability, then recovers the other components from
    the off-diagonal sums and differences.
    """
    R = np.asarray(R, dtype=np.float64)
    shape = R.shape[:-2]
    R = R.reshape(-1, 3, 3)
    tr = np.trace(R, axis1=1, axis2=2)
    d = np.stack([tr, R[:, 0, 0], R[:, 1, 1], R[:, 2, 2]], 1)
    case = np.argmax(d, axis=1)
    q = np.empty((len(R), 4))
    for c in range(4):
        s = case == c
        if not s.any():
            continue
        M = R[s]
        if c == 0:
            w = 0.5 * np.sqrt(np.maximum(1 + tr[s], 0))
            f = 0.25 / w
            q[s] = np.stack([(M[:, 2, 1] - M[:, 1, 2]) * f, (M[:, 0, 2] - M[:, 2, 0]) * f,
                             (M[:, 1, 0] - M[:, 0, 1]) * f, w], 1)
        else:
            i, j, k = [(0, 1, 2), (1, 2, 0), (2, 0, 1)][c - 1]
            a = 0.5 * np.sqrt(np.maximum(1 + M[:, i, i] - M[:, j, j] - M[:, k, k], 0))
            f = 0.25 / a
            v = np.empty((s.sum(), 4))
            v[:, i] = a
            v[:, j] = (M[:, j, i] + M[:, i, j]) * f
            v[:, k] = (M[:, k, i] + M[:, i, k]) * f
            v[:, 3] = (M[:, k, j] - M[:, j, k]) * f
            q[s] = v
    q *= np.where(q[:, 3:] < 0, -1.0, 1.0)
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    return q.reshape(shape + (4,))


def rigid_parts(T: np.ndarray, *, tolerance: float = 1e-5, source=None) -> tuple[np.ndarray, np.ndarray]:
    """Split 3x4 transforms into rotations and translations, checking that they are rigid.

    Parameters
    ----------
    T : (..., 3, 4) array

    Returns
    -------
    R : (..., 3, 3), t : (..., 3)

    Notes
    -----
    Rigid means ``||R^T R - I||_max <= tolerance`` and ``det R > 0``; only
    such transforms are a glTF joint's rotation and translation (TRS
    channels cannot hold shear).
    """
    T = np.asarray(T, dtype=np.float64)
    R, t = T[..., :3], T[..., 3]
    err = np.abs(np.einsum("...ji,...jk->...ik", R, R) - np.eye(3)).max(axis=(-1, -2))
    det = np.linalg.det(R)
    if err.size and (err.max() > tolerance or det.min() <= 0):
        bad = np.unravel_index(int(np.argmax(err + (det <= 0))), err.shape)
        raise InputError(f"bone transform {tuple(int(x) for x in bad)} is not a rotation plus translation "
                         f"(it scales: |R^T R - I| = {err[bad]:.2g}, det = {det[bad]:.3g})",
                         source=source, field="animation",
                         fix="start from the glTF source, or write USD (glTF export: rotation + translation)")
    return R, t
