"""A reduction problem in null-space coordinates: the SPD system every exact solver solves.

With equality constraints only, the feasible weights of
:mod:`rigslim.plugins.solvers.problem` are ``alpha_v = a_v + N_v^T z_v``
for any feasible base point ``a`` and ``N_v`` (r, k) an orthonormal basis
of the null space of ``C_v`` (its rows; SVD, so redundant rows are
harmless). In ``z`` the energy is ``E(a) + 2 z^T g + z^T A z`` with the
block-sparse symmetric positive definite matrix and reduced gradient

    A_vw = Q_vw (N_v B_v)(N_w B_w)^T + [v = w] N_v E_v N_v^T,     g_v = N_v (H a + f)_v

where ``E_v = diag(eps)`` on valid slots and 1 on padding slots, and
``(H a + f)_v = B_v^T (Q (X - Y))_v + eps (a_v - alpha0_v)``
(:meth:`ReductionProblem.gradient`). Its minimiser solves ``A z = -g``.
``A`` has ``Q``'s block pattern (r x r blocks, formed in numba without the
(m k)^2 Hessian); r is the largest null-space dimension, and vertices with
fewer null directions (linear precision) get identity "dummy" rows that
solve to zero.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from numba import njit, prange


@njit(parallel=True, cache=True)
def _galerkin_blocks(indptr, indices, q, Bn, out):  # pragma: no cover - numba
    m = len(indptr) - 1
    r = Bn.shape[1]
    D = Bn.shape[2]
    for v in prange(m):
        for p in range(indptr[v], indptr[v + 1]):
            w = indices[p]
            c = q[p]
            for i in range(r):
                for j in range(r):
                    s = 0.0
                    for d in range(D):
                        s += Bn[v, i, d] * Bn[w, j, d]
                    out[p, i, j] = c * s


@njit(cache=True)
def _upper_scalar_csr(indptr, indices, blocks):  # pragma: no cover - numba
    """Scalar CSR (int32 indptr / indices, sorted) of the upper triangle, diagonal included, of a
    block-CSR matrix with sorted block columns."""
    m = len(indptr) - 1
    r = blocks.shape[1]
    count = 0
    for v in range(m):
        for p in range(indptr[v], indptr[v + 1]):
            w = indices[p]
            if w > v:
                count += r * r
            elif w == v:
                count += r * (r + 1) // 2
    out_ptr = np.empty(m * r + 1, dtype=np.int32)
    out_idx = np.empty(count, dtype=np.int32)
    out_val = np.empty(count)
    out_ptr[0] = 0
    t = 0
    for v in range(m):
        for i in range(r):
            for p in range(indptr[v], indptr[v + 1]):
                w = indices[p]
                if w < v:
                    continue
                j0 = i if w == v else 0
                for j in range(j0, r):
                    out_idx[t] = w * r + j
                    out_val[t] = blocks[p, i, j]
                    t += 1
            out_ptr[v * r + i + 1] = t
    return out_ptr, out_idx, out_val


def nullspace_basis(C: np.ndarray, rtol: float = 1e-10) -> tuple[np.ndarray, np.ndarray]:
    """Orthonormal null-space rows ``N`` (m, r, k) of every ``C_v`` (m, q, k), zero-padded to the
    largest null dimension r; ``dummy`` (m, r) marks the padding rows."""
    m, q, k = C.shape
    _, s, Vt = np.linalg.svd(C, full_matrices=True)
    rank = (s > rtol * np.maximum(s[:, :1], 1e-300)).sum(axis=1)
    r = int(k - rank.min()) if m else 0
    idx = rank[:, None] + np.arange(r)[None, :]
    dummy = idx >= k
    N = np.take_along_axis(Vt, np.minimum(idx, k - 1)[:, :, None], axis=1)
    N[dummy] = 0.0
    return np.ascontiguousarray(N), dummy


@dataclass
class NullSpaceSystem:
    """``A z = -g`` of the module docstring, around the feasible base point ``base``.

    Attributes
    ----------
    N : (m, r, k) array
    dummy : (m, r) bool array
    base : (m, k) array
    indptr, indices : int arrays
        Block pattern (that of ``Q``, diagonal stored).
    blocks : (nnz, r, r) array
    rhs : (m r,) array
        ``-g`` at the base point.
    """

    N: np.ndarray
    dummy: np.ndarray
    base: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    blocks: np.ndarray
    rhs: np.ndarray

    @property
    def unknowns(self) -> int:
        return int(self.rhs.size)

    def weights(self, z: np.ndarray) -> np.ndarray:
        """``alpha = base + N^T z`` (m, k)."""
        m, r, _ = self.N.shape
        return self.base + np.einsum("mrk,mr->mk", self.N, z.reshape(m, r))

    def reduced_gradient(self, prob, alpha: np.ndarray) -> np.ndarray:
        """``N (H alpha + f)`` (m r,): zero exactly at the equality-constrained optimum."""
        return np.einsum("mrk,mk->mr", self.N, prob.gradient(alpha)).ravel()

    def matrix(self) -> sp.bsr_matrix:
        """``A`` as a scipy BSR matrix."""
        n = self.unknowns
        return sp.bsr_matrix((self.blocks, self.indices, self.indptr), shape=(n, n))

    def upper_blocks(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The upper block triangle of ``A`` (diagonal blocks included, whole) in block-CSR arrays:
        int32 ``indptr`` (m + 1,) and ``indices`` (block columns ``w >= v``, sorted), and the blocks'
        values (nnz r^2,), each block stored column by column: the block sparse row input of MKL
        PARDISO (``iparm(37) = r``), which orders, factorises and solves on the block graph."""
        m = len(self.indptr) - 1
        rows = np.repeat(np.arange(m), np.diff(self.indptr))
        keep = self.indices >= rows
        ptr = np.zeros(m + 1, dtype=np.int32)
        np.cumsum(np.bincount(rows[keep], minlength=m), out=ptr[1:])
        values = np.ascontiguousarray(self.blocks[keep].transpose(0, 2, 1)).ravel()
        return ptr, self.indices[keep].astype(np.int32), values

    def upper_triangle(self) -> sp.csr_matrix:
        """The upper triangle of ``A`` (diagonal included) as a scalar CSR matrix with sorted int32
        indices, written straight from the blocks (what a symmetric factorisation such as PARDISO's
        reads; equal to ``scipy.sparse.triu(A)``, without forming the full scalar matrix)."""
        n = self.unknowns
        ptr, idx, val = _upper_scalar_csr(self.indptr, self.indices, self.blocks)
        U = sp.csr_matrix((val, idx, ptr), shape=(n, n))
        U.has_sorted_indices = True
        return U


def nullspace_system(prob, base: np.ndarray | None = None) -> NullSpaceSystem:
    """Assemble the null-space system of ``prob`` around a feasible ``base`` (default: the
    least-norm solution ``C_v^+ d_v`` of every vertex's constraints)."""
    C = np.where(prob.valid[:, None, :], prob.C, 0.0)
    N, dummy = nullspace_basis(C)
    m, r, k = N.shape
    if base is None:
        base = np.einsum("mkq,mq->mk", np.linalg.pinv(C), prob.d)
        base = np.where(prob.valid, base, 0.0)
    base = np.asarray(base, dtype=np.float64)
    Q = sp.coo_matrix(prob.Q, dtype=np.float64)
    # Store every diagonal entry (block Gauss-Seidel needs the diagonal blocks): explicit
    # zeros added in COO survive the conversion (duplicates are summed).
    ar = np.arange(m)
    Q = sp.coo_matrix((np.r_[Q.data, np.zeros(m)], (np.r_[Q.row, ar], np.r_[Q.col, ar])), shape=(m, m)).tocsr()
    Q.sort_indices()
    rows = np.repeat(np.arange(m), np.diff(Q.indptr))
    Bn = np.ascontiguousarray(np.einsum("mrk,mkd->mrd", N, prob.B))
    blocks = np.empty((Q.nnz, r, r))
    indptr = Q.indptr.astype(np.int64)
    indices = Q.indices.astype(np.int64)
    _galerkin_blocks(indptr, indices, np.ascontiguousarray(Q.data), Bn, blocks)
    e = np.where(prob.valid, prob.eps, 1.0)
    diag = np.flatnonzero(rows == indices)
    rr = np.arange(r)
    extra = np.einsum("mik,mk,mjk->mij", N, e, N)
    extra[:, rr, rr] += dummy
    blocks[diag] += extra
    sysm = NullSpaceSystem(N, dummy, base, indptr, indices, blocks, np.zeros(m * r))
    sysm.rhs = -sysm.reduced_gradient(prob, base)
    return sysm
