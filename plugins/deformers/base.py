"""What every deformer back end shares: the bound-deformer object, weight layouts, normal data.

``Deformer.bind(mesh, weights, params)`` returns a :class:`BoundDeformer`:
calling it with one pose's (n, 3, 4) transforms gives (m, 3) positions
(what :class:`rigslim.plugin.evaluation.Evaluation` needs), and
``bound.deform(T, normals=True)`` gives ``(positions, normals)``. Back ends
that can estimate normals in the same pass take ``normals:`` in their
parameters and an optional ``handles=`` at bind (cages need the rest
handle positions).

Weight layouts (docs/algorithms.md section 3):

- ``fixed``: k (index int32, weight float32) pairs per vertex, padded with
  (0, 0), stored slot-major (``[l * m + v]``) so that neighbouring work-items
  read neighbouring words;
- ``compact``: the same with uint16 indices and float16 weights (4 bytes per
  influence instead of 8; weights rounded to 11 significant bits);
- ``csr``: the full sparse input weights (row pointers, columns, values).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError, StepError
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import per_vertex_normals
from rigslim.plugin import Params

NormalsMode = Literal["auto", "none", "blended-matrix", "approximate-affine"]
Layout = Literal["auto", "fixed", "compact", "csr"]

#: Largest handle count the compact layout's uint16 indices can address.
COMPACT_MAX_HANDLES = 65536


class DeformerParams(Params):
    """Parameters every deformer takes."""

    normals: NormalsMode = "auto"
    """Normals computed with ``deform(T, normals=True)``: ``auto`` picks ``approximate-affine`` for cages and
    ``blended-matrix`` otherwise."""


def resolve_normals(mode: str, handles) -> str | None:
    """The normal method a bound deformer uses (None for ``none``)."""
    is_cage = handles is not None and handles.is_cage
    if mode == "none":
        return None
    if mode == "auto":
        return "approximate-affine" if is_cage else "blended-matrix"
    if mode == "approximate-affine" and not is_cage:
        raise StepError("approximate-affine normals need the cage's rest positions",
                        field="normals", fix="bind with handles=<cage handles>, or use normals: blended-matrix")
    if mode == "blended-matrix" and is_cage:
        raise StepError("blended-matrix normals need bone transforms; a cage's blended linear part is zero",
                        field="normals", fix="use normals: approximate-affine for cages")
    return mode


def check_transforms(T, n_handles: int, source: str = "deformer") -> np.ndarray:
    """One pose's transforms as a C-contiguous (n, 3, 4) float64 array, or an InputError."""
    T = np.asarray(T, dtype=np.float64)
    if T.shape != (n_handles, 3, 4):
        raise InputError(f"transforms have shape {T.shape}, expected ({n_handles}, 3, 4)", source=source,
                         field="T", fix="pass one pose's 3x4 transform per handle")
    if not np.isfinite(T).all():
        raise InputError("transforms contain NaN or inf", source=source, field="T", fix="check the pose")
    return np.ascontiguousarray(T)


def n_handles_of(weights) -> int:
    return weights.n_handles if isinstance(weights, ReducedWeights) else sp.csr_matrix(weights).shape[1]


def check_weights(mesh, weights, source: str = "deformer"):
    """The weights as ReducedWeights or CSR, checked against the mesh."""
    if not isinstance(weights, ReducedWeights):
        weights = sp.csr_matrix(weights)
        rows = weights.shape[0]
    else:
        rows = weights.n_vertices
    if rows != mesh.n_vertices:
        raise InputError(f"weights have {rows} rows but the mesh has {mesh.n_vertices} vertices", source=source,
                         field="weights", fix="bind the weights made for this mesh")
    return weights


def fixed_k_arrays(weights, k: int | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(m, k) int32 indices and float64 values of sparse or fixed-k weights, padded with (0, 0).

    Sparse weights get ``k = max non-zeros per row`` unless k is given (then
    it must be at least that; no weight is dropped).
    """
    if isinstance(weights, ReducedWeights):
        return weights.indices, weights.values
    A = sp.csr_matrix(weights)
    counts = np.diff(A.indptr)
    width = int(counts.max(initial=1))
    k = width if k is None else k
    if k < width:
        raise StepError(f"{width} influences in some row but the layout has k = {k}", field="k",
                        fix="reduce the weights first (select/solve steps) or use the csr layout")
    m = A.shape[0]
    slot = np.arange(A.nnz) - np.repeat(A.indptr[:-1], counts)
    rows = np.repeat(np.arange(m), counts)
    idx = np.zeros((m, k), dtype=np.int32)
    val = np.zeros((m, k), dtype=np.float64)
    idx[rows, slot] = A.indices
    val[rows, slot] = A.data
    return idx, val


@dataclass(frozen=True)
class DeviceWeights:
    """Weights packed for a kernel or shader.

    Attributes
    ----------
    layout : {"fixed", "compact", "csr"}
    k : int
        Slots per vertex (fixed/compact); the largest row length for csr.
    indices, values : arrays
        fixed: (m, k) int32 / float32; compact: (m, k) uint16 / float16;
        csr: (nnz,) int32 / float32 column indices and values.
    indptr : (m + 1,) int32 array or None
        csr row pointers.
    effective : ReducedWeights or csr_matrix
        The weights the device really uses (rounded to float32, or float16
        for compact), for the numpy reference a test compares against.
    """

    layout: str
    k: int
    indices: np.ndarray
    values: np.ndarray
    indptr: np.ndarray | None
    effective: object

    @property
    def nbytes(self) -> int:
        return int(self.indices.nbytes + self.values.nbytes + (0 if self.indptr is None else self.indptr.nbytes))


def pack_weights(weights, layout: str, n_handles: int) -> DeviceWeights:
    """Pack weights for a device in the given layout (``auto``: csr for sparse input, fixed for fixed-k)."""
    if layout == "auto":
        layout = "fixed" if isinstance(weights, ReducedWeights) else "csr"
    if layout == "csr":
        A = weights.to_sparse() if isinstance(weights, ReducedWeights) else sp.csr_matrix(weights)
        A = sp.csr_matrix(A, copy=True)
        A.sort_indices()
        k = int(np.diff(A.indptr).max(initial=0))
        values = A.data.astype(np.float32)
        A.data = values.astype(np.float64)
        return DeviceWeights("csr", k, A.indices.astype(np.int32), values, A.indptr.astype(np.int32), A)
    idx, val = fixed_k_arrays(weights)
    k = idx.shape[1]
    if layout == "compact":
        if n_handles > COMPACT_MAX_HANDLES:
            raise StepError(f"{n_handles} handles do not fit 16-bit indices", field="layout",
                            fix="use layout: fixed")
        val16 = val.astype(np.float16)
        eff = ReducedWeights(idx, val16.astype(np.float64), n_handles)
        return DeviceWeights("compact", k, idx.astype(np.uint16), val16, None, eff)
    if layout != "fixed":
        raise StepError(f"unknown weight layout '{layout}'", field="layout", fix="use auto, fixed, compact or csr")
    val32 = val.astype(np.float32)
    return DeviceWeights("fixed", k, idx, val32, None, ReducedWeights(idx, val32.astype(np.float64), n_handles))


def rest_normal_data(mode: str | None, mesh, weights, handles) -> np.ndarray | None:
    """Per-vertex float64 (m, 4) data a kernel needs for normals.

    ``blended-matrix``: the rest normal ``(n, 0)``; ``approximate-affine``:
    ``(n, lambda)`` with the ridge of :func:`affine_fit_rest` (the kernel forms
    P from the same float32 handle differences as X: computing ``X^{-1} P``
    from a P rounded on its own would cost ``cond(P) * eps`` in accuracy).
    """
    if mode is None:
        return None
    N0 = per_vertex_normals(mesh.V, mesh.F)
    out = np.zeros((mesh.n_vertices, 4))
    if mode == "blended-matrix":
        out[:, :3] = N0
        return out
    from rigslim.numerics.affine_normals import affine_fit_rest

    fit = affine_fit_rest(weights, handles.cage.V, N0)
    out[:, :3] = N0
    out[:, 3] = fit.ridge
    return out


def handle_data(T: np.ndarray, C0: np.ndarray | None) -> np.ndarray:
    """(n, 5, 4) float32 per-handle records a kernel reads: rows of T, ``chat = T [c0; 1]``, ``c0``.

    ``chat`` and ``c0`` are centred on their means: the affine fit only uses
    differences, and centring keeps float32 from losing digits to large
    coordinates. Without rest positions (skeletons) the last two records are zero.
    """
    n = T.shape[0]
    out = np.zeros((n, 5, 4), dtype=np.float32)
    out[:, :3, :] = T
    if C0 is not None:
        chat = np.einsum("nij,nj->ni", T[:, :, :3], C0) + T[:, :, 3]
        out[:, 3, :3] = chat - chat.mean(axis=0)
        out[:, 4, :3] = C0 - C0.mean(axis=0)
    return out


class BoundDeformer:
    """A deformer bound to one mesh and weights; buffers live as long as it does.

    Call it with one pose's (n, 3, 4) transforms for (m, 3) positions, or use
    :meth:`deform` with ``normals=True`` for ``(positions, normals)``.

    Attributes
    ----------
    backend : str
        The plugin name.
    normals_mode : str or None
        ``blended-matrix``, ``approximate-affine`` or None.
    last_seconds : float or None
        Device time of the last frame (OpenCL profiling event, GL timer query;
        wall time for numpy).
    """

    backend = ""

    def __init__(self, n_vertices: int, n_handles: int, normals_mode: str | None):
        self.n_vertices = n_vertices
        self.n_handles = n_handles
        self.normals_mode = normals_mode
        self.last_seconds: float | None = None

    def __call__(self, T: np.ndarray) -> np.ndarray:
        return self.deform(T)

    def deform(self, T: np.ndarray, normals: bool = False):
        """Positions (m, 3), or ``(positions, normals)`` when ``normals`` is true."""
        T = check_transforms(T, self.n_handles, source=f"{self.backend} deformer")
        if normals and self.normals_mode is None:
            raise StepError("this deformer was bound without normals", field="normals",
                            fix="bind with normals: auto, blended-matrix or approximate-affine")
        return self._deform(T, bool(normals))

    def _deform(self, T: np.ndarray, normals: bool):
        raise NotImplementedError

    def bytes_per_frame(self, normals: bool) -> int:
        """Bytes a frame must move at least: inputs read once, outputs written once."""
        raise NotImplementedError

    def close(self) -> None:
        """Release device buffers (a no-op where there are none)."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


class DeviceBound(BoundDeformer):
    """A bound deformer on a device (OpenCL, OpenGL): ``launch`` runs one frame and, with
    ``read=True``, reads float32 results into ``_host_positions`` / ``_host_normals``."""

    def launch(self, T: np.ndarray, normals: bool = False, read: bool = True):
        raise NotImplementedError

    def _deform(self, T, normals):
        self.launch(T, normals, read=True)
        P = self._host_positions.astype(np.float64)
        return (P, self._host_normals.astype(np.float64)) if normals else P
