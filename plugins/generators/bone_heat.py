"""Bone heat skinning weights (Baran & Popovic 2007, "Automatic rigging and
animation of 3D characters", the weights of Pinocchio).

Each bone's weight is the equilibrium temperature of the surface when that
bone is held at temperature 1 and the others at 0, heat flowing from a bone
to the vertices that see it as their nearest bone.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import numpy as np
import scipy.sparse as sp
from pydantic import Field
from scipy.sparse.csgraph import connected_components
from scipy.sparse.linalg import splu

from rigslim.errors import StepError
from rigslim.plugin import Params, WeightGenerator

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext


def point_segment_distances(P: np.ndarray, A: np.ndarray, B: np.ndarray):
    """Distances from points to segments, and the closest points.

    Parameters
    ----------
    P : (m, 3) array
    A, B : (n, 3) arrays
        Segment end points.

    Returns
    -------
    dist : (m, n) array
    Q : (m, n, 3) array
        ``Q = A + t (B - A)``, ``t = clamp(((P - A) . (B - A)) / |B - A|^2, 0, 1)``.
    """
    AB = B - A
    len2 = np.maximum(np.einsum("ij,ij->i", AB, AB), 1e-300)
    t = np.clip(np.einsum("mnk,nk->mn", P[:, None, :] - A[None], AB) / len2, 0.0, 1.0)
    Q = A[None] + t[..., None] * AB[None]
    return np.linalg.norm(P[:, None, :] - Q, axis=2), Q


def nearest_visible_bones(V, F, A, B, *, visibility: bool = True, tie: float = 1e-6, progress=None):
    """For each vertex, the nearest bone whose closest point it can see.

    Parameters
    ----------
    V, F : surface mesh
    A, B : (n, 3) arrays
        Bone segments.
    visibility : bool
        Test the segment from the vertex to the bone's closest point against
        the mesh (``igl.AABB.intersect_ray_first``); without it the nearest
        bone is taken.
    tie : float
        Bones within ``(1 + tie)`` of the nearest distance share the vertex.

    Returns
    -------
    P : (m, n) array
        ``p_j^i``: 1 for the nearest visible bone (split equally among ties),
        rows of vertices that see no bone are 0.
    d : (m,) array
        Distance to the nearest visible bone (inf if none).
    """
    import igl

    m, n = len(V), len(A)
    dist, Q = point_segment_distances(V, A, B)
    order = np.argsort(dist, axis=1)
    visible = np.zeros((m, n), dtype=bool)
    found = np.full(m, np.inf)
    if visibility:
        tree = igl.AABB()
        tree.init(V, F)
        diag = float(np.linalg.norm(V.max(0) - V.min(0)))
        start = 1e-5 * diag
        pending = np.arange(m)
        ranks = range(n)
        if progress is not None:
            ranks = progress(ranks, total=n, description="bone visibility")
        for r in ranks:
            if pending.size == 0:
                continue
            bone = order[pending, r]
            # once a visible bone is found, only bones tied with it need testing
            D = Q[pending, bone] - V[pending]
            L = np.linalg.norm(D, axis=1)
            U = D / np.maximum(L, 1e-300)[:, None]
            O = V[pending] + start * U
            hit, t, _ = tree.intersect_ray_first(V, F, O, Q[pending, bone] - O, 1.0)
            ok = (hit < 0) | (L <= start)
            seen = pending[ok]
            visible[seen, bone[ok]] = True
            found[seen] = np.minimum(found[seen], dist[seen, bone[ok]])
            nxt = order[pending, min(r + 1, n - 1)]
            keep = np.isinf(found[pending]) | (dist[pending, nxt] <= found[pending] * (1 + tie))
            pending = pending[keep] if r + 1 < n else pending[:0]
    else:
        visible[:] = True
        found = dist.min(axis=1)
    near = visible & (dist <= found[:, None] * (1 + tie))
    Pm = near / np.maximum(near.sum(axis=1, keepdims=True), 1)
    return Pm, found


def bone_heat_weights(mesh, joints: np.ndarray, bones: np.ndarray, *, heat: float = 1.0,
                      visibility: bool = True, progress=None, report: dict | None = None) -> np.ndarray:
    """Bone heat weights of a surface mesh for a skeleton.

    Parameters
    ----------
    mesh : rigslim.model.mesh.Mesh
        Closed surface; its cotangent Laplacian and Voronoi mass matrix are used.
    joints : (J, 3) array
    bones : (n, 2) int array
        (parent joint, child joint) of each bone.
    heat : float
        ``c`` in ``H_jj = c / d_j^2``.
    visibility : bool
        Only bones a vertex can see heat it (the paper); otherwise the nearest bone.
    report : dict, optional
        Receives statistics (vertices seeing no bone, clipped negatives).

    Returns
    -------
    (m, n) float64 array
        Dense, non-negative weights, rows summing to one.

    Notes
    -----
    For each bone i solve (Baran & Popovic 2007, sec. 4)

    .. math::

        (-\\Delta + H)\\, w_i = H\\, p_i, \\qquad \\Delta = M^{-1} L,

    i.e. the symmetric system ``(-L + M H) w_i = M H p_i`` with ``L`` the
    cotangent Laplacian (``igl.cotmatrix``) and ``M`` the Voronoi mass
    matrix (``igl.massmatrix``). ``p_i(j) = 1`` if bone i is the nearest bone
    that vertex j sees (the segment from the vertex to the bone's closest
    point does not cross the surface), ``H_jj = c / d_j^2`` with ``d_j`` that
    distance, and ``H_jj = 0`` for vertices that see no bone. Because
    ``L 1 = 0`` and ``sum_i p_i = 1`` wherever ``H > 0``, the weights sum to
    one; round-off negatives (obtuse triangles make ``-L + MH`` a non-M-matrix)
    are clipped and rows renormalised. A connected component where no vertex
    sees a bone falls back to the nearest bone without visibility.
    """
    V, F = mesh.V, mesh.F
    joints = np.asarray(joints, dtype=np.float64)
    bones = np.asarray(bones, dtype=np.int64)
    A, B = joints[bones[:, 0]], joints[bones[:, 1]]
    Pm, d = nearest_visible_bones(V, F, A, B, visibility=visibility, progress=progress)
    blind = np.isinf(d)
    # components that see no bone at all would make the system singular
    ncomp, labels = connected_components(mesh.adjacency, directed=False)
    lit = np.bincount(labels[~blind], minlength=ncomp) > 0
    dark = ~lit[labels]
    if dark.any():
        Pn, dn = nearest_visible_bones(V[dark], F, A, B, visibility=False)
        Pm[dark], d[dark] = Pn, dn
        blind = np.isinf(d)
    Hd = np.where(blind, 0.0, heat / np.maximum(d, 1e-12 * mesh.bbox_diagonal) ** 2)
    M = mesh.massmatrix
    MH = sp.diags(M.diagonal() * Hd)
    K = sp.csc_matrix(-mesh.cotmatrix + MH)
    lu = splu(K)
    W = lu.solve(np.asarray(MH @ Pm))
    negatives = int((W < -1e-10).sum())
    W = np.clip(W, 0.0, None)
    W /= W.sum(axis=1, keepdims=True)
    if report is not None:
        report.update({"vertices_seeing_no_bone": int(blind.sum()), "dark_components": int((~lit).sum()),
                       "clipped_negatives": negatives, "heat": heat, "visibility": visibility})
    return W


class BoneHeatGeneratorParams(Params):
    heat: float = Field(1.0, gt=0, description="c in H_jj = c / d_j^2")
    visibility: bool = Field(True, description="only bones a vertex sees heat it")


class BoneHeatGenerator(WeightGenerator[BoneHeatGeneratorParams]):
    """``generate: bone-heat``: Pinocchio's bone heat weights for the pipeline's skeleton."""

    name = "bone-heat"
    summary = "bone heat skinning weights (Baran & Popovic 2007): cotangent heat diffusion from visible bones"

    def generate(self, asset: Asset, params: BoneHeatGeneratorParams, ctx: StepContext) -> sp.spmatrix | np.ndarray:
        h = asset.handles
        assert h is not None and asset.mesh is not None  # WeightGenerator.apply required them
        if h.is_cage or h.joints is None or h.bones is None:
            raise StepError("bone-heat needs a skeleton, the handles are a cage", field="generate.bone-heat",
                            fix="give 'skeleton: file.tgf' under inputs, or use mean-value/harmonic for cages")
        return bone_heat_weights(asset.mesh, h.joints, h.bones, heat=params.heat, visibility=params.visibility,
                                 progress=ctx.progress, report=ctx.report)
