"""What the one-command front ends need to know about a USD file: clips, joints, a description, world-space poses.

``rigslim reduce``/``lod``/``compare``/``inspect`` (docs/usd.md) use these
the way they use the glTF document for ``.glb`` inputs.

World space (:func:`world_points`): UsdSkel poses points in the skeleton's
space; the Skeleton prim's local-to-world transform places them in the stage,
``metersPerUnit`` turns stage units into metres and a ``Z`` up axis is turned
into glTF's ``Y`` up (``(x, y, z) -> (x, z, -y)``), so that a USD file and a
glTF file of the same character compare in the same frame.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.io.usd.stage import open_stage, pxr_modules, time_codes_per_second, to_columns

#: Z-up to Y-up: (x, y, z) -> (x, z, -y).
Z_TO_Y = np.array([[1.0, 0, 0], [0, 0, 1.0], [0, -1.0, 0]])


def clip_info(path, animation=None, fps: float = 30.0) -> tuple[int, str | None, float]:
    """Frames of the clip sampled at ``fps`` (1 without animation), its path and its duration in seconds."""
    from rigslim.io.usd.read import _animation_query, _choose_binding, skel_bindings

    path = Path(path)
    stage = open_stage(path)
    cache, bindings = skel_bindings(stage, path)
    binding = _choose_binding(bindings, None, None, path)
    query, anim_path = _animation_query(cache, cache.GetSkelQuery(binding.GetSkeleton()), animation, stage, path)
    keys = np.array(query.GetJointTransformTimeSamples(), np.float64) if query else np.zeros(0)
    if len(keys) < 1:
        return 1, anim_path, 0.0
    duration = float(keys.max() - keys.min()) / time_codes_per_second(stage)
    return int(np.floor(duration * fps + 1e-3)) + 1, anim_path, duration


def joint_count(path) -> int:
    """Joints of the largest skeleton that has skinned meshes."""
    from rigslim.io.usd.read import skel_bindings

    path = Path(path)
    stage = open_stage(path)         # held: the bindings' prims live as long as their stage
    _, bindings = skel_bindings(stage, path)
    return max(len(b.GetSkeleton().GetJointsAttr().Get() or []) for b in bindings)


def describe(path) -> dict:
    """A JSON-able description: stage metadata, skeletons with their meshes and animations, LOD variants."""
    Usd, UsdGeom, UsdSkel, _, _, _ = pxr_modules()
    from rigslim.io.usd.read import skel_bindings

    path = Path(path)
    stage = open_stage(path)
    _, bindings = skel_bindings(stage, path)
    skeletons = []
    for b in bindings:
        skel = b.GetSkeleton()
        meshes = []
        for q in b.GetSkinningTargets():
            prim = q.GetPrim()
            mesh = UsdGeom.Mesh(prim)
            counts = (np.array(mesh.GetFaceVertexCountsAttr().Get() or [], np.int64) if prim.IsA(UsdGeom.Mesh)
                      else np.zeros(0, np.int64))
            points = mesh.GetPointsAttr().Get(Usd.TimeCode.EarliestTime()) if prim.IsA(UsdGeom.Mesh) else None
            meshes.append({"path": str(prim.GetPath()), "type": str(prim.GetTypeName()),
                           "points": 0 if points is None else len(points), "faces": int(len(counts)),
                           "triangles": int(np.maximum(np.asarray(counts) - 2, 0).sum()) if len(counts) else 0,
                           "element_size": int(q.GetNumInfluencesPerComponent()),
                           "interpolation": str(q.GetInterpolation()),
                           "blend_shapes": len(UsdSkel.BindingAPI(prim).GetBlendShapesAttr().Get() or [])})
        source = UsdSkel.BindingAPI(skel.GetPrim()).GetAnimationSourceRel()
        targets = source.GetTargets() if source else []
        skeletons.append({"path": str(skel.GetPrim().GetPath()), "joints": len(skel.GetJointsAttr().Get() or []),
                          "animation": str(targets[0]) if targets else None, "meshes": meshes})
    animations = []
    for prim in stage.Traverse():
        if prim.IsA(UsdSkel.Animation):
            anim = UsdSkel.Animation(prim)
            times = sorted({t for a in (anim.GetTranslationsAttr(), anim.GetRotationsAttr(), anim.GetScalesAttr())
                            for t in a.GetTimeSamples()})
            animations.append({"path": str(prim.GetPath()), "joints": len(anim.GetJointsAttr().Get() or []),
                               "time_codes": [times[0], times[-1]] if times else None})
    lods = {str(p.GetPath()): p.GetVariantSets().GetVariantSet("LOD").GetVariantNames()
            for p in stage.Traverse() if p.GetVariantSets().HasVariantSet("LOD")}
    return {"path": str(path), "up_axis": str(UsdGeom.GetStageUpAxis(stage)),
            "meters_per_unit": float(UsdGeom.GetStageMetersPerUnit(stage)),
            "time_codes_per_second": time_codes_per_second(stage),
            "default_prim": str(stage.GetDefaultPrim().GetPath()) if stage.GetDefaultPrim() else None,
            "skeletons": skeletons, "animations": animations, "lod_variants": lods}


def world_transform(skin) -> np.ndarray:
    """(4, 4) skeleton space -> glTF-like world (metres, Y up) at the stage's default time (module docstring)."""
    Usd, UsdGeom, _, _, _, _ = pxr_modules()
    prim = skin.stage.GetPrimAtPath(skin.skeleton)
    if not prim:
        raise InputError(f"the skeleton {skin.skeleton} is gone", source=skin.path, field="skeleton",
                         fix="re-read the file")
    L = to_columns([UsdGeom.Xformable(prim).ComputeLocalToWorldTransform(Usd.TimeCode.EarliestTime())])[0]
    S = np.eye(4)
    S[:3, :3] *= float(UsdGeom.GetStageMetersPerUnit(skin.stage))
    if UsdGeom.GetStageUpAxis(skin.stage) == UsdGeom.Tokens.z:
        S[:3, :3] = Z_TO_Y @ S[:3, :3]
    return S @ L


def world_points(skin, frames=None) -> np.ndarray:
    """(p, m, 3) the skin's merged mesh posed by rigslim's linear blend, in world metres, Y up."""
    from rigslim.numerics.blend import linear_blend

    frames = range(len(skin.poses)) if frames is None else frames
    M = world_transform(skin)
    out = np.array([linear_blend(skin.mesh.V, skin.weights, skin.poses.T[f]) for f in frames])
    return out @ M[:3, :3].T + M[:3, 3]
