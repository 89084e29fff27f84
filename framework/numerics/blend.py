"""Linear blending of handle transforms, the numpy reference of every deformer.

``v^j = sum_i a_{v,i} T_i^j [v; 1]`` (docs/algorithms.md section 1), for sparse
input weights and for fixed-k reduced weights alike.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from rigslim.model.weights import ReducedWeights


def blended_matrices(weights, T: np.ndarray) -> np.ndarray:
    """Per-vertex blended transforms ``X_v = sum_i a_{v,i} T_i``.

    Parameters
    ----------
    weights : (m, n) sparse matrix or ReducedWeights
    T : (n, 3, 4) array
        One pose's handle transforms.

    Returns
    -------
    (m, 3, 4) array
    """
    n = T.shape[0]
    flat = T.reshape(n, 12)
    if isinstance(weights, ReducedWeights):
        X = np.einsum("vk,vkc->vc", weights.values, flat[weights.indices])
    else:
        X = np.asarray(sp.csr_matrix(weights) @ flat)
    return X.reshape(-1, 3, 4)


def linear_blend(V: np.ndarray, weights, T: np.ndarray) -> np.ndarray:
    """Deformed positions of one pose.

    Parameters
    ----------
    V : (m, 3) array
        Rest positions.
    weights : (m, n) sparse matrix or ReducedWeights
    T : (n, 3, 4) array

    Returns
    -------
    (m, 3) array
        ``v' = X_v [v; 1]`` with ``X_v = sum_i a_{v,i} T_i``.

    Example
    -------
    >>> import numpy as np, scipy.sparse as sp
    >>> T = np.zeros((1, 3, 4)); T[0, :, :3] = np.eye(3); T[0, :, 3] = [1, 0, 0]
    >>> linear_blend(np.zeros((2, 3)), sp.csr_matrix(np.ones((2, 1))), T)[0]
    array([1., 0., 0.])
    """
    X = blended_matrices(weights, T)
    return np.einsum("vij,vj->vi", X[:, :, :3], V) + X[:, :, 3]


def basis_positions(V: np.ndarray, T: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Basis positions ``b_{v,l}^j = T_{i_l}^j [v; 1]`` for given influence indices.

    Parameters
    ----------
    V : (m, 3) array
    T : (p, n, 3, 4) array
        Handle transforms of p poses.
    indices : (m, k) int array

    Returns
    -------
    (p, m, k, 3) array
        So that the reduced deformation is ``v^j = sum_l alpha_{v,l} b_{v,l}^j``.
    """
    Tv = T[:, indices]  # (p, m, k, 3, 4)
    return np.einsum("pmkij,mj->pmki", Tv[..., :3], V) + Tv[..., 3]


def per_vertex_normals(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (as ``igl.per_vertex_normals``, AREA weighting, to rounding).

    Applies the face->vertex operator of F, built once per face array
    (:mod:`rigslim.numerics.area_weighted_normals`); libigl where numba is missing.
    """
    try:
        from rigslim.numerics.area_weighted_normals import area_weighted_normals
    except ImportError:            # a minimal install without numba (the GPU machine)
        import igl

        return igl.per_vertex_normals(np.ascontiguousarray(V, dtype=np.float64), F,
                                      igl.PER_VERTEX_NORMALS_WEIGHTING_TYPE_AREA)
    return area_weighted_normals(V, F)
