"""The weight-reduction energies of [P10] as one quadratic problem.

Every method (geometric, smooth, Poisson; docs/algorithms.md section 2) is

    E(alpha) = sum_c (X_c - Y_c)^T Q (X_c - Y_c) + eps ||alpha - alpha0||^2
    X_{v,c}  = sum_l alpha_{v,l} B_{v,l,c}

subject, per vertex, to ``C_v alpha_v = d_v`` (sum to one; plus linear
precision on cages) and optionally ``alpha_v >= 0``, where

- ``alpha`` (m, k) are the weights on the influence sets,
- ``B`` (m, k, D) is a per-vertex basis and ``Y`` (m, D) the target:
  for geometric and Poisson, ``B_{v,l} = [b_{v,l}^1; ...; b_{v,l}^p]`` stacks
  the basis positions ``b_{v,l}^j = T_{i_l}^j [v; 1]`` of the p example poses
  (D = 3p) and ``Y_v`` the full deformation ``vhat_v^j``; for smooth weights,
  ``B_{v,l} = e_{i_l}`` (D = n handles) and ``Y = A`` the input weights,
- ``Q`` (m, m) couples vertices: ``I`` for geometric (eq. 3),
  ``L^T M^-1 L`` (mass-weighted) or ``L^T L`` (plain) for smooth and
  Poisson, plus ``lambda s W`` for Poisson's position term (W = M or I,
  ``s = tr(L^T M^-1 L) / tr(W)`` so that lambda is dimensionless),
- ``eps`` is a tiny ridge towards the k-largest weights ``alpha0``
  (``ridge`` times the mean diagonal of the local Hessians) that makes the
  problem strictly convex (the Poisson energy does not see translations).

Padding slots (``valid`` False) have zero basis and are pinned to zero.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.numerics.blend import basis_positions, linear_blend
from rigslim.numerics.clip_balance import fit_transforms

if TYPE_CHECKING:
    from rigslim.model.weights import InfluenceSets

#: Default ridge, relative to the mean diagonal of the local Hessians.
RIDGE = 1e-9


@dataclass
class ReductionProblem:
    """One convex quadratic reduction problem (see module docstring).

    Attributes
    ----------
    B : (m, k, D) array
    Y : (m, D) array
    Q : (m, m) csr_matrix, symmetric positive semi-definite
    C : (m, q, k) array
    d : (m, q) array
    valid : (m, k) bool array
    alpha0 : (m, k) array
        k-largest weights (ridge centre; rows sum to one).
    eps : float
    nonneg : bool
    coupled : bool
        False when Q is diagonal (geometric): one local pass is exact.
    info : dict
        What was built (energy name, Laplacian kind...), for the report.
    """

    B: np.ndarray
    Y: np.ndarray
    Q: sp.csr_matrix
    C: np.ndarray
    d: np.ndarray
    valid: np.ndarray
    alpha0: np.ndarray
    eps: float
    nonneg: bool
    coupled: bool = True
    info: dict = field(default_factory=dict)

    @property
    def m(self) -> int:
        return self.B.shape[0]

    @property
    def k(self) -> int:
        return self.B.shape[1]

    def blend(self, alpha: np.ndarray) -> np.ndarray:
        """``X = sum_l alpha_l B_l`` (m, D)."""
        return np.einsum("mkd,mk->md", self.B, alpha)

    def energy(self, alpha: np.ndarray) -> float:
        """``E(alpha)`` of the module docstring."""
        R = self.blend(alpha) - self.Y
        return float(np.einsum("md,md->", R, self.Q @ R) + self.eps * np.sum((alpha - self.alpha0) ** 2))

    def local_hessians(self) -> np.ndarray:
        """(m, k, k) ``Q_vv B_v^T B_v + eps I``; padding rows and columns are the identity."""
        G = np.einsum("mkd,mld->mkl", self.B, self.B)
        H = self.Q.diagonal()[:, None, None] * G
        kk = np.arange(self.k)
        H[:, kk, kk] += self.eps
        pad = ~self.valid
        H = np.where(pad[:, :, None] | pad[:, None, :], 0.0, H)
        H[:, kk, kk] = np.where(pad, 1.0, H[:, kk, kk])
        return H

    def residual_energy_terms(self, alpha):
        """``R = X - Y`` and ``Q R`` (m, D), the state a local sweep maintains."""
        R = self.blend(alpha) - self.Y
        return R, np.asarray(self.Q @ R)

    def gradient(self, alpha: np.ndarray) -> np.ndarray:
        """Half the energy gradient, ``H a + f`` (m, k) in the global solver's notation:
        ``B_v^T (Q (X - Y))_v + eps (alpha_v - alpha0_v)`` on valid slots, ``alpha_v`` on padding."""
        _, QR = self.residual_energy_terms(alpha)
        g = np.einsum("mkd,md->mk", self.B, QR) + self.eps * (alpha - self.alpha0)
        return np.where(self.valid, g, alpha)


def laplacian_operator(mesh, laplacian: str) -> tuple[sp.csr_matrix, sp.csr_matrix]:
    """``K`` (``L^T M^-1 L`` or ``L^T L``) and the matching position weight ``W`` (``M`` or ``I``)."""
    L = sp.csr_matrix(mesh.cotmatrix)
    if laplacian == "mass-weighted":
        mass = mesh.massmatrix.diagonal().copy()
        tiny = mass[mass > 0].min() * 1e-6 if (mass > 0).any() else 1.0
        mass = np.maximum(mass, tiny)
        K = (L.T @ sp.diags(1.0 / mass) @ L).tocsr()
        W = sp.diags(mass).tocsr()
    else:
        K = (L.T @ L).tocsr()
        W = sp.identity(mesh.n_vertices, format="csr")
    K = ((K + K.T) * 0.5).tocsr()
    K.sort_indices()
    return K, W


def gather(A: sp.csr_matrix, influences: InfluenceSets) -> np.ndarray:
    """(m, k) input weights ``A[v, i_l]`` on the influence sets (0 on padding slots)."""
    A = sp.csr_matrix(A)
    m, k = influences.indices.shape
    rows = np.repeat(np.arange(m), k)
    vals = np.asarray(A[rows, influences.indices.ravel()]).reshape(m, k)
    return np.where(influences.valid, vals, 0.0)


def default_nonnegative(asset) -> bool:
    """On for skeletons and for inputs without negative weights; off otherwise."""
    return (not asset.handles.is_cage) or bool(asset.weights.data.min(initial=0.0) >= 0.0)


def initial_weights(A, influences) -> np.ndarray:
    """k-largest weights (selected input weights divided by their sum; uniform where that sum is 0)."""
    vals = gather(A, influences)
    sums = vals.sum(axis=1, keepdims=True)
    nvalid = np.maximum(influences.valid.sum(axis=1, keepdims=True), 1)
    uniform = influences.valid / nvalid
    ok = np.abs(sums) > 1e-12
    return np.where(ok, vals / np.where(ok, sums, 1.0), uniform)


def constraints(asset, influences, linear_precision: bool) -> tuple[np.ndarray, np.ndarray]:
    """Per-vertex equality rows: ``1^T alpha = 1``; with linear precision on a cage also
    ``sum_l alpha_l b_{v,l}^rest = v`` (for skeletons that row is the sum row again, so it is left out)."""
    m, k = influences.indices.shape
    valid = influences.valid
    if linear_precision and asset.handles.is_cage:
        Trest = asset.handles.rest_transforms()[None]
        Brest = basis_positions(asset.mesh.V, Trest, influences.indices)[0]  # (m, k, 3)
        C = np.concatenate([np.ones((m, 1, k)), Brest.transpose(0, 2, 1)], axis=1)
        d = np.concatenate([np.ones((m, 1)), asset.mesh.V], axis=1)
    else:
        C = np.ones((m, 1, k))
        d = np.ones((m, 1))
    C = np.where(valid[:, None, :], C, 0.0)
    if C.shape[1] > 1:
        # Influence sets that cannot reproduce their vertex (e.g. 4 coplanar cage vertices
        # for a point off their plane) keep only the sum-to-one row.
        x = np.einsum("mkq,mq->mk", np.linalg.pinv(C), d)
        miss = np.linalg.norm(np.einsum("mqk,mk->mq", C, x) - d, axis=1)
        bad = miss > 1e-9 * (1.0 + np.linalg.norm(d, axis=1))
        C[bad, 1:] = 0.0
        d[bad, 1:] = 0.0
    return C, d


def pose_basis(asset, influences, balance: str = "clips", clip_scale=None):
    """Geometric / Poisson basis ``B`` (m, k, 3p) and target ``Y`` (m, 3p) of the example poses, each pose
    scaled by the square root of its frame weight (``balance`` and ``clip_scale``,
    :func:`rigslim.numerics.clip_balance.fit_transforms`)."""
    T, _ = fit_transforms(asset, influences.indices.shape[1], balance, clip_scale)
    V = asset.mesh.V
    Bp = basis_positions(V, T, influences.indices)  # (p, m, k, 3)
    p, m, k, _ = Bp.shape
    B = np.ascontiguousarray(Bp.transpose(1, 2, 0, 3)).reshape(m, k, 3 * p)
    B = np.where(influences.valid[:, :, None], B, 0.0)
    Y = np.stack([linear_blend(V, asset.weights, T[j]) for j in range(p)], axis=1).reshape(m, 3 * p)
    return B, Y


def handle_basis(asset, influences):
    """Smooth-weights basis: ``B_{v,l} = e_{i_l}`` (m, k, n) and target ``Y = A`` (m, n)."""
    m, k = influences.indices.shape
    n = asset.weights.shape[1]
    B = np.zeros((m, k, n))
    rows = np.repeat(np.arange(m), k)
    cols = np.tile(np.arange(k), m)
    B[rows, cols, influences.indices.ravel()] = influences.valid.ravel().astype(float)
    return B, asset.weights.toarray()


def build_problem(asset, method: str, *, nonnegative: bool | None = None, laplacian: str = "mass-weighted",
                  linear_precision: bool = False, position_weight: float = 0.0,
                  ridge: float = RIDGE, balance: str = "clips", clip_scale=None) -> ReductionProblem:
    """Assemble the energy of ``method`` in {"geometric", "smooth", "poisson"} on the asset's influence sets
    (``balance``, ``clip_scale``: the example frames' weights, :func:`pose_basis`)."""
    influences = asset.influences
    A = asset.weights
    if influences.n_vertices != asset.mesh.n_vertices:
        raise StepError(f"influence sets cover {influences.n_vertices} vertices but the mesh has "
                        f"{asset.mesh.n_vertices}", field="influences", fix="run 'select' on this mesh")
    nonneg = default_nonnegative(asset) if nonnegative is None else bool(nonnegative)
    alpha0 = initial_weights(A, influences)
    C, d = constraints(asset, influences, linear_precision)
    info = {"energy": method, "constraints": int(C.shape[1])}
    if C.shape[1] > 1:
        info["linear_precision_dropped"] = int((np.abs(C[:, 1:]).sum(axis=(1, 2)) == 0).sum())
    if method == "smooth":
        B, Y = handle_basis(asset, influences)
    else:
        B, Y = pose_basis(asset, influences, balance, clip_scale)
        info["example_poses"] = int(Y.shape[1] // 3)
        info["balance"] = balance
    if method == "geometric":
        Q = sp.identity(asset.mesh.n_vertices, format="csr")
        coupled = False
    else:
        K, W = laplacian_operator(asset.mesh, laplacian)
        info["laplacian"] = laplacian
        Q = K
        if method == "poisson" and position_weight > 0:
            s = K.diagonal().sum() / W.diagonal().sum()
            Q = (K + (position_weight * s) * W).tocsr()
            info["position_weight"] = float(position_weight)
        coupled = True
    prob = ReductionProblem(B, Y, Q, C, d, influences.valid.copy(), alpha0, 0.0, nonneg, coupled, info)
    Hd = prob.local_hessians()
    diag = np.einsum("mkk->mk", Hd)[influences.valid]
    prob.eps = float(ridge * diag.mean()) if diag.size else 0.0
    info["ridge"] = prob.eps
    return prob
