"""glTF extensions that change how a document's bytes are read: checked, decoded, or refused in one line.

:func:`prepare_extensions` runs when a document is loaded (:func:`rigslim.io.gltf.document.load_gltf`):

- ``extensionsRequired``: every name must be one rigslim reads (:data:`DECODED`, :data:`UNDERSTOOD`) or one
  that does not change geometry, skins or animation and is kept byte for byte (:data:`PASSED_THROUGH`);
  any other required extension is refused, since rigslim cannot know what it changes;
- ``EXT_meshopt_compression`` / ``KHR_meshopt_compression``: every compressed bufferView is decoded with
  meshoptimizer's decoder (the ``meshopt`` package) into plain bytes, and the extension is removed: the
  document rigslim works on, and writes, is uncompressed;
- ``KHR_draco_mesh_compression``: every compressed primitive is decoded with Draco (the ``DracoPy`` package)
  into ordinary accessors, and the extension is removed;
- ``KHR_mesh_quantization`` needs nothing: integer and normalized positions, normals and UVs are decoded by
  :func:`rigslim.io.gltf.document.read_accessor` as the specification says.

What was decoded is recorded in ``GltfDocument.decoded`` (the writers' reports say so).
"""

from __future__ import annotations

import numpy as np

from rigslim.errors import InputError
from rigslim.io.gltf.document import accessor_bounds

#: Extensions whose data rigslim decodes at load time (and removes from the document).
DECODED = ("EXT_meshopt_compression", "KHR_meshopt_compression", "KHR_draco_mesh_compression")
#: Extensions rigslim's reader understands as they are.
UNDERSTOOD = ("KHR_mesh_quantization", "MSFT_lod")
#: Required extensions that change neither geometry, skins nor animation: kept byte for byte.
PASSED_THROUGH = ("KHR_materials_", "KHR_texture_transform", "KHR_texture_basisu", "EXT_texture_webp",
                  "EXT_texture_avif", "KHR_lights_punctual", "KHR_materials_variants", "KHR_xmp_json_ld")

_FILTERS = {None: None, "NONE": None, "OCTAHEDRAL": "OCTAHEDRAL", "QUATERNION": "QUATERNION",
            "EXPONENTIAL": "EXPONENTIAL", "COLOR": "COLOR"}
_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}
_WIDTH = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4}


def readable(name: str) -> bool:
    """Whether a required extension is one rigslim can honour."""
    return name in DECODED or name in UNDERSTOOD or any(name.startswith(p) for p in PASSED_THROUGH)


def check_required(doc) -> None:
    """Refuse, in one line, a document that requires an extension rigslim cannot read."""
    for i, name in enumerate(doc.json.get("extensionsRequired", []) or []):
        if not readable(str(name)):
            raise InputError(f"the file requires the extension {name}, which rigslim cannot read", source=doc.path,
                             field=f"extensionsRequired[{i}]",
                             fix="re-export without it (e.g. gltf-transform or gltfpack -noq)")


def fallback_buffer(buf: dict) -> bool:
    """A meshopt fallback buffer: it may have no data at all (its views are decoded from another buffer)."""
    ext = buf.get("extensions") or {}
    return any(bool((ext.get(n) or {}).get("fallback")) for n in ("EXT_meshopt_compression",
                                                                  "KHR_meshopt_compression"))


def prepare_extensions(doc) -> None:
    """Check ``extensionsRequired`` and decode meshopt bufferViews and Draco primitives in place."""
    check_required(doc)
    for name in ("EXT_meshopt_compression", "KHR_meshopt_compression"):
        if _uses(doc.json, name):
            _decode_meshopt(doc, name)
    if _uses(doc.json, "KHR_draco_mesh_compression"):
        _decode_draco(doc)


def _uses(js: dict, name: str) -> bool:
    return name in (js.get("extensionsUsed") or []) or name in (js.get("extensionsRequired") or [])


def _forget(doc, name: str) -> None:
    js = doc.json
    for key in ("extensionsUsed", "extensionsRequired"):
        if name in (js.get(key) or []):
            js[key] = [n for n in js[key] if n != name]
            if not js[key]:
                js.pop(key)
    doc.decoded.append(name)


def _new_buffer(doc, data: bytes) -> int:
    doc.json.setdefault("buffers", []).append({"byteLength": len(data)})
    doc.buffers.append(bytes(data))
    return len(doc.buffers) - 1


def _decode_meshopt(doc, name: str) -> None:
    try:
        import meshopt
    except ImportError:
        raise InputError(f"the file is compressed with {name}, which needs the meshopt package", source=doc.path,
                         field="extensionsUsed", fix="pip install meshopt (part of rigslim[gltf])") from None
    js = doc.json
    decoded, views = bytearray(), []
    for i, view in enumerate(js.get("bufferViews", [])):
        ext = (view.get("extensions") or {}).get(name)
        if ext is None:
            continue
        where = f"bufferViews[{i}].extensions.{name}"
        try:
            src = doc.buffers[ext["buffer"]]
            data = src[ext.get("byteOffset", 0):ext.get("byteOffset", 0) + ext["byteLength"]]
            out = meshopt.decode_gltf_buffer(data, int(ext["count"]), int(ext["byteStride"]), ext.get("mode"),
                                             _FILTERS[ext.get("filter")])
        except (KeyError, IndexError, ValueError, RuntimeError, TypeError) as e:
            raise InputError(f"the meshopt stream cannot be decoded ({type(e).__name__}: {e})", source=doc.path,
                             field=where, fix="re-export the file") from None
        raw = np.ascontiguousarray(out).tobytes()
        decoded += b"\0" * ((-len(decoded)) % 4)
        views.append((view, len(decoded), raw))
        decoded += raw
    index = _new_buffer(doc, bytes(decoded))
    for view, offset, raw in views:
        view["extensions"].pop(name)
        if not view["extensions"]:
            view.pop("extensions")
        view.update({"buffer": index, "byteOffset": offset, "byteLength": len(raw)})
    for buf in js.get("buffers", []):
        exts = buf.get("extensions") or {}
        if name in exts:
            exts.pop(name)
            if not exts:
                buf.pop("extensions")
    _forget(doc, name)


def _decode_draco(doc) -> None:
    try:
        import DracoPy
    except ImportError:
        raise InputError("the file is compressed with KHR_draco_mesh_compression, which needs DracoPy",
                         source=doc.path, field="extensionsUsed", fix="pip install DracoPy (part of rigslim[gltf])"
                         ) from None
    js = doc.json
    blob = bytearray()
    pending = []
    for mi, mesh in enumerate(js.get("meshes", [])):
        for pi, prim in enumerate(mesh.get("primitives", [])):
            ext = (prim.get("extensions") or {}).get("KHR_draco_mesh_compression")
            if ext is None:
                continue
            where = f"meshes[{mi}].primitives[{pi}].extensions.KHR_draco_mesh_compression"
            try:
                decoded = DracoPy.decode(doc.buffer_view_bytes(ext["bufferView"]))
                arrays = {n: np.asarray(decoded.get_attribute_by_unique_id(int(uid))["data"])
                          for n, uid in ext["attributes"].items()}
                faces = np.asarray(decoded.faces, np.int64).reshape(-1)
            except Exception as e:  # noqa: BLE001 - DracoPy raises its own and generic errors alike
                raise InputError(f"the Draco stream cannot be decoded ({type(e).__name__}: {e})", source=doc.path,
                                 field=where, fix="re-export the file") from None
            for name, arr in arrays.items():
                acc = js["accessors"][prim["attributes"][name]]
                pending.append((acc, _cast(arr, acc, doc, f"{where}.attributes.{name}")))
                _rebound(acc, pending[-1][1])
            if "indices" in prim:
                acc = js["accessors"][prim["indices"]]
                pending.append((acc, _cast(faces, acc, doc, f"{where} (indices)")))
            prim["extensions"].pop("KHR_draco_mesh_compression")
            if not prim["extensions"]:
                prim.pop("extensions")
    index = _new_buffer(doc, b"")
    for acc, raw in pending:
        blob += b"\0" * ((-len(blob)) % 4)
        js.setdefault("bufferViews", []).append({"buffer": index, "byteOffset": len(blob), "byteLength": len(raw)})
        acc["bufferView"] = len(js["bufferViews"]) - 1
        acc.pop("byteOffset", None)
        blob += raw
    doc.buffers[index] = bytes(blob)
    js["buffers"][index]["byteLength"] = len(blob)
    _forget(doc, "KHR_draco_mesh_compression")


def _rebound(acc: dict, raw: bytes) -> None:
    """The accessor's ``min`` / ``max`` made those of its decoded values. A lossy Draco stream (quantised
    positions: gltf-transform's default is 14 bits) decodes to values a little off the bounds the exporter
    declared from the original data; written out uncompressed, those bounds would fail the validator
    (``ACCESSOR_MAX_MISMATCH``). Per glTF 2.0 the bounds are of the stored values, normalised or not."""
    if ("min" in acc or "max" in acc) and acc["count"]:
        width = _WIDTH.get(acc.get("type", "SCALAR"), 1)
        arr = np.frombuffer(raw, np.dtype(_DTYPES[acc["componentType"]]).newbyteorder("<")).reshape(-1, width)
        lo, hi = accessor_bounds(arr, acc["componentType"])
        acc.update({k: v for k, v in (("min", lo), ("max", hi)) if k in acc})


def _cast(arr: np.ndarray, acc: dict, doc, where: str) -> bytes:
    """A decoded Draco attribute in the accessor's own component type and count."""
    dtype = np.dtype(_DTYPES[acc["componentType"]])
    width = _WIDTH.get(acc.get("type", "SCALAR"), 1)
    arr = np.asarray(arr).reshape(len(arr), -1) if width > 1 else np.asarray(arr).reshape(-1)
    if len(arr) != acc["count"] or (width > 1 and arr.shape[1:] != (width,)):
        raise InputError(f"Draco decoded {arr.shape} values, the accessor says {acc['count']} x {width}",
                         source=doc.path, field=where, fix="re-export the file")
    if dtype.kind in "iu":
        arr = np.rint(arr)
    return np.ascontiguousarray(arr.astype(dtype.newbyteorder("<"))).tobytes()
