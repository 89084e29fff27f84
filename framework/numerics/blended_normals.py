"""Blended-matrix normals for skeletons, the math: the inverse transpose of the blended linear part.

Linear blend skinning moves vertex v by ``X_v = sum_l w_l T_{i_l}``; near v
the deformation is (to first order, ignoring the weight gradients) the
linear map ``R_v = sum_l w_l R_{i_l}`` (the 3x3 parts), so normals move by
``R_v^{-T}`` ([P10] section 5, docs/algorithms.md section 3).
"""

from __future__ import annotations

import numpy as np

from rigslim.blend import blended_matrices


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
    r0, r1, r2 = R[:, 0], R[:, 1], R[:, 2]
    return np.stack([np.einsum("ij,ij->i", np.cross(r1, r2), n),
                     np.einsum("ij,ij->i", np.cross(r2, r0), n),
                     np.einsum("ij,ij->i", np.cross(r0, r1), n)], axis=1)


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
    N = cofactor_apply(R, N0)
    return normalize_rows(N * np.sign(np.linalg.det(R))[:, None])
