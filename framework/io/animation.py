"""libigl's stacked linear-blend-skinning animation (the elephant's format).

A (12n) x p matrix, one column per frame; a column read as a (4n) x 3
matrix in column-major order holds, for each bone b, rows 4b..4b+3 = the
transposed 3x4 bone transform ``[R^T; t^T]``, so that deformed positions are
``sum_b W[:, b] * ([V, 1] @ T[4b:4b+4])``.
"""

from __future__ import annotations

import numpy as np

from rigslim.errors import InputError
from rigslim.io.dmat import read_dmat
from rigslim.model.poses import Poses


def stacked_to_transforms(D: np.ndarray, *, source=None) -> np.ndarray:
    """(12n, p) stacked columns to (p, n, 3, 4) transforms."""
    rows, p = D.shape
    if rows % 12:
        raise InputError(f"{rows} rows is not a multiple of 12 (one stacked 4x3 transform per bone)",
                         source=source, field="rows", fix="give libigl's stacked LBS animation (12 rows per bone)")
    n = rows // 12
    columns = D.T.reshape(p, 3, 4 * n)     # column j as (4n, 3) column-major == (3, 4n) row-major
    T = columns.reshape(p, 3, n, 4).transpose(0, 2, 1, 3)  # (p, n, 3, 4): T[j, b] = block_b^T
    return np.ascontiguousarray(T)


def transforms_to_stacked(T: np.ndarray) -> np.ndarray:
    """Inverse of :func:`stacked_to_transforms`."""
    p, n = T.shape[:2]
    return np.ascontiguousarray(T.transpose(0, 2, 1, 3).reshape(p, 12 * n).T)


def read_stacked_animation(path, n_handles: int | None = None) -> Poses:
    """Read a stacked-transform DMAT animation into :class:`Poses` (frames 0..p-1)."""
    D = read_dmat(path)
    T = stacked_to_transforms(D, source=path)
    if n_handles is not None and T.shape[1] != n_handles:
        raise InputError(f"animation has {T.shape[1]} bones, the skeleton has {n_handles}", source=path,
                         field="rows", fix="use the animation made for this skeleton")
    return Poses(T, np.arange(T.shape[0]), source=str(path))
