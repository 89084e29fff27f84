"""Blended-matrix normals for skeletons, the math: the inverse transpose of the blended linear part.

Linear blend skinning moves vertex v by ``X_v = sum_l w_l T_{i_l}``; near v
the deformation is (to first order, ignoring the weight gradients) the
linear map ``R_v = sum_l w_l R_{i_l}`` (the 3x3 parts), so normals move by
``R_v^{-T}`` ([P10] section 5, docs/algorithms.md section 3).
"""

from __future__ import annotations

import numpy as np

from rigslim.numerics.blend import blended_matrices


def _cofactor_apply_det(R: np.ndarray, n: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(cof(R) n, det R)`` from the rows' cross products, on contiguous components (no LU, no np.cross)."""
    a0, a1, a2 = R[:, 0, 0], R[:, 0, 1], R[:, 0, 2]
    b0, b1, b2 = R[:, 1, 0], R[:, 1, 1], R[:, 1, 2]
    c0, c1, c2 = R[:, 2, 0], R[:, 2, 1], R[:, 2, 2]
    nx, ny, nz = n[:, 0], n[:, 1], n[:, 2]
    u0, u1, u2 = b1 * c2 - b2 * c1, b2 * c0 - b0 * c2, b0 * c1 - b1 * c0      # r1 x r2
    out = np.empty((len(R), 3))
    out[:, 0] = u0 * nx + u1 * ny + u2 * nz
    out[:, 1] = (c1 * a2 - c2 * a1) * nx + (c2 * a0 - c0 * a2) * ny + (c0 * a1 - c1 * a0) * nz   # (r2 x r0) . n
    out[:, 2] = (a1 * b2 - a2 * b1) * nx + (a2 * b0 - a0 * b2) * ny + (a0 * b1 - a1 * b0) * nz   # (r0 x r1) . n
    return out, a0 * u0 + a1 * u1 + a2 * u2


def cofactor_apply(R: np.ndarray, n: np.ndarray) -> np.ndarray:
    """``cof(R) n = det(R) R^{-T} n`` for stacks of 3x3 matrices, without a division.

    With rows ``r0, r1, r2`` of R, ``cof(R) n = (n.(r1 x r2), n.(r2 x r0), n.(r0 x r1))``.

    Parameters
    ----------
    R : (m, 3, 3) array
    n : (m, 3) array

    Returns
    -------
    (m, 3) array
    """
    return _cofactor_apply_det(R, n)[0]


def normalize_rows(N: np.ndarray) -> np.ndarray:
    """Rows scaled to unit length (zero rows stay zero)."""
    length = np.linalg.norm(N, axis=1, keepdims=True)
    return N / np.where(length > 0, length, 1.0)


def blended_matrix_normals(N0: np.ndarray, weights, T: np.ndarray) -> np.ndarray:
    """Normals transformed by the inverse transpose of the blended linear part.

    Parameters
    ----------
    N0 : (m, 3) array
        Rest unit normals.
    weights : (m, n) sparse matrix or ReducedWeights
    T : (n, 3, 4) array
        One pose's handle transforms.

    Returns
    -------
    (m, 3) array
        Unit normals.

    Notes
    -----
    With ``R_v = sum_l w_l R_{i_l}`` (3x3 part of the blended transform),

    .. math:: n'_v = \\operatorname{sign}(\\det R_v)\\,
              \\frac{\\operatorname{cof}(R_v)\\, n_v}{\\lVert \\operatorname{cof}(R_v)\\, n_v \\rVert},
              \\qquad \\operatorname{cof}(R) = \\det(R)\\, R^{-T}.

    Equal to ``normalize(R_v^{-T} n_v)``; the sign keeps orientation under
    reflections. Identity at rest (``R_v = I``); exact for rigid motion of a
    vertex's bones.
    """
    return normals_from_linear_parts(blended_matrices(weights, T)[:, :, :3], N0)


def normals_from_linear_parts(R: np.ndarray, N0: np.ndarray) -> np.ndarray:
    """``sign(det R) normalize(cof(R) n)`` per vertex, for (m, 3, 3) blended linear parts R."""
    N, det = _cofactor_apply_det(R, N0)
    return normalize_rows(N * np.sign(det)[:, None])
