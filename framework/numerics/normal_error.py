"""Angles between two sets of unit normals ([P10] fig. 10's normal error), their statistics, and which
vertex normals are defined at all.

Shared by the ``normal-deviation`` metric and the Poisson solver's held-out choice of lambda.

Degenerate normals
------------------
The area-weighted normal of vertex v is the direction of ``s_v = sum_{f ni v} n_f`` with
``n_f = (x_1 - x_0) x (x_2 - x_0)`` (twice the area times the unit normal). Where the faces around v
cancel (a fin, a folded sheet, the two sides of a zero-thickness wall) ``|s_v|`` is tiny against the
faces' own size, and the direction of ``s_v`` is decided by round-off: two deformations that agree to
1e-15 can give opposite normals there. The *conditioning* of the normal is

.. math:: c_v = \\frac{|\\sum_{f \\ni v} n_f|}{\\sum_{f \\ni v} |n_f|} \\in [0, 1],

(0 where the vertex is in no face or its faces have no area), and the normal is *degenerate* when
``c_v <`` :data:`DEGENERATE_RATIO`. A perturbation of the positions that changes every ``n_f`` by a
fraction ``delta`` of its size moves ``s_v`` by at most ``delta sum |n_f|``, so it turns a normal
with ``c_v >= tau`` by at most ``arcsin(delta / tau)``: with ``tau = 1e-3`` and round-off ``delta``
of 1e-12 (double precision, meshes up to 1e4 edge lengths from the origin) that is 1e-9 rad, never a
flip.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

__all__ = ["DEGENERATE_RATIO", "degenerate_normals", "normal_angles", "normal_conditioning", "normal_rms_angle",
           "normal_statistics", "vertex_face_incidence"]

#: ``c_v`` (module docstring) below this: the vertex normal is degenerate (cancelling faces or zero area).
DEGENERATE_RATIO = 1e-3


def normal_angles(N: np.ndarray, Nhat: np.ndarray) -> np.ndarray:
    """Per-vertex angle (rad) ``atan2(|n x nhat|, n . nhat)`` between unit normals, accurate for small angles."""
    cross = np.linalg.norm(np.cross(N, Nhat), axis=1)
    dot = np.einsum("ij,ij->i", N, Nhat)
    return np.arctan2(cross, dot)


def normal_rms_angle(N: np.ndarray, Nhat: np.ndarray, valid: np.ndarray | None = None) -> float:
    """``sqrt(mean_v angle(n_v, nhat_v)^2)`` in radians, for unit normals, over the vertices ``valid``
    (all by default; 0 when none)."""
    theta = normal_angles(N, Nhat)
    if valid is not None:
        theta = theta[valid]
    return float(np.sqrt(np.mean(theta ** 2))) if theta.size else 0.0


def vertex_face_incidence(F: np.ndarray, n_vertices: int) -> sp.csr_matrix:
    """(m, f) 0/1 matrix: entry (v, f) is 1 when face f has corner v."""
    F = np.asarray(F, dtype=np.int64)
    rows = F.ravel()
    cols = np.repeat(np.arange(len(F)), 3)
    S = sp.csr_matrix((np.ones(rows.size), (rows, cols)), shape=(n_vertices, len(F)))
    S.data[:] = 1.0          # a face listing a vertex twice counts once
    return S


def normal_conditioning(V: np.ndarray, F: np.ndarray, incidence: sp.csr_matrix | None = None) -> np.ndarray:
    """``c_v = |sum_f n_f| / sum_f |n_f|`` (module docstring) of every vertex of positions V on triangles F.

    Parameters
    ----------
    V : (m, 3) array
    F : (f, 3) int array
    incidence : (m, f) sparse matrix, optional
        :func:`vertex_face_incidence` of F, when the caller evaluates many poses of one mesh.

    Returns
    -------
    (m,) float array in [0, 1]; 0 for vertices in no face or with zero-area faces only.
    """
    V = np.asarray(V, dtype=np.float64)
    F = np.asarray(F, dtype=np.int64)
    if incidence is None:
        incidence = vertex_face_incidence(F, len(V))
    if len(F) == 0:
        return np.zeros(len(V))
    n = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])
    total = np.asarray(incidence @ np.linalg.norm(n, axis=1)).ravel()
    summed = np.linalg.norm(np.asarray(incidence @ n), axis=1)
    return np.where(total > 0, summed / np.where(total > 0, total, 1.0), 0.0)


def degenerate_normals(V: np.ndarray, F: np.ndarray, ratio: float = DEGENERATE_RATIO) -> np.ndarray:
    """(m,) bool: vertices whose normal is degenerate, ``c_v < ratio`` (:func:`normal_conditioning`)."""
    return normal_conditioning(V, F) < ratio


def normal_statistics(theta: np.ndarray, areas: np.ndarray | None = None, valid: np.ndarray | None = None,
                      flip_valid: np.ndarray | None = None) -> dict:
    """Statistics of per-vertex angles ``theta`` (rad) over the vertices ``valid``.

    Parameters
    ----------
    theta : (m,) array
    areas : (m,) array, optional
        Vertex areas for the area-weighted RMS ``sqrt(sum_v A_v theta_v^2 / sum_v A_v)``.
    valid : (m,) bool array, optional
        The vertices the statistics are over (default all): the others' normals are degenerate.
    flip_valid : (m,) bool array, optional
        Where a turn by more than 90 degrees counts as a flip (default ``valid``): both normals defined.

    Returns
    -------
    dict
        ``normal_rms_rad`` ``sqrt(mean_v theta_v^2)``; ``normal_median_rad``, ``normal_p95_rad``,
        ``normal_p99_rad`` (``numpy.percentile``, linear interpolation); ``normal_flipped``: the number of
        vertices with ``theta_v > pi / 2`` and ``flip_valid``; ``normal_area_rms_rad`` when ``areas`` have a
        positive sum over ``valid``. All 0 when no vertex is valid.
    """
    theta = np.asarray(theta, dtype=np.float64)
    valid = np.ones(theta.shape, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    flip_valid = valid if flip_valid is None else (np.asarray(flip_valid, dtype=bool) & valid)
    t = theta[valid]
    if t.size:
        out = {"normal_rms_rad": float(np.sqrt(np.mean(t ** 2))),
               "normal_median_rad": float(np.percentile(t, 50)),
               "normal_p95_rad": float(np.percentile(t, 95)),
               "normal_p99_rad": float(np.percentile(t, 99))}
    else:
        out = dict.fromkeys(("normal_rms_rad", "normal_median_rad", "normal_p95_rad", "normal_p99_rad"), 0.0)
    out["normal_flipped"] = int(np.count_nonzero(flip_valid & (theta > 0.5 * np.pi)))
    if areas is not None:
        a = np.asarray(areas, dtype=np.float64)[valid]
        if a.sum() > 0:
            out["normal_area_rms_rad"] = float(np.sqrt(np.sum(a * t ** 2) / np.sum(a)))
    return out
