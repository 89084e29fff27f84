"""Bounded biharmonic weights (Jacobson, Baran, Popovic & Sorkine 2011) through libigl.

Computed on a tetrahedral mesh of the solid (the MEDIT ``.mesh`` reader keeps
it in ``asset.extras["volume"]``) and restricted to its surface vertices.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
from pydantic import Field

from rigslim.errors import StepError
from rigslim.plugin import Params, WeightGenerator

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext


def bounded_biharmonic_weights(V, T, joints, bones, *, max_iter: int = 8, report: dict | None = None) -> np.ndarray:
    """Bounded biharmonic weights of a tetrahedral mesh for a skeleton's bones.

    Parameters
    ----------
    V : (N, 3) array
        Tetrahedral mesh vertices; the bones must run along mesh vertices.
    T : (t, 4) int array
        Tetrahedra.
    joints : (J, 3) array
    bones : (n, 2) int array
    max_iter : int
        Active-set iterations of ``igl.bbw``.

    Returns
    -------
    (N, n) float64 array
        Weights in [0, 1] with rows summing to one.

    Notes
    -----
    Each weight minimises the Laplacian energy
    ``1/2 sum_i w_i^T (L M^{-1} L) w_i`` subject to ``w_i = 1`` on bone i,
    ``0`` on the other bones (``igl.boundary_conditions``), and
    ``0 <= w_i <= 1`` (``igl.bbw``, an active-set QP); rows are then divided
    by their sums (``igl::normalize_row_sums``), as libigl's tutorial does.

    Raises
    ------
    StepError
        If some bone touches no mesh vertex (no boundary condition).
    """
    import igl

    V = np.ascontiguousarray(V, dtype=np.float64)
    T = np.ascontiguousarray(T, dtype=np.int64)
    C = np.ascontiguousarray(joints, dtype=np.float64)
    BE = np.ascontiguousarray(bones, dtype=np.int64)
    fix = "tetrahedralise with the bones' points as constraints (as libigl's hand is)"
    try:
        b, bc = igl.boundary_conditions(V, T, C, np.zeros(0, dtype=np.int64), BE, np.zeros((0, 2), dtype=np.int64))
    except RuntimeError:  # libigl fails when some handle gets no vertex
        raise StepError("some bone runs through no vertex of the tetrahedral mesh", field="bbw", fix=fix) from None
    missing = np.flatnonzero(~(np.asarray(bc) > 0.5).any(axis=0)) if len(b) else np.arange(len(BE))
    if missing.size:
        raise StepError(f"bones {missing.tolist()} run through no vertex of the tetrahedral mesh", field="bbw",
                        fix=fix)
    W = igl.bbw(V, T, np.asarray(b, dtype=np.int64), np.asarray(bc, dtype=np.float64),
                partition_unity=False, max_iter=max_iter)
    W = np.clip(W, 0.0, 1.0)
    W /= W.sum(axis=1, keepdims=True)
    if report is not None:
        report.update({"tet_vertices": len(V), "tetrahedra": len(T), "constrained_vertices": int(len(b)),
                       "max_iter": max_iter})
    return W


class BBWGeneratorParams(Params):
    max_iter: int = Field(8, ge=1, le=1000, description="active-set iterations of igl.bbw")


class BBWGenerator(WeightGenerator[BBWGeneratorParams]):
    """``generate: bbw``: bounded biharmonic weights on the input's tetrahedral mesh."""

    name = "bbw"
    summary = "bounded biharmonic weights (Jacobson et al. 2011, igl.bbw) on a tetrahedral .mesh input"

    def generate(self, asset: Asset, params: BBWGeneratorParams, ctx: StepContext) -> sp.spmatrix | np.ndarray:
        h = asset.handles
        assert h is not None and asset.mesh is not None  # WeightGenerator.apply required them
        if h.is_cage or h.joints is None or h.bones is None:
            raise StepError("bbw needs a skeleton, the handles are a cage", field="generate.bbw",
                            fix="give 'skeleton: file.tgf' under inputs")
        volume = asset.extras.get("volume")
        if volume is None:
            raise StepError("bbw needs a tetrahedral mesh, the input mesh is a surface", field="inputs.mesh",
                            fix="give the mesh as a MEDIT .mesh file with tetrahedra")
        W = bounded_biharmonic_weights(volume["V"], volume["T"], h.joints, h.bones, max_iter=params.max_iter,
                                       report=ctx.report)
        return W[np.asarray(volume["surface_vertices"])]
