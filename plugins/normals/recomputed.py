"""Recomputed normals: area-weighted vertex normals of the deformed mesh (precomputed face->vertex operator)."""

from __future__ import annotations

from rigslim.blend import per_vertex_normals
from rigslim.plugin import NormalEstimator


class RecomputedNormals(NormalEstimator):
    name = "recomputed"
    summary = ("area-weighted vertex normals of the deformed mesh (precomputed face->vertex operator, "
               "compiled; equal to igl.per_vertex_normals to rounding)")

    def estimate(self, mesh, weights, handles, T, positions, params, ctx=None):
        return per_vertex_normals(positions, mesh.F)
