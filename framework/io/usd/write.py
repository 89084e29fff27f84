"""Writing UsdSkel: reduced weights into the source stage, levels of detail beside them.

:func:`write_usd` flattens the source stage (every layer, reference and
variant composed into one layer; asset paths re-anchored to the output's
folder), replaces the joint influences of the meshes that were read with
``primvars:skel:jointIndices``/``jointWeights`` of ``elementSize = k``
(interpolation ``vertex``, float32 rows summing to one, and ``skel:joints``
set to the skeleton's order where the mesh had its own), and keeps every other
prim and property as it was: materials, UVs, blend shapes, animations.

Levels of detail (:mod:`rigslim.io.usd.levels`), in one of two layouts:

- ``lod="variant"`` (default): a variant set ``LOD`` on the model prim (the
  ``SkelRoot``) with variants ``LOD0`` (the full meshes, moved into it) ..
  ``LODn``; every level's meshes have the same prim paths, so material
  bindings and anything that targets them stay valid. The selection is ``LOD0``.
  Unreal Engine's USD importer reads a ``LOD`` variant set of ``LOD0``,
  ``LOD1``, ... variants as the levels of one mesh; usdview, Houdini and
  Omniverse switch it as a variant; Blender's importer reads the selected one.
- ``lod="prims"``: one prim per level under an ``LODs`` prim carrying
  ``UsdLod``'s ``LODRootAPI`` (USD 26.x's level-of-detail schema: its children
  ``LOD0`` .. ``LODn`` are the items, in order; ``lod:default:index = 0``);
  the full meshes move into ``LOD0``. Renderers that do not know ``UsdLod``
  draw every child, so levels ``1..n`` are authored ``invisible``.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from pathlib import Path

import numpy as np

from rigslim.errors import StepError
from rigslim.io.atomic import atomic_path
from rigslim.io.usd.export import set_influences
from rigslim.io.usd.stage import diagnostics, pxr_modules

#: Layouts of levels of detail.
LOD_LAYOUTS = ("variant", "prims")
#: Per-point topology attributes that cannot follow a simplification: cleared on levels.
_TOPOLOGY_ATTRIBUTES = ("creaseIndices", "creaseLengths", "creaseSharpnesses", "cornerIndices",
                        "cornerSharpnesses", "holeIndices", "velocities", "accelerations")


def write_usd(path, source, reduced=None, *, levels=None, hierarchy=None, lod: str = "variant",
              clamp_negative: bool = False) -> dict:
    """Write the source stage with new weights and levels.

    Parameters
    ----------
    path : path-like
        ``.usd``/``.usdc`` (binary crate), ``.usda`` (text) or ``.usdz`` (a package with its textures).
    source : UsdSkin
        What :func:`rigslim.io.usd.read.read_usd_skin` returned.
    reduced : ReducedWeights, optional
        Weights of ``source.mesh``'s vertices (k per vertex); None keeps the file's influences.
    levels : list of SimplifiedLevel, optional
        Levels taken from ``hierarchy`` (built on ``source.mesh``).
    lod : {"variant", "prims"}
        Layout of the levels (module docstring).
    clamp_negative : bool
        Set negative weights to zero and renormalise instead of refusing them.

    Returns
    -------
    dict
        ``element_size`` (k written, or None), ``levels``, ``lod``, ``meshes`` and, with ``clamp_negative``,
        ``clamped_vertices`` / ``most_negative``.
    """
    Usd = pxr_modules()[0]
    if lod not in LOD_LAYOUTS:
        raise StepError(f"unknown LOD layout '{lod}'", field="lod", fix="use variant or prims")
    if Path(path).resolve() == Path(source.path).resolve():
        raise StepError(f"the output {Path(path).name} is the USD input itself", field="write",
                        fix="write to another file: rigslim never overwrites its inputs")
    if reduced is not None and reduced.n_vertices != source.mesh.n_vertices:
        raise StepError(f"{reduced.n_vertices} reduced rows for {source.mesh.n_vertices} vertices", field="reduced",
                        fix="reduce the mesh the USD reader made")
    with diagnostics():
        layer = source.stage.Flatten()
    stage = Usd.Stage.Open(layer)
    stats: dict = {"element_size": None, "levels": 0, "lod": None, "meshes": len(source.parts)}
    if reduced is not None:
        clamp: dict = {}
        for part in source.parts:
            rows = slice(part.start, part.start + part.count)
            prim = stage.GetPrimAtPath(part.path)
            _merge(clamp, set_influences(prim, reduced.indices[rows], reduced.values[rows],
                                         clamp_negative=clamp_negative))
            _skeleton_order(prim, source.joints)
        stats["element_size"] = reduced.k
        stats.update(clamp)
    if levels:
        from rigslim.io.usd.levels import level_parts

        parts = [level_parts(source, hierarchy, lv) for lv in levels]
        place = _variant_layout if lod == "variant" else _prims_layout
        clamp = place(stage, source, levels, parts, clamp_negative)
        stats.update(levels=len(levels), lod=lod, level_faces=[lv.n_faces for lv in levels])
        if clamp:
            stats["clamped_vertices"] = stats.get("clamped_vertices", 0) + clamp.get("clamped_vertices", 0)
            stats["most_negative"] = min(stats.get("most_negative", 0.0), clamp.get("most_negative", 0.0))
    save_stage(stage, path)
    return stats


def _merge(total: dict, stats: dict) -> None:
    if stats:
        total["clamped_vertices"] = total.get("clamped_vertices", 0) + stats["clamped_vertices"]
        total["most_negative"] = min(total.get("most_negative", 0.0), stats["most_negative"])


def _skeleton_order(prim, joints: list[str]) -> None:
    """Author ``skel:joints`` = the skeleton's order where the mesh (or an ancestor) set another one."""
    _, _, UsdSkel, _, _, Vt = pxr_modules()
    api = UsdSkel.BindingAPI(prim)
    p, order = prim, None
    while p and order is None:
        attr = UsdSkel.BindingAPI(p).GetJointsAttr()
        order = attr.Get() if attr and attr.HasAuthoredValue() else None
        p = p.GetParent()
    if order is not None and [str(j) for j in order] != list(joints):
        api.CreateJointsAttr().Set(Vt.TokenArray(list(joints)))


# --------------------------------------------------------------------------- layouts


def _relative(root: str, path: str) -> str:
    if not path.startswith(root + "/"):
        raise StepError(f"mesh {path} is not under the model prim {root}", field="levels",
                        fix="keep the skinned meshes under their SkelRoot")
    return path[len(root) + 1:]


def _move(layer, src: str, dst: str) -> None:
    """Move a prim spec (with its children) to ``dst`` in the same layer."""
    _, _, _, Sdf, _, _ = pxr_modules()
    Sdf.CreatePrimInLayer(layer, Sdf.Path(dst))
    if not Sdf.CopySpec(layer, Sdf.Path(src), layer, Sdf.Path(dst)):
        raise StepError(f"could not copy {src} into {dst}", field="levels", fix="report this file")
    spec = layer.GetPrimAtPath(src)
    parent = spec.nameParent if spec.nameParent else layer.pseudoRoot
    del parent.nameChildren[spec.name]


def _variant_layout(stage, source, levels, parts, clamp_negative) -> dict:
    """Variant set ``LOD`` on the model prim; ``LOD0`` holds the full meshes (module docstring)."""
    Usd = pxr_modules()[0]
    layer = stage.GetRootLayer()
    root = stage.GetPrimAtPath(source.root)
    vset = root.GetVariantSets().AddVariantSet("LOD")
    names = [f"LOD{i}" for i in range(len(levels) + 1)]
    for name in names:
        vset.AddVariant(name)
    rels = [_relative(source.root, part.path) for part in source.parts]
    for part, rel in zip(source.parts, rels, strict=True):
        _move(layer, part.path, f"{source.root}{{LOD=LOD0}}{rel}")
    clamp: dict = {}
    for i, level_meshes in enumerate(parts, start=1):
        for rel in rels:
            _copy(layer, f"{source.root}{{LOD=LOD0}}{rel}", f"{source.root}{{LOD={names[i]}}}{rel}")
        vset.SetVariantSelection(names[i])
        with Usd.EditContext(stage, vset.GetVariantEditTarget()):
            for lp in level_meshes:
                _merge(clamp, write_level_mesh(stage.GetPrimAtPath(lp.part.path), source, levels[i - 1], lp,
                                               clamp_negative))
    vset.SetVariantSelection("LOD0")
    return clamp


def _prims_layout(stage, source, levels, parts, clamp_negative) -> dict:
    """``LODs`` prim with ``UsdLod.RootAPI``; children ``LOD0`` (the full meshes) .. ``LODn`` (module docstring)."""
    _, UsdGeom, _, Sdf, _, _ = pxr_modules()
    from pxr import UsdLod

    layer = stage.GetRootLayer()
    base = f"{source.root}/LODs"
    if stage.GetPrimAtPath(base):
        raise StepError(f"{base} already exists", field="lod", fix="write with lod: variant, or rename that prim")
    lods = UsdGeom.Scope.Define(stage, base)
    api = UsdLod.RootAPI.Apply(lods.GetPrim())
    api.CreateLodDefaultIndexAttr(0)
    rels = [_relative(source.root, part.path) for part in source.parts]
    for i in range(len(levels) + 1):
        UsdGeom.Scope.Define(stage, f"{base}/LOD{i}")
    for part, rel in zip(source.parts, rels, strict=True):
        _ensure_parents(stage, f"{base}/LOD0/{rel}")
        _move(layer, part.path, f"{base}/LOD0/{rel}")
    clamp: dict = {}
    for i, level_meshes in enumerate(parts, start=1):
        for rel in rels:
            _ensure_parents(stage, f"{base}/LOD{i}/{rel}")
            _copy(layer, f"{base}/LOD0/{rel}", f"{base}/LOD{i}/{rel}")
        UsdGeom.Imageable(stage.GetPrimAtPath(f"{base}/LOD{i}")).MakeInvisible()
        for lp, rel in zip(level_meshes, rels, strict=True):
            _merge(clamp, write_level_mesh(stage.GetPrimAtPath(f"{base}/LOD{i}/{rel}"), source, levels[i - 1], lp,
                                           clamp_negative))
    for part in source.parts:       # the meshes moved: nothing may target the old paths
        _retarget(stage, Sdf.Path(part.path), Sdf.Path(f"{base}/LOD0/{_relative(source.root, part.path)}"))
    return clamp


def _ensure_parents(stage, path: str) -> None:
    """Define missing ancestors of ``path`` as Xforms (a mesh's parent path under an LOD item)."""
    _, UsdGeom, _, Sdf, _, _ = pxr_modules()
    for anc in reversed(list(Sdf.Path(path).GetParentPath().GetPrefixes())):
        if not stage.GetPrimAtPath(anc):
            UsdGeom.Xform.Define(stage, anc)


def _retarget(stage, old, new) -> None:
    """Point relationships that targeted a moved prim (or below it) at its new place."""
    for prim in stage.Traverse():
        for rel in prim.GetRelationships():
            targets = rel.GetTargets()
            if any(t.HasPrefix(old) for t in targets):
                rel.SetTargets([t.ReplacePrefix(old, new) if t.HasPrefix(old) else t for t in targets])


def _copy(layer, src: str, dst: str) -> None:
    _, _, _, Sdf, _, _ = pxr_modules()
    Sdf.CreatePrimInLayer(layer, Sdf.Path(dst))
    if not Sdf.CopySpec(layer, Sdf.Path(src), layer, Sdf.Path(dst)):
        raise StepError(f"could not copy {src} into {dst}", field="levels", fix="report this file")


# --------------------------------------------------------------------------- one level mesh


def write_level_mesh(prim, source, level, lp, clamp_negative: bool) -> dict:
    """Replace a copied mesh prim's geometry, primvars, subsets, blend shapes and influences by a level's.

    ``prim`` holds a copy of the full mesh (authored in the current edit target).
    """
    Usd, UsdGeom, _, _, _, Vt = pxr_modules()
    part = lp.part
    mesh = UsdGeom.Mesh(prim)
    t0 = Usd.TimeCode.EarliestTime()
    src_points = np.array(mesh.GetPointsAttr().Get(t0), np.float64).reshape(-1, 3)
    tri_points = np.asarray(source.mesh.F[part.face_start:part.face_start + part.n_triangles], np.int64) - part.start
    Ginv = np.linalg.inv(part.geom_bind)
    P = lp.V @ Ginv[:3, :3].T + Ginv[:3, 3]
    for name in ("points", "faceVertexCounts", "faceVertexIndices", "extent", "normals", *_TOPOLOGY_ATTRIBUTES):
        attr = prim.GetAttribute(name)
        if attr:
            attr.Clear()           # time samples too: a level is one rest shape
    mesh.GetPointsAttr().Set(Vt.Vec3fArray.FromNumpy(P.astype(np.float32)))
    mesh.GetFaceVertexCountsAttr().Set(Vt.IntArray.FromNumpy(np.full(len(lp.faces), 3, np.int32)))
    mesh.GetFaceVertexIndicesAttr().Set(Vt.IntArray.FromNumpy(lp.faces.astype(np.int32).ravel()))
    if len(P):
        mesh.GetExtentAttr().Set(UsdGeom.PointBased.ComputeExtent(mesh.GetPointsAttr().Get()))
    for name in _TOPOLOGY_ATTRIBUTES:
        attr = prim.GetAttribute(name)
        if attr and attr.GetTypeName().isArray:
            attr.Set(attr.GetTypeName().type.pythonClass())
    _normals(source, prim, mesh, lp, tri_points, len(src_points))
    _primvars(prim, lp, tri_points, len(src_points))
    _subsets(prim, lp)
    _blend_shapes(prim, lp, tri_points, len(src_points))
    rows = lp.rows
    stats = set_influences(prim, level.weights.indices[rows], level.weights.values[rows],
                           clamp_negative=clamp_negative)
    _skeleton_order(prim, source.joints)
    return stats


def _values(raw) -> np.ndarray:
    """A Vt array as a (count, C) numpy array."""
    A = np.array(raw)
    return A.reshape(len(A), -1) if A.ndim != 2 else A


def _carry(lp, X: np.ndarray, interp: str, tri_points: np.ndarray, n_points: int):
    """Values of a level for source values of one interpolation (None when they do not fit the mesh)."""
    integer = not np.issubdtype(X.dtype, np.floating)
    if interp in ("vertex", "varying") and len(X) == n_points:
        if integer:
            near = lp.nearest_corner()
            C = X[tri_points[lp.source]][np.arange(len(lp.source))[:, None], near]
            out = np.zeros((len(lp.V),) + X.shape[1:], X.dtype)
            out[lp.faces.ravel()] = C.reshape((-1,) + X.shape[1:])
            return out
        return lp.point_values(X.astype(np.float64), tri_points)
    if interp == "faceVarying" and len(X) >= int(lp.part.corners.max(initial=-1)) + 1:
        if integer:
            near = lp.nearest_corner()
            return X[lp.part.corners[lp.source]][np.arange(len(lp.source))[:, None], near].reshape(
                (-1,) + X.shape[1:])
        return lp.corner_values(X.astype(np.float64)).reshape(-1, X.shape[1])
    if interp == "uniform" and len(X) > int(lp.part.polygon.max(initial=-1)):
        return lp.face_values(X)
    return None


def _set_array(attr, Y: np.ndarray) -> None:
    cls = attr.GetTypeName().type.pythonClass
    base = cls.__name__.removesuffix("Array")        # Vec2f, Vec3h, Float, Double, Half...
    dtype: type = np.float64 if base == "Double" or base.endswith("d") else (
        np.float16 if base == "Half" or base.endswith("h") else np.float32)
    if np.issubdtype(Y.dtype, np.integer) or np.issubdtype(Y.dtype, np.bool_):
        attr.Set(cls.FromNumpy(np.ascontiguousarray(Y)))
        return
    Y = np.ascontiguousarray(Y.astype(dtype))
    attr.Set(cls.FromNumpy(Y if Y.shape[1:] != (1,) else Y[:, 0]))


def _normals(source, prim, mesh, lp, tri_points, n_points) -> None:
    """The mesh's ``normals`` (read from the source stage: the copy was cleared), carried and renormalised."""
    Usd, UsdGeom, _, _, _, _ = pxr_modules()
    attr = prim.GetAttribute("normals")
    original = source.stage.GetPrimAtPath(lp.part.path)
    src_attr = original.GetAttribute("normals") if original else None
    raw = src_attr.Get(Usd.TimeCode.EarliestTime()) if src_attr else None
    if raw is None or not attr:
        return
    interp = UsdGeom.Mesh(original).GetNormalsInterpolation()
    Y = _carry(lp, _values(raw).astype(np.float64), interp, tri_points, n_points)
    if Y is None:
        attr.Block()
        return
    Y = Y / np.maximum(np.linalg.norm(Y, axis=1, keepdims=True), 1e-30)
    _set_array(attr, Y)
    mesh.SetNormalsInterpolation(interp)


def _primvars(prim, lp, tri_points, n_points) -> None:
    Usd, UsdGeom, _, _, _, _ = pxr_modules()
    for pv in UsdGeom.PrimvarsAPI(prim).GetPrimvars():
        name = pv.GetPrimvarName()
        if str(name).startswith("skel:"):
            continue
        interp = pv.GetInterpolation()
        if interp == "constant" or not pv.GetTypeName().isArray:
            continue
        raw = pv.ComputeFlattened(Usd.TimeCode.EarliestTime())
        if raw is None:
            continue
        X = _values(raw)
        Y = _carry(lp, X, interp, tri_points, n_points)
        attr = pv.GetAttr()
        attr.Clear()
        if pv.IsIndexed():
            pv.GetIndicesAttr().Clear()
            pv.BlockIndices()
        if Y is None:
            attr.Block()
            continue
        if str(name) in ("normals", "N"):
            Y = Y / np.maximum(np.linalg.norm(Y, axis=1, keepdims=True), 1e-30)
        if interp == "faceVarying" and np.issubdtype(Y.dtype, np.floating):
            Y, index = np.unique(np.round(Y, 7), axis=0, return_inverse=True)
            _set_array(attr, Y)
            pv.SetIndices(np.asarray(index, np.int32).ravel().tolist())
        else:
            _set_array(attr, Y)


def _subsets(prim, lp) -> None:
    """Face GeomSubsets (materials) follow each level face's source polygon; others are emptied."""
    _, UsdGeom, _, _, _, Vt = pxr_modules()
    polygon = lp.part.polygon[lp.source]
    for subset in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(prim)):
        attr = subset.GetIndicesAttr()
        old = np.array(attr.Get() or [], np.int64)
        attr.Clear()
        if subset.GetElementTypeAttr().Get() == UsdGeom.Tokens.face:
            new = np.flatnonzero(np.isin(polygon, old)).astype(np.int32)
        else:
            new = np.zeros(0, np.int32)
        attr.Set(Vt.IntArray.FromNumpy(new))


def _blend_shapes(prim, lp, tri_points, n_points) -> None:
    """Blend shapes below the mesh: dense per-point offsets carried like vertex primvars, then made sparse."""
    Usd, _, UsdSkel, _, _, Vt = pxr_modules()
    rel = UsdSkel.BindingAPI(prim).GetBlendShapeTargetsRel()
    if not rel:
        return
    for target in rel.GetTargets():
        shape_prim = prim.GetStage().GetPrimAtPath(target)
        if not shape_prim or not target.HasPrefix(prim.GetPath()):
            continue        # shapes shared with other meshes are left as they are (offsets still index points)
        shape = UsdSkel.BlendShape(shape_prim)
        idx_attr = shape.GetPointIndicesAttr()
        idx = np.array(idx_attr.Get() or [], np.int64) if idx_attr.HasAuthoredValue() else None
        carried = {}
        for attr in shape_prim.GetAttributes():
            name = attr.GetName()
            if not (name in ("offsets", "normalOffsets") or name.startswith("inbetweens:")):
                continue
            raw = attr.Get()
            if raw is None:
                continue
            X = _values(raw).astype(np.float64)
            D = np.zeros((n_points, X.shape[1]))
            if idx is None:
                D[:len(X)] = X[:n_points]
            else:
                D[idx[:len(X)]] = X[:len(idx)]
            carried[attr] = lp.point_values(D, tri_points)
        if not carried:
            continue
        used = np.flatnonzero(np.any([np.abs(Y).max(axis=1) > 0 for Y in carried.values()], axis=0))
        for attr, Y in carried.items():
            attr.Clear()
            _set_array(attr, Y[used])
        idx_attr.Clear()
        idx_attr.Set(Vt.IntArray.FromNumpy(used.astype(np.int32)))


# --------------------------------------------------------------------------- saving


def save_stage(stage, path) -> None:
    """Write the stage's root layer atomically: crate (``.usd``/``.usdc``), text (``.usda``) or a ``.usdz`` package.

    Absolute asset paths (what flattening made of relative ones) that lie in
    the output's folder tree are written relative to it again.
    """
    from pxr import Sdf, UsdUtils

    path = Path(path)
    layer = stage.GetRootLayer()
    folder = path.resolve().parent

    def anchor(asset: str) -> str:
        if asset and os.path.isabs(asset) and "[" not in asset:
            rel = os.path.relpath(asset, folder)
            if not rel.startswith(".."):
                return "./" + rel
        return asset

    if path.suffix.lower() != ".usdz":
        UsdUtils.ModifyAssetPaths(layer, anchor)
    with atomic_path(path) as tmp:
        if path.suffix.lower() == ".usdz":
            with tempfile.TemporaryDirectory(prefix="rigslim-usdz-") as work:
                crate = Path(work) / (path.stem + ".usdc")
                _export(layer, crate)
                package = Path(work) / path.name
                with diagnostics() as found:
                    ok = UsdUtils.CreateNewUsdzPackage(Sdf.AssetPath(str(crate)), str(package))
                if not ok:
                    raise StepError(f"could not package {path.name} ({'; '.join(found) or 'no reason given'})",
                                    field="write", fix="write .usdc instead, or check the textures it names")
                shutil.copyfile(package, tmp)
        else:
            _export(layer, Path(tmp), fmt=path.suffix.lower())


def _export(layer, target: Path, fmt: str | None = None) -> None:
    """Export a layer to ``target``; ``fmt`` ``.usd`` writes crate even when ``target``'s name says otherwise."""
    args = {"format": "usdc"} if fmt in (".usd", ".usdc") else ({"format": "usda"} if fmt == ".usda" else {})
    with diagnostics() as found:
        ok = layer.Export(str(target), args=args) if args else layer.Export(str(target))
    if not ok:
        raise StepError(f"USD could not write the layer ({'; '.join(found) or 'no reason given'})", field="write",
                        fix="check the output folder")
