"""The cage options shared by the cage-coordinate generators (mean value, harmonic).

A cage generator works on the pipeline's cage (``inputs: cage: file.obj``),
on a cage file named by its ``cage`` parameter, or on a cage it builds
(``cage: auto``). When the pipeline's handles were a skeleton with weights
and an animation, the skeleton's poses become cage poses by skinning the
cage (``cage_poses: from-skeleton``), so the cage reduction is judged on the
skeleton's real motion.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

import numpy as np
from pydantic import Field

from rigslim.errors import StepError
from rigslim.model.handles import Handles
from rigslim.model.mesh import Mesh
from rigslim.plugin import Params


class CageParams(Params):
    """Parameters naming the cage and its poses."""

    cage: str | None = Field(None, description="None: the pipeline's cage; 'auto': build one; else a mesh file")
    cage_vertices: int = Field(100, ge=4, description="target vertex count of an automatic cage")
    cage_offset: float = Field(0.03, gt=0, description="offset of an automatic cage (fraction of the bbox diagonal)")
    cage_resolution: int = Field(64, ge=8, le=512, description="grid cells of the offset surface (longest side)")
    cage_clearance: float = Field(0.002, ge=0, description="least distance mesh-to-cage (fraction of the diagonal)")
    cage_poses: Literal["auto", "from-skeleton", "keep"] = Field(
        "auto", description="from-skeleton: skin the cage to the skeleton's animation; auto: do so when "
                            "the handles were a skeleton with poses")
    save_cage: str | None = Field(None, description="write the cage used to this mesh file")


def prepare_cage(asset, params: CageParams, ctx, step: str) -> Mesh:
    """Make ``asset.handles`` the cage the parameters name, with matching poses.

    Returns
    -------
    Mesh
        The rest cage. ``asset.handles`` becomes its cage handles; when the
        handles were a skeleton, the skeleton, its weights and its poses are
        kept in ``asset.extras["skeleton"]``, ``["skeleton_weights"]`` and
        ``["skeleton_poses"]``, and ``asset.poses`` becomes the skinned cage
        poses. ``ctx.report["cage"]`` records the cage's size and enclosure.
    """
    from rigslim.plugins.generators.cage import build_cage, enclosure, skinned_cage_poses, transfer_weights

    old = asset.handles
    skeleton_poses = old is not None and not old.is_cage and asset.poses is not None
    if params.cage_poses == "from-skeleton" and not skeleton_poses:
        raise StepError("cage_poses: from-skeleton needs a skeleton and its animation", field=f"{step}.cage_poses",
                        fix="add inputs.skeleton and inputs.animation, or set cage_poses: keep")
    if params.cage is None:
        if old is None or not old.is_cage:
            raise StepError("no cage to compute coordinates for", field=f"{step}.cage",
                            fix="add 'cage: file.obj' under inputs, or set 'cage: auto' (or a path) on this step")
        cage = old.cage
        origin = old.source or "inputs.cage"
    elif params.cage == "auto":
        cage = build_cage(asset.mesh, params.cage_vertices, offset=params.cage_offset,
                          resolution=params.cage_resolution, clearance=params.cage_clearance,
                          progress=ctx.progress)
        origin = "auto"
    else:
        from rigslim.io import read_mesh

        path = Path(params.cage)
        cage = read_mesh(path if path.is_absolute() else ctx.base_dir / path)
        origin = str(path)
    enc = enclosure(cage, asset.mesh.V)
    ctx.report["cage"] = {"source": origin, "vertices": cage.n_vertices, "faces": cage.n_faces,
                          "min_winding_number": float(enc.winding.min()),
                          "vertices_outside": int((enc.winding < 0.5).sum()),
                          "min_clearance": float(enc.clearance.min()),
                          "min_clearance_relative": float(enc.clearance.min() / asset.mesh.bbox_diagonal)}
    if ctx.report["cage"]["vertices_outside"]:
        ctx.log(f"{ctx.report['cage']['vertices_outside']} mesh vertices lie outside the cage: mean value "
                "coordinates extend there (possibly negative), harmonic ones take the nearest boundary values")
    if params.save_cage:
        _save_mesh(cage, params.save_cage, ctx)

    if old is not None and old.is_cage and old.cage is cage:
        return cage
    new = Handles.from_cage(cage, source=origin)
    mode = params.cage_poses
    if mode == "auto":
        mode = "from-skeleton" if skeleton_poses else "keep"
    if mode == "from-skeleton":
        if asset.weights is None or asset.weights.shape[1] != old.n:
            raise StepError("cage_poses: from-skeleton needs the skeleton's weights to skin the cage",
                            field=f"{step}.cage_poses", fix="add inputs.weights (or a bone-heat step) before it")
        Wc = transfer_weights(asset.mesh, asset.weights, cage.V)
        asset.extras["skeleton"] = old
        asset.extras["skeleton_weights"] = asset.weights
        asset.extras["skeleton_poses"] = asset.poses
        asset.poses = skinned_cage_poses(cage, Wc, asset.poses)
        ctx.report["cage_poses"] = {"source": "skinned to the skeleton", "poses": len(asset.poses)}
    elif asset.poses is not None and asset.poses.n_handles != cage.n_vertices:
        raise StepError(f"the poses have {asset.poses.n_handles} handles but the cage has {cage.n_vertices} "
                        "vertices", field=f"{step}.cage_poses",
                        fix="give a cage animation made for this cage, or cage_poses: from-skeleton")
    asset.handles = new
    asset.influences = None
    asset.reduced = None
    return cage


def _save_mesh(cage: Mesh, target: str, ctx) -> None:
    import igl

    from rigslim.io.atomic import atomic_path

    path = Path(target)
    path = path if path.is_absolute() else ctx.base_dir / path
    with atomic_path(path) as tmp:
        ok = igl.write_triangle_mesh(str(tmp), np.ascontiguousarray(cage.V), np.ascontiguousarray(cage.F))
        if ok is False:
            raise StepError("could not write the cage", source=path, field="save_cage",
                            fix="use a .obj, .off or .ply path in a writable folder")
    ctx.log(f"cage written to {path}")
