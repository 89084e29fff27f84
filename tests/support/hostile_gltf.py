"""Skinned glTF files built byte by byte for the hostile tests: every encoding the specification allows, and the
ways real exporters get it wrong.

:func:`build_gltf` writes a ``.glb`` from :class:`Part` records (one primitive each) on a chain of joints with
an animation, choosing how each accessor is stored: float / normalized unsigned weights, ubyte / ushort / float
(and wrongly ``normalized``) joints, KHR_mesh_quantization positions, sparse weights, EXT_meshopt_compression or
KHR_draco_mesh_compression bufferViews, extra ``extensionsRequired``, an EXT_structural_metadata table, a bad
``byteStride``, duplicate joints, a broken inverse bind matrix. :func:`rigid_parts` and :func:`random_parts` make
the geometry. :func:`posed_file_positions` poses a file's own vertices (no welding) with numpy, the reference
the tests compare rigslim's outputs with.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

CT = {"f32": 5126, "u8": 5121, "u16": 5123, "u32": 5125, "i8": 5120, "i16": 5122}
NP = {5126: np.float32, 5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5120: np.int8, 5122: np.int16}


@dataclass
class Part:
    """One primitive: positions (m, 3), triangles (f, 3), joints and weights (m, c) (c <= 4 per set)."""

    V: np.ndarray
    F: np.ndarray
    J: np.ndarray
    W: np.ndarray
    extra: dict = field(default_factory=dict)


def rigid_parts(n_parts: int = 3, n: int = 6) -> list[Part]:
    """``n_parts`` boxes stacked along x, each bound rigidly (one influence) to its own joint; neighbours share
    the corners of their common face (coincident, as separate vertices of separate primitives)."""
    parts = []
    for p in range(n_parts):
        V, F = _grid_box(p, p + 1, n)
        J = np.zeros((len(V), 4), np.int64)
        J[:, 0] = p
        W = np.zeros((len(V), 4))
        W[:, 0] = 1.0
        parts.append(Part(V, F, J, W))
    return parts


def smooth_tube(rings: int = 25, around: int = 12, length: float = 3.0, radius: float = 0.3) -> Part:
    """A closed round tube along x over joints 0..3 (joint i at x = i), each vertex blended between the two
    nearest joints: a bending limb whose collapses all cost something."""
    xs = np.linspace(0.0, length, rings)
    th = np.linspace(0.0, 2 * np.pi, around, endpoint=False)
    V = np.array([[x, radius * np.cos(t), radius * np.sin(t)] for x in xs for t in th] + [[0, 0, 0], [length, 0, 0]])
    F = [[i * around + r, i * around + (r + 1) % around, (i + 1) * around + (r + 1) % around]
         for i in range(rings - 1) for r in range(around)]
    F += [[i * around + r, (i + 1) * around + (r + 1) % around, (i + 1) * around + r]
          for i in range(rings - 1) for r in range(around)]
    a, b = len(V) - 2, len(V) - 1
    F += [[a, (r + 1) % around, r] for r in range(around)]
    F += [[b, (rings - 1) * around + r, (rings - 1) * around + (r + 1) % around] for r in range(around)]
    x = np.clip(V[:, 0], 0.0, 2.999)
    J = np.zeros((len(V), 4), np.int64)
    W = np.zeros((len(V), 4))
    J[:, 0], J[:, 1] = np.floor(x), np.floor(x) + 1
    W[:, 1] = x - np.floor(x)
    W[:, 0] = 1.0 - W[:, 1]
    return Part(V, np.array(F, np.int64), J, W)


def _grid_box(x0: float, x1: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A closed box [x0, x1] x [-0.5, 0.5]^2 as a triangulated tube with caps (shared vertices)."""
    xs = np.linspace(x0, x1, n)
    ring = np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]])
    V = np.array([[x, y, z] for x in xs for y, z in ring], float)
    F = []
    for i in range(n - 1):
        for r in range(4):
            a, b = 4 * i + r, 4 * i + (r + 1) % 4
            c, d = a + 4, b + 4
            F += [[a, b, d], [a, d, c]]
    F += [[0, 2, 1], [0, 3, 2]]
    e = 4 * (n - 1)
    F += [[e, e + 1, e + 2], [e, e + 2, e + 3]]
    return V, np.array(F, np.int64)


def random_parts(rng: np.random.Generator, n_parts: int, k: int, n_joints: int, n: int = 5) -> list[Part]:
    """Parts like :func:`rigid_parts` (coincident corners between neighbours), each vertex with 1..k random
    influences (distinct joints, positive weights summing to one)."""
    parts = []
    for p in range(n_parts):
        V, F = _grid_box(p, p + 1, n)
        m = len(V)
        width = 4 * max(1, -(-k // 4))
        J = np.zeros((m, width), np.int64)
        W = np.zeros((m, width))
        for v in range(m):
            c = int(rng.integers(1, min(k, n_joints) + 1))
            J[v, :c] = rng.choice(n_joints, c, replace=False)
            w = rng.random(c) + 0.05
            W[v, :c] = w / w.sum()
        parts.append(Part(V, F, J, W))
    return parts


class _Bin:
    def __init__(self):
        self.data = bytearray()
        self.views: list[dict] = []
        self.accessors: list[dict] = []

    def view(self, raw: bytes, *, target: int | None = None, stride: int | None = None, align: int = 4) -> int:
        self.data += b"\0" * ((-len(self.data)) % align)
        v = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if target:
            v["target"] = target
        if stride:
            v["byteStride"] = stride
        self.data += raw
        self.views.append(v)
        return len(self.views) - 1

    def accessor(self, arr: np.ndarray, ct: int, type_: str, *, normalized: bool = False, minmax: bool = False,
                 target: int | None = 34962, stride: int | None = None) -> int:
        arr = np.asarray(arr).astype(NP[ct])
        rows = arr.reshape(len(arr), -1)
        if stride:
            elem = rows.shape[1] * rows.itemsize
            raw = b"".join(r.tobytes() + b"\xee" * (stride - elem) for r in rows)
        else:
            raw = rows.tobytes()
        acc = {"bufferView": self.view(raw, target=target, stride=stride), "componentType": ct,
               "count": len(arr), "type": type_}
        if normalized:
            acc["normalized"] = True
        if minmax:
            cast = float if ct == 5126 else int
            acc["min"] = [cast(x) for x in rows.min(axis=0)]
            acc["max"] = [cast(x) for x in rows.max(axis=0)]
        self.accessors.append(acc)
        return len(self.accessors) - 1


def quantize_unorm(W: np.ndarray, scale: int) -> np.ndarray:
    """Normalized unsigned weights whose rows sum exactly to ``scale`` (the largest slot takes the rest)."""
    Q = np.rint(W * scale).astype(np.int64)
    top = np.argmax(W, axis=1)
    rows = np.arange(len(W))
    Q[rows, top] = 0
    Q[rows, top] = scale - Q.sum(axis=1)
    return Q


def chain_animation(n_joints: int, frames: int = 9, seconds: float = 1.0, amplitude: float = 0.6):
    """Rotation keys (frames, n_joints, 4) about z for a chain of joints one unit apart, and the key times."""
    t = np.linspace(0.0, seconds, frames)
    ang = amplitude * np.sin(2 * np.pi * t[:, None] / seconds + np.arange(n_joints)[None, :])
    q = np.zeros((frames, n_joints, 4))
    q[..., 2] = np.sin(ang / 2)
    q[..., 3] = np.cos(ang / 2)
    return t, q


def build_gltf(path, parts: list[Part], n_joints: int | None = None, *, weights: str = "f32", joints: str = "u8",
               joints_normalized: bool = False, positions: str = "f32", separate_meshes: bool = False,
               sparse_weights: bool = False, weight_stride: int | None = None, meshopt: bool = False,
               draco: bool = False, draco_bits: int = 30, required: tuple[str, ...] = (), metadata: bool = False,
               duplicate_joint: bool = False, ibm: np.ndarray | None = None, frames: int = 9,
               scale: float = 1.0, root_scale: float = 1.0) -> Path:
    """Write a skinned ``.glb``: ``parts`` on a chain of ``n_joints`` joints along x (joint i at x = i), with a
    ``frames``-key rotation animation.

    Parameters
    ----------
    weights : ``f32``, ``u8`` or ``u16`` (normalized, rows summing exactly to one)
    joints : ``u8``, ``u16`` or ``f32`` (the last is not allowed by the specification)
    joints_normalized : mark JOINTS_n ``normalized: true`` (not allowed by the specification)
    positions : ``f32``, or ``i16``/``i8``/``u16`` for KHR_mesh_quantization (normalized, the mesh node scaled
        back by the inverse quantisation scale and offset)
    separate_meshes : one mesh and node per part instead of one mesh with a primitive per part
    sparse_weights : store WEIGHTS_0 as a zero accessor with every vertex in its sparse substitution
    weight_stride : byteStride of the WEIGHTS_0 bufferView (33 is not a multiple of 4)
    meshopt : store the vertex attributes and indices in EXT_meshopt_compression bufferViews over an empty
        fallback buffer (extension required)
    draco : compress every primitive with KHR_draco_mesh_compression (extension required)
    draco_bits : Draco's position quantisation bits (30: lossless to float32 round-off; gltf-transform's
        default is 14, whose decoded positions miss the bounds declared from the originals)
    required : more names for ``extensionsRequired`` (and ``extensionsUsed``)
    metadata : add an EXT_structural_metadata property table whose values live in a bufferView
    duplicate_joint : list the last joint twice in the skin
    ibm : (n_joints, 4, 4) inverse bind matrices to write instead of the correct ones
    scale : uniform scale of every position and joint offset
    root_scale : the root joint scales by this and the bind-space mesh and joint offsets are divided by it, so the
        posed (world) geometry is the same: 0.01 is assimp's centimetre FBX conversion (bind space in cm, world
        in m)
    """
    n_joints = n_joints or max(int(p.J.max()) + 1 for p in parts)
    b = _Bin()
    js: dict = {"asset": {"version": "2.0", "generator": "rigslim tests hostile_gltf"}, "scene": 0}
    used, req = set(required), set(required)
    prims = []
    node_extra: dict = {}
    allV = np.concatenate([np.asarray(p.V, float) for p in parts]) * scale / root_scale
    lo_all, hi_all = allV.min(axis=0), allV.max(axis=0)      # one dequantisation for the whole skin
    for part in parts:
        attrs, prim = {}, {"mode": 4}
        V = np.asarray(part.V, float) * scale / root_scale
        if positions == "f32":
            attrs["POSITION"] = b.accessor(V, CT["f32"], "VEC3", minmax=True)
        else:
            used.add("KHR_mesh_quantization")
            req.add("KHR_mesh_quantization")
            lo, hi = lo_all, hi_all
            smax = {"i16": 32767, "i8": 127, "u16": 65535}[positions]
            ext = np.maximum(hi - lo, 1e-12)
            q = np.rint((V - lo) / ext * smax) if positions == "u16" else np.rint(((V - lo) / ext * 2 - 1) * smax)
            attrs["POSITION"] = b.accessor(q, CT[positions], "VEC3", normalized=True, minmax=True,
                                           stride=4 if positions == "i8" else 8)
            # decoded value x_n = q / smax (or max(q / smax, -1)); world = lo + ext * (x_n [+ 1] / 2)
            node_extra = {"quantization": (lo, ext, positions)}
        for s in range(part.J.shape[1] // 4):
            Js, Ws = part.J[:, 4 * s:4 * s + 4], part.W[:, 4 * s:4 * s + 4]
            Js = np.where(Ws > 0, Js, 0)
            jname = f"JOINTS_{s}"
            attrs[jname] = b.accessor(Js, CT[joints], "VEC4", normalized=joints_normalized)
            if weights == "f32":
                enc, norm = Ws.astype(np.float32), False
            else:
                enc, norm = quantize_unorm(Ws, 255 if weights == "u8" else 65535), True
            if s == 0 and sparse_weights:
                idx = np.arange(len(enc), dtype=np.uint32)
                b.accessors.append({"componentType": CT[weights], "count": len(enc), "type": "VEC4",
                                    "normalized": norm or None,
                                    "sparse": {"count": len(enc),
                                               "indices": {"bufferView": b.view(idx.tobytes()),
                                                           "componentType": 5125},
                                               "values": {"bufferView": b.view(enc.astype(NP[CT[weights]])
                                                                               .tobytes())}}})
                if not norm:
                    b.accessors[-1].pop("normalized")
                attrs[f"WEIGHTS_{s}"] = len(b.accessors) - 1
            else:
                attrs[f"WEIGHTS_{s}"] = b.accessor(enc, CT[weights], "VEC4", normalized=norm,
                                                   stride=weight_stride if s == 0 else None)
        prim["attributes"] = attrs
        F = np.asarray(part.F).reshape(-1)
        prim["indices"] = b.accessor(F, CT["u16"] if len(V) < 65535 else CT["u32"], "SCALAR", target=34963)
        prim.update(part.extra)
        prims.append(prim)
    # skeleton: a chain along x, joint i at x = i * scale
    jstart = 0
    nodes: list[dict] = []
    for i in range(n_joints):
        node = {"name": f"joint{i}", "translation": [scale / root_scale * (1.0 if i else 0.0), 0.0, 0.0]}
        if i == 0 and root_scale != 1.0:
            node["scale"] = [root_scale] * 3
        if i + 1 < n_joints:
            node["children"] = [i + 1]
        nodes.append(node)
    mesh_nodes = []
    if separate_meshes:
        js["meshes"] = [{"name": f"part{i}", "primitives": [p]} for i, p in enumerate(prims)]
        mesh_nodes = list(range(len(prims)))
    else:
        js["meshes"] = [{"name": "body", "primitives": prims}]
        mesh_nodes = [0]
    for mi in mesh_nodes:
        node = {"name": f"mesh{mi}", "mesh": mi, "skin": 0}
        if node_extra:
            lo, ext, kind = node_extra["quantization"]
            # dequantised rest space: the mesh node carries the scale/offset (ignored by skinning, as the
            # specification says: the inverse bind matrices must include it)
            node["extras"] = {"quantization_offset": lo.tolist(), "quantization_scale": ext.tolist()}
        nodes.append(node)
    joint_list = list(range(jstart, jstart + n_joints))
    if duplicate_joint:
        joint_list = joint_list + [joint_list[-1]]
    nj = len(joint_list)
    if ibm is None:
        M = np.tile(np.eye(4), (n_joints, 1, 1))
        # bind-space joint i at x = scale i / root_scale; G_i IBM_i = root_scale I at rest (assimp's cm files)
        M[:, 0, 3] = -scale / root_scale * np.arange(n_joints)
    else:
        M = np.asarray(ibm, float)
    if duplicate_joint:
        M = np.concatenate([M, M[-1:]])
    if node_extra:
        lo, ext, kind = node_extra["quantization"]
        D = np.eye(4)                       # dequantisation: normalized value -> bind space
        if kind == "u16":
            D[:3, :3] = np.diag(ext)
            D[:3, 3] = lo
        else:
            D[:3, :3] = np.diag(ext / 2)
            D[:3, 3] = lo + ext / 2
        M = M @ D
    ibm_acc = b.accessor(M.transpose(0, 2, 1).reshape(nj, 16), CT["f32"], "MAT4", target=None)
    js["skins"] = [{"joints": joint_list, "inverseBindMatrices": ibm_acc}]
    js["nodes"] = nodes
    js["scenes"] = [{"nodes": [0] + [n_joints + i for i in range(len(mesh_nodes))]}]
    t, q = chain_animation(n_joints, frames)
    tin = b.accessor(t, CT["f32"], "SCALAR", minmax=True, target=None)
    samplers, channels = [], []
    for j in range(n_joints):
        samplers.append({"input": tin, "output": b.accessor(q[:, j], CT["f32"], "VEC4", target=None),
                         "interpolation": "LINEAR"})
        channels.append({"sampler": j, "target": {"node": j, "path": "rotation"}})
    js["animations"] = [{"name": "wave", "samplers": samplers, "channels": channels}]
    if metadata:
        used.add("EXT_structural_metadata")
        values = b.view(np.arange(4, dtype=np.float32).tobytes())
        js["extensions"] = {"EXT_structural_metadata": {
            "schema": {"id": "s", "classes": {"c": {"properties": {"height": {"type": "SCALAR",
                                                                                "componentType": "FLOAT32"}}}}},
            "propertyTables": [{"class": "c", "count": 4, "properties": {"height": {"values": values}}}]}}
    js["accessors"], js["bufferViews"] = b.accessors, b.views
    data = bytes(b.data) + b"\0" * ((-len(b.data)) % 4)
    js["buffers"] = [{"byteLength": len(data)}]
    if meshopt:
        data = _meshopt(js, data)
        used.add("EXT_meshopt_compression")
        req.add("EXT_meshopt_compression")
    if draco:
        data = _draco(js, data, parts, draco_bits)
        used.add("KHR_draco_mesh_compression")
        req.add("KHR_draco_mesh_compression")
    if used:
        js["extensionsUsed"] = sorted(used)
    if req:
        js["extensionsRequired"] = sorted(req)
    return write_glb(path, js, data)


def write_glb(path, js: dict, data: bytes) -> Path:
    """A GLB container of ``js`` and one binary chunk."""
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    data = data + b"\0" * ((-len(data)) % 4)
    chunks = struct.pack("<II", len(text), 0x4E4F534A) + text
    if data:
        chunks += struct.pack("<II", len(data), 0x004E4942) + data
    path = Path(path)
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(chunks)) + chunks)
    return path


def _meshopt(js: dict, data: bytes) -> bytes:
    """Move every vertex-attribute and index bufferView into EXT_meshopt_compression: buffer 0 (the GLB chunk)
    holds the compressed bytes and the views left plain; buffer 1 is the fallback, with no data at all."""
    import meshopt

    users = {acc["bufferView"]: acc for acc in js["accessors"] if "bufferView" in acc}
    out, fallback = bytearray(), 0
    for vi, view in enumerate(js["bufferViews"]):
        raw = data[view["byteOffset"]:view["byteOffset"] + view["byteLength"]]
        acc = users.get(vi)
        target = view.get("target")
        size = view["byteLength"] // acc["count"] if acc and acc["count"] else 0
        out += b"\0" * ((-len(out)) % 4)
        if acc is None or target not in (34962, 34963) or "byteStride" in view or (target == 34962 and size % 4):
            view["buffer"], view["byteOffset"] = 0, len(out)
            out += raw
            continue
        if target == 34963:
            mode, enc = "TRIANGLES", meshopt.encode_index_buffer(
                np.frombuffer(raw, NP[acc["componentType"]]).astype(np.uint32))
            if size == 2:   # the encoder reads 32-bit indices; the stream decodes to either width
                enc = meshopt.encode_index_buffer(np.frombuffer(raw, np.uint16).astype(np.uint32))
        else:
            mode, enc = "ATTRIBUTES", meshopt.encode_vertex_buffer(np.frombuffer(raw, np.uint8).reshape(-1, size))
        view["extensions"] = {"EXT_meshopt_compression": {"buffer": 0, "byteOffset": len(out),
                                                          "byteLength": len(enc), "byteStride": size,
                                                          "count": acc["count"], "mode": mode}}
        out += enc
        fallback += (-fallback) % 4
        view["buffer"], view["byteOffset"] = 1, fallback
        fallback += view["byteLength"]
    js["buffers"] = [{"byteLength": len(out)},
                     {"byteLength": fallback, "extensions": {"EXT_meshopt_compression": {"fallback": True}}}]
    return bytes(out)


def _draco(js: dict, data: bytes, parts: list[Part], bits: int = 30) -> bytes:
    """Compress each primitive's POSITION, JOINTS_0 and WEIGHTS_0 with Draco (positions quantised to ``bits``;
    30 keeps them to float32 round-off) into a bufferView the primitive's KHR_draco_mesh_compression names. The
    accessors keep the bounds of the original positions, as exporters write them."""
    import DracoPy

    out = bytearray(data)
    prims = [p for m in js["meshes"] for p in m["primitives"]]
    for prim, part in zip(prims, parts, strict=True):
        attrs = prim["attributes"]
        J = np.asarray(part.J[:, :4], np.float32)
        W = np.asarray(part.W[:, :4], np.float32)
        enc = DracoPy.encode(np.asarray(part.V, np.float32), np.asarray(part.F, np.uint32),
                             quantization_bits=bits, compression_level=1, preserve_order=True,
                             generic_attributes={0: J, 1: W})
        out += b"\0" * ((-len(out)) % 4)
        js["bufferViews"].append({"buffer": 0, "byteOffset": len(out), "byteLength": len(enc)})
        out += enc
        dec = DracoPy.decode(enc)        # the encoder numbers the attributes itself: read its ids back
        pos = next(a["unique_id"] for a in dec.attributes if a["attribute_type"] == 0)
        generic = sorted(a["unique_id"] for a in dec.attributes if a["attribute_type"] != 0)
        ids = {"POSITION": pos, "JOINTS_0": generic[0], "WEIGHTS_0": generic[1]}
        prim["extensions"] = {"KHR_draco_mesh_compression": {"bufferView": len(js["bufferViews"]) - 1,
                                                             "attributes": ids}}
        for name, a in attrs.items():      # the accessors stay (count, type, min/max) without their data
            if name in ids:
                js["accessors"][a].pop("bufferView", None)
        js["accessors"][prim["indices"]].pop("bufferView", None)
    js["buffers"][0]["byteLength"] = len(out)
    return bytes(out)


def posed_file_positions(path, times) -> list[np.ndarray]:
    """Per time, the (m, 3) skinned positions of every file vertex of the default scene's skinned primitives
    (in file order, no welding), posed with numpy from rigslim's own unwelded reader."""
    from rigslim.io.gltf.skin import read_gltf_skin
    from rigslim.numerics.blend import linear_blend

    skin = read_gltf_skin(path, weld=False, times=list(times))
    return [linear_blend(skin.mesh.V, skin.weights, skin.poses.T[j]) for j in range(len(times))]
