"""Multilevel-preconditioned conjugate gradients for block-sparse SPD systems.

Solves ``A z = b`` for a symmetric positive definite block-sparse ``A``
(``m`` block rows of size ``r``, CSR pattern of blocks), whose blocks are
coupled only between vertices of different colours of a given colouring
(same-colour off-diagonal blocks are zero). In the weight solvers of [P10]
(docs/algorithms.md section 2) a block row is one vertex's weights in null-space
coordinates and the colouring is a distance-2 colouring of the mesh graph.

Method
------
- **Smoother**: colour-batched block Gauss-Seidel. For each colour class
  ``S`` in turn, every ``v`` in ``S`` solves its own block exactly,

      z_v <- z_v + A_vv^{-1} (b_v - sum_w A_vw z_w),

  all ``v`` of a class at once (they do not touch each other's rows).
  For the reduction energies this is exactly the per-vertex local solve of
  [P10] (the equality-constrained k-variable QP, in the null-space
  coordinates of its constraints).
- **Coarse correction**: the levels 1.. of an algebraic multigrid hierarchy
  built by smoothed aggregation (Vanek, Mandel & Brezina 1996; ``pyamg``)
  on ``A`` itself, with near-null-space candidates ``B`` (default: one per
  block component).
- **V-cycle**: ``nu`` pre-sweeps in colour order, coarse correction
  ``z += P A_c^{-1}~ P^T (b - A z)`` (one pyamg V-cycle below), ``nu``
  post-sweeps in *reverse* colour order. Pre- and post-smoother are
  adjoint, so the cycle is a symmetric positive definite operator and can
  precondition conjugate gradients.
- **PCG** (Hestenes & Stiefel 1952): stops when ``||b - A z|| <= tol ||b||``.

Example
-------
>>> ml = MultilevelSystem(indptr, indices, blocks, classes)     # doctest: +SKIP
>>> z, info = ml.solve(b, tol=1e-10)                            # doctest: +SKIP
"""

from __future__ import annotations

import time

import numpy as np
import scipy.sparse as sp
from numba import njit


@njit(cache=True)
def _colored_block_sweep(indptr, indices, data, dinv, x, b, order, bounds, reverse):  # pragma: no cover - numba
    ncol = len(bounds) - 1
    r = x.shape[1]
    for cc in range(ncol):
        c = ncol - 1 - cc if reverse else cc
        for t in range(bounds[c], bounds[c + 1]):
            v = order[t]
            res = b[v].copy()
            for p in range(indptr[v], indptr[v + 1]):
                w = indices[p]
                for i in range(r):
                    s = 0.0
                    for j in range(r):
                        s += data[p, i, j] * x[w, j]
                    res[i] -= s
            for i in range(r):
                s = 0.0
                for j in range(r):
                    s += dinv[v, i, j] * res[j]
                x[v, i] += s


@njit(cache=True)
def _dot(a, b):  # pragma: no cover - numba
    s = 0.0
    for i in range(a.shape[0]):
        s += a[i] * b[i]
    return s


@njit(cache=True)
def _axpy(y, a, x):  # pragma: no cover - numba
    for i in range(y.shape[0]):
        y[i] += a * x[i]


@njit(cache=True)
def _xpay(x, a, y):  # pragma: no cover - numba
    for i in range(y.shape[0]):
        y[i] = x[i] + a * y[i]


@njit(cache=True)
def _diagonal_positions(indptr, indices):  # pragma: no cover - numba
    m = len(indptr) - 1
    pos = np.full(m, -1, dtype=np.int64)
    for v in range(m):
        for p in range(indptr[v], indptr[v + 1]):
            if indices[p] == v:
                pos[v] = p
    return pos


def diagonal_positions(indptr, indices) -> np.ndarray:
    """Index of the diagonal block of every block row (raises if one is missing)."""
    pos = _diagonal_positions(np.asarray(indptr, dtype=np.int64), np.asarray(indices, dtype=np.int64))
    if (pos < 0).any():
        raise ValueError("block matrix has rows without a stored diagonal block")
    return pos


class ColoredBlockSmoother:
    """Colour-batched block Gauss-Seidel on a block-CSR matrix (see module docstring).

    Parameters
    ----------
    indptr, indices : int arrays
        Block-CSR pattern (``m + 1`` and ``nnz`` entries).
    blocks : (nnz, r, r) array
    classes : list of int arrays
        Colour classes of block rows; no stored off-diagonal block joins two
        rows of one class.
    """

    def __init__(self, indptr, indices, blocks, classes):
        self.indptr = np.ascontiguousarray(indptr, dtype=np.int64)
        self.indices = np.ascontiguousarray(indices, dtype=np.int64)
        self.blocks = blocks
        self.m = len(self.indptr) - 1
        self.r = blocks.shape[1]
        self.order = np.ascontiguousarray(np.concatenate(classes), dtype=np.int64) if classes else np.zeros(0, np.int64)
        self.bounds = np.concatenate([[0], np.cumsum([len(S) for S in classes])]).astype(np.int64)
        diag = blocks[diagonal_positions(self.indptr, self.indices)]
        self.dinv = np.ascontiguousarray(np.linalg.inv(diag))

    def sweep(self, x, b, reverse: bool = False, sweeps: int = 1) -> None:
        """``sweeps`` in-place sweeps on ``x`` (m r,) or (m, r), colours reversed when ``reverse``."""
        X = x.reshape(self.m, self.r)
        Bv = np.ascontiguousarray(b, dtype=np.float64).reshape(self.m, self.r)
        for _ in range(sweeps):
            _colored_block_sweep(self.indptr, self.indices, self.blocks, self.dinv, X, Bv, self.order,
                                 self.bounds, reverse)


class MultilevelSystem:
    """``A z = b`` with the colour-smoothed V-cycle of the module docstring as CG preconditioner.

    Parameters
    ----------
    indptr, indices : int arrays
        Block-CSR pattern of ``A`` (``m`` block rows).
    blocks : (nnz, r, r) array
        Symmetric positive definite overall.
    classes : list of int arrays
        Colour classes (see :class:`ColoredBlockSmoother`).
    candidates : (m r, c) array, optional
        Near-null-space candidates for smoothed aggregation (default: the
        r block-component indicator vectors).
    strength : (m, m) sparse matrix, optional
        Node graph that aggregation follows (for example the mesh's one-ring
        adjacency; default pyamg's symmetric strength of ``A``).
    sweeps : int
        Pre- and post-smoothing sweeps per V-cycle.
    max_coarse : int
        Size below which pyamg solves the coarsest level directly.
    **amg
        Further options of ``pyamg.smoothed_aggregation_solver``.
    """

    def __init__(self, indptr, indices, blocks, classes, *, candidates=None, strength=None, sweeps: int = 1,
                 max_coarse: int = 1000, **amg):
        import pyamg
        from pyamg.multilevel import MultilevelSolver

        t0 = time.perf_counter()
        self.smoother = ColoredBlockSmoother(indptr, indices, blocks, classes)
        m, r = self.smoother.m, self.smoother.r
        self.n = m * r
        self.A = sp.bsr_matrix((blocks, self.smoother.indices, self.smoother.indptr), shape=(self.n, self.n))
        if candidates is None:
            candidates = np.kron(np.ones((m, 1)), np.eye(r))
        if strength is not None:
            strength = ("predefined", {"C": sp.csr_matrix(strength)})
        else:
            strength = "symmetric"
        self.hierarchy = pyamg.smoothed_aggregation_solver(self.A, B=candidates, symmetry="symmetric",
                                                           strength=strength, max_coarse=max_coarse,
                                                           keep=False, coarse_solver="splu", **amg)
        self.sweeps = int(sweeps)
        levels = self.hierarchy.levels
        if len(levels) > 1:
            self.P = sp.csr_matrix(levels[0].P)
            self.R = sp.csr_matrix(levels[0].R)
            self.coarse = MultilevelSolver(levels[1:], coarse_solver="splu").aspreconditioner(cycle="V")
        else:
            self.P = self.R = self.coarse = None
        self.setup_seconds = time.perf_counter() - t0

    @property
    def levels(self) -> list[int]:
        """Unknowns per level of the hierarchy, finest first."""
        return [int(lv.A.shape[0]) for lv in self.hierarchy.levels]

    def vcycle(self, b: np.ndarray) -> np.ndarray:
        """One V-cycle from zero: the preconditioner ``M^-1 b`` (symmetric positive definite)."""
        x = np.zeros(self.n)
        self.smoother.sweep(x, b, reverse=False, sweeps=self.sweeps)
        if self.coarse is not None:
            res = b - self.A @ x
            x += self.P @ (self.coarse @ (self.R @ res))
        self.smoother.sweep(x, b, reverse=True, sweeps=self.sweeps)
        return x

    def solve(self, b, x0=None, *, tol: float = 1e-8, maxiter: int = 500, callback=None):
        """Preconditioned conjugate gradients.

        Parameters
        ----------
        b : (n,) array
        x0 : (n,) array, optional
        tol : float
            Stop when ``||b - A x|| <= tol ||b||``.
        maxiter : int
        callback : callable, optional
            ``callback(iteration, x, decrease)`` after every iteration, where
            ``decrease = (r^T z)^2 / p^T A p`` is that iteration's decrease of
            ``x^T A x - 2 b^T x``.

        Returns
        -------
        x : (n,) array
        info : dict
            ``iterations``, ``residual`` (final relative residual),
            ``converged``, ``residual_history``, ``seconds``.
        """
        t0 = time.perf_counter()
        A = self.A
        b = np.ascontiguousarray(b, dtype=np.float64)
        x = np.zeros(self.n) if x0 is None else np.array(x0, dtype=np.float64)
        bnorm = max(np.sqrt(_dot(b, b)), 1e-300)
        r = b - A @ x if x0 is not None else b.copy()
        history = [float(np.sqrt(_dot(r, r)) / bnorm)]
        it = 0
        converged = history[-1] <= tol
        if not converged:
            z = self.vcycle(r)
            p = z.copy()
            rz = _dot(r, z)
            while it < maxiter:
                Ap = A @ p
                pAp = _dot(p, Ap)
                if pAp <= 0.0:
                    break
                alpha = rz / pAp
                _axpy(x, alpha, p)
                _axpy(r, -alpha, Ap)
                it += 1
                history.append(float(np.sqrt(_dot(r, r)) / bnorm))
                if callback is not None:
                    callback(it, x, rz * rz / pAp)
                if history[-1] <= tol:
                    converged = True
                    break
                z = self.vcycle(r)
                rz_new = _dot(r, z)
                _xpay(z, rz_new / rz, p)
                rz = rz_new
        info = dict(iterations=it, residual=history[-1], converged=bool(converged), residual_history=history,
                    seconds=time.perf_counter() - t0)
        return x, info
