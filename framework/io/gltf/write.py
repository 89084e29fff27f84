"""Writing glTF 2.0: reduced skin weights into an existing document, or a new skinned document.

:func:`write_gltf` keeps the source document and replaces only the skinning
attributes (``JOINTS_n``/``WEIGHTS_n``) of the primitives that were read;
materials, textures, UVs, morph targets, animations, extras and extensions
stay as they were (their accessor data is copied byte for byte). Simplified
levels (``asset.levels``) become meshes of their own, optionally
linked with the ``MSFT_lod`` extension.

:func:`export_skinned` builds a skinned document from libigl-style data (a
mesh, a TGF skeleton, dense weights and a stacked bone animation).
"""

from __future__ import annotations

import base64
import copy
import json
import struct
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
import scipy.sparse as sp

from rigslim.errors import StepError
from rigslim.io.atomic import atomic_path, output_transaction
from rigslim.io.transforms import matrix_quaternion

if TYPE_CHECKING:
    from rigslim.model.weights import ReducedWeights

from rigslim.io.gltf.document import CHUNK_BIN, CHUNK_JSON, GLB_MAGIC, URI_SCHEME, accessor_bounds
from rigslim.io.gltf.level_skins import level_skin, source_inverse_binds, used_joints
from rigslim.io.gltf.lod import (
    hierarchy_attributes,
    level_document,
    level_primitives,
    level_sources,
    lod_level_count,
    lod_nodes,
)
from rigslim.io.gltf.primitives import primitive_data
from rigslim.io.gltf.skin import GltfSkin, skinning_sets

#: Weight encodings: name -> (numpy dtype, componentType, normalized, scale).
QUANTIZATIONS = {
    "float": (np.float32, 5126, False, None),
    "ushort": (np.uint16, 5123, True, 65535),
    "ubyte": (np.uint8, 5121, True, 255),
}
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963


# --------------------------------------------------------------------------- quantisation


def quantize_weights(values: np.ndarray, kind: str = "float") -> np.ndarray:
    """Encode rows of weights so that each row sums exactly to one after decoding.

    Parameters
    ----------
    values : (m, c) array
        Non-negative weights, rows summing to one (within round-off).
    kind : {"float", "ushort", "ubyte"}
        float32, or unsigned normalized 16/8-bit integers.

    Returns
    -------
    (m, c) array of the encoding's dtype

    Notes
    -----
    For integers with scale ``S`` (255 or 65535): ``q_c = round(S w_c)`` for
    every slot but each row's largest, which gets ``q_max = S - sum_{c != max} q_c``,
    so ``sum_c q_c / S = 1`` exactly. ``q_max >= S/c - (c-1)/2 > 0`` for
    ``c <= 8``, so it never goes negative. For float32 the largest weight is
    set to ``1 - sum_{c != max} w_c``, the others' float32 values summed
    exactly (in float64) and the result rounded once to float32, so the
    exact row sum is within half a float32 ulp of the largest weight from
    one (a float32 sum of the others left 1 + 2^-20 on bcn_epileptic, over
    the glTF validator's 2e-7 per weight).
    """
    if kind not in QUANTIZATIONS:
        raise StepError(f"unknown weight encoding '{kind}'", field="quantize", fix="use float, ushort or ubyte")
    W = np.asarray(values, dtype=np.float64)
    if W.size and W.min() < -1e-9:
        v = int(np.argmin(W.min(axis=1)))
        raise StepError(f"vertex {v} has a negative weight ({W[v].min():.3g}); glTF skin weights are non-negative",
                        field="weights", fix="solve with 'nonnegative: true', or write with 'clamp_negative: true'")
    W = np.clip(W, 0.0, None)
    sums = W.sum(axis=1, keepdims=True)
    if (sums <= 0).any():
        v = int(np.flatnonzero(sums[:, 0] <= 0)[0])
        raise StepError(f"vertex {v} has no weight", field="weights", fix="give every vertex an influence")
    W = W / sums
    dtype, _, _, scale = QUANTIZATIONS[kind]
    rows = np.arange(len(W))
    top = np.argmax(W, axis=1)
    if scale is None:
        Q = W.astype(np.float32)
        Q[rows, top] = 0
        Q[rows, top] = (1.0 - Q.sum(axis=1, dtype=np.float64)).astype(np.float32)
        return Q
    Q = np.rint(W * scale).astype(np.int64)
    Q[rows, top] = 0
    Q[rows, top] = scale - Q.sum(axis=1)
    return Q.astype(dtype)


def clamp_negative_weights(values: np.ndarray) -> tuple[np.ndarray, dict]:
    """Set negative weights to zero and renormalise the rows that had any.

    Parameters
    ----------
    values : (m, k) array, rows summing to one

    Returns
    -------
    values : (m, k) array
        ``w_c <- max(w_c, 0) / sum_c max(w_c, 0)`` on rows with a negative entry.
    stats : dict
        ``clamped_vertices`` (rows changed) and ``most_negative`` (smallest weight, 0 if none).
    """
    W = np.asarray(values, dtype=np.float64)
    bad = (W < 0).any(axis=1)
    stats = {"clamped_vertices": int(bad.sum()), "most_negative": float(min(W.min(initial=0.0), 0.0))}
    if not bad.any():
        return W, stats
    W = W.copy()
    P = np.clip(W[bad], 0.0, None)
    sums = P.sum(axis=1, keepdims=True)
    if (sums <= 0).any():
        v = int(np.flatnonzero(bad)[np.flatnonzero(sums[:, 0] <= 0)[0]])
        raise StepError(f"vertex {v} has no positive weight to keep", field="weights",
                        fix="solve with 'nonnegative: true'")
    W[bad] = P / sums
    return W, stats


def skinning_sets_arrays(indices: np.ndarray, values: np.ndarray, kind: str = "float",
                         n_sets: int | None = None) -> list[tuple[np.ndarray, np.ndarray]]:
    """Split fixed-width weights into glTF ``(JOINTS_n, WEIGHTS_n)`` sets of four.

    Parameters
    ----------
    indices, values : (m, k) arrays
        Handle (= skin joint) index and weight of each slot.
    kind : {"float", "ushort", "ubyte"}
    n_sets : int, optional
        Number of sets. Default: as many as the widest vertex needs, ``max(1, ceil(c / 4))`` for ``c`` the
        largest count of non-zero encoded weights of a vertex (k = 8 on vertices with at most 4 influences
        gives one set, not a second one of zeros).

    Returns
    -------
    list of (joints (m, 4) int, weights (m, 4) encoded)
        Slots sorted by decreasing weight; empty slots hold joint 0, weight 0.
    """
    indices = np.asarray(indices, dtype=np.int64)
    values = np.asarray(values, dtype=np.float64)
    m, k = values.shape
    width = 4 * (n_sets or max(1, -(-k // 4)))
    if k > width:
        raise StepError(f"{k} weights per vertex do not fit in {n_sets} sets of four", field="k",
                        fix="reduce to k <= 8")
    order = np.argsort(-values, axis=1, kind="stable")
    I = np.take_along_axis(indices, order, 1)
    W = np.take_along_axis(values, order, 1)
    I = np.pad(I, ((0, 0), (0, width - k)))
    W = np.pad(W, ((0, 0), (0, width - k)))
    Q = quantize_weights(W, kind)
    I = np.where(Q != 0, I, 0)
    sets = [(I[:, 4 * s:4 * s + 4], Q[:, 4 * s:4 * s + 4]) for s in range(width // 4)]
    return sets if n_sets else used_sets(sets)


def used_sets(sets: list[tuple[np.ndarray, np.ndarray]]) -> list[tuple[np.ndarray, np.ndarray]]:
    """``sets`` without its trailing sets whose weights are zero at every vertex (at least the first is kept).

    Slots are sorted by decreasing weight, so what remains is ``max(1, ceil(c / 4))`` sets for ``c`` the widest
    vertex's count of non-zero weights: a ``WEIGHTS_n`` of zeros only costs memory and shader work.
    """
    n = len(sets)
    while n > 1 and not np.any(sets[n - 1][1]):
        n -= 1
    return sets[:n]


# --------------------------------------------------------------------------- binary assembly


class _Blob:
    """Accumulates bufferViews into one new binary buffer (4-byte aligned)."""

    def __init__(self, js: dict):
        self.js = js
        self.parts: list[bytes] = []
        self.size = 0

    def add_view(self, data: bytes, *, target: int | None = None, stride: int | None = None,
                 template: dict | None = None) -> dict:
        pad = (-self.size) % 4
        if pad:
            self.parts.append(b"\0" * pad)
            self.size += pad
        view = dict(template or {})
        view.pop("byteOffset", None)
        view.update({"buffer": 0, "byteOffset": self.size, "byteLength": len(data)})
        if target is not None:
            view["target"] = target
        if stride is not None:
            view["byteStride"] = stride
        self.parts.append(bytes(data))
        self.size += len(data)
        return view

    def new_accessor(self, array: np.ndarray, component: int, type_: str, *, normalized=False, target=ARRAY_BUFFER,
                     minmax=False) -> int:
        js = self.js
        views = js.setdefault("bufferViews", [])
        views.append(self.add_view(np.ascontiguousarray(array).astype(array.dtype.newbyteorder("<")).tobytes(),
                                   target=target))
        acc = {"bufferView": len(views) - 1, "componentType": component, "count": int(len(array)), "type": type_}
        if normalized:
            acc["normalized"] = True
        if minmax:
            acc["min"], acc["max"] = accessor_bounds(array, component)
        js.setdefault("accessors", []).append(acc)
        return len(js["accessors"]) - 1

    def bytes(self) -> bytes:
        pad = (-self.size) % 4
        return b"".join(self.parts) + b"\0" * pad


def _accessor_refs(js: dict):
    """Yield (container, key) for every place that holds an accessor index."""
    for mesh in js.get("meshes", []):
        for prim in mesh.get("primitives", []):
            for key in list(prim.get("attributes", {})):
                yield prim["attributes"], key
            if "indices" in prim:
                yield prim, "indices"
            for target in prim.get("targets", []):
                for key in list(target):
                    yield target, key
    for skin in js.get("skins", []):
        if "inverseBindMatrices" in skin:
            yield skin, "inverseBindMatrices"
    for anim in js.get("animations", []):
        for s in anim.get("samplers", []):
            yield s, "input"
            yield s, "output"
    for node in js.get("nodes", []):
        inst = node.get("extensions", {}).get("EXT_mesh_gpu_instancing")
        if inst:
            for key in list(inst.get("attributes", {})):
                yield inst["attributes"], key


def _view_refs(js: dict):
    """Yield (container, key) for every place that holds a bufferView index."""
    for acc in js.get("accessors", []):
        if "bufferView" in acc:
            yield acc, "bufferView"
        sparse = acc.get("sparse")
        if sparse:
            yield sparse["indices"], "bufferView"
            yield sparse["values"], "bufferView"
    for img in js.get("images", []):
        if "bufferView" in img:
            yield img, "bufferView"
    for mesh in js.get("meshes", []):
        for prim in mesh.get("primitives", []):
            draco = prim.get("extensions", {}).get("KHR_draco_mesh_compression")
            if draco and "bufferView" in draco:
                yield draco, "bufferView"


def _drop(js: dict, kind: str, drop: set[int], refs) -> None:
    """Remove array entries ``js[kind][i]`` for i in drop and renumber every reference."""
    if not drop:
        return
    keep = [i for i in range(len(js[kind])) if i not in drop]
    new = {old: new for new, old in enumerate(keep)}
    for container, key in refs(js):
        container[key] = new[container[key]]
    js[kind] = [js[kind][i] for i in keep]


def _mime(data: bytes, uri: str) -> str:
    if data[:8] == b"\x89PNG\r\n\x1a\n":
        return "image/png"
    if data[:3] == b"\xff\xd8\xff":
        return "image/jpeg"
    if data[:4] == b"RIFF" and data[8:12] == b"WEBP":
        return "image/webp"
    ext = uri.rsplit(".", 1)[-1].lower()
    return {"png": "image/png", "jpg": "image/jpeg", "jpeg": "image/jpeg", "webp": "image/webp",
            "ktx2": "image/ktx2"}.get(ext, "application/octet-stream")


# --------------------------------------------------------------------------- document writer


def _level_primitive(blob: _Blob, level, n_joints: int, kind: str, n_sets: int | None, material=None,
                     clamp: dict | None = None) -> dict:
    from rigslim.numerics.blend import per_vertex_normals

    mesh = level.mesh
    V = np.asarray(mesh.V, np.float32)
    F = np.asarray(mesh.F)
    attrs = {"POSITION": blob.new_accessor(V, 5126, "VEC3", minmax=True)}
    if len(F):
        N = per_vertex_normals(mesh.V, mesh.F).astype(np.float32)
        N[~np.isfinite(N).all(axis=1) | (np.abs(N).sum(axis=1) < 0.5)] = [0, 0, 1]   # no face: zero or NaN
        attrs["NORMAL"] = blob.new_accessor(N, 5126, "VEC3")
    # keep only as many slots as the level's busiest vertex uses (levels may come as dense rows)
    values = np.asarray(level.weights.values, dtype=np.float64)
    if clamp is not None:
        values, stats = clamp_negative_weights(values)
        _merge_clamp(clamp, stats)
    order = np.argsort(-values, axis=1, kind="stable")
    width = max(1, int((values != 0).sum(axis=1).max(initial=1)))
    keep = order[:, :width]
    _put_sets(blob, attrs, np.take_along_axis(level.weights.indices, keep, 1), np.take_along_axis(values, keep, 1),
              n_joints, kind, n_sets)
    idx_dtype, idx_ct = (np.uint16, 5123) if len(V) < 65535 else (np.uint32, 5125)
    prim = {"attributes": attrs, "mode": 4,
            "indices": blob.new_accessor(F.reshape(-1).astype(idx_dtype), idx_ct, "SCALAR",
                                         target=ELEMENT_ARRAY_BUFFER)}
    if material is not None:
        prim["material"] = material
    return prim


def _merge_clamp(total: dict, stats: dict) -> None:
    total["clamped_vertices"] = total.get("clamped_vertices", 0) + stats["clamped_vertices"]
    total["most_negative"] = min(total.get("most_negative", 0.0), stats["most_negative"])


def _put_sets(blob: _Blob, attrs: dict, indices, values, n_joints: int, kind: str, n_sets: int | None,
              exact: SourceRows | None = None) -> str:
    """Write JOINTS_n/WEIGHTS_n accessors into ``attrs``; returns the weight encoding used.

    With ``exact``, the rows it marks are written with the source file's own values (the encoding becomes the
    finer of ``kind`` and the source's, :func:`lossless_encoding`), every other row quantised as usual.
    """
    jdt, jct = (np.uint8, 5121) if n_joints <= 256 else (np.uint16, 5123)
    if exact is not None and exact.mask.any():
        kind = lossless_encoding(kind, exact.kind)
    _, wct, wnorm, _ = QUANTIZATIONS[kind]
    k = np.asarray(values).shape[1]
    sets = skinning_sets_arrays(indices, values, kind, n_sets or max(1, -(-k // 4)))
    if exact is not None and exact.mask.any():
        J = np.concatenate([j for j, _ in sets], axis=1)
        Q = np.concatenate([q for _, q in sets], axis=1)
        EJ, EQ = exact.slots(kind, J.shape[1])
        J[exact.mask], Q[exact.mask] = EJ, EQ
        sets = [(J[:, 4 * i:4 * i + 4], Q[:, 4 * i:4 * i + 4]) for i in range(len(sets))]
    if not n_sets:
        sets = used_sets(sets)
    for s, (J, W) in enumerate(sets):
        attrs[f"JOINTS_{s}"] = blob.new_accessor(J.astype(jdt), jct, "VEC4")
        attrs[f"WEIGHTS_{s}"] = blob.new_accessor(W, wct, "VEC4", normalized=wnorm)
    return kind


#: Weight encodings from coarsest to finest.
_FINENESS = ("ubyte", "ushort", "float")


def lossless_encoding(requested: str, source: str) -> str:
    """The encoding that stores both newly computed weights (at least ``requested``) and the source's own
    ``source``-encoded values exactly: ubyte codes are exact in ushort (``q * 257``), ushort only in ushort,
    float32 only in float; the finer of the two otherwise."""
    if requested == source or (source == "ubyte" and requested == "ushort"):
        return requested
    return max(requested, source, key=_FINENESS.index)


@dataclass
class SourceRows:
    """The file's own skinning values of one primitive's vertices whose weights did not change.

    Attributes
    ----------
    mask : (m,) bool
        Vertices written with the source's values.
    joints, codes : (r, c) arrays
        Their JOINTS_n and raw (undecoded) WEIGHTS_n values, all sets side by side (r = mask.sum()).
    kind : {"ubyte", "ushort", "float"}
        The source's weight encoding.
    """

    mask: np.ndarray
    joints: np.ndarray
    codes: np.ndarray
    kind: str

    def slots(self, kind: str, width: int) -> tuple[np.ndarray, np.ndarray]:
        """(r, width) joints and values in encoding ``kind``, largest first, zeros padded."""
        scale = {"ubyte": 255, "ushort": 65535}
        Q = self.codes
        if kind == self.kind:
            out = Q
        elif self.kind == "ubyte" and kind == "ushort":
            out = Q.astype(np.int64) * 257
        elif kind == "float":
            out = (Q.astype(np.float64) / scale[self.kind]).astype(np.float32)
        else:  # pragma: no cover - lossless_encoding never asks for a coarser encoding
            raise ValueError(f"{self.kind} weights cannot be written exactly as {kind}")
        order = np.argsort(-np.asarray(out, np.float64), axis=1, kind="stable")
        J = np.take_along_axis(self.joints, order, 1)
        W = np.take_along_axis(np.asarray(out), order, 1)
        c = J.shape[1]
        if c < width:
            J, W = np.pad(J, ((0, 0), (0, width - c))), np.pad(W, ((0, 0), (0, width - c)))
        elif np.any(W[:, width:] != 0):  # pragma: no cover - callers keep only rows with <= width weights
            raise ValueError("a kept row has more weights than the output's sets hold")
        J, W = J[:, :width], W[:, :width]
        dtype = QUANTIZATIONS[kind][0]
        return np.where(W != 0, J, 0), W.astype(dtype)


_KINDS = {5126: "float", 5123: "ushort", 5121: "ubyte"}


def source_rows(source: GltfSkin, part, indices: np.ndarray, values: np.ndarray) -> SourceRows | None:
    """Which vertices of one primitive keep exactly the weights they were read with, and the file's values.

    A vertex qualifies when its reduced row (``indices``/``values``, the primitive's file rows) is the row the
    reader gave it (same joints, bit-equal values) and its stored values are valid as they are (integer codes
    summing exactly to 255 / 65535, float rows summing to one within the glTF validator's 2e-7 per non-zero
    weight). None when
    no vertex does or the sets mix encodings.
    """
    from rigslim.io.gltf.document import read_accessor

    doc = source.document
    attrs = doc.json["meshes"][part.mesh]["primitives"][part.primitive]["attributes"]
    sets = skinning_sets(attrs)
    cts = {doc.json["accessors"][attrs[f"WEIGHTS_{s}"]]["componentType"] for s in sets}
    if len(cts) != 1 or next(iter(cts)) not in _KINDS:
        return None
    kind = _KINDS[next(iter(cts))]
    m = part.count
    J = np.concatenate([np.asarray(read_accessor(doc, attrs[f"JOINTS_{s}"], normalize=False)).reshape(m, -1)
                        for s in sets], axis=1)
    Q = np.concatenate([np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"], normalize=False)).reshape(m, -1)
                        for s in sets], axis=1)
    rows = source.file_rows(part)
    read = sp.csr_matrix(source.weights)[rows]
    mine = sp.csr_matrix((np.asarray(values, float).ravel(), (np.repeat(np.arange(m), indices.shape[1]),
                                                              np.asarray(indices, np.int64).ravel())),
                         shape=read.shape)
    mine.eliminate_zeros()
    diff = abs(mine - read)
    same = (np.asarray(diff.max(axis=1).todense()).ravel() == 0) & (np.diff(mine.indptr) == np.diff(read.indptr))
    if kind == "float":
        # the glTF validator's rule (rigslim.io.gltf.lod.input_weights_normalized): 2e-7 per non-zero weight
        valid = np.abs(Q.astype(np.float64).sum(axis=1) - 1.0) <= 2e-7 * np.count_nonzero(Q, axis=1)
    else:
        valid = Q.astype(np.int64).sum(axis=1) == (255 if kind == "ubyte" else 65535)
    valid &= (Q >= 0).all(axis=1) & np.isfinite(Q.astype(np.float64)).all(axis=1)
    valid &= (np.asarray(J, np.float64) == np.rint(np.asarray(J, np.float64))).all(axis=1)
    mask = same & valid
    if not mask.any():
        return None
    return SourceRows(mask, np.asarray(J[mask], np.int64), Q[mask], kind)


def write_gltf(path, source: GltfSkin, reduced=None, *, quantize: str = "float", sets: int | None = None,
               levels=None, lod: bool = False, embed: bool = False, clamp_negative: bool = False,
               hierarchy=None, coverage=None, level_extras=None, level_skins: bool = True) -> dict:
    """Write the source document with new skin weights (and simplified levels).

    Parameters
    ----------
    path : path-like
        ``.glb`` (one binary chunk) or ``.gltf`` (JSON plus ``<stem>.bin``
        beside it, or one base64 data URI when ``embed``).
    source : GltfSkin
        What :func:`rigslim.io.gltf.skin.read_gltf_skin` returned.
    reduced : ReducedWeights, optional
        Weights of the merged mesh (rows in the order of ``source.slices``);
        None keeps the source weights (a plain rewrite).
    quantize : {"float", "ushort", "ubyte"}
        Encoding of ``WEIGHTS_n``; every vertex's weights sum exactly to one
        after decoding (:func:`quantize_weights`).
    sets : int, optional
        Number of JOINTS/WEIGHTS sets of every primitive written (default: per primitive, as many as its
        widest vertex needs, :func:`used_sets`).
    levels : list of SimplifiedLevel, optional
        Each becomes, for each mesh the reader used, a mesh of its own with
        one primitive per source primitive (every attribute and morph target
        carried, :mod:`rigslim.io.gltf.lod`), on one new node per skinned
        node with the same skin. Levels without ``hierarchy`` become one
        primitive (single-primitive, single-node skins only).
    hierarchy : ProgressiveHierarchy, optional
        The hierarchy the levels were taken from (``asset.hierarchy``).
    lod : bool
        Link each skinned node to its own level nodes with ``MSFT_lod``
        (coarser levels in order, plus ``MSFT_screencoverage`` in the node's
        extras); otherwise each level gets its own scene.
    coverage : list of float, optional
        ``MSFT_screencoverage`` of each linked node (``len(levels) + 1`` values, from the levels'
        measured errors: :func:`rigslim.numerics.screen_coverage.coverage_series`); default halving.
    level_extras : list of dict, optional
        ``extras`` of each level's nodes (e.g. the level's measured error).
    level_skins : bool
        Give each level mesh a skin of only the joints its vertices use (:mod:`rigslim.io.gltf.level_skins`);
        false: every level node uses the source skin (all its joints).
    embed : bool
        For ``.gltf``: store the buffer as a data URI instead of a ``.bin`` file.
    clamp_negative : bool
        glTF weights must be non-negative: set negative weights to zero and
        renormalise those rows (:func:`clamp_negative_weights`) instead of
        raising a StepError. [S09] levels may carry negative weights.

    Returns
    -------
    dict
        ``clamped_vertices`` and ``most_negative`` (when clamping); with ``reduced``, ``sets`` (the most
        sets a primitive got), ``weight_encodings`` and ``vertices_kept_exact``.

    Notes
    -----
    Every accessor, bufferView, image and extension not involved in
    skinning is kept with the same content; only the replaced
    ``JOINTS_n``/``WEIGHTS_n`` accessors (and bufferViews nothing else uses)
    are dropped, and indices are renumbered. All binary data is repacked
    into a single buffer; images stored as external files are embedded when
    the output goes to another folder.
    """
    path = Path(path)
    js = copy.deepcopy(source.document.json)
    _check_rewrite(path, source, reduced, quantize, js)
    clamp: dict[str, Any] | None = {} if clamp_negative else None
    if reduced is not None and clamp is not None:
        reduced = _clamped(reduced, clamp)
    blob = _repacked(path, js, source, reduced)
    _exact_affine_binds(js, blob, source)
    stats: dict = _put_reduced(js, blob, source, reduced, quantize, sets) if reduced is not None else {}
    if levels:
        stats.update(_put_levels(js, blob, source, levels, hierarchy, quantize, sets, clamp, lod, coverage,
                                 level_extras, level_skins))
    _write_one_buffer(path, js, blob, embed)
    if clamp is not None:
        stats.update({"clamped_vertices": 0, "most_negative": 0.0} | clamp)
    return stats


def _exact_affine_binds(js: dict, blob: _Blob, source: GltfSkin) -> None:
    """The skin read gets inverse bind matrices whose last rows are exactly ``[0, 0, 0, 1]``.

    The reader accepts a last row within ``1e-6`` of it (the ``0.9999999`` some exporters write), the validator
    does not (``ACCESSOR_INVALID_IBM``): such matrices are written again with the row made exact, as the level
    skins' are (:mod:`rigslim.io.gltf.level_skins`), so that a rewritten file carries no error its source had
    there. Exact matrices keep their accessor."""
    from rigslim.io.gltf.document import read_accessor

    sk = js.get("skins", [])[source.skin] if source.skin is not None and js.get("skins") else None
    if sk is None or "inverseBindMatrices" not in sk:
        return
    ibm = np.asarray(read_accessor(source.document, source.document.json["skins"][source.skin]["inverseBindMatrices"]),
                     np.float32).reshape(-1, 4, 4)      # column-major: row 3 of each matrix is [:, :, 3]
    if (ibm[:, :, 3] == np.array([0, 0, 0, 1], np.float32)).all():
        return
    ibm[:, :, 3] = [0.0, 0.0, 0.0, 1.0]
    sk["inverseBindMatrices"] = blob.new_accessor(ibm.reshape(-1, 16), 5126, "MAT4", target=None)


def _check_rewrite(path: Path, source: GltfSkin, reduced, quantize: str, js: dict) -> None:
    """What :func:`write_gltf` can write: a glTF suffix, a known encoding, weights of the mesh read, and no
    meshopt-compressed buffers."""
    if path.suffix.lower() not in (".glb", ".gltf"):
        raise StepError(f"'{path.suffix}' is not a glTF suffix", field="write", fix="write to .glb or .gltf")
    if quantize not in QUANTIZATIONS:
        raise StepError(f"unknown weight encoding '{quantize}'", field="quantize", fix="use float, ushort or ubyte")
    if reduced is not None and reduced.n_vertices != source.mesh.n_vertices:
        raise StepError(f"reduced weights have {reduced.n_vertices} rows, the glTF mesh {source.mesh.n_vertices}",
                        field="reduced", fix="write the weights of the mesh read from this file")
    for ext in ("EXT_meshopt_compression", "KHR_meshopt_compression"):
        if ext in js.get("extensionsRequired", []) + js.get("extensionsUsed", []):
            raise StepError(f"documents using {ext} cannot be rewritten", field="extensionsUsed",
                            fix="decompress the file first (e.g. gltfpack -noq)")


def _clamped(reduced, clamp: dict[str, Any]):
    """``reduced`` with negative weights set to zero and the rows renormalised; the counts go to ``clamp``."""
    from rigslim.model.weights import ReducedWeights

    values, st = clamp_negative_weights(reduced.values)
    _merge_clamp(clamp, st)
    return ReducedWeights(reduced.indices, values, reduced.n_handles)


def _repacked(path: Path, js: dict, source: GltfSkin, reduced) -> _Blob:
    """Steps 1 and 2 of :func:`write_gltf` on ``js``, the copy of the source document: with new weights,
    the skinning attributes come out and their accessors (and views) that nothing else uses are dropped;
    every kept bufferView is copied byte for byte into the new blob, then images stored as files (when
    the output goes to another folder)."""
    doc = source.document
    replaced: set[int] = set()
    if reduced is not None:
        for sl in source.slices:
            attrs = js["meshes"][sl.mesh]["primitives"][sl.primitive]["attributes"]
            for s in skinning_sets(attrs):
                replaced.add(attrs.pop(f"JOINTS_{s}"))
                replaced.add(attrs.pop(f"WEIGHTS_{s}"))
    unused = replaced - {c[k] for c, k in _accessor_refs(js)}
    _drop(js, "accessors", unused, _accessor_refs)
    view_users = {c[k] for c, k in _view_refs(js)}
    orphan_views = {doc.json["accessors"][a]["bufferView"] for a in unused
                    if "bufferView" in doc.json["accessors"][a]} - view_users
    kept_views = [i for i in range(len(js.get("bufferViews", []))) if i not in orphan_views]
    _drop(js, "bufferViews", orphan_views, _view_refs)

    blob = _Blob(js)
    js["bufferViews"] = [blob.add_view(doc.buffer_view_bytes(i), template=view)
                         for i, view in zip(kept_views, js.get("bufferViews", []), strict=False)]
    if not js["bufferViews"]:
        js.pop("bufferViews")
    same_folder = path.parent.resolve() == doc.path.parent.resolve()
    for i, img in enumerate(js.get("images", [])):
        uri = img.get("uri")
        if uri is None or uri.startswith("data:") or same_folder or URI_SCHEME.match(uri):
            continue
        data = _image_bytes(doc, uri, i)
        mime = _mime(data, uri) if data is not None else None
        if data is None or mime not in EMBEDDED_IMAGE_TYPES:   # missing, or a type glTF cannot embed: a link
            img["uri"] = relinked_uri(uri, doc.path.parent, path.parent)
            continue
        js.setdefault("bufferViews", []).append(blob.add_view(data))
        img.pop("uri")
        img["bufferView"] = len(js["bufferViews"]) - 1
        img.setdefault("mimeType", mime)
    return blob


#: Image types an output embeds (``images[].bufferView`` + ``mimeType``): the core PNG and JPEG and the types
#: of EXT_texture_webp and KHR_texture_basisu. Any other image stays a file the output links to.
EMBEDDED_IMAGE_TYPES = ("image/png", "image/jpeg", "image/webp", "image/ktx2")


def _image_bytes(doc, uri: str, i: int) -> bytes | None:
    """The bytes of an image file, or None when it cannot be read: the output then links to where the source
    does (it was no better there), rather than failing after all the work."""
    from urllib.parse import unquote

    if not (doc.path.parent / unquote(uri)).is_file():
        return None
    return doc.uri_bytes(uri, f"images[{i}]")          # its checks: the folder policy, readable bytes


def relinked_uri(uri: str, source_folder: Path, output_folder: Path) -> str:
    """A relative URI of the source's file ``uri`` as seen from ``output_folder`` (glTF URIs: ``/``-separated,
    percent-encoded)."""
    import os
    from urllib.parse import quote, unquote

    target = (source_folder / unquote(uri)).resolve()
    try:
        rel = os.path.relpath(target, output_folder.resolve())
    except ValueError:                 # another drive (Windows): only an absolute path reaches it
        return target.as_uri()
    return quote(rel.replace(os.sep, "/"))


def _put_reduced(js: dict, blob: _Blob, source: GltfSkin, reduced, quantize: str, sets: int | None) -> dict:
    """Step 2b of :func:`write_gltf`: the new JOINTS_n/WEIGHTS_n of every primitive the reader used (rows a
    source file already holds exactly keep its bytes); ``weight_encodings``, ``vertices_kept_exact`` and
    ``sets``, the most JOINTS_n/WEIGHTS_n sets a primitive got (each as many as its widest vertex needs)."""
    encodings, kept, n_sets = [], 0, 1
    for sl in source.slices:
        attrs = js["meshes"][sl.mesh]["primitives"][sl.primitive]["attributes"]
        rows = source.file_rows(sl)
        I, W = reduced.indices[rows], reduced.values[rows]
        exact = source_rows(source, sl, I, W)
        encodings.append(_put_sets(blob, attrs, I, W, len(source.joints), quantize, sets, exact))
        kept += int(exact.mask.sum()) if exact is not None else 0
        n_sets = max(n_sets, len(skinning_sets(attrs)))
    return {"weight_encodings": encodings, "vertices_kept_exact": kept, "sets": n_sets}


def _put_levels(js: dict, blob: _Blob, source: GltfSkin, levels, hierarchy, quantize: str, sets: int | None,
                clamp: dict[str, Any] | None, lod: bool, coverage, level_extras, level_skins: bool) -> dict:
    """Step 3 of :func:`write_gltf`: the simplified levels as meshes of their own (one primitive per source
    primitive from a hierarchy, else one merged primitive); ``level_primitives`` in the first case."""
    n_joints = len(source.joints)
    for level in levels:
        if level.weights.n_handles != n_joints:
            raise StepError(f"level '{level.label}' has weights for {level.weights.n_handles} handles, "
                            f"the skin has {n_joints} joints", field="levels",
                            fix="simplify the mesh read from this glTF file")
    if hierarchy is not None and all(lv.vertex_ids is not None for lv in levels):
        return {"level_primitives": _write_levels(js, blob, source, levels, hierarchy, quantize, sets, clamp,
                                                  lod, coverage, level_extras, level_skins)}
    _write_merged_levels(js, blob, source, levels, quantize, sets, clamp, lod, coverage)
    return {}


def _write_one_buffer(path: Path, js: dict, blob: _Blob, embed: bool) -> None:
    """Step 4 of :func:`write_gltf`: the blob as the document's one buffer, then the file."""
    data = blob.bytes()
    js["buffers"] = [{"byteLength": len(data)}] if data else []
    if not data:
        js.pop("buffers")
    _write_document(path, js, data, embed=embed)


def _skinned_nodes(js: dict, source: GltfSkin) -> list[int]:
    """Nodes that instantiate one of the meshes the reader used, with the skin it used."""
    meshes = {s.mesh for s in source.slices}
    return [i for i, n in enumerate(js.get("nodes", [])) if n.get("skin") == source.skin and n.get("mesh") in meshes]


def _link_levels(js: dict, source: GltfSkin, node_levels: dict[int, list[int]], lod: bool, labels,
                 coverage=None) -> None:
    """MSFT_lod on each original node (its own level nodes only), or one scene per level.

    ``coverage``: the ``MSFT_screencoverage`` values (one per level and one for the node itself,
    :func:`rigslim.numerics.screen_coverage.coverage_series`); default halving 0.5, 0.25, ... (unmeasured).
    """
    if lod:
        for i, ids in node_levels.items():
            node = js["nodes"][i]
            node.setdefault("extensions", {})["MSFT_lod"] = {"ids": ids}
            node.setdefault("extras", {})["MSFT_screencoverage"] = (
                [float(c) for c in coverage[:len(ids)]] + [float(coverage[-1])] if coverage is not None
                else [0.5 ** (j + 1) for j in range(len(ids))] + [0.0])
        used_ext = js.setdefault("extensionsUsed", [])
        if "MSFT_lod" not in used_ext:
            used_ext.append("MSFT_lod")
    else:
        roots = _joint_roots(js, source.joints)
        for j, label in enumerate(labels):
            nodes = [ids[j] for ids in node_levels.values()]
            js.setdefault("scenes", []).append({"name": label, "nodes": nodes + roots})


def _write_merged_levels(js, blob, source, levels, quantize, sets, clamp, lod, coverage=None) -> None:
    """Levels without a hierarchy (e.g. static-qslim): one primitive, only for a single-node, single-primitive skin."""
    skinned = _skinned_nodes(js, source)
    if len(skinned) != 1 or len(source.slices) != 1:
        raise StepError(f"levels without a progressive hierarchy cannot be split into this file's "
                        f"{len(source.slices)} primitives on {len(skinned)} nodes", field="levels",
                        fix="simplify with quartic, mohr-gleicher or decoro-rusinkiewicz (they record a hierarchy)")
    first = source.slices[0]
    material = js["meshes"][first.mesh]["primitives"][first.primitive].get("material")
    ids = []
    for level in levels:
        prim = _level_primitive(blob, level, len(source.joints), quantize, sets, material, clamp)
        js.setdefault("meshes", []).append({"name": level.label, "primitives": [prim]})
        js["nodes"].append({"name": level.label, "mesh": len(js["meshes"]) - 1, "skin": source.skin})
        ids.append(len(js["nodes"]) - 1)
    _link_levels(js, source, {skinned[0]: ids}, lod, [lv.label for lv in levels], coverage)


#: Primitive properties a level primitive copies from its source primitive.
_PRIMITIVE_KEEP = ("material", "extensions", "extras")


def _write_levels(js, blob, source, levels, hierarchy, quantize, sets, clamp, lod, coverage=None,
                  node_extras=None, level_skins: bool = True) -> list[dict]:
    """Per-node, per-primitive levels with every attribute (:mod:`rigslim.io.gltf.lod`).

    For each level and each mesh the reader used, a new mesh with one
    primitive per source primitive (same material, attributes and morph
    targets); for each skinned node, one level node per level with that
    mesh and a skin of the joints that mesh uses (:mod:`rigslim.io.gltf.level_skins`). Each node's
    ``MSFT_lod`` lists only its own level nodes (a primitive without faces at a level is left out, a mesh
    without any gives an empty level node). Returns per level each primitive's faces and each skin's joints.
    """

    data = primitive_data(source)
    attributes = hierarchy_attributes(source, hierarchy, data)
    shared = level_sources(source, data)
    skinned = _skinned_nodes(js, source)
    node_levels: dict[int, list[int]] = {i: [] for i in skinned}
    summary = []
    ibm = source_inverse_binds(source)
    for _j, level in enumerate(levels):
        parts = level_primitives(source, hierarchy, level, data, attributes, sources=shared)
        values = np.asarray(level.weights.values, dtype=np.float64)
        if clamp is not None:
            values, st = clamp_negative_weights(values)
            _merge_clamp(clamp, st)
        width = max(1, int((values != 0).sum(axis=1).max(initial=1)))
        order = np.argsort(-values, axis=1, kind="stable")[:, :width]
        I = np.take_along_axis(level.weights.indices, order, 1)
        W = np.take_along_axis(values, order, 1)
        skins = _level_skins(js, blob, source, parts, I, W, level.label, ibm if level_skins else None, quantize)
        by_mesh: dict[int, list] = {}
        for part in parts:
            sl = source.slices[part.slice_index]
            src = js["meshes"][sl.mesh]["primitives"][sl.primitive]
            prim = {k: copy.deepcopy(src[k]) for k in _PRIMITIVE_KEEP if k in src}
            attrs = {"POSITION": blob.new_accessor(part.positions.astype(np.float32), 5126, "VEC3", minmax=True)}
            for name, arr in part.attributes.items():
                attrs[name] = blob.new_accessor(arr.astype(np.float32), 5126, _vec(arr.shape[1]))
            ls = skins[sl.mesh]
            _put_sets(blob, attrs, ls.remap(I[part.weight_rows]), W[part.weight_rows], ls.n_joints, quantize, sets)
            prim["attributes"] = attrs
            if part.targets:
                prim["targets"] = [{name: blob.new_accessor(arr.astype(np.float32), 5126, _vec(arr.shape[1]),
                                                            minmax=name == "POSITION")
                                    for name, arr in t.items()} for t in part.targets]
            idx_dtype, idx_ct = (np.uint16, 5123) if len(part.positions) < 65535 else (np.uint32, 5125)
            prim["indices"] = blob.new_accessor(part.faces.reshape(-1).astype(idx_dtype), idx_ct, "SCALAR",
                                                target=ELEMENT_ARRAY_BUFFER)
            prim["mode"] = 4
            by_mesh.setdefault(sl.mesh, []).append((sl.primitive, prim, len(part.faces)))
        meshes = js.setdefault("meshes", [])
        new_mesh = {}
        for mi, prims in by_mesh.items():
            src_mesh = js["meshes"][mi]
            mesh = {"name": f"{src_mesh.get('name', f'mesh{mi}')}-{level.label}",
                    "primitives": [p for _, p, _ in sorted(prims, key=lambda x: x[0])]}
            for key in ("weights", "extras"):
                if key in src_mesh:
                    mesh[key] = copy.deepcopy(src_mesh[key])
            meshes.append(mesh)
            new_mesh[mi] = len(meshes) - 1
        for i in skinned:
            node = js["nodes"][i]
            mi = node["mesh"]
            js["nodes"].append({"name": f"{node.get('name', f'node{i}')}-{level.label}"})
            if mi in new_mesh:           # else every face of the mesh went: the level node shows nothing
                js["nodes"][-1].update({"mesh": new_mesh[mi], "skin": skins[mi].skin})
            if node_extras is not None and node_extras[_j]:
                js["nodes"][-1]["extras"] = copy.deepcopy(node_extras[_j])
            node_levels[i].append(len(js["nodes"]) - 1)
            for anim in js.get("animations", []) if mi in new_mesh else []:   # morph weights play on levels too
                for ch in list(anim.get("channels", [])):
                    if ch.get("target", {}).get("node") == i and ch["target"].get("path") == "weights":
                        anim["channels"].append({"sampler": ch["sampler"],
                                                 "target": {"node": len(js["nodes"]) - 1, "path": "weights"}})
        summary.append({"label": level.label, "primitive_faces": [n for ps in by_mesh.values() for _, _, n in ps],
                        "skin_joints": {int(mi): skins[mi].n_joints for mi in by_mesh},
                        "joints": len(set().union(*[set(skins[mi].used.tolist()) for mi in by_mesh]))})
    _link_levels(js, source, node_levels, lod, [lv.label for lv in levels], coverage)
    return summary


def _level_skins(js, blob, source, parts, I, W, label, ibm, quantize: str = "float") -> dict:
    """Source mesh -> the :class:`~rigslim.io.gltf.level_skins.LevelSkin` of its level mesh (the joints its
    primitives' vertices use once their weights are encoded: a weight that rounds to 0 uses no joint)."""
    rows: dict[int, list] = {}
    for part in parts:
        rows.setdefault(source.slices[part.slice_index].mesh, []).append(part.weight_rows)
    out = {}
    n = len(source.joints)
    for mi, row_blocks in rows.items():
        r = np.concatenate(row_blocks)
        used = used_joints(I[r], quantize_weights(W[r], quantize)) if ibm is not None else np.arange(n)
        out[mi] = level_skin(js, blob, source, used, label, ibm)
    return out


def _vec(width: int) -> str:
    return {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4"}[width]


def _joint_roots(js: dict, joints: list[int]) -> list[int]:
    """Root nodes of the trees that hold the joints."""
    from rigslim.io.gltf.scene import node_parents

    parent = node_parents(js)
    roots = []
    for j in joints:
        r = j
        while parent[r] >= 0:
            r = int(parent[r])
        if r not in roots:
            roots.append(r)
    return roots


def _write_document(path: Path, js: dict, data: bytes, *, embed: bool = False) -> None:
    """Write JSON + one binary buffer as .glb, or .gltf with a .bin (or a data URI)."""
    if path.suffix.lower() == ".glb":
        json_bytes = json.dumps(js, separators=(",", ":"), ensure_ascii=False).encode("utf-8")
        json_bytes += b" " * ((-len(json_bytes)) % 4)
        chunks = struct.pack("<II", len(json_bytes), CHUNK_JSON) + json_bytes
        if data:
            chunks += struct.pack("<II", len(data), CHUNK_BIN) + data
        out = struct.pack("<III", GLB_MAGIC, 2, 12 + len(chunks)) + chunks
        with atomic_path(path) as tmp:
            tmp.write_bytes(out)
        return
    if data:
        if embed:
            js["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode()
        else:
            js["buffers"][0]["uri"] = path.stem + ".bin"
    text = json.dumps(js, indent=2, ensure_ascii=False) + "\n"
    if data and not embed:  # the .gltf and its .bin are renamed into place together
        with output_transaction(), atomic_path(path.with_name(path.stem + ".bin")) as tmp_bin, \
                atomic_path(path) as tmp:
            tmp_bin.write_bytes(data)
            tmp.write_text(text, encoding="utf-8")
    else:
        with atomic_path(path) as tmp:
            tmp.write_text(text, encoding="utf-8")


# --------------------------------------------------------------------------- export from libigl data


def _dense_rows(W: sp.csr_matrix) -> tuple[np.ndarray, np.ndarray]:
    """Fixed-width (m, c) indices and values of a sparse weight matrix, c = max non-zeros per row."""
    W = sp.csr_matrix(W)
    counts = np.diff(W.indptr)
    c = max(1, int(counts.max(initial=1)))
    m = W.shape[0]
    I = np.zeros((m, c), np.int64)
    V = np.zeros((m, c))
    slot = np.arange(W.nnz) - np.repeat(W.indptr[:-1], counts)
    rows = np.repeat(np.arange(m), counts)
    I[rows, slot] = W.indices
    V[rows, slot] = W.data
    return I, V


def fixed_width_weights(W) -> ReducedWeights:
    """Sparse (m, n) weights as :class:`ReducedWeights` with k = the largest row count."""
    from rigslim.model.weights import ReducedWeights

    I, V = _dense_rows(W)
    return ReducedWeights(I, V, sp.csr_matrix(W).shape[1])


def export_skinned(path, mesh, handles, weights, poses=None, *, fps: float = 30.0, quantize: str = "float",
                   name: str = "rigslim", animation_name: str = "animation", embed: bool = False,
                   levels=None, lod: bool = False, clamp_negative: bool = False, clips=None) -> dict:
    """Write a skinned glTF from libigl-style data (mesh, TGF skeleton, weights, bone transforms).

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf``.
    mesh : Mesh
        Rest mesh; the rest pose is the bind pose.
    handles : Handles
        A skeleton; handle b is bone b, ``bones[b] = (parent joint, child joint)``.
        Each bone becomes a joint node at its parent-joint position.
    weights : scipy.sparse matrix (m, n) or ReducedWeights
        Rows sum to one; all non-zeros are written (``ceil(max per row / 4)`` sets).
    poses : Poses, optional
        Per-bone 3x4 transforms relative to the rest pose (libigl's stacked
        LBS convention); written as one animation with LINEAR translation, rotation
        and (where a joint scales) scale channels, frame f at ``f / fps`` seconds.
    fps : float
    quantize : {"float", "ushort", "ubyte"}
    name, animation_name : str
        Names of the mesh/node and of the animation.
    levels, lod, clamp_negative :
        Simplified levels and how to link them, as in :func:`write_gltf`.
    clips : list of (str, Poses), optional
        More animations of the same handles, each written after ``poses``' as an animation of that name
        with its own frames (frame f at ``f / fps`` s); default none: ``poses`` is the only animation.

    Returns
    -------
    dict
        ``sets``, and with ``clamp_negative`` ``clamped_vertices`` / ``most_negative``.

    Notes
    -----
    With ``s_b`` the bone's start and ``T_b = [R_b | t_b]`` its pose
    transform, the joint's global transform is ``G_b = T_b @ Trans(s_b) =
    [R_b | R_b s_b + t_b]`` and its inverse bind matrix ``Trans(-s_b)``, so
    ``G_b @ IBM_b = T_b``: the glTF skin reproduces the libigl deformation.
    Local transforms are ``G_parent^{-1} G_b`` (rotation ``R_p^T R_b``,
    translation ``R_p^T (x_b - x_p)``); a joint that scales gets a scale channel too (:func:`local_trs`),
    and only a local shear cannot be written.
    """
    path = Path(path)
    if handles is None or handles.kind != "skeleton" or handles.bones is None:
        raise StepError("exporting a skinned glTF needs a skeleton with bones", field="handles",
                        fix="read a TGF skeleton (inputs.skeleton)")
    n = handles.n
    start = np.asarray(handles.joints, float)[np.asarray(handles.bones)[:, 0]]
    parents = np.asarray(handles.parents, np.int64)
    clamp: dict[str, Any] | None = {} if clamp_negative else None
    I, W = _export_weights(weights, mesh, clamp)
    js: dict[str, Any] = {"asset": {"version": "2.0", "generator": "rigslim export_skinned"}, "scene": 0,
                          "nodes": [], "meshes": [], "skins": [], "accessors": [], "bufferViews": []}
    blob = _Blob(js)
    _put_export_mesh(js, blob, mesh, I, W, n, quantize, name)
    roots = _put_export_skeleton(js, blob, handles, n, start, parents, name)
    _put_export_levels(js, blob, levels or [], n, quantize, clamp, lod, roots)
    if poses is not None and len(poses):
        _put_export_animation(js, blob, poses, n, start, parents, fps, animation_name)
    for clip_name, clip_poses in clips or []:
        if clip_poses is not None and len(clip_poses):
            _put_export_animation(js, blob, clip_poses, n, start, parents, fps, clip_name)
    data = blob.bytes()
    js["buffers"] = [{"byteLength": len(data)}]
    _write_document(path, js, data, embed=embed)
    stats = {"sets": len(skinning_sets(js["meshes"][0]["primitives"][0]["attributes"]))}
    if clamp is not None:
        stats.update({"clamped_vertices": 0, "most_negative": 0.0} | clamp)
    return stats


def _export_weights(weights, mesh, clamp: dict[str, Any] | None) -> tuple[np.ndarray, np.ndarray]:
    """(m, k) joint indices and weights of every vertex for :func:`export_skinned`, negative weights
    clamped when ``clamp`` is a dict (the counts go there)."""
    from rigslim.model.weights import ReducedWeights

    if isinstance(weights, ReducedWeights):
        I, W = weights.indices, weights.values
    else:
        I, W = _dense_rows(weights)
    if clamp is not None:
        W, st = clamp_negative_weights(W)
        _merge_clamp(clamp, st)
    if W.shape[0] != mesh.n_vertices:
        raise StepError(f"weights have {W.shape[0]} rows, the mesh {mesh.n_vertices} vertices", field="weights",
                        fix="give the weights of this mesh")
    return I, W


def _put_export_mesh(js: dict, blob: _Blob, mesh, I: np.ndarray, W: np.ndarray, n: int, quantize: str,
                     name: str) -> None:
    """Mesh 0: positions, area-weighted normals (+z where a vertex has no face), the skinning sets, indices."""
    from rigslim.numerics.blend import per_vertex_normals

    V = np.asarray(mesh.V, np.float32)
    N = per_vertex_normals(mesh.V, mesh.F).astype(np.float32)
    N[~np.isfinite(N).all(axis=1) | (np.abs(N).sum(axis=1) < 0.5)] = [0, 0, 1]   # no face: zero or NaN
    attrs = {"POSITION": blob.new_accessor(V, 5126, "VEC3", minmax=True),
             "NORMAL": blob.new_accessor(N, 5126, "VEC3")}
    _put_sets(blob, attrs, I, W, n, quantize, None)
    idx_dtype, idx_ct = (np.uint16, 5123) if len(V) < 65535 else (np.uint32, 5125)
    indices = blob.new_accessor(np.asarray(mesh.F).reshape(-1).astype(idx_dtype), idx_ct, "SCALAR",
                                target=ELEMENT_ARRAY_BUFFER)
    js["meshes"].append({"name": name, "primitives": [{"attributes": attrs, "indices": indices, "mode": 4}]})


def _put_export_skeleton(js: dict, blob: _Blob, handles, n: int, start: np.ndarray, parents: np.ndarray,
                         name: str) -> list[int]:
    """Node 0 (the mesh) and the joint nodes: node b + 1 is bone b at its start ``s_b``, rest = bind, no
    rotation; the skin (inverse bind matrices ``Trans(-s_b)``) and scene 0. Returns the root joint nodes."""
    children: list[list[int]] = [[] for _ in range(n)]
    for b in range(n):
        if parents[b] >= 0:
            children[parents[b]].append(b + 1)
    js["nodes"].append({"name": name, "mesh": 0, "skin": 0})
    for b in range(n):
        p = parents[b]
        translation = (start[b] - (start[p] if p >= 0 else 0)).tolist()
        node: dict[str, Any] = {"name": handles.names[b], "translation": translation}
        if children[b]:
            node["children"] = children[b]
        js["nodes"].append(node)
    ibm = np.tile(np.eye(4), (n, 1, 1))
    ibm[:, :3, 3] = -start
    js["skins"].append({"joints": list(range(1, n + 1)), "name": name,
                        "inverseBindMatrices": blob.new_accessor(ibm.transpose(0, 2, 1).reshape(n, 16)
                                                                 .astype(np.float32), 5126, "MAT4", target=None)})
    roots = [b + 1 for b in range(n) if parents[b] < 0]
    js["scenes"] = [{"name": name, "nodes": [0] + roots}]
    return roots


def _put_export_levels(js: dict, blob: _Blob, levels: list, n: int, quantize: str, clamp: dict[str, Any] | None,
                       lod: bool, roots: list[int]) -> None:
    """One mesh and node per level with the same skin: linked from node 0 by ``MSFT_lod`` (halving screen
    coverage), or each in a scene of its own."""
    level_nodes = []
    for level in levels:
        if level.weights.n_handles != n:
            raise StepError(f"level '{level.label}' has weights for {level.weights.n_handles} handles, "
                            f"the skeleton has {n} bones", field="levels", fix="simplify this mesh")
        prim = _level_primitive(blob, level, n, quantize, None, None, clamp)
        js["meshes"].append({"name": level.label, "primitives": [prim]})
        js["nodes"].append({"name": level.label, "mesh": len(js["meshes"]) - 1, "skin": 0})
        level_nodes.append(len(js["nodes"]) - 1)
        if not lod:
            js["scenes"].append({"name": level.label, "nodes": [level_nodes[-1]] + roots})
    if level_nodes and lod:
        js["nodes"][0]["extensions"] = {"MSFT_lod": {"ids": level_nodes}}
        js["nodes"][0]["extras"] = {"MSFT_screencoverage": [0.5 ** (j + 1) for j in range(len(level_nodes))] + [0.0]}
        js["extensionsUsed"] = ["MSFT_lod"]


def _put_export_animation(js: dict, blob: _Blob, poses, n: int, start: np.ndarray, parents: np.ndarray,
                          fps: float, animation_name: str) -> None:
    """The poses as one more animation: LINEAR translation, rotation and (where a joint scales) scale channels of
    every joint node, local transforms ``G_parent^{-1} G_b`` (the Notes of :func:`export_skinned`), frame f
    at ``f / fps`` s."""
    if poses.n_handles != n:
        raise StepError(f"poses have {poses.n_handles} handles, the skeleton {n} bones", field="poses",
                        fix="use the animation of this skeleton")
    Rl, Sl, xl = local_trs(poses.T, start, parents, source=poses.source)
    q = matrix_quaternion(Rl)                                   # (p, n, 4)
    for j in range(1, len(q)):                                  # shortest arcs between frames
        flip = np.sum(q[j] * q[j - 1], axis=1) < 0
        q[j, flip] *= -1
    times = (np.arange(len(poses)) / fps).astype(np.float32)
    tacc = blob.new_accessor(times, 5126, "SCALAR", target=None, minmax=True)
    samplers, channels = [], []
    for b in range(n):
        paths = [("translation", xl[:, b], "VEC3"), ("rotation", q[:, b], "VEC4")]
        if np.abs(Sl[:, b] - 1.0).max() > 1e-7:
            paths.append(("scale", Sl[:, b], "VEC3"))
        for path_name, values, type_ in paths:
            out = blob.new_accessor(values.astype(np.float32), 5126, type_, target=None)
            samplers.append({"input": tacc, "output": out, "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": b + 1, "path": path_name}})
    js.setdefault("animations", []).append({"name": animation_name, "samplers": samplers, "channels": channels})


def local_trs(T: np.ndarray, start: np.ndarray, parents: np.ndarray, *, tolerance: float = 1e-5,
              source=None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The glTF node transforms (rotation, scale, translation) of the joints of per-bone pose transforms.

    Parameters
    ----------
    T : (p, n, 3, 4)
        ``T_b = [A_b | t_b]``, the libigl pose transforms of :func:`export_skinned`.
    start : (n, 3)
        Each bone's start (its joint node's rest position).
    parents : (n,)
        Parent bone, -1 for a root.

    Returns
    -------
    R : (p, n, 3, 3), S : (p, n, 3), x : (p, n, 3)
        With the joint's global transform ``G_b = [A_b | x_b]``, ``x_b = A_b s_b + t_b``, the local one is
        ``L_b = A_p^{-1} A_b`` (a root: ``A_b``) and ``x_b' = A_p^{-1} (x_b - x_p)``; glTF's node matrix is
        ``T R S``, so ``S`` is the column norms of ``L_b`` and ``R = L_b S^{-1}``, which must be a rotation: a
        rigid or uniformly scaled rig always decomposes, a local shear does not (one line,
        :class:`~rigslim.errors.InputError`).
    """
    from rigslim.errors import InputError

    T = np.asarray(T, dtype=np.float64)
    A, t = T[..., :3], T[..., 3]
    det = np.linalg.det(A)
    if det.size and not (det > 0).all():
        bad = np.unravel_index(int(np.argmin(det)), det.shape)
        raise InputError(f"bone transform {tuple(int(x) for x in bad)} mirrors or flattens (det = {det[bad]:.3g})",
                         source=source, field="animation", fix="give transforms with positive determinant")
    x = np.einsum("pnij,nj->pni", A, start) + t                # joint world positions
    L, xl = A.copy(), x.copy()
    for b in range(len(parents)):
        p = parents[b]
        if p >= 0:
            inv = np.linalg.inv(A[:, p])
            L[:, b] = inv @ A[:, b]
            xl[:, b] = np.einsum("pij,pj->pi", inv, x[:, b] - x[:, p])
    S = np.linalg.norm(L, axis=-2)                             # (p, n, 3): column norms
    R = L / S[..., None, :]
    err = np.abs(np.einsum("...ji,...jk->...ik", R, R) - np.eye(3)).max(axis=(-1, -2))
    if err.size and err.max() > tolerance:
        bad = np.unravel_index(int(np.argmax(err)), err.shape)
        raise InputError(f"bone transform {tuple(int(x) for x in bad)} is not a rotation plus translation and "
                         f"scale (it shears: |R^T R - I| = {err[bad]:.2g})", source=source, field="animation",
                         fix="start from the glTF source, or write USD, which keeps any joint matrix")
    return R, S, xl


# --------------------------------------------------------------------------- pruned copies (one file per level)


def write_pruned(path, doc, js: dict) -> None:
    """Write ``js`` (a modified copy of ``doc.json``) without the meshes, accessors and bufferViews nothing uses.

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf``.
    doc : GltfDocument
        Where the bufferViews' bytes come from (``js`` uses its numbering).
    js : dict
        The document to write; changed in place (unused entries dropped, indices renumbered).
    """
    path = Path(path)
    used_meshes = {n["mesh"] for n in js.get("nodes", []) if "mesh" in n}
    drop = set(range(len(js.get("meshes", [])))) - used_meshes

    def mesh_refs(j):
        for n in j.get("nodes", []):
            if "mesh" in n:
                yield n, "mesh"

    _drop(js, "meshes", drop, mesh_refs)

    def skin_refs(j):
        for n in j.get("nodes", []):
            if "skin" in n:
                yield n, "skin"

    if "skins" in js:            # a level file keeps only its own skins (not the full mesh's)
        _drop(js, "skins", set(range(len(js["skins"]))) - {n["skin"] for n in js.get("nodes", []) if "skin" in n},
              skin_refs)
        if not js["skins"]:
            js.pop("skins")
    used = {c[k] for c, k in _accessor_refs(js)}
    _drop(js, "accessors", set(range(len(js.get("accessors", [])))) - used, _accessor_refs)
    used_views = {c[k] for c, k in _view_refs(js)}
    old_views = list(range(len(js.get("bufferViews", []))))
    keep = [i for i in old_views if i in used_views]
    _drop(js, "bufferViews", set(old_views) - used_views, _view_refs)
    blob = _Blob(js)
    js["bufferViews"] = [blob.add_view(doc.buffer_view_bytes(i), template=view)
                         for i, view in zip(keep, js.get("bufferViews", []), strict=False)]
    if not js["bufferViews"]:
        js.pop("bufferViews")
    data = blob.bytes()
    js["buffers"] = [{"byteLength": len(data)}] if data else []
    if not data:
        js.pop("buffers")
    if path.parent.resolve() != doc.path.parent.resolve():    # images kept as links: from the new folder
        for img in js.get("images", []):
            uri = img.get("uri")
            if uri is not None and not URI_SCHEME.match(uri):
                img["uri"] = relinked_uri(uri, doc.path.parent, path.parent)
    _write_document(path, js, data)


def split_levels(path, outputs) -> None:
    """Write each ``MSFT_lod`` level of a file as a file of its own (the level's meshes on the original nodes).

    Parameters
    ----------
    path : path-like
        A file written with ``lod: true``.
    outputs : list of path-like
        One per level, finest first (``len(outputs)`` levels are written).
    """
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.write import write_pruned

    doc = load_gltf(path)
    lods = lod_nodes(doc.json)
    level_ids = {j for ids in lods.values() for j in ids}
    if len(outputs) > lod_level_count(doc.json):
        raise StepError(f"{len(outputs)} outputs for {lod_level_count(doc.json)} levels", field="--split",
                        fix="give one output per level")
    first = min(level_ids) if level_ids else len(doc.json.get("nodes", []))
    if any(j < first for j in level_ids) or len(doc.json["nodes"]) - first != len(level_ids):
        raise StepError("the LOD nodes are not the last nodes of the document", field="MSFT_lod",
                        fix="split files written by rigslim's glTF writer")
    for level, out in enumerate(outputs, 1):
        js = level_document(doc, level).json
        js["nodes"] = js["nodes"][:first]
        for node in js["nodes"]:
            node.get("extensions", {}).pop("MSFT_lod", None)
            if "extensions" in node and not node["extensions"]:
                node.pop("extensions")
            node.get("extras", {}).pop("MSFT_screencoverage", None)
            if "extras" in node and not node["extras"]:
                node.pop("extras")
        for anim in js.get("animations", []):
            anim["channels"] = [c for c in anim.get("channels", []) if c.get("target", {}).get("node", 0) < first]
        used = js.get("extensionsUsed", [])
        if "MSFT_lod" in used:
            used.remove("MSFT_lod")
            if not used:
                js.pop("extensionsUsed")
        write_pruned(out, doc, js)
