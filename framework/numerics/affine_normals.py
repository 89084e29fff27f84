"""Approximate-affine normals for cages: the math ([P10] section 5, docs/algorithms.md section 3).

A cage's blended transforms have no linear part (``T_i = [0 | c_i]``), so
normals cannot come from a blended matrix. Instead each vertex fits the
affine map that best carries its influencing handles' rest positions to
their deformed positions, weighting handle l by ``w_l^2``, and moves its
normal by that map's inverse transpose. Everything that depends on the rest
pose only (the weighted centroid, ``P`` and ``P n``) is computed once per
mesh; a pose costs one 3x3 adjugate per vertex, so it fits in a vertex
shader without adjacency.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blended_normals import normalize_rows

#: A vertex whose weighted rest handles (nearly) span less than 3 dimensions
#: (``lambda_min(P) < DEGENERATE * lambda_max(P)``) gets a ridge term. At a
#: condition number of 1e4 float32 (GPU) arithmetic already loses about
#: 1e-4 rad on the fit, so such fits count as undetermined.
DEGENERATE = 1e-4
#: Ridge weight, relative to ``trace(P) / 3``, for such vertices.
RIDGE = 1e-3


@dataclass(frozen=True)
class AffineFitRest:
    """Rest-pose part of the per-vertex affine fit.

    Attributes
    ----------
    q : (m, 3) array
        ``(P + lambda I) n`` per vertex.
    ridge : (m,) array
        ``lambda`` per vertex: 0 where the fit is determined, ``RIDGE trace(P)/3`` where not.
    degenerate : (m,) bool array
        Vertices whose weighted handles are (nearly) coplanar, collinear or single.
    """

    q: np.ndarray
    ridge: np.ndarray
    degenerate: np.ndarray


def squared_weights(weights) -> sp.csr_matrix:
    """``w^2`` as an (m, n) CSR matrix, from sparse or fixed-k weights (padding drops out)."""
    A = weights.to_sparse() if isinstance(weights, ReducedWeights) else sp.csr_matrix(weights)
    return sp.csr_matrix(A.multiply(A))


def _weighted_outer(W2: sp.csr_matrix, A: np.ndarray, B: np.ndarray) -> np.ndarray:
    """``sum_l w_l^2 (a_l - abar)(b_l - bbar)^T`` per vertex, (m, 3, 3)."""
    sw = np.asarray(W2.sum(axis=1)).ravel()
    sw = np.where(sw > 0, sw, 1.0)
    abar = (W2 @ A) / sw[:, None]
    bbar = (W2 @ B) / sw[:, None]
    outer = (A[:, :, None] * B[:, None, :]).reshape(len(A), 9)
    return (W2 @ outer).reshape(-1, 3, 3) - sw[:, None, None] * abar[:, :, None] * bbar[:, None, :]


def affine_fit_rest(weights, C0: np.ndarray, N0: np.ndarray) -> AffineFitRest:
    """Precompute ``q = (P + lambda I) n`` and the ridge ``lambda`` of every vertex.

    Parameters
    ----------
    weights : (m, n) sparse matrix or ReducedWeights
    C0 : (n, 3) array
        Rest positions of the handles (cage vertices).
    N0 : (m, 3) array
        Rest unit normals.

    Notes
    -----
    ``P_v = sum_l w_l^2 (c_l - cbar)(c_l - cbar)^T`` with the weighted centroid
    ``cbar = sum_l w_l^2 c_l / sum_l w_l^2``. Where P is (nearly) singular the
    affine fit is not determined; a ridge ``lambda ||M - I||_F^2`` added to the
    fitting energy replaces P by ``P + lambda I`` and X by ``X + lambda I``,
    i.e. undetermined directions follow the identity.
    """
    C0 = np.asarray(C0, dtype=np.float64)
    C0 = C0 - C0.mean(axis=0)          # P is translation invariant; centring keeps the sums well conditioned
    W2 = squared_weights(weights)
    P = _weighted_outer(W2, C0, C0)
    eig = np.linalg.eigvalsh(P)
    degenerate = eig[:, 0] <= DEGENERATE * np.maximum(eig[:, 2], 1e-300)
    ridge = np.where(degenerate, RIDGE * np.trace(P, axis1=1, axis2=2) / 3.0, 0.0)
    ridge = np.where(degenerate & (ridge <= 0), 1.0, ridge)  # a single influence: P = 0
    q = np.einsum("vij,vj->vi", P, N0) + ridge[:, None] * N0
    return AffineFitRest(q=q, ridge=ridge, degenerate=degenerate)


def handle_positions(T: np.ndarray, C0: np.ndarray) -> np.ndarray:
    """Deformed handle positions ``chat_i = T_i [c_i; 1]`` ((n, 3); for a cage ``T_i = [0 | chat_i]``)."""
    return np.einsum("nij,nj->ni", T[:, :, :3], C0) + T[:, :, 3]


def approximate_affine_normals(weights, C0: np.ndarray, T: np.ndarray, rest: AffineFitRest) -> np.ndarray:
    """Normals moved by the inverse transpose of each vertex's weighted affine fit.

    Parameters
    ----------
    weights : (m, n) sparse matrix or ReducedWeights
    C0 : (n, 3) array
        Rest handle positions.
    T : (n, 3, 4) array
        One pose's handle transforms.
    rest : AffineFitRest
        From :func:`affine_fit_rest` on the same weights, handles and rest normals.

    Returns
    -------
    (m, 3) array
        Unit normals.

    Notes
    -----
    With ``chat_l = T_l [c_l; 1]``, the weighted centroids ``cbar``, ``chatbar``,
    ``P = sum w_l^2 (c_l - cbar)(c_l - cbar)^T`` and
    ``X = sum w_l^2 (c_l - cbar)(chat_l - chatbar)^T``, the fitted linear map is
    ``M = X^T P^{-1}``, whose inverse transpose is ``X^{-1} P = adj(X) P / det X``:

    .. math:: n' = \\operatorname{sign}(\\det X)\\,
              \\frac{\\operatorname{adj}(X)\\, P n}{\\lVert \\operatorname{adj}(X)\\, P n \\rVert}

    (with ``P, X`` replaced by ``P + lambda I, X + lambda I`` on degenerate
    vertices). At rest ``X = P``, so ``n' = n``; when a vertex has 4 affinely
    independent influences and the cage moves by an affine map, the fit is
    that map and ``n'`` is exact.
    """
    C0 = np.asarray(C0, dtype=np.float64)
    Chat = handle_positions(np.asarray(T, dtype=np.float64), C0)
    C0c = C0 - C0.mean(axis=0)
    W2 = squared_weights(weights)
    X = _weighted_outer(W2, C0c, Chat - Chat.mean(axis=0))
    X = X + rest.ridge[:, None, None] * np.eye(3)
    r0, r1, r2 = X[:, 0], X[:, 1], X[:, 2]
    q = rest.q
    N = q[:, :1] * np.cross(r1, r2) + q[:, 1:2] * np.cross(r2, r0) + q[:, 2:3] * np.cross(r0, r1)
    det = np.einsum("ij,ij->i", r0, np.cross(r1, r2))
    return normalize_rows(N * np.sign(det)[:, None])


def cage_rest_positions(handles) -> np.ndarray:
    """Rest handle positions of a cage, or a StepError naming the fix for skeletons."""
    if handles is None or not handles.is_cage:
        raise StepError("approximate-affine normals fit handle positions, which only a cage has",
                        field="normals", fix="use 'normals: blended-matrix' for skeletons")
    return handles.cage.V
