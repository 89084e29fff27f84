"""Write ``tube_two_materials.glb``: a textured, skinned, animated tube in two meshes and three primitives.

A hand-made test character for the LOD writer (not written by rigslim; only
numpy, struct and Pillow). A tube of radius 0.3 along +y, 0 <= y <= 2, with
32 segments around and 24 rings:

- mesh ``Legs`` (node ``Legs``): rings 0..12, one primitive, material ``Skin``;
- mesh ``Torso`` (node ``Torso``): rings 12..24, two primitives: the front
  half (``Skin``) and the back half (``Cloth``), the back one with a morph
  target (a bulge);
- every primitive has POSITION, NORMAL, TEXCOORD_0 (u around, v along; a UV
  seam where u wraps from 1 to 0), JOINTS_0/WEIGHTS_0;
- skin: joints ``Root`` (y = 0) and ``Knee`` (y = 1), the knee bends about z
  by up to 60 degrees over 1 s (LINEAR, 21 keys), morph weight 0 -> 1;
- weights blend across y = 0.8..1.2 and are deliberately left unnormalised
  (sums 0.9..1.1, stored as floats), as exporters sometimes do;
- one embedded 16x16 PNG checkerboard texture used by both materials.

Run: ``python make_tube.py`` (writes the file beside this script).
"""

from __future__ import annotations

import io
import json
import struct
from pathlib import Path

import numpy as np

SEGMENTS, RINGS, RADIUS, HEIGHT = 32, 24, 0.3, 2.0


def _png() -> bytes:
    from PIL import Image

    a = np.indices((16, 16)).sum(axis=0) % 2
    img = np.stack([200 * a + 40, 80 + 100 * (1 - a), 60 * a + 30], axis=-1).astype(np.uint8)
    buf = io.BytesIO()
    Image.fromarray(img, "RGB").save(buf, format="PNG")
    return buf.getvalue()


def _grid(r0: int, r1: int, s0: int, s1: int):
    """Vertices (rings r0..r1, segments s0..s1 inclusive) and triangles of one tube patch."""
    rings = np.arange(r0, r1 + 1)
    segs = np.arange(s0, s1 + 1)
    R, S = np.meshgrid(rings, segs, indexing="ij")
    theta = 2 * np.pi * (S % SEGMENTS) / SEGMENTS       # u = 1 lands bit-identically on u = 0: a closed UV seam
    y = HEIGHT * R / RINGS
    P = np.stack([RADIUS * np.cos(theta), y, RADIUS * np.sin(theta)], axis=-1).reshape(-1, 3)
    N = np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=-1).reshape(-1, 3)
    UV = np.stack([S / SEGMENTS, 1.0 - R / RINGS], axis=-1).reshape(-1, 2)
    nr, ns = len(rings), len(segs)
    idx = np.arange(nr * ns).reshape(nr, ns)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    F = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    return P, N, UV, F


def _weights(P: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    t = np.clip((P[:, 1] - 0.8) / 0.4, 0, 1)
    w = np.stack([1 - t, t, np.zeros_like(t), np.zeros_like(t)], axis=1)
    wobble = 1.0 + 0.1 * np.sin(7.0 * P[:, 0] + 3.0 * P[:, 1])          # sums 0.9..1.1: unnormalised
    w = w * wobble[:, None]
    J = np.tile(np.array([0, 1, 0, 0], np.uint8), (len(P), 1))
    return J, w.astype(np.float32)


def _bulge(P: np.ndarray, N: np.ndarray) -> np.ndarray:
    """Morph target deltas: the torso swells outwards, most at y = 1.5."""
    return N * (0.1 * np.sin(np.pi * (P[:, 1:2] - 1.0))) * np.array([1.0, 0.0, 1.0])


class _Doc:
    def __init__(self):
        self.bin = bytearray()
        self.js = {"asset": {"version": "2.0", "generator": "rigslim examples/data/gltf/make_tube.py"},
                   "bufferViews": [], "accessors": []}

    def view(self, data: bytes, target=None) -> int:
        self.bin += b"\0" * ((-len(self.bin)) % 4)
        v = {"buffer": 0, "byteOffset": len(self.bin), "byteLength": len(data)}
        if target:
            v["target"] = target
        self.bin += data
        self.js["bufferViews"].append(v)
        return len(self.js["bufferViews"]) - 1

    def acc(self, a: np.ndarray, ctype: int, type_: str, target=34962, minmax=False) -> int:
        view = self.view(np.ascontiguousarray(a).tobytes(), target)
        acc = {"bufferView": view, "componentType": ctype, "count": len(a), "type": type_}
        if minmax:
            acc["min"] = [float(x) for x in a.reshape(len(a), -1).min(0)]
            acc["max"] = [float(x) for x in a.reshape(len(a), -1).max(0)]
        self.js["accessors"].append(acc)
        return len(self.js["accessors"]) - 1

    def primitive(self, P, N, UV, F, material, morph=None) -> dict:
        J, W = _weights(P)
        prim = {"attributes": {"POSITION": self.acc(P.astype(np.float32), 5126, "VEC3", minmax=True),
                               "NORMAL": self.acc(N.astype(np.float32), 5126, "VEC3"),
                               "TEXCOORD_0": self.acc(UV.astype(np.float32), 5126, "VEC2"),
                               "JOINTS_0": self.acc(J, 5121, "VEC4"),
                               "WEIGHTS_0": self.acc(W, 5126, "VEC4")},
                "indices": self.acc(F.astype(np.uint16).ravel(), 5123, "SCALAR", target=34963),
                "material": material, "mode": 4}
        if morph is not None:
            prim["targets"] = [{"POSITION": self.acc(morph.astype(np.float32), 5126, "VEC3", minmax=True)}]
        return prim


def build() -> bytes:
    d = _Doc()
    half = SEGMENTS // 2
    legs = d.primitive(*_grid(0, 12, 0, SEGMENTS), material=0)
    P, N, UV, F = _grid(12, 24, 0, half)
    front = d.primitive(P, N, UV, F, material=0, morph=_bulge(P, N))
    P, N, UV, F = _grid(12, 24, half, SEGMENTS)
    back = d.primitive(P, N, UV, F, material=1, morph=_bulge(P, N))
    png = d.view(_png())
    # skin: Root at the origin, Knee at y = 1; inverse bind matrices (column-major) translate by -joint
    ibm = np.tile(np.eye(4, dtype=np.float32), (2, 1, 1))
    ibm[1, 1, 3] = -1.0
    ibm_acc = d.acc(ibm.transpose(0, 2, 1).reshape(2, 16), 5126, "MAT4", target=None)
    times = np.linspace(0, 1, 21, dtype=np.float32)
    ang = np.radians(60.0) * np.sin(np.pi * times / 2)
    rot = np.stack([np.zeros_like(ang), np.zeros_like(ang), np.sin(ang / 2), np.cos(ang / 2)], 1).astype(np.float32)
    t_acc = d.acc(times, 5126, "SCALAR", target=None, minmax=True)
    r_acc = d.acc(rot, 5126, "VEC4", target=None)
    w_acc = d.acc(times.copy(), 5126, "SCALAR", target=None)
    js = d.js
    js.update({
        "scene": 0,
        "scenes": [{"name": "tube", "nodes": [0, 1, 2]}],
        "nodes": [{"name": "Legs", "mesh": 0, "skin": 0}, {"name": "Torso", "mesh": 1, "skin": 0},
                  {"name": "Root", "children": [3]}, {"name": "Knee", "translation": [0.0, 1.0, 0.0]}],
        "meshes": [{"name": "Legs", "primitives": [legs]},
                   {"name": "Torso", "primitives": [front, back], "weights": [0.0],
                    "extras": {"targetNames": ["bulge"]}}],
        "skins": [{"name": "tube", "joints": [2, 3], "inverseBindMatrices": ibm_acc, "skeleton": 2}],
        "materials": [{"name": "Skin", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                                 "metallicFactor": 0.0}},
                      {"name": "Cloth", "pbrMetallicRoughness": {"baseColorTexture": {"index": 0},
                                                                  "baseColorFactor": [0.6, 0.7, 1.0, 1.0],
                                                                  "metallicFactor": 0.0}}],
        "textures": [{"source": 0, "sampler": 0}],
        "samplers": [{"magFilter": 9728, "minFilter": 9728}],
        "images": [{"bufferView": png, "mimeType": "image/png"}],
        "animations": [{"name": "bend", "samplers": [{"input": t_acc, "output": r_acc, "interpolation": "LINEAR"},
                                                     {"input": t_acc, "output": w_acc, "interpolation": "LINEAR"}],
                        "channels": [{"sampler": 0, "target": {"node": 3, "path": "rotation"}},
                                     {"sampler": 1, "target": {"node": 1, "path": "weights"}}]}],
    })
    d.bin += b"\0" * ((-len(d.bin)) % 4)
    js["buffers"] = [{"byteLength": len(d.bin)}]
    text = json.dumps(js, separators=(",", ":")).encode()
    text += b" " * ((-len(text)) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(d.bin), 0x004E4942) + bytes(d.bin)
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


if __name__ == "__main__":
    out = Path(__file__).with_name("tube_two_materials.glb")
    out.write_bytes(build())
    print(f"wrote {out}")
