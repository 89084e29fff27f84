"""Weights: dense/sparse input weights, influence sets, and fixed-k reduced weights.

Input weights are an (m, n) ``scipy.sparse.csr_matrix`` A with rows summing
to one. Reduced weights have the fixed-width layout GPUs want: ``indices``
(m, k) int32 and ``values`` (m, k), padded with (index 0, weight 0).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError

#: Input entries with absolute value below this are round-off and become zero
#: (libigl's elephant weights carry -9e-10 entries).
ROUNDOFF = 1e-8
#: Rows must sum to one within this tolerance (or the input asks to normalise).
SUM_TOLERANCE = 1e-6


def validate_weights(W, n_vertices: int, *, n_handles: int | None = None, normalize: bool = False,
                     source: str | None = None) -> sp.csr_matrix:
    """Check and clean input weights.

    Parameters
    ----------
    W : (m, n) array or sparse matrix
    n_vertices : int
        The mesh's vertex count; W must have that many rows.
    n_handles : int, optional
        The number of handles; W must have that many columns.
    normalize : bool
        Divide each row by its sum instead of rejecting rows that do not sum to 1.

    Returns
    -------
    scipy.sparse.csr_matrix
        With round-off entries (``|a| < 1e-8``) removed.
    """
    where = source or "weights"
    A = sp.csr_matrix(W, dtype=np.float64)
    if A.shape[0] != n_vertices:
        hint = " (the file may be transposed)" if A.shape[1] == n_vertices else ""
        raise InputError(f"weights have {A.shape[0]} rows but the mesh has {n_vertices} vertices{hint}",
                         source=where, field="rows", fix="use the weights made for this mesh")
    if n_handles is not None and A.shape[1] != n_handles:
        raise InputError(f"weights have {A.shape[1]} columns but there are {n_handles} handles",
                         source=where, field="columns", fix="use the weights made for this skeleton or cage")
    if not np.isfinite(A.data).all():
        raise InputError("weights contain NaN or inf", source=where, field="values",
                         fix="recompute or re-export the weights")
    A.data[np.abs(A.data) < ROUNDOFF] = 0.0
    A.eliminate_zeros()
    sums = np.asarray(A.sum(axis=1)).ravel()
    if normalize:
        if (np.abs(sums) < 1e-12).any():
            v = int(np.flatnonzero(np.abs(sums) < 1e-12)[0])
            raise InputError(f"vertex {v} has no weight at all; it cannot be normalised", source=where,
                             field=f"row {v}", fix="give every vertex at least one influence")
        A = sp.csr_matrix(sp.diags(1.0 / sums) @ A)
    else:
        off = np.abs(sums - 1.0)
        if off.max(initial=0.0) > SUM_TOLERANCE:
            v = int(np.argmax(off))
            raise InputError(f"{int((off > SUM_TOLERANCE).sum())} rows do not sum to 1 "
                             f"(row {v} sums to {sums[v]:.6g})", source=where, field=f"row {v}",
                             fix="set 'normalize: true' under inputs to divide each row by its sum")
    A.sort_indices()
    return A


@dataclass(frozen=True, eq=False)
class InfluenceSets:
    """Which handles may influence each vertex after reduction.

    Parameters
    ----------
    indices : (m, k) int32 array
        Handle indices; slots where ``valid`` is False are padding.
    valid : (m, k) bool array
        Which slots hold a real influence.
    """

    indices: np.ndarray
    valid: np.ndarray

    @property
    def k(self) -> int:
        return self.indices.shape[1]

    @property
    def n_vertices(self) -> int:
        return self.indices.shape[0]


@dataclass(frozen=True, eq=False)
class ReducedWeights:
    """At most k weights per vertex in a fixed-width layout.

    Parameters
    ----------
    indices : (m, k) int32 array
        Handle index of each slot; padding slots hold index 0.
    values : (m, k) float array
        Weights; padding slots hold 0. Rows sum to 1.
    n_handles : int
        Number of handles (columns of the equivalent sparse matrix).
    """

    indices: np.ndarray
    values: np.ndarray
    n_handles: int

    def __post_init__(self):
        idx = np.ascontiguousarray(self.indices, dtype=np.int32)
        val = np.ascontiguousarray(self.values, dtype=np.float64)
        if idx.shape != val.shape or idx.ndim != 2:
            raise ValueError(f"indices {idx.shape} and values {val.shape} must be equal (m, k) arrays")
        object.__setattr__(self, "indices", idx)
        object.__setattr__(self, "values", val)

    @property
    def k(self) -> int:
        return self.indices.shape[1]

    @property
    def n_vertices(self) -> int:
        return self.indices.shape[0]

    def to_sparse(self) -> sp.csr_matrix:
        """The (m, n) sparse matrix with the same weights (padding dropped)."""
        m, k = self.indices.shape
        rows = np.repeat(np.arange(m), k)
        A = sp.csr_matrix((self.values.ravel(), (rows, self.indices.ravel())), shape=(m, self.n_handles))
        A.eliminate_zeros()
        return A

    def influence_counts(self) -> np.ndarray:
        """(m,) number of non-zero weights of each vertex."""
        return (self.values != 0).sum(axis=1)

    @staticmethod
    def from_influences(influences: InfluenceSets, values: np.ndarray, n_handles: int) -> ReducedWeights:
        """Weights on given influence sets, with padding slots set to (0, 0)."""
        values = np.where(influences.valid, values, 0.0)
        indices = np.where(influences.valid, influences.indices, 0)
        return ReducedWeights(indices, values, n_handles)


def influence_counts(A: sp.csr_matrix) -> np.ndarray:
    """(m,) number of non-zero weights in each row of a sparse weight matrix."""
    return np.diff(sp.csr_matrix(A).indptr)
