"""What a UsdSkel character looks like, read for a glTF output: materials, textures, UVs, normals, subsets.

:func:`read_looks` reads, for every mesh of a :class:`rigslim.io.usd.read.UsdSkin`, per triangle of
the merged mesh:

- the bound ``Material`` (a ``materialBind`` ``GeomSubset`` of the face, else the mesh's own binding),
  whose ``UsdPreviewSurface`` gives the glTF material: ``diffuseColor`` (a constant, or a ``UsdUVTexture``
  whose file becomes the base colour texture, its ``scale`` the factor), ``opacity`` (a constant, or the
  texture's ``a``), ``opacityThreshold`` (``MASK``), ``metallic`` and ``roughness``; ``doubleSided`` from the
  mesh (or the material's ``customData`` ``rigslim:doubleSided``, which the glTF export writes, since a USD
  mesh, not a material, is double-sided). Faces bound to no material get USD's fallback look: the
  constant ``displayColor`` (else grey), not metallic;
- the texture coordinates the texture reads (``UsdPrimvarReader_float2`` ``varname``, default ``st``) at each
  corner, any interpolation, ``v`` flipped to glTF's top-left origin;
- the normals (``primvars:normals``, else ``normals``) at each corner, turned by ``geomBindTransform``.

:func:`export_with_looks` writes the glTF of such a character (:func:`rigslim.io.gltf.write.export_skinned`)
and then splits each mesh into one primitive per material, unwelding vertices where a corner's UV or
normal differs (seams and hard edges stay), so that the glTF renders as the USD file does. Levels taken
from a progressive hierarchy carry the same data through their source triangles
(:func:`rigslim.io.usd.levels.level_parts`).
"""

from __future__ import annotations

import base64
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigslim.io.usd.stage import pxr_modules

#: UsdPreviewSurface's defaults for inputs left unauthored.
PREVIEW_DEFAULTS: dict[str, Any] = {"diffuseColor": (0.18, 0.18, 0.18), "opacity": 1.0, "opacityThreshold": 0.0,
                    "metallic": 0.0, "roughness": 0.5}
#: glTF sampler wrap modes of UsdUVTexture's ``wrapS``/``wrapT``.
WRAP = {"repeat": 10497, "mirror": 33648, "clamp": 33071, "black": 33071}
#: Custom data key on a Material prim: the glTF material was double-sided.
DOUBLE_SIDED_KEY = "rigslim:doubleSided"
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


@dataclass
class Look:
    """One glTF material made from a USD material (or USD's fallback look).

    Attributes
    ----------
    name : str
    base_color : (4,) tuple
        ``baseColorFactor``: the diffuse colour (or the texture's scale) and the opacity.
    metallic, roughness : float
    alpha_mode : {"OPAQUE", "MASK", "BLEND"}
    alpha_cutoff : float
        ``opacityThreshold`` (with ``MASK``).
    double_sided : bool
    texture : bytes or None
        The base colour image (PNG or JPEG bytes).
    mime : str
    wrap : (int, int)
        glTF ``wrapS``, ``wrapT``.
    uv_set : str
        The primvar the texture reads.
    """

    name: str
    base_color: tuple[float, float, float, float]
    metallic: float
    roughness: float
    alpha_mode: str = "OPAQUE"
    alpha_cutoff: float = 0.5
    double_sided: bool = False
    texture: bytes | None = None
    mime: str = ""
    wrap: tuple[int, int] = (10497, 10497)
    uv_set: str = "st"


@dataclass
class PartLooks:
    """Per triangle of one mesh part: its look, and the UVs and normals of its three corners."""

    look: np.ndarray                     # (t,) index into Looks.looks
    uv: np.ndarray | None                # (t, 3, 2), glTF orientation
    normals: np.ndarray | None           # (t, 3, 3), skeleton space, unit


@dataclass
class Looks:
    looks: list[Look]
    parts: list[PartLooks]
    notes: list[str] = field(default_factory=list)


# --------------------------------------------------------------------------- reading


def read_looks(skin) -> Looks:
    """The looks of every mesh part of ``skin`` (module docstring)."""
    Usd, UsdGeom, _, _, _, _ = pxr_modules()
    from pxr import UsdShade

    stage = skin.stage
    looks: list[Look] = []
    index: dict[tuple, int] = {}
    notes: list[str] = []
    parts = []
    for part in skin.parts:
        prim = stage.GetPrimAtPath(part.path)
        mesh = UsdGeom.Mesh(prim)
        double = bool(mesh.GetDoubleSidedAttr().Get())
        n_polygons = int(part.polygon.max(initial=-1)) + 1
        poly_material: list = [None] * n_polygons
        api = UsdShade.MaterialBindingAPI(prim)
        own = api.ComputeBoundMaterial()[0]
        for p in range(n_polygons):
            poly_material[p] = own if own else None
        for subset in api.GetMaterialBindSubsets():
            mat = UsdShade.MaterialBindingAPI(subset.GetPrim()).ComputeBoundMaterial()[0]
            faces = np.asarray(subset.GetIndicesAttr().Get() or [], np.int64)
            for f in faces[(faces >= 0) & (faces < n_polygons)]:
                poly_material[f] = mat if mat else None
        keys = []
        for mat in poly_material:
            key = (str(mat.GetPath()) if mat else None, double)
            if key not in index:
                index[key] = len(looks)
                looks.append(_look(mat, prim, double, notes, skin.path) if mat else _fallback(prim, double))
            keys.append(index[key])
        look = np.asarray(keys, np.int64)[part.polygon] if keys else np.zeros(part.n_triangles, np.int64)
        used = {looks[i].uv_set for i in np.unique(look) if looks[i].texture is not None} or {"st"}
        uv_name = sorted(used)[0]
        if len(used) > 1:
            notes.append(f"{part.path}: textures read {len(used)} UV sets; glTF gets '{uv_name}' only")
        uv = _corner_values(prim, uv_name, part, 2)
        if uv is not None:
            uv = np.stack([uv[..., 0], 1.0 - uv[..., 1]], axis=-1)
        nrm = _corner_values(prim, "normals", part, 3)
        if nrm is None and mesh.GetNormalsAttr().HasAuthoredValue():
            nrm = _spread(np.asarray(mesh.GetNormalsAttr().Get(Usd.TimeCode.EarliestTime()), np.float64),
                          str(mesh.GetNormalsInterpolation()), prim, part, 3)
        if nrm is not None:
            G = part.geom_bind[:3, :3]
            nrm = nrm @ np.linalg.inv(G)           # n' = G^-T n, as rows
            length = np.linalg.norm(nrm, axis=-1, keepdims=True)
            nrm = np.where(length > 1e-12, nrm / np.maximum(length, 1e-12), nrm)
        parts.append(PartLooks(look, uv, nrm))
    return Looks(looks, parts, notes)


def _corner_values(prim, name: str, part, width: int) -> np.ndarray | None:
    """(t, 3, width) values of primvar ``name`` at each triangle corner (None: unauthored or not fitting)."""
    _, UsdGeom, _, _, _, _ = pxr_modules()
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar(name)
    if not pv or not pv.HasValue():
        return None
    return _spread(pv.ComputeFlattened(), str(pv.GetInterpolation()), prim, part, width)


def _spread(raw, interp: str, prim, part, width: int) -> np.ndarray | None:
    """Values of one interpolation at each triangle corner of ``part``, or None when they do not fit."""
    Usd, UsdGeom, _, _, _, _ = pxr_modules()
    try:
        X = np.asarray(raw, np.float64).reshape(-1, width)
    except (TypeError, ValueError):
        return None
    if not np.isfinite(X).all():
        return None
    indices = np.asarray(UsdGeom.Mesh(prim).GetFaceVertexIndicesAttr().Get(Usd.TimeCode.EarliestTime()), np.int64)
    corners = part.corners
    if interp == "faceVarying":
        pick = corners
    elif interp in ("vertex", "varying"):
        pick = indices[corners] if len(corners) else corners
    elif interp == "uniform":
        pick = np.repeat(part.polygon[:, None], 3, axis=1)
    elif interp == "constant":
        pick = np.zeros_like(corners)
    else:
        return None
    if len(pick) and int(pick.max()) >= len(X):
        return None
    return X[pick]


def _input(shader, name: str):
    """``(value, source shader, output name)`` of a shader input: its value, or what it is connected to."""
    inp = shader.GetInput(name)
    if not inp:
        return PREVIEW_DEFAULTS.get(name), None, None
    if inp.HasConnectedSource():
        source, output, _ = inp.GetConnectedSource()
        from pxr import UsdShade

        return None, UsdShade.Shader(source.GetPrim()), str(output)
    value = inp.Get()
    return (PREVIEW_DEFAULTS.get(name) if value is None else value), None, None


def _look(material, prim, double: bool, notes: list[str], path) -> Look:
    """A Look from a Material's UsdPreviewSurface (module docstring)."""
    name = material.GetPrim().GetName()
    shader = material.ComputeSurfaceSource()[0]
    custom = material.GetPrim().GetCustomDataByKey(DOUBLE_SIDED_KEY)
    double = bool(custom) if custom is not None else double
    if not shader or shader.GetIdAttr().Get() != "UsdPreviewSurface":
        notes.append(f"material {material.GetPath()} has no UsdPreviewSurface: written with its defaults")
        return Look(name, (0.18, 0.18, 0.18, 1.0), 0.0, 0.5, double_sided=double)
    color, tex, _ = _input(shader, "diffuseColor")
    opacity, alpha_tex, alpha_out = _input(shader, "opacity")
    threshold = float(_input(shader, "opacityThreshold")[0] or 0.0)
    metallic = float(_input(shader, "metallic")[0] if _input(shader, "metallic")[1] is None else 0.0)
    roughness = float(_input(shader, "roughness")[0] if _input(shader, "roughness")[1] is None else 0.5)
    look = Look(name, (0.18, 0.18, 0.18, 1.0), metallic, roughness, double_sided=double)
    alpha = float(opacity) if opacity is not None else 1.0
    if tex is not None and tex.GetIdAttr().Get() == "UsdUVTexture":
        _texture(look, tex, notes, material, path)
        scale = tex.GetInput("scale").Get() if tex.GetInput("scale") else None
        r, g, b = (float(x) for x in list(scale if scale is not None else (1, 1, 1, 1))[:3])
        if alpha_tex is not None and alpha_out == "a":
            alpha = float(scale[3]) if scale is not None else 1.0
    else:
        r, g, b = (float(x) for x in list(color if color is not None else PREVIEW_DEFAULTS["diffuseColor"])[:3])
    look.base_color = (r, g, b, alpha)
    if threshold > 0:
        look.alpha_mode, look.alpha_cutoff = "MASK", threshold
    elif alpha_tex is not None or alpha < 1.0:
        look.alpha_mode = "BLEND"
    return look


def _texture(look: Look, tex, notes: list[str], material, path) -> None:
    """Fill ``look``'s image, wrap modes and UV set from a UsdUVTexture (image files glTF holds: PNG, JPEG)."""
    from pxr import Ar, UsdShade

    file_input = tex.GetInput("file")
    asset = file_input.Get() if file_input else None
    resolved = getattr(asset, "resolvedPath", "") if asset is not None else ""
    if not resolved:
        notes.append(f"material {material.GetPath()}: texture {asset} not found: left out")
        return
    try:
        data = bytes(Ar.GetResolver().OpenAsset(Ar.ResolvedPath(resolved)).GetBuffer())
    except Exception:  # noqa: BLE001 -- any resolver failure means the same: no image
        data = b""
    mime = image_mime(data)
    if mime is None:
        notes.append(f"material {material.GetPath()}: texture {resolved} is not PNG or JPEG: left out")
        return
    look.texture, look.mime = data, mime
    wraps = []
    for axis in ("wrapS", "wrapT"):
        w = tex.GetInput(axis).Get() if tex.GetInput(axis) else None
        wraps.append(WRAP.get(str(w), 10497) if w is not None else 10497)
    look.wrap = (wraps[0], wraps[1])
    st = tex.GetInput("st")
    if st and st.HasConnectedSource():
        reader = UsdShade.Shader(st.GetConnectedSource()[0].GetPrim())
        var = reader.GetInput("varname").Get() if reader.GetInput("varname") else None
        if var:
            look.uv_set = str(var)


def _fallback(prim, double: bool) -> Look:
    """USD's look of a face bound to no material: its constant displayColor (else grey), not metallic."""
    _, UsdGeom, _, _, _, _ = pxr_modules()
    pv = UsdGeom.PrimvarsAPI(prim).GetPrimvar("displayColor")
    r, g, b = 0.5, 0.5, 0.5
    if pv and pv.HasValue():
        value = np.asarray(pv.ComputeFlattened(), np.float64).reshape(-1, 3)
        if len(value):
            r, g, b = (float(x) for x in value.mean(axis=0)[:3])
    return Look("displayColor", (r, g, b, 1.0), 0.0, 0.5, double_sided=double)


def image_mime(data: bytes) -> str | None:
    """``image/png`` or ``image/jpeg`` from an image's first bytes (None: neither)."""
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if data[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    return None


# --------------------------------------------------------------------------- writing glTF


class _Views:
    """The bufferViews of a loaded document followed by new ones (what write_pruned reads bytes from)."""

    def __init__(self, doc, extra: list[bytes]):
        self.path, self._doc, self._extra, self._n = doc.path, doc, extra, len(doc.json.get("bufferViews", []))

    def buffer_view_bytes(self, i: int) -> bytes:
        return self._doc.buffer_view_bytes(i) if i < self._n else self._extra[i - self._n]


class _Builder:
    """Adds accessors, images and materials to a document whose new bufferViews go to ``extra``."""

    def __init__(self, js: dict, looks: Looks):
        self.js, self.looks = js, looks
        self.extra: list[bytes] = []
        self.n_views = len(js.get("bufferViews", []))
        self.materials: dict[int, int] = {}

    def view(self, data: bytes, target: int | None) -> int:
        views = self.js.setdefault("bufferViews", [])
        view = {"buffer": 0, "byteLength": len(data)}
        if target is not None:
            view["target"] = target
        views.append(view)
        self.extra.append(data)
        return len(views) - 1

    def accessor(self, array: np.ndarray, component: int, type_: str, *, target: int | None = ARRAY_BUFFER,
                 normalized: bool = False, minmax: bool = False) -> int:
        array = np.ascontiguousarray(array)
        acc = {"bufferView": self.view(array.astype(array.dtype.newbyteorder("<")).tobytes(), target),
               "componentType": component, "count": int(len(array)), "type": type_}
        if normalized:
            acc["normalized"] = True
        if minmax:
            a = array.reshape(len(array), -1)
            acc["min"] = [float(x) for x in a.min(axis=0)]
            acc["max"] = [float(x) for x in a.max(axis=0)]
        self.js.setdefault("accessors", []).append(acc)
        return len(self.js["accessors"]) - 1

    def material(self, i: int) -> int:
        if i in self.materials:
            return self.materials[i]
        look = self.looks.looks[i]
        pbr: dict = {"baseColorFactor": [float(x) for x in look.base_color], "metallicFactor": float(look.metallic),
                     "roughnessFactor": float(look.roughness)}
        if look.texture is not None:
            images = self.js.setdefault("images", [])
            images.append({"name": look.name, "bufferView": self.view(look.texture, None), "mimeType": look.mime})
            samplers = self.js.setdefault("samplers", [])
            samplers.append({"magFilter": 9729, "minFilter": 9987, "wrapS": look.wrap[0], "wrapT": look.wrap[1]})
            textures = self.js.setdefault("textures", [])
            textures.append({"sampler": len(samplers) - 1, "source": len(images) - 1})
            pbr["baseColorTexture"] = {"index": len(textures) - 1}
        mat: dict = {"name": look.name, "pbrMetallicRoughness": pbr}
        if look.alpha_mode != "OPAQUE":
            mat["alphaMode"] = look.alpha_mode
        if look.alpha_mode == "MASK":
            mat["alphaCutoff"] = float(look.alpha_cutoff)
        if look.double_sided:
            mat["doubleSided"] = True
        self.js.setdefault("materials", []).append(mat)
        self.materials[i] = len(self.js["materials"]) - 1
        return self.materials[i]


def _primitives(b: _Builder, doc, old: dict, corner_rows: np.ndarray, look: np.ndarray, uv, nrm) -> list[dict]:
    """One primitive per look of the faces, vertices unwelded where a corner's UV or normal differs.

    ``corner_rows`` (t, 3) are the rows of ``old`` (the primitive export_skinned wrote) at each corner.
    """
    from rigslim.io.gltf.document import read_accessor

    attrs = old["attributes"]
    columns = {k: (read_accessor(doc, a, normalize=False), doc.json["accessors"][a]) for k, a in attrs.items()
               if k == "POSITION" or k.startswith(("JOINTS_", "WEIGHTS_")) or (k == "NORMAL" and nrm is None)}
    out = []
    for m in np.unique(look):
        faces = np.flatnonzero(look == m)
        rows = corner_rows[faces].reshape(-1)
        keys = [rows[:, None].astype(np.float64)]
        if uv is not None:
            keys.append(np.round(uv[faces].reshape(-1, 2), 7))
        if nrm is not None:
            keys.append(np.round(nrm[faces].reshape(-1, 3), 6))
        _, first, inverse = np.unique(np.hstack(keys), axis=0, return_index=True, return_inverse=True)
        inverse = np.asarray(inverse).reshape(-1)
        prim_attrs = {}
        for k, (X, acc) in columns.items():
            prim_attrs[k] = b.accessor(X[rows[first]], acc["componentType"], acc["type"],
                                       normalized=bool(acc.get("normalized")), minmax=k == "POSITION")
        if nrm is not None:
            N = nrm[faces].reshape(-1, 3)[first].astype(np.float32)
            bad = ~np.isfinite(N).all(axis=1) | (np.abs(N).sum(axis=1) < 0.5)
            N[bad] = [0, 0, 1]
            prim_attrs["NORMAL"] = b.accessor(N, 5126, "VEC3")
        if uv is not None:
            prim_attrs["TEXCOORD_0"] = b.accessor(uv[faces].reshape(-1, 2)[first].astype(np.float32), 5126, "VEC2")
        big = len(first) >= 65535
        idx = inverse.astype(np.uint32 if big else np.uint16)
        out.append({"attributes": prim_attrs, "indices": b.accessor(idx, 5125 if big else 5123, "SCALAR",
                                                                   target=ELEMENT_ARRAY_BUFFER),
                    "mode": 4, "material": b.material(int(m))})
    return out


def _level_corners(skin, looks: Looks, level, hierarchy):
    """``(corner_rows, look, uv, normals)`` of a level's faces, carried from their source triangles."""
    from rigslim.io.usd.levels import level_parts

    rows, ls, uvs, ns = [], [], [], []
    for lp, pl in zip(level_parts(skin, hierarchy, level), looks.parts, strict=True):
        rows.append(lp.rows[lp.faces])
        ls.append(pl.look[lp.source])
        if pl.uv is not None:
            uvs.append(np.einsum("tcj,tjk->tck", lp.bary, pl.uv[lp.source]))
        if pl.normals is not None:
            n = np.einsum("tcj,tjk->tck", lp.bary, pl.normals[lp.source])
            ns.append(n / np.maximum(np.linalg.norm(n, axis=-1, keepdims=True), 1e-12))
    uv = np.concatenate(uvs) if len(uvs) == len(looks.parts) else None
    nrm = np.concatenate(ns) if len(ns) == len(looks.parts) else None
    return np.concatenate(rows), np.concatenate(ls), uv, nrm


def _named_clips(skin, poses, export: dict) -> list[str]:
    """Put the clip names and the other clips of a USD character into ``export`` (``animation_name``, ``clips``
    of :func:`rigslim.io.gltf.write.export_skinned`) unless given; the notes on siblings left out."""
    from rigslim.io.usd.read import sibling_clips

    if skin.animation is None or poses is None or not len(poses):
        return []
    export.setdefault("animation_name", skin.animation.rsplit("/", 1)[-1])
    if "clips" in export:
        return []
    export["clips"], notes = sibling_clips(skin)
    return notes


def export_with_looks(path, skin, mesh, handles, weights, poses=None, *, levels=None, hierarchy=None,
                      **export) -> dict:
    """:func:`rigslim.io.gltf.write.export_skinned` of a USD character, with its looks (module docstring).

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf``.
    skin : UsdSkin
        The USD source (``skin.mesh`` is ``mesh``).
    mesh, handles, weights, poses, levels :
        As for ``export_skinned``.
    hierarchy : ProgressiveHierarchy, optional
        The hierarchy the levels were taken from (their faces carry the looks); a level without one gets the
        look most of the source's faces have.
    **export
        ``fps``, ``quantize``, ``embed``, ``lod``, ``clamp_negative``: passed to ``export_skinned``. The
        animation ``poses`` is named after the ``SkelAnimation`` the skin sampled, and every other clip
        beside it (:func:`rigslim.io.usd.read.sibling_clips`) follows under its own name.

    Returns
    -------
    dict
        ``export_skinned``'s statistics, ``materials``, ``textures``, ``primitives`` (of the full mesh) and
        ``looks_notes``.
    """
    from rigslim.errors import StepError
    from rigslim.io.atomic import atomic_path, scratch_folder
    from rigslim.io.gltf.document import load_gltf, parse_glb
    from rigslim.io.gltf.write import export_skinned, write_pruned

    path = Path(path)
    embed = bool(export.pop("embed", False))
    looks = read_looks(skin)
    looks.notes += _named_clips(skin, poses, export)
    with scratch_folder("rigslim-looks-") as tmp:
        base = tmp / "export.glb"
        stats = export_skinned(base, mesh, handles, weights, poses, levels=levels, **export)
        doc = load_gltf(base)
        js = json.loads(json.dumps(doc.json))
        b = _Builder(js, looks)
        corner_rows = np.asarray(mesh.F, np.int64)
        look = np.concatenate([p.look for p in looks.parts])
        full = [p.uv for p in looks.parts]
        uv = np.concatenate([u for u in full if u is not None]) if all(u is not None for u in full) else None
        fulln = [p.normals for p in looks.parts]
        nrm = np.concatenate([n for n in fulln if n is not None]) if all(n is not None for n in fulln) else None
        meshes = js["meshes"]
        meshes[0]["primitives"] = _primitives(b, doc, meshes[0]["primitives"][0], corner_rows, look, uv, nrm)
        common = int(np.bincount(look).argmax()) if len(look) else 0
        for i, level in enumerate(levels or []):
            old = meshes[i + 1]["primitives"][0]
            try:
                rows, lk, luv, ln = _level_corners(skin, looks, level, hierarchy)
            except StepError:
                old["material"] = b.material(common)
                looks.notes.append(f"level '{level.label}' has no source faces: one material for all of it")
                continue
            meshes[i + 1]["primitives"] = _primitives(b, doc, old, rows, lk, luv, ln)
        textures = len(js.get("textures", []))
        n_prims = len(meshes[0]["primitives"])
        if path.suffix.lower() == ".gltf" and embed:
            packed = tmp / "packed.glb"
            write_pruned(packed, _Views(doc, b.extra), js)
            out_js, data = parse_glb(packed.read_bytes(), packed)
            if data:
                out_js["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode()
            with atomic_path(path) as target:
                Path(target).write_text(json.dumps(out_js, separators=(",", ":")), encoding="utf-8")
        else:
            write_pruned(path, _Views(doc, b.extra), js)
    return {**stats, "materials": len(js.get("materials", [])), "textures": textures, "primitives": n_prims,
            "looks_notes": looks.notes}
