"""``static-qslim``: what most pipelines do today, a QSlim of the rest pose only (pymeshlab).

The rest mesh is simplified by MeshLab's quadric edge collapse
(Garland & Heckbert 1997, optimal placement, boundary and topology
preserving), ignoring the animation; each new vertex takes the skin weights
of the nearest original rest vertex. Levels are nested: each target is
reached from the previous, finer one. No vertex-split record comes out of
pymeshlab, so the hierarchy is ``None``.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
from pydantic import Field

from rigslim.errors import StepError
from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.weights import ReducedWeights
from rigslim.plugin import Decimation, Decimator, Params
from rigslim.plugins.decimation.articulated import FaceTarget, limited_weights, target_faces, target_label

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Decimation, Params, StepContext


def nearest_vertex_weights(V_orig: np.ndarray, W: np.ndarray, V_new: np.ndarray) -> ReducedWeights:
    """Weights of each new vertex copied from the nearest original vertex (dense W, (m, n))."""
    from scipy.spatial import cKDTree

    _, nearest = cKDTree(V_orig).query(V_new)
    rows = W[nearest]
    k = max(1, int(np.count_nonzero(rows, axis=1).max()))
    order = np.argsort(rows == 0, axis=1, kind="stable")[:, :k]
    vals = np.take_along_axis(rows, order, axis=1)
    return ReducedWeights(np.where(vals != 0, order, 0), vals, W.shape[1])


class StaticQSlimParams(Params):
    targets: list[FaceTarget] = Field(default_factory=list)
    """Fractions (< 1) of the input faces or face counts."""
    max_bones: int | None = Field(default=None, ge=1)
    """At most this many non-zero weights per vertex at every level."""
    preserve_boundary: bool = True
    """pymeshlab's preserveboundary: keep the mesh border."""
    preserve_topology: bool = True
    """pymeshlab's preservetopology: no collapse that changes the topology."""
    preserve_normal: bool = True
    """pymeshlab's preservenormal: no collapse that flips a face."""
    quality_threshold: float = Field(default=0.3, ge=0.0, le=1.0)
    """pymeshlab's qualitythr: penalise collapses that make faces worse than this quality (0..1)."""


class StaticQSlim(Decimator[StaticQSlimParams]):
    name = "static-qslim"
    summary = "rest-pose QSlim (pymeshlab quadric edge collapse), weights from the nearest original vertex"

    def decimate(self, asset: Asset, params: StaticQSlimParams, ctx: StepContext) -> Decimation:
        try:
            import pymeshlab
        except ImportError:  # pragma: no cover - pymeshlab is in the 'metro' extra
            raise StepError("static-qslim needs pymeshlab", field="decimate",
                            fix="pip install 'rigslim[metro]'") from None
        step = f"decimate: {self.name}"
        asset.require("mesh", "weights", step=step)
        if not params.targets:
            raise StepError("static-qslim needs targets", field="targets", fix="add e.g. 'targets: [0.1, 0.02]'")
        mesh = asset.mesh
        assert mesh is not None  # require() raised otherwise
        if mesh.n_faces == 0:  # pymeshlab's filter would fail ("does not have Any Faces")
            raise StepError("the mesh has no triangles (its primitives are points or lines): nothing to simplify",
                            field="faces", fix="give a file whose primitives are triangles")
        W = limited_weights(asset.weights, params.max_bones)
        faces = target_faces(params.targets, mesh.n_faces)
        ms = pymeshlab.MeshSet()
        ms.add_mesh(pymeshlab.Mesh(mesh.V, mesh.F.astype(np.int32)))
        levels = []
        for i in ctx.progress(sorted(range(len(faces)), key=lambda i: -faces[i]), total=len(faces),
                              description="static-qslim levels"):
            ms.meshing_decimation_quadric_edge_collapse(
                targetfacenum=faces[i], qualitythr=params.quality_threshold,
                preserveboundary=params.preserve_boundary, preservetopology=params.preserve_topology,
                preservenormal=params.preserve_normal, optimalplacement=True, autoclean=True)
            cur = ms.current_mesh()
            V2, F2 = np.asarray(cur.vertex_matrix(), float), np.asarray(cur.face_matrix(), np.int64)
            from rigslim.model.mesh import Mesh

            levels.append(SimplifiedLevel(Mesh(V2, F2, source="static-qslim"), nearest_vertex_weights(mesh.V, W, V2),
                                          target_label(self.name, params.targets[i], faces[i]), None,
                                          float("nan"), self.name))
        levels.sort(key=lambda lv: -lv.n_faces)
        ctx.report.update({"input_faces": mesh.n_faces,
                           "levels": [{"label": lv.label, "faces": lv.n_faces, "vertices": lv.n_vertices,
                                       "max_bones": int(lv.weights.influence_counts().max())} for lv in levels]})
        return Decimation(levels, None)
