"""A small GLB (binary glTF 2.0) builder and reader for the suite's converters (numpy + json + struct).

Not rigslim's writer: the suite's characters must come from other tools' code
paths, so the converters in this folder build their files with this module.
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np

FLOAT, UBYTE, USHORT, UINT = 5126, 5121, 5123, 5125
ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER = 34962, 34963
_TYPES = {1: "SCALAR", 2: "VEC2", 3: "VEC3", 4: "VEC4", 16: "MAT4"}
_CTYPES = {np.dtype(np.float32): FLOAT, np.dtype(np.uint8): UBYTE, np.dtype(np.uint16): USHORT,
           np.dtype(np.uint32): UINT}
_DTYPES = {v: k for k, v in _CTYPES.items()}
_WIDTH = {v: k for k, v in _TYPES.items()}


class GlbBuilder:
    """Accumulates one binary buffer and the JSON document that points into it."""

    def __init__(self, generator: str):
        self.doc: dict = {"asset": {"version": "2.0", "generator": generator}, "buffers": [],
                          "bufferViews": [], "accessors": []}
        self.blob = bytearray()

    def view(self, data: bytes, target: int | None = None) -> int:
        """Append ``data`` (4-byte aligned) as a new bufferView; return its index."""
        while len(self.blob) % 4:
            self.blob.append(0)
        entry = {"buffer": 0, "byteOffset": len(self.blob), "byteLength": len(data)}
        if target is not None:
            entry["target"] = target
        self.blob += data
        self.doc["bufferViews"].append(entry)
        return len(self.doc["bufferViews"]) - 1

    def accessor(self, a: np.ndarray, *, target: int | None = None, minmax: bool = False,
                 normalized: bool = False, matrix: bool = False) -> int:
        """Append an array as an accessor (rows = elements); return its index."""
        a = np.ascontiguousarray(a)
        width = 16 if matrix else (1 if a.ndim == 1 else a.shape[1])
        entry = {"bufferView": self.view(a.tobytes(), target), "componentType": _CTYPES[a.dtype],
                 "count": int(a.shape[0]), "type": _TYPES[width]}
        if normalized:
            entry["normalized"] = True
        if minmax:
            flat = a.reshape(a.shape[0], -1)
            entry["min"] = [float(x) for x in flat.min(axis=0)]
            entry["max"] = [float(x) for x in flat.max(axis=0)]
        self.doc["accessors"].append(entry)
        return len(self.doc["accessors"]) - 1

    def image(self, data: bytes, mime: str) -> int:
        """Embed an image; return its index in ``images``."""
        self.doc.setdefault("images", []).append({"bufferView": self.view(data), "mimeType": mime})
        return len(self.doc["images"]) - 1

    def add(self, key: str, entry: dict) -> int:
        """Append ``entry`` to the top-level array ``key``; return its index."""
        self.doc.setdefault(key, []).append(entry)
        return len(self.doc[key]) - 1

    def write(self, path: Path) -> None:
        """Write the GLB container (JSON chunk padded with spaces, BIN chunk with zeros)."""
        write_glb(path, self.doc, bytes(self.blob))


def write_glb(path: Path, doc: dict, blob: bytes) -> None:
    """Write ``doc`` and its single buffer ``blob`` as a .glb file."""
    blob = blob + b"\0" * (-len(blob) % 4)
    doc = dict(doc)
    doc["buffers"] = [{"byteLength": len(blob)}]
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    total = 12 + 8 + len(text) + 8 + len(blob)
    out = struct.pack("<4sII", b"glTF", 2, total) + struct.pack("<I4s", len(text), b"JSON") + text
    out += struct.pack("<I4s", len(blob), b"BIN\0") + blob
    Path(path).write_bytes(out)


def read_glb(path: Path) -> tuple[dict, bytes]:
    """The JSON document and the BIN chunk of a .glb file."""
    raw = Path(path).read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", raw, 0)
    if magic != b"glTF" or version != 2:
        raise ValueError(f"{path}: not a glTF 2.0 binary file")
    n, kind = struct.unpack_from("<I4s", raw, 12)
    doc = json.loads(raw[20:20 + n])
    off = 20 + n
    blob = b""
    if off < len(raw):
        m, kind = struct.unpack_from("<I4s", raw, off)
        blob = raw[off + 8:off + 8 + m]
    return doc, blob


def read_accessor(doc: dict, blob: bytes, index: int) -> np.ndarray:
    """An accessor's elements as a (count, width) array (float for normalized integers is not applied)."""
    a = doc["accessors"][index]
    bv = doc["bufferViews"][a["bufferView"]]
    dt = _DTYPES[a["componentType"]]
    width = _WIDTH[a["type"]]
    start = bv.get("byteOffset", 0) + a.get("byteOffset", 0)
    stride = bv.get("byteStride", 0) or dt.itemsize * width
    rows = np.lib.stride_tricks.as_strided(
        np.frombuffer(blob, np.uint8, offset=start, count=stride * (a["count"] - 1) + dt.itemsize * width),
        shape=(a["count"], dt.itemsize * width), strides=(stride, 1))
    return np.frombuffer(np.ascontiguousarray(rows).tobytes(), dt).reshape(a["count"], width)
