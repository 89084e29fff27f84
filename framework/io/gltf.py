"""glTF 2.0 skinned meshes and their animations, read into rigslim's data model.

A glTF skin deforms a vertex ``v`` (given in the mesh's own, "bind", space)
as (glTF 2.0 specification, section 3.7.3 "Skins")::

    v' = sum_i w_i  G(joint_i) @ IBM_i @ [v; 1]

where ``G`` is a joint node's global transform in the current pose and
``IBM_i`` the skin's inverse bind matrix; the transform of the node that
instantiates the skinned mesh is ignored. This is exactly rigslim's linear
blend model (docs/algorithms.md section 1) with one handle per joint and
``T_i = (G(joint_i) @ IBM_i)[:3, :]``.

:func:`read_gltf_skin` returns the merged skinned mesh, the skeleton handles,
the sparse weights from every ``JOINTS_n``/``WEIGHTS_n`` set, and the poses of
one animation clip sampled at a fixed frame rate. The document itself (raw
JSON plus buffer bytes) travels with the result so that
:mod:`rigslim.io.gltf_write` can write it back with new skin weights.

pygltflib parses every document into its typed model, which rejects
properties of the wrong type with a clear error; the arrays themselves are
decoded from the raw JSON dictionary, which is kept because pygltflib's
serialisation drops properties it does not know, rewrites integer min/max as
floats and replaces ``asset.generator``, while a writer must keep everything
it does not change.
"""

from __future__ import annotations

import base64
import binascii
import json
import os
import re
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError, brief
from rigslim.handles import Handles
from rigslim.io.transforms import slerp, trs_matrix
from rigslim.mesh import Mesh
from rigslim.poses import Poses
from rigslim.weights import validate_weights

#: glTF component types: numpy dtype of each.
COMPONENT_DTYPES = {5120: np.int8, 5121: np.uint8, 5122: np.int16, 5123: np.uint16,
                    5125: np.uint32, 5126: np.float32}
#: Number of components of each accessor type.
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
GLB_MAGIC = 0x46546C67
CHUNK_JSON = 0x4E4F534A
CHUNK_BIN = 0x004E4942
#: Most frames :func:`read_gltf_skin` samples, and most (frames x nodes) local transforms it builds
#: (128 bytes each): fps and clip length are refused beyond these rather than exhausting memory.
MAX_FRAMES = 100_000
MAX_FRAME_NODES = 4_000_000
_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


# --------------------------------------------------------------------------- document


@dataclass
class GltfDocument:
    """A loaded glTF document: raw JSON, typed view, and the bytes of every buffer.

    Attributes
    ----------
    path : Path
        The file it was read from (external URIs resolve against its folder).
    json : dict
        The JSON document exactly as stored.
    buffers : list of bytes
        Contents of ``buffers[i]`` (GLB binary chunk, data URI or external file).
    allow_external_uris : bool or None
        Whether URIs may name files outside the document's folder (see
        :meth:`uri_bytes`); None: as :func:`external_uris_allowed` says.
    """

    path: Path
    json: dict
    buffers: list[bytes]
    _typed: object = field(default=None, repr=False)
    allow_external_uris: bool | None = None

    @property
    def typed(self):
        """pygltflib's :class:`GLTF2` view of :attr:`json` (built on first use)."""
        if self._typed is None:
            import pygltflib

            self._typed = pygltflib.GLTF2.from_json(json.dumps(self.json))
        return self._typed

    def buffer_view_bytes(self, index: int) -> bytes:
        """The bytes of bufferView ``index``."""
        bv = self.json["bufferViews"][index]
        data = self.buffers[bv["buffer"]]
        start = bv.get("byteOffset", 0)
        return data[start:start + bv["byteLength"]]

    def uri_bytes(self, uri: str, what: str, length: int | None = None) -> bytes:
        """Bytes of a data URI or of a file relative to the document.

        A file URI must name a regular file inside the document's folder
        after symbolic links are resolved (``../x``, absolute paths and links
        leading out are refused) unless :attr:`allow_external_uris` is set;
        other schemes (``file:``, ``http:``) are never read. With ``length``,
        only that many bytes are read, after checking the file holds them
        (so ``/dev/zero`` or a huge file cannot exhaust memory).
        """
        field_name = f"{what}.uri"
        if uri.startswith("data:"):
            head, _, payload = uri.partition(",")
            if not head.endswith(";base64"):
                raise InputError(f"{what} has a data URI that is not base64", source=self.path, field=field_name,
                                 fix="re-export with base64 data URIs or external files")
            try:
                return base64.b64decode(payload, validate=True)
            except (binascii.Error, ValueError) as e:
                raise InputError(f"the data URI is not valid base64 ({e})", source=self.path, field=field_name,
                                 fix="re-export the file") from None
        if _SCHEME.match(uri):
            raise InputError(f"URI '{brief(uri)}' has a scheme rigslim does not read", source=self.path,
                             field=field_name, fix="give a data: URI or a path relative to the .gltf")
        folder = self.path.parent.resolve()
        file = (self.path.parent / unquote(uri)).resolve()
        if not external_uris_allowed(self.allow_external_uris) and not file.is_relative_to(folder):
            raise InputError(f"'{brief(uri)}' leads outside the glTF's folder ({file})", source=self.path,
                             field=field_name, fix="move the file next to the .gltf, or, if you trust this "
                             "file, set 'allow_external_uris: true' on the gltf input (or --allow-external-uris)")
        try:
            st = os.stat(file)
        except OSError as e:
            raise InputError(f"refers to '{brief(uri)}', which cannot be read ({e.strerror})", source=self.path,
                             field=field_name, fix="keep the .bin/.png files next to the .gltf") from None
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"'{brief(uri)}' is not a regular file", source=self.path, field=field_name,
                             fix="give the .bin/.png file itself")
        if length is not None and st.st_size < length:
            raise InputError(f"'{brief(uri)}' holds {st.st_size} bytes, byteLength says {length}", source=self.path,
                             field=f"{what}.byteLength", fix="re-export the file")
        try:
            with open(file, "rb") as f:
                return f.read() if length is None else f.read(length)
        except OSError as e:
            raise InputError(f"refers to '{brief(uri)}', which cannot be read ({e.strerror})", source=self.path,
                             field=field_name, fix="keep the .bin/.png files next to the .gltf") from None


def _parse_glb(data: bytes, path) -> tuple[dict, bytes | None]:
    """JSON and BIN chunks of a GLB container (glTF 2.0 section 4.4)."""
    if len(data) < 20:
        raise InputError("file is too short to be a GLB", source=path, field="header", fix="re-export the file")
    magic, version, length = struct.unpack_from("<III", data, 0)
    if magic != GLB_MAGIC or version != 2:
        raise InputError(f"not a glTF 2.0 binary (magic {magic:#x}, version {version})", source=path,
                         field="header", fix="give a glTF 2.0 .glb file")
    offset, js, binary = 12, None, None
    while offset + 8 <= min(length, len(data)):
        clen, ctype = struct.unpack_from("<II", data, offset)
        chunk = data[offset + 8:offset + 8 + clen]
        if ctype == CHUNK_JSON and js is None:
            js = chunk
        elif ctype == CHUNK_BIN and binary is None:
            binary = chunk
        offset += 8 + clen
    if js is None:
        raise InputError("GLB has no JSON chunk", source=path, field="chunks", fix="re-export the file")
    return json.loads(js.decode("utf-8")), binary


def external_uris_allowed(flag: bool | None = None) -> bool:
    """``flag`` when given, else whether ``RIGSLIM_ALLOW_EXTERNAL_URIS`` is ``1``/``true``/``yes``
    (what ``rigslim run --allow-external-uris`` sets)."""
    if flag is not None:
        return bool(flag)
    return os.environ.get("RIGSLIM_ALLOW_EXTERNAL_URIS", "").strip().lower() in ("1", "true", "yes")


def load_gltf(path, *, allow_external_uris: bool | None = None) -> GltfDocument:
    """Load a ``.glb`` or ``.gltf`` file with all its buffers.

    Parameters
    ----------
    path : path-like
        ``.glb`` (binary container) or ``.gltf`` (JSON with embedded data
        URIs or external ``.bin`` files).
    allow_external_uris : bool
        Let buffer and image URIs name files outside the file's folder
        (:meth:`GltfDocument.uri_bytes`).

    Returns
    -------
    GltfDocument
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", source=path, field="path", fix="check the path") from None
    binary = None
    try:
        if data[:4] == b"glTF":
            doc, binary = _parse_glb(data, path)
        else:
            doc = json.loads(data.decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"malformed glTF JSON ({e})", source=path, field="json", fix="re-export the file") from None
    except RecursionError:
        raise InputError("the JSON is nested too deeply", source=path, field="json", fix="re-export the file") from None
    from rigslim.io.gltf_schema import check_document

    check_document(doc, path)
    out = GltfDocument(path, doc, [], allow_external_uris=allow_external_uris)
    try:  # pygltflib's typed parse rejects properties of the wrong type (a string where a list belongs...)
        _ = out.typed
    except (TypeError, ValueError, AttributeError, KeyError) as e:
        raise InputError(f"the document does not follow the glTF 2.0 schema ({type(e).__name__}: {e})",
                         source=path, field="json",
                         fix="re-export the file; check it with the glTF-Validator") from None
    for i, buf in enumerate(doc.get("buffers", [])):
        if "uri" in buf:
            raw = out.uri_bytes(buf["uri"], f"buffers[{i}]", buf["byteLength"])
        elif i == 0 and binary is not None:
            raw = binary
        else:
            raise InputError(f"buffers[{i}] has no uri and no GLB binary chunk", source=path,
                             field=f"buffers[{i}]", fix="re-export the file")
        if len(raw) < buf["byteLength"]:
            raise InputError(f"buffers[{i}] holds {len(raw)} bytes, byteLength says {buf['byteLength']}",
                             source=path, field=f"buffers[{i}].byteLength", fix="re-export the file")
        out.buffers.append(bytes(raw[:buf["byteLength"]]))
    return out


def read_accessor(doc: GltfDocument, index: int, *, normalize: bool = True) -> np.ndarray:
    """Decode one accessor into a numpy array.

    Parameters
    ----------
    doc : GltfDocument
    index : int
        Accessor index.
    normalize : bool
        Map ``normalized`` integer accessors to floats (the specification's
        formulas: ``c / 255``, ``c / 65535``, ``max(c / 127, -1)``,
        ``max(c / 32767, -1)``).

    Returns
    -------
    (count,) or (count, components) array
        Handles ``byteStride``, accessor and view offsets, and sparse
        substitution; an accessor without a bufferView starts as zeros.
    """
    acc = doc.json["accessors"][index]
    where = f"accessors[{index}]"
    ctype = acc["componentType"]
    if ctype not in COMPONENT_DTYPES or acc.get("type") not in TYPE_SIZES:
        raise InputError(f"unknown componentType {ctype} or type {acc.get('type')}", source=doc.path, field=where,
                         fix="re-export the file")
    dtype = np.dtype(COMPONENT_DTYPES[ctype]).newbyteorder("<")
    ncomp = TYPE_SIZES[acc["type"]]
    count = acc["count"]
    if "bufferView" in acc:
        bv = doc.json["bufferViews"][acc["bufferView"]]
        data = doc.buffer_view_bytes(acc["bufferView"])
        elem = dtype.itemsize * ncomp
        stride = bv.get("byteStride") or elem
        off = acc.get("byteOffset", 0)
        if count and off + stride * (count - 1) + elem > len(data):
            raise InputError("accessor runs past the end of its bufferView", source=doc.path, field=where,
                             fix="re-export the file")
        # matrices of 1- and 2-byte components pad columns to 4 bytes (spec 3.6.2.4)
        if acc["type"] in ("MAT2", "MAT3") and dtype.itemsize < 4:
            rows = int(round(np.sqrt(ncomp)))
            col = ((rows * dtype.itemsize + 3) // 4) * 4
            byte = (off + np.arange(count)[:, None, None] * stride + np.arange(rows)[None, :, None] * col
                    + np.arange(rows * dtype.itemsize)[None, None, :])
            raw = np.frombuffer(data, np.uint8)[byte]
            out = np.ascontiguousarray(raw).view(dtype).reshape(count, rows, rows)
            arr = out.reshape(count, ncomp)
        else:
            buf = np.frombuffer(data, np.uint8)
            arr = np.lib.stride_tricks.as_strided(buf[off:], shape=(count, elem), strides=(stride, 1))
            arr = np.ascontiguousarray(arr).view(dtype).reshape(count, ncomp)
        arr = arr.copy()
    else:
        arr = np.zeros((count, ncomp), dtype)
    sparse = acc.get("sparse")
    if sparse:
        n = sparse["count"]
        ind, val = sparse["indices"], sparse["values"]
        idt = np.dtype(COMPONENT_DTYPES[ind["componentType"]]).newbyteorder("<")
        idx = np.frombuffer(doc.buffer_view_bytes(ind["bufferView"]), idt, count=n, offset=ind.get("byteOffset", 0))
        vals = np.frombuffer(doc.buffer_view_bytes(val["bufferView"]), dtype, count=n * ncomp,
                             offset=val.get("byteOffset", 0)).reshape(n, ncomp)
        if n and idx.max() >= count:
            raise InputError("sparse accessor index out of range", source=doc.path, field=f"{where}.sparse",
                             fix="re-export the file")
        arr[idx.astype(np.int64)] = vals
    if normalize and acc.get("normalized", False) and ctype != 5126:
        scale = {5120: 127.0, 5121: 255.0, 5122: 32767.0, 5123: 65535.0, 5125: 4294967295.0}[ctype]
        arr = np.maximum(arr.astype(np.float64) / scale, -1.0)
    return arr[:, 0] if ncomp == 1 else arr


# --------------------------------------------------------------------------- transforms


def node_trs(node: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray] | None:
    """A node's rest translation, rotation and scale, or None when it has a ``matrix``."""
    if "matrix" in node:
        return None
    return (np.array(node.get("translation", [0.0, 0.0, 0.0]), float),
            np.array(node.get("rotation", [0.0, 0.0, 0.0, 1.0]), float),
            np.array(node.get("scale", [1.0, 1.0, 1.0]), float))


def node_matrix(node: dict) -> np.ndarray:
    """A node's rest local transform (4 x 4): its column-major ``matrix`` or ``T @ R @ S``."""
    if "matrix" in node:
        return np.array(node["matrix"], dtype=np.float64).reshape(4, 4).T
    return trs_matrix(*node_trs(node))


def node_parents(doc: dict) -> np.ndarray:
    """(nodes,) parent node index of every node (-1 for roots)."""
    nodes = doc.get("nodes", [])
    parent = np.full(len(nodes), -1, dtype=np.int64)
    for i, node in enumerate(nodes):
        for c in node.get("children", []):
            parent[c] = i
    return parent


def _topological(parent: np.ndarray) -> list[int]:
    """Node indices with every parent before its children (iterative; rejects cycles)."""
    order, seen = [], np.zeros(len(parent), bool)
    for i in range(len(parent)):
        chain = []
        j = i
        while j >= 0 and not seen[j]:
            chain.append(j)
            if len(chain) > len(parent):
                raise InputError("the node hierarchy has a cycle", field="nodes", fix="repair the file")
            j = int(parent[j])
        for j in reversed(chain):
            seen[j] = True
            order.append(j)
    return order


def world_matrices(local: np.ndarray, parent: np.ndarray) -> np.ndarray:
    """Global transforms from local ones.

    Parameters
    ----------
    local : (nodes, ..., 4, 4) array
    parent : (nodes,) int array, -1 for roots

    Returns
    -------
    (nodes, ..., 4, 4) array
        ``G(n) = G(parent(n)) @ L(n)``, ``G(root) = L(root)``.
    """
    world = np.empty_like(local)
    for i in _topological(parent):
        world[i] = local[i] if parent[i] < 0 else world[parent[i]] @ local[i]
    return world


# --------------------------------------------------------------------------- animation


def sample_sampler(times: np.ndarray, values: np.ndarray, interpolation: str, t: np.ndarray,
                   *, rotation: bool = False) -> np.ndarray:
    """Evaluate one animation sampler at times ``t``.

    Parameters
    ----------
    times : (K,) increasing keyframe times
    values : (K, c) keyframe values, or (3K, c) for CUBICSPLINE
        (in-tangent, value, out-tangent per keyframe)
    interpolation : {"LINEAR", "STEP", "CUBICSPLINE"}
    t : (p,) sample times; clamped to the keyframe range
    rotation : bool
        Values are quaternions: LINEAR uses :func:`slerp`, CUBICSPLINE results
        are normalised.

    Returns
    -------
    (p, c) array

    Notes
    -----
    CUBICSPLINE (glTF 2.0 Appendix C) between keys k and k+1, ``d = t_{k+1} - t_k``,
    ``s = (t - t_k) / d``::

        p(s) = (2s^3 - 3s^2 + 1) v_k + (s^3 - 2s^2 + s) d b_k
             + (-2s^3 + 3s^2) v_{k+1} + (s^3 - s^2) d a_{k+1}

    with ``b_k`` the out-tangent of key k and ``a_{k+1}`` the in-tangent of key k+1.
    """
    times = np.asarray(times, float)
    t = np.clip(np.asarray(t, float), times[0], times[-1])
    K = len(times)
    if interpolation == "CUBICSPLINE":
        V = values.reshape(K, 3, -1)
        a, v, b = V[:, 0], V[:, 1], V[:, 2]
    else:
        v = values.reshape(K, -1)
    if K == 1:
        out = np.repeat(v[:1], len(t), axis=0)
        return out / np.linalg.norm(out, axis=-1, keepdims=True) if rotation else out
    k = np.clip(np.searchsorted(times, t, side="right") - 1, 0, K - 2)
    d = times[k + 1] - times[k]
    s = np.where(d > 0, (t - times[k]) / np.where(d > 0, d, 1.0), 0.0)
    if interpolation == "STEP":
        out = np.where((s >= 1.0)[:, None], v[k + 1], v[k])
    elif interpolation == "CUBICSPLINE":
        s2, s3 = s * s, s * s * s
        h00, h10, h01, h11 = 2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, -2 * s3 + 3 * s2, s3 - s2
        out = (h00[:, None] * v[k] + (h10 * d)[:, None] * b[k] + h01[:, None] * v[k + 1]
               + (h11 * d)[:, None] * a[k + 1])
        if rotation:
            out = out / np.linalg.norm(out, axis=-1, keepdims=True)
    elif interpolation == "LINEAR":
        if rotation:
            out = slerp(v[k], v[k + 1], s)
        else:
            out = (1 - s)[:, None] * v[k] + s[:, None] * v[k + 1]
    else:
        raise ValueError(f"unknown interpolation {interpolation!r}")
    return out


def find_animation(doc: GltfDocument, animation) -> int | None:
    """Index of an animation given by name or index (None when the file has none and none is asked)."""
    anims = doc.json.get("animations", [])
    if animation is None:
        return 0 if anims else None
    if isinstance(animation, (int, np.integer)) or (isinstance(animation, str) and animation.isdigit()
                                                    and not any(a.get("name") == animation for a in anims)):
        i = int(animation)
        if 0 <= i < len(anims):
            return i
        raise InputError(f"animation index {i} is out of range (the file has {len(anims)})", source=doc.path,
                         field="animation", fix=f"choose 0..{len(anims) - 1}" if anims else "remove 'animation'")
    names = [a.get("name", f"#{i}") for i, a in enumerate(anims)]
    if animation in names:
        return names.index(animation)
    from rigslim.errors import closest

    raise InputError(f"no animation named '{animation}'", source=doc.path, field="animation",
                     fix=closest(str(animation), names) if names else "the file has no animations")


def animation_duration(doc: GltfDocument, index: int) -> float:
    """Largest keyframe time over the animation's samplers (seconds)."""
    anim = doc.json["animations"][index]
    end = 0.0
    for s in anim.get("samplers", []):
        times = np.asarray(read_accessor(doc, s["input"]), np.float64)
        times = times[np.isfinite(times)]  # sampler_keys refuses the others with their place
        if times.size:
            end = max(end, float(times.max()))
    return end


_PATH_WIDTH = {"translation": 3, "rotation": 4, "scale": 3}


def sampler_keys(doc: GltfDocument, animation: int, index: int, path: str) -> tuple[np.ndarray, np.ndarray]:
    """Key times and values of a sampler driving ``path``, checked.

    Times must be finite, non-negative and strictly increasing (glTF 2.0
    section 3.11); there must be one value per key (three, in-tangent /
    value / out-tangent, for CUBICSPLINE) of the path's width, finite, and
    no rotation key may be a zero quaternion.
    """
    sampler = doc.json["animations"][animation]["samplers"][index]
    where = f"animations[{animation}].samplers[{index}]"
    _expect_type(doc, sampler["input"], ("SCALAR",), f"{where}.input")
    times = np.asarray(read_accessor(doc, sampler["input"]), np.float64)
    if times.ndim != 1:
        raise InputError("key times are not SCALAR", source=doc.path, field=f"{where}.input", fix="re-export the file")
    bad = ~np.isfinite(times) | (times < 0)
    if bad.any():
        k = int(np.argmax(bad))
        raise InputError(f"key time {k} is {times[k]}, not a finite time >= 0", source=doc.path,
                         field=f"{where}.input", fix="re-export the animation")
    if (np.diff(times) <= 0).any():
        k = int(np.argmax(np.diff(times) <= 0))
        raise InputError(f"key times are not strictly increasing (key {k + 1} at {times[k + 1]:.6g} s after "
                         f"{times[k]:.6g} s)", source=doc.path, field=f"{where}.input", fix="re-export the animation")
    values = np.asarray(read_accessor(doc, sampler["output"]), np.float64)
    values = values.reshape(len(values), -1)
    interp = sampler.get("interpolation", "LINEAR")
    per_key = 3 if interp == "CUBICSPLINE" else 1
    width = _PATH_WIDTH[path]
    if values.shape[1] != width or len(values) != per_key * len(times):
        raise InputError(f"{len(values)} output values of width {values.shape[1]} for {len(times)} keys; {interp} "
                         f"{path} needs {per_key * len(times)} of width {width}", source=doc.path,
                         field=f"{where}.output", fix="re-export the animation")
    if not np.isfinite(values).all():
        raise InputError("output values contain NaN or inf", source=doc.path, field=f"{where}.output",
                         fix="re-export the animation")
    if path == "rotation":
        keyed = values.reshape(len(times), per_key, 4)[:, per_key // 2]
        zero = np.linalg.norm(keyed, axis=1) < 1e-6
        if zero.any():
            raise InputError(f"rotation key {int(np.argmax(zero))} is a zero quaternion", source=doc.path,
                             field=f"{where}.output", fix="re-export the animation with unit quaternions")
    return times, values


def local_matrices(doc: GltfDocument, animation: int | None, t: np.ndarray) -> np.ndarray:
    """(nodes, p, 4, 4) local transforms of every node at times ``t``.

    Animated nodes take their sampled translation/rotation/scale (channels of
    the other paths keep the node's rest value); others keep their rest
    ``matrix`` or TRS. ``weights`` (morph target) channels do not move joints
    and are ignored here.
    """
    nodes = doc.json.get("nodes", [])
    p = len(t)
    trs = [node_trs(n) for n in nodes]
    animated: dict[int, dict[str, np.ndarray]] = {}
    if animation is not None:
        anim = doc.json["animations"][animation]
        for ci, ch in enumerate(anim.get("channels", [])):
            target = ch.get("target", {})
            path, node = target.get("path"), target.get("node")
            if node is None or path not in ("translation", "rotation", "scale"):
                continue
            if trs[node] is None:
                raise InputError(f"channel {ci} animates node {node}, which has a matrix", source=doc.path,
                                 field=f"animations[{animation}].channels[{ci}]",
                                 fix="re-export with TRS node transforms")
            sampler = anim["samplers"][ch["sampler"]]
            times, values = sampler_keys(doc, animation, ch["sampler"], path)
            interp = sampler.get("interpolation", "LINEAR")
            animated.setdefault(node, {})[path] = sample_sampler(times, np.asarray(values, float), interp, t,
                                                                 rotation=path == "rotation")
    local = np.empty((len(nodes), p, 4, 4))
    for i, node in enumerate(nodes):
        if i in animated:
            rt, rr, rs = trs[i]
            a = animated[i]
            local[i] = trs_matrix(a.get("translation", np.broadcast_to(rt, (p, 3))),
                                  a.get("rotation", np.broadcast_to(rr, (p, 4))),
                                  a.get("scale", np.broadcast_to(rs, (p, 3))))
        else:
            local[i] = node_matrix(node)
    return local


# --------------------------------------------------------------------------- skinned mesh


@dataclass(frozen=True)
class PrimitiveSlice:
    """Where one glTF primitive's vertices sit in the merged mesh.

    Attributes
    ----------
    mesh, primitive : int
        Indices into ``meshes`` and its ``primitives``.
    start, count : int
        Rows ``start:start + count`` of the merged vertex array.
    """

    mesh: int
    primitive: int
    start: int
    count: int


@dataclass
class GltfSkin:
    """Everything :func:`read_gltf_skin` extracts, plus what a writer needs.

    Attributes
    ----------
    document : GltfDocument
    skin : int
        The skin used.
    joints : list of int
        Node index of each handle (``skins[skin].joints``).
    slices : list of PrimitiveSlice
        The merged mesh's primitives, in order.
    mesh, handles, weights, poses :
        The rigslim inputs.
    animation : int or None
        Index of the sampled animation.
    fps : float
        Frame rate of the samples: frame f is at time ``f / fps`` seconds.
    """

    document: GltfDocument
    skin: int
    joints: list[int]
    slices: list[PrimitiveSlice]
    mesh: Mesh
    handles: Handles
    weights: sp.csr_matrix
    poses: Poses
    animation: int | None
    fps: float
    vertex_map: np.ndarray | None = None

    def file_rows(self, part: PrimitiveSlice) -> np.ndarray:
        """Rows of :attr:`mesh` that hold the vertices of one primitive, in the file's order."""
        rows = np.arange(part.start, part.start + part.count)
        return rows if self.vertex_map is None else self.vertex_map[rows]


def weld_vertices(V: np.ndarray, F: np.ndarray, weights: sp.csr_matrix):
    """Merge file vertices that are one skinned vertex: the same position *and* the same weights.

    glTF splits a surface's vertices at UV seams, hard edges and material boundaries; solvers and decimators
    need them joined. Welding is a connectivity device only: corners that the file keeps apart with different
    weights (separate parts that touch, each bound to its own joint) stay apart, and no file vertex ever gets
    another's weights.

    Parameters
    ----------
    V : (m, 3) positions, F : (f, 3) triangles, weights : (m, n) sparse rows summing to one

    Returns
    -------
    vertex_map : (m,) int array
        Welded vertex of every input vertex; welded vertices are numbered in
        order of first occurrence.
    V, F, weights
        The welded mesh (faces that became degenerate are dropped) and its
        weights: the row every merged vertex has (``A_w[g] = A[first(g)]``, bit for bit).

    Notes
    -----
    Two vertices merge when ``x_a = x_b`` and ``A[a, :] = A[b, :]`` exactly (compared as bytes, with
    ``-0.0`` read as ``0.0``).
    """
    A = sp.csr_matrix(weights, copy=True)
    A.sum_duplicates()
    A.eliminate_zeros()
    A.sort_indices()
    m = len(V)
    counts = np.diff(A.indptr)
    width = int(counts.max(initial=0))
    slot = np.arange(A.nnz) - np.repeat(A.indptr[:-1], counts)
    row = np.repeat(np.arange(m), counts)
    cols = np.full((m, width), -1.0)
    vals = np.zeros((m, width))
    cols[row, slot] = A.indices
    vals[row, slot] = A.data
    key = np.ascontiguousarray(np.concatenate([np.asarray(V, np.float64) + 0.0, cols, vals + 0.0], axis=1))
    void = key.view(np.dtype((np.void, key.dtype.itemsize * key.shape[1]))).ravel()
    _, first, inverse = np.unique(void, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    order = np.argsort(first, kind="stable")
    rank = np.empty_like(order)
    rank[order] = np.arange(len(order))
    vertex_map = rank[inverse]
    keep_rows = first[order]
    Vw = np.asarray(V)[keep_rows]
    Fw = vertex_map[F]
    keep = (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 2] != Fw[:, 0])
    Aw = sp.csr_matrix(sp.csr_matrix(weights)[keep_rows])
    Aw.sort_indices()
    return vertex_map, Vw, Fw[keep], Aw


def _triangles(mode: int, idx: np.ndarray) -> np.ndarray:
    """Triangles of a primitive (TRIANGLES, TRIANGLE_STRIP, TRIANGLE_FAN); none for points and lines."""
    if mode == 4:
        return idx[: len(idx) // 3 * 3].reshape(-1, 3)
    if mode == 5 and len(idx) >= 3:
        i = np.arange(len(idx) - 2)
        even = i % 2 == 0
        F = np.stack([idx[i], np.where(even, idx[i + 1], idx[i + 2]), np.where(even, idx[i + 2], idx[i + 1])], 1)
        return F
    if mode == 6 and len(idx) >= 3:
        i = np.arange(1, len(idx) - 1)
        return np.stack([np.full(len(i), idx[0]), idx[i], idx[i + 1]], 1)
    return np.zeros((0, 3), np.int64)


def skinning_sets(attributes: dict) -> list[int]:
    """Set numbers n for which a primitive has both ``JOINTS_n`` and ``WEIGHTS_n``."""
    sets = sorted(int(k.split("_")[1]) for k in attributes if k.startswith("JOINTS_") and k.split("_")[1].isdigit())
    return [n for n in sets if f"WEIGHTS_{n}" in attributes]


def _expect_type(doc: GltfDocument, index: int, types: tuple[str, ...], where: str) -> None:
    """Refuse an accessor whose ``type`` is not one the property requires (glTF 2.0 section 3.7)."""
    kind = doc.json["accessors"][index].get("type")
    if kind not in types:
        raise InputError(f"accessors[{index}] is {kind}, not {' or '.join(types)}", source=doc.path, field=where,
                         fix="re-export the file")


def _choose_skin(doc: GltfDocument, skin, mesh) -> tuple[int, list[int]]:
    js = doc.json
    skins = js.get("skins", [])
    if not skins:
        raise InputError("the file has no skin", source=doc.path, field="skins",
                         fix="give a skinned glTF (a mesh node with 'skin')")
    users = {}  # skin -> ordered unique mesh indices
    nodes = js.get("nodes", [])
    if mesh is None and js.get("scenes"):
        # only what the default scene shows (levels written as extra scenes or MSFT_lod nodes stay out)
        scene = js["scenes"][js.get("scene", 0)]
        shown, stack, seen = [], list(reversed(scene.get("nodes", []))), set()
        while stack:
            i = stack.pop()
            if i in seen:  # a cycle or a shared child (check_document refuses both; never loop)
                raise InputError(f"node {i} is reached twice from scene {js.get('scene', 0)}", source=doc.path,
                                 field=f"nodes[{i}]", fix="repair the node hierarchy (it must be a tree)")
            seen.add(i)
            shown.append(i)
            stack.extend(reversed(nodes[i].get("children", [])))
    else:
        shown = range(len(nodes))
    for node in (nodes[i] for i in shown):
        if "skin" in node and "mesh" in node:
            users.setdefault(node["skin"], [])
            if node["mesh"] not in users[node["skin"]]:
                users[node["skin"]].append(node["mesh"])
    if not users:
        raise InputError("no node instantiates a mesh with a skin", source=doc.path, field="nodes",
                         fix="give a skinned glTF (a mesh node with 'skin')")
    meshes = js.get("meshes", [])
    if mesh is not None:
        if isinstance(mesh, str) and not mesh.isdigit():
            names = [m.get("name") for m in meshes]
            if mesh not in names:
                from rigslim.errors import closest

                raise InputError(f"no mesh named '{mesh}'", source=doc.path, field="mesh",
                                 fix=closest(mesh, [n for n in names if n]))
            mesh = names.index(mesh)
        mesh = int(mesh)
        cands = [s for s, ms in users.items() if mesh in ms]
        if not cands:
            raise InputError(f"mesh {mesh} is not used by any skinned node", source=doc.path, field="mesh",
                             fix="choose one of meshes " + ", ".join(str(m) for ms in users.values() for m in ms))
        if skin is None:
            skin = cands[0]
        return int(skin), [mesh]
    if skin is None:
        if len(users) > 1:
            raise InputError(f"{len(users)} skins are used by mesh nodes", source=doc.path, field="skin",
                             fix="choose one with 'skin: INDEX' (or a mesh with 'mesh:')")
        skin = next(iter(users))
    skin = int(skin)
    if skin not in users:
        raise InputError(f"skin {skin} is not used by any mesh node", source=doc.path, field="skin",
                         fix="choose one of " + ", ".join(map(str, users)))
    return skin, users[skin]


def read_gltf_skin(path, *, animation=None, fps: float = 30.0, mesh=None, skin=None,
                   normalize: bool = True, weld: bool = False, times=None,
                   allow_external_uris: bool | None = None) -> GltfSkin:
    """Read a skinned glTF: merged mesh, joints as handles, weights and sampled poses.

    Parameters
    ----------
    path : path-like
        ``.glb`` or ``.gltf``.
    animation : str or int, optional
        Clip name or index; default the first animation (none: the rest pose
        as the only frame).
    fps : float
        Sampling rate: frame f is the pose at time ``f / fps`` seconds, for
        ``f = 0 .. floor(duration * fps + 0.001)`` (a thousandth of a frame absorbs float32 key times;
        times past the last key clamp).
    mesh : str or int, optional
        Read only this mesh (name or index), wherever its node is; default
        every mesh that nodes of the default scene instantiate with the
        chosen skin (depth-first order), primitives merged in order.
    skin : int, optional
        Which skin, when several are used.
    normalize : bool
        Divide each vertex's weights by their sum (quantised weights rarely
        sum exactly to one); otherwise rows must sum to 1 within 1e-6.
    weld : bool
        Merge vertices with identical positions (:func:`weld_vertices`), as
        solvers and decimators need a connected mesh; the writer maps the
        results back onto the file's vertices.
    times : sequence of float, optional
        Sample the clip at these times (seconds) instead: frame j is
        ``times[j]`` (``fps`` then only labels the frames for writers).
    allow_external_uris : bool, optional
        Let buffer and image URIs name files outside the file's folder
        (by default they must resolve inside it, symbolic links resolved);
        None: :func:`external_uris_allowed` (the environment) decides.

    Returns
    -------
    GltfSkin

    Notes
    -----
    ``T_i^f = (G_f(joint_i) @ IBM_i)[:3, :]``, where ``G_f`` composes node
    local transforms (``matrix`` or ``T @ R @ S``, animated channels sampled
    at ``f / fps``) from the roots down; vertices stay in the mesh's bind
    space. Weights: ``A[v, JOINTS_n[v, c]] += WEIGHTS_n[v, c]`` over all sets
    n and slots c.
    """
    doc = load_gltf(path, allow_external_uris=allow_external_uris)
    try:
        return _read_gltf_skin(doc, animation, fps, mesh, skin, normalize, weld, times)
    except (KeyError, IndexError) as e:
        raise InputError(f"malformed document: a required property or index is missing or out of range ({e!r})",
                         source=doc.path, field="json", fix="re-export the file; check it with the glTF-Validator"
                         ) from None


def _read_gltf_skin(doc: GltfDocument, animation, fps, mesh, skin, normalize, weld, times) -> GltfSkin:
    js = doc.json
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps {fps} is not a positive number", source=doc.path, field="fps", fix="give e.g. fps: 30")
    skin_index, mesh_indices = _choose_skin(doc, skin, mesh)
    sk = js["skins"][skin_index]
    joints = [int(j) for j in sk["joints"]]
    n = len(joints)
    if "inverseBindMatrices" in sk:
        _expect_type(doc, sk["inverseBindMatrices"], ("MAT4",), f"skins[{skin_index}].inverseBindMatrices")
        ibm = read_accessor(doc, sk["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1).astype(float)
        if len(ibm) < n:
            raise InputError(f"{len(ibm)} inverse bind matrices for {n} joints", source=doc.path,
                             field=f"skins[{skin_index}].inverseBindMatrices", fix="re-export the file")
        ibm = ibm[:n]
        where = f"skins[{skin_index}].inverseBindMatrices"
        if not np.isfinite(ibm).all():
            raise InputError("inverse bind matrices contain NaN or inf", source=doc.path, field=where,
                             fix="re-export the file")
        with np.errstate(all="ignore"):
            det = np.linalg.det(ibm[:, :3, :3])
            scale = np.abs(ibm[:, :3, :3]).max(axis=(1, 2))
        singular = ~(np.abs(det) > 1e-12 * np.maximum(scale, 1e-300) ** 3)
        affine = np.abs(ibm[:, 3, :] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-6 * np.maximum(scale, 1.0)
        if not affine.all():
            j = int(np.argmin(affine))
            raise InputError(f"the inverse bind matrix of joint {j} (node {joints[j]}) is not affine (last row "
                             f"{np.round(ibm[j, 3], 6).tolist()}, not [0, 0, 0, 1])", source=doc.path,
                             field=f"{where}[{j}]", fix="re-export the skin")
        if singular.any():
            j = int(np.argmax(singular))
            raise InputError(f"the inverse bind matrix of joint {j} (node {joints[j]}) is singular", source=doc.path,
                             field=f"{where}[{j}]", fix="re-export the skin with invertible bind matrices")
    else:
        ibm = np.broadcast_to(np.eye(4), (n, 4, 4)).copy()

    Vs, Fs, rows, cols, vals, slices = [], [], [], [], [], []
    start = 0
    for mi in mesh_indices:
        for pi, prim in enumerate(js["meshes"][mi]["primitives"]):
            attrs = prim.get("attributes", {})
            where = f"meshes[{mi}].primitives[{pi}]"
            sets = skinning_sets(attrs)
            if "POSITION" not in attrs or not sets:
                continue
            if prim.get("extensions", {}).get("KHR_draco_mesh_compression") is not None:
                raise InputError("Draco-compressed primitives are not supported", source=doc.path, field=where,
                                 fix="re-export without Draco compression")
            _expect_type(doc, attrs["POSITION"], ("VEC3",), f"{where}.attributes.POSITION")
            for s_ in sets:
                _expect_type(doc, attrs[f"JOINTS_{s_}"], ("VEC4",), f"{where}.attributes.JOINTS_{s_}")
                _expect_type(doc, attrs[f"WEIGHTS_{s_}"], ("VEC4",), f"{where}.attributes.WEIGHTS_{s_}")
            if "indices" in prim:
                _expect_type(doc, prim["indices"], ("SCALAR",), f"{where}.indices")
            V = np.asarray(read_accessor(doc, attrs["POSITION"]), float)
            m = len(V)
            for name in ["POSITION"] + [f"{a}_{s}" for s in sets for a in ("JOINTS", "WEIGHTS")]:
                count = js["accessors"][attrs[name]]["count"]
                if count != m or (name == "POSITION" and V.shape != (m, 3)):
                    raise InputError(f"{name} has {count} elements of type {js['accessors'][attrs[name]]['type']}; "
                                     f"the primitive has {m} VEC3 positions", source=doc.path,
                                     field=f"{where}.attributes.{name}", fix="re-export the file")
            idx = (np.asarray(read_accessor(doc, prim["indices"]), np.int64) if "indices" in prim
                   else np.arange(m, dtype=np.int64))
            if idx.ndim != 1 or (len(idx) and (idx.min() < 0 or idx.max() >= m)):
                raise InputError(f"indices must be SCALAR vertex numbers below {m}", source=doc.path,
                                 field=f"{where}.indices", fix="re-export the file")
            F = _triangles(prim.get("mode", 4), idx)
            for s in sets:
                J = np.asarray(read_accessor(doc, attrs[f"JOINTS_{s}"]), np.int64).reshape(m, -1)
                W = np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"]), float).reshape(m, -1)
                nz = W != 0
                if (J[nz] >= n).any() or (J[nz] < 0).any():
                    raise InputError(f"JOINTS_{s} refers to joint {int(J[nz].max())} but the skin has {n}",
                                     source=doc.path, field=f"{where}.attributes.JOINTS_{s}", fix="re-export the file")
                r, c = np.nonzero(nz)
                rows.append(r + start)
                cols.append(J[r, c])
                vals.append(W[r, c])
            Vs.append(V)
            Fs.append(F + start)
            slices.append(PrimitiveSlice(mi, pi, start, m))
            start += m
    if not slices:
        raise InputError("no primitive has POSITION, JOINTS_n and WEIGHTS_n", source=doc.path, field="meshes",
                         fix="give a skinned mesh")
    V = np.concatenate(Vs)
    F = np.concatenate(Fs)
    A = sp.csr_matrix((np.concatenate(vals), (np.concatenate(rows), np.concatenate(cols))), shape=(len(V), n))
    A.sum_duplicates()
    weights = validate_weights(A, len(V), n_handles=n, normalize=normalize, source=f"{doc.path} (WEIGHTS_n)")
    vertex_map = None
    if weld:
        vertex_map, V, F, weights = weld_vertices(V, F, weights)
    mesh_obj = Mesh(V, F, source=str(doc.path))

    # handles: one per joint, placed at the joint's bind position
    nodes = js.get("nodes", [])
    parent = node_parents(js)
    names = [nodes[j].get("name") or f"joint{i}" for i, j in enumerate(joints)]
    position = np.linalg.inv(ibm)[:, :3, 3]
    joint_of = {node: i for i, node in enumerate(joints)}
    parents = np.full(n, -1, np.int64)
    for i, node in enumerate(joints):
        p = parent[node]
        while p >= 0 and p not in joint_of:
            p = parent[p]
        parents[i] = joint_of.get(int(p), -1) if p >= 0 else -1
    first_child = {}
    for i in range(n):
        if parents[i] >= 0:
            first_child.setdefault(int(parents[i]), i)
    bones = np.array([[i, first_child.get(i, i)] for i in range(n)], np.int64)
    handles = Handles("skeleton", names, joints=position, bones=bones, parents=parents, source=str(doc.path))

    # poses
    anim = find_animation(doc, animation)
    if times is not None:
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        if not len(t) or not np.isfinite(t).all() or (t < 0).any():
            raise InputError("times must be a non-empty list of non-negative seconds", source=doc.path,
                             field="times", fix="give e.g. times: [0, 0.5, 1.25]")
    elif anim is None:
        t = np.zeros(1)
    else:
        duration = animation_duration(doc, anim)
        frames = np.floor(duration * fps + 1e-3) + 1
        if frames > MAX_FRAMES:
            raise InputError(f"{duration:.6g} s at {fps:g} fps is {frames:.6g} frames, more than {MAX_FRAMES}",
                             source=doc.path, field="fps", fix="sample fewer frames: a lower fps or 'times:'")
        t = np.arange(int(frames)) / fps
    if len(t) * max(len(nodes), 1) > MAX_FRAME_NODES:
        raise InputError(f"{len(t)} frames of {len(nodes)} nodes exceed the limit of {MAX_FRAME_NODES} sampled "
                         "transforms", source=doc.path, field="times" if times is not None else "fps",
                         fix="sample fewer frames")
    local = local_matrices(doc, anim, t)
    world = world_matrices(local, parent) if len(nodes) else local
    T = np.einsum("jpab,jbc->pjac", world[joints], ibm)[:, :, :3, :]
    label = str(doc.path) if anim is None else f"{doc.path} animation {js['animations'][anim].get('name', anim)}"
    poses = Poses(T, np.arange(len(t)), source=label)
    return GltfSkin(doc, skin_index, joints, slices, mesh_obj, handles, weights, poses, anim, float(fps), vertex_map)
