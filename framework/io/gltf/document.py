"""glTF 2.0 documents: .gltf/.glb parsing, buffers and accessors."""

from __future__ import annotations

import base64
import binascii
import contextlib
import contextvars
import json
import os
import re
import stat
import struct
from dataclasses import dataclass, field
from pathlib import Path
from urllib.parse import unquote

import numpy as np

from rigslim.errors import InputError, brief

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


#: A URI with a scheme (``data:``, ``http:``...), not a path relative to the glTF file.
URI_SCHEME = re.compile(r"^[A-Za-z][A-Za-z0-9+.-]*:")


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
    decoded: list = field(default_factory=list)

    @property
    def typed(self):
        """pygltflib's :class:`GLTF2` view of :attr:`json`, for plugins that want one (built on first use).

        Loading never builds it: :func:`rigslim.io.gltf.schema.check_document` checks the types already
        (strict pydantic models), and pygltflib's parse took 0.12-0.5 s a file on the suite characters."""
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
        if URI_SCHEME.match(uri):
            raise InputError(f"URI {brief(uri)} has a scheme rigslim does not read", source=self.path,
                             field=field_name, fix="give a data: URI or a path relative to the .gltf")
        folder = self.path.parent.resolve()
        file = (self.path.parent / unquote(uri)).resolve()
        if not external_uris_allowed(self.allow_external_uris) and not file.is_relative_to(folder):
            raise InputError(f"{brief(uri)} leads outside the glTF's folder ({file})", source=self.path,
                             field=field_name, fix="move the file next to the .gltf, or, if you trust this "
                             "file, set 'allow_external_uris: true' on the gltf input (or --allow-external-uris)")
        try:
            st = os.stat(file)
        except OSError as e:
            raise InputError(f"refers to {brief(uri)}, which cannot be read ({e.strerror})", source=self.path,
                             field=field_name, fix="keep the .bin/.png files next to the .gltf") from None
        if not stat.S_ISREG(st.st_mode):
            raise InputError(f"{brief(uri)} is not a regular file", source=self.path, field=field_name,
                             fix="give the .bin/.png file itself")
        if length is not None and st.st_size < length:
            raise InputError(f"{brief(uri)} holds {st.st_size} bytes, byteLength says {length}", source=self.path,
                             field=f"{what}.byteLength", fix="re-export the file")
        try:
            with open(file, "rb") as f:
                return f.read() if length is None else f.read(length)
        except OSError as e:
            raise InputError(f"refers to {brief(uri)}, which cannot be read ({e.strerror})", source=self.path,
                             field=field_name, fix="keep the .bin/.png files next to the .gltf") from None


def parse_glb(data: bytes, path) -> tuple[dict, bytes | None]:
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


_loaded: contextvars.ContextVar[dict | None] = contextvars.ContextVar("rigslim_gltf_loaded", default=None)


@contextlib.contextmanager
def read_once():
    """Within this block, :func:`load_gltf` parses each file once and hands the same document out again.

    A file is the same while its real path, ``(st_dev, st_ino)``, ``st_mtime_ns`` and ``st_size`` are
    (and the URI policy it was loaded under); a file rewritten in between is read anew. The ``rigslim``
    commands read their input through it once per command. Callers must not modify the document they get
    (copy its ``json`` first, as the writers do). Nested blocks share the outermost one's documents.
    """
    if _loaded.get() is not None:
        yield
        return
    token = _loaded.set({})
    try:
        yield
    finally:
        _loaded.reset(token)


def _file_key(path: Path, allow_external_uris: bool | None):
    try:
        st = os.stat(path)
    except OSError:
        return None
    return (os.path.realpath(path), st.st_dev, st.st_ino, st.st_mtime_ns, st.st_size,
            external_uris_allowed(allow_external_uris))


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
        Inside :func:`read_once`, the document already loaded from the same file, if any.
    """
    path = Path(path)
    cache = _loaded.get()
    key = _file_key(path, allow_external_uris) if cache is not None else None
    if cache is not None and key is not None and key in cache:
        return cache[key]
    doc = _load_gltf_file(path, allow_external_uris)
    if cache is not None and key is not None:
        cache[key] = doc
    return doc


def _load_gltf_file(path: Path, allow_external_uris: bool | None) -> GltfDocument:
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", source=path, field="path", fix="check the path") from None
    binary = None
    try:
        if data[:4] == b"glTF":
            doc, binary = parse_glb(data, path)
        else:
            doc = json.loads(data.decode("utf-8-sig"))
    except (UnicodeDecodeError, json.JSONDecodeError) as e:
        raise InputError(f"malformed glTF JSON ({e})", source=path, field="json", fix="re-export the file") from None
    except RecursionError:
        raise InputError("the JSON is nested too deeply", source=path, field="json", fix="re-export the file") from None
    from rigslim.io.gltf.schema import check_document

    check_document(doc, path)
    out = GltfDocument(path, doc, [], allow_external_uris=allow_external_uris)
    from rigslim.io.gltf.extensions import fallback_buffer, prepare_extensions

    for i, buf in enumerate(doc.get("buffers", [])):
        if "uri" not in buf and fallback_buffer(buf) and not (i == 0 and binary is not None):
            out.buffers.append(b"")          # no data: its views are decoded from a compressed stream
            continue
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
    prepare_extensions(out)
    return out


def accessor_bounds(array: np.ndarray, component: int) -> tuple[list, list]:
    """The ``min`` and ``max`` an accessor of ``component`` type declares for the stored values ``array``
    ((count, width) or (count,); glTF 2.0: the stored values, normalised accessors included), per component:
    floats for FLOAT (5126), integers otherwise."""
    a = np.asarray(array).reshape(len(array), -1)
    cast = float if component == 5126 else int
    return [cast(x) for x in a.min(axis=0)], [cast(x) for x in a.max(axis=0)]


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


def expect_accessor_type(doc: GltfDocument, index: int, types: tuple[str, ...], where: str) -> None:
    """Refuse an accessor whose ``type`` is not one the property requires (glTF 2.0 section 3.7)."""
    kind = doc.json["accessors"][index].get("type")
    if kind not in types:
        raise InputError(f"accessors[{index}] is {kind}, not {' or '.join(types)}", source=doc.path, field=where,
                         fix="re-export the file")
