"""Convert 0 A.D. skinned models (PMD v4 mesh, PSA animations, skeleton XML) to glTF 2.0 binary.

0ad-data ships its Collada sources only as the game's cached binary formats
(``*.dae.cached.pmd`` / ``*.dae.cached.psa`` in public.zip), which assimp
does not read. This script follows the formats as 0 A.D.'s ModelDef and
SkeletonAnimDef read them:

- PMD: ``"PSMD"``, version 4, data size; ``numVertices``, ``numUVs``; per
  vertex position[3], normal[3], uv[numUVs][2], 4 bone indices (uint8, 255 =
  none), 4 weights (float); ``numFaces`` x 3 uint16; ``numBones`` x the bind
  pose (translation[3], rotation quaternion x, y, z, w) in model space; prop
  points (ignored);
- PSA: ``"PSSA"``, version 1, data size; name; frame length (ms); numBones,
  numFrames; frame-major keys (translation[3], rotation[4]) in model space;
- the skeleton XML's ``<standard_skeleton>``: bone names and parents, in the
  depth-first order the PMD and PSA bones use.

The glTF: one node per bone whose local TRS is ``inv(parent's model
transform) * model transform`` (rigid: translation and rotation), inverse bind
matrices ``inv(B_j)`` of the model-space bind pose, one primitive, one clip
per PSA (LINEAR, ``k * frame length``), y-up as 0 A.D. is.

Usage::

    python tools/suite/pmd2gltf.py MESH.pmd SKELETON.xml -o out.glb --anim idle=idle.psa --anim attack=attack.psa
"""

from __future__ import annotations

import argparse
import struct
import sys
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from glb import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GlbBuilder  # noqa: E402


def read_pmd(path: Path) -> dict:
    """Vertices (position, normal, uv, joints, weights), faces and the model-space bind pose of a PMD v4 file."""
    b = Path(path).read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", b, 0)
    if magic != b"PSMD" or version != 4:
        raise ValueError(f"{path}: not a PMD version 4 file ({magic!r}, {version})")
    nv, nuv = struct.unpack_from("<2I", b, 12)
    rec = np.dtype([("p", "<f4", 3), ("n", "<f4", 3), ("uv", "<f4", (nuv, 2)), ("j", "u1", 4), ("w", "<f4", 4)])
    o = 20
    vx = np.frombuffer(b, rec, nv, o)
    o += rec.itemsize * nv
    nf = struct.unpack_from("<I", b, o)[0]
    faces = np.frombuffer(b, np.uint16, 3 * nf, o + 4).reshape(-1, 3)
    o += 4 + 6 * nf
    nb = struct.unpack_from("<I", b, o)[0]
    bones = np.frombuffer(b, np.float32, 7 * nb, o + 4).reshape(-1, 7).astype(np.float64)
    return {"P": vx["p"].copy(), "N": vx["n"].copy(), "UV": vx["uv"][:, 0].copy() if nuv else None,
            "J": vx["j"].copy(), "W": vx["w"].astype(np.float64), "F": faces.astype(np.int64), "bones": bones}


def read_psa(path: Path) -> tuple[float, np.ndarray]:
    """Frame length in seconds and the keys (frames, bones, 7) of a PSA file."""
    b = Path(path).read_bytes()
    magic, version, _ = struct.unpack_from("<4sII", b, 0)
    if magic != b"PSSA" or version != 1:
        raise ValueError(f"{path}: not a PSA version 1 file")
    n = struct.unpack_from("<I", b, 12)[0]
    o = 16 + n
    frame_ms, nb, nfr = struct.unpack_from("<fII", b, o)
    keys = np.frombuffer(b, np.float32, 7 * nb * nfr, o + 12).reshape(nfr, nb, 7).astype(np.float64)
    return frame_ms / 1000.0, keys


def read_skeleton(path: Path) -> list[tuple[str, int]]:
    """(name, parent index) of the standard skeleton's bones, depth first."""
    root = ET.parse(path).getroot().find("standard_skeleton")
    out: list[tuple[str, int]] = []

    def walk(el, parent):
        for child in el.findall("bone"):
            out.append((child.get("name"), parent))
            walk(child, len(out) - 1)

    walk(root, -1)
    return out


def _qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    x1, y1, z1, w1 = np.moveaxis(a, -1, 0)
    x2, y2, z2, w2 = np.moveaxis(b, -1, 0)
    return np.stack([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                     w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2], axis=-1)


def _qrot(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    qv = np.concatenate([v, np.zeros(v.shape[:-1] + (1,))], axis=-1)
    conj = q * np.array([-1.0, -1.0, -1.0, 1.0])
    return _qmul(_qmul(q, qv), conj)[..., :3]


def local_trs(world: np.ndarray, parents: list[int]) -> tuple[np.ndarray, np.ndarray]:
    """Local translation and rotation of model-space keys (..., bones, 7): ``L = inv(W_parent) W``."""
    t, q = world[..., :3], world[..., 3:]
    q = q / np.linalg.norm(q, axis=-1, keepdims=True)
    lt, lq = t.copy(), q.copy()
    for j, p in enumerate(parents):
        if p >= 0:
            pc = q[..., p, :] * np.array([-1.0, -1.0, -1.0, 1.0])
            lq[..., j, :] = _qmul(pc, q[..., j, :])
            lt[..., j, :] = _qrot(pc, t[..., j, :] - t[..., p, :])
    return lt, lq


def _matrix(t, q) -> np.ndarray:
    x, y, z, w = q / np.linalg.norm(q)
    M = np.eye(4)
    M[:3, :3] = [[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                 [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                 [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]]
    M[:3, 3] = t
    return M


def _hemisphere(q: np.ndarray) -> np.ndarray:
    q = q.copy()
    for k in range(1, len(q)):
        if np.dot(q[k], q[k - 1]) < 0:
            q[k] = -q[k]
    return q


def convert(pmd: Path, skeleton: Path, out: Path, anims: list, name: str) -> None:
    m = read_pmd(pmd)
    bones = read_skeleton(skeleton)
    if len(bones) != len(m["bones"]):
        raise ValueError(f"{skeleton}: {len(bones)} bones for {len(m['bones'])} in {pmd}")
    parents = [p for _, p in bones]
    g = GlbBuilder(f"rigslim tools/suite/pmd2gltf.py from {pmd.name}")
    bt, bq = local_trs(m["bones"], parents)
    nodes = []
    for j, (bone, parent) in enumerate(bones):
        q = np.clip(bq[j] / np.linalg.norm(bq[j]), -1, 1)
        nodes.append(g.add("nodes", {"name": bone, "translation": [float(x) for x in bt[j]],
                                     "rotation": [float(x) for x in q.astype(np.float32)]}))
        if parent >= 0:
            g.doc["nodes"][nodes[parent]].setdefault("children", []).append(nodes[-1])
    roots = [nodes[j] for j, p in enumerate(parents) if p < 0]
    ibm = np.stack([np.linalg.inv(_matrix(b[:3], b[3:])) for b in m["bones"]])
    ibm[:, 3, :] = [0.0, 0.0, 0.0, 1.0]
    skin = g.add("skins", {"joints": nodes, "inverseBindMatrices":
                           g.accessor(ibm.transpose(0, 2, 1).reshape(-1, 16).astype(np.float32), matrix=True)})
    J, W = m["J"].astype(np.uint16), m["W"]
    W = np.where(J == 255, 0.0, W)
    J[J == 255] = 0
    W = W / np.maximum(W.sum(axis=1, keepdims=True), 1e-12)
    attrs = {"POSITION": g.accessor(m["P"], target=ARRAY_BUFFER, minmax=True),
             "NORMAL": g.accessor((m["N"] / np.maximum(np.linalg.norm(m["N"], axis=1, keepdims=True), 1e-12))
                                  .astype(np.float32), target=ARRAY_BUFFER),
             "JOINTS_0": g.accessor(J, target=ARRAY_BUFFER),
             "WEIGHTS_0": g.accessor(W.astype(np.float32), target=ARRAY_BUFFER)}
    if m["UV"] is not None:
        attrs["TEXCOORD_0"] = g.accessor(m["UV"], target=ARRAY_BUFFER)
    F = m["F"]
    a, b_, c = (m["P"][F[:, k]].astype(np.float64) for k in range(3))
    if (np.einsum("ij,ij->i", np.cross(b_ - a, c - a), m["N"][F].sum(axis=1)) < 0).sum() > len(F) / 2:
        F = F[:, ::-1]
    mat = g.add("materials", {"name": name, "pbrMetallicRoughness": {"baseColorFactor": [0.72, 0.6, 0.45, 1.0],
                                                                     "metallicFactor": 0.0, "roughnessFactor": 0.9}})
    mesh = g.add("meshes", {"name": name, "primitives": [{
        "attributes": attrs, "indices": g.accessor(F.reshape(-1).astype(np.uint16), target=ELEMENT_ARRAY_BUFFER),
        "material": mat, "mode": 4}]})
    mesh_node = g.add("nodes", {"name": name, "mesh": mesh, "skin": skin})
    g.doc["scenes"] = [{"nodes": roots + [mesh_node]}]
    g.doc["scene"] = 0
    for clip, psa in anims:
        dt, keys = read_psa(psa)
        if keys.shape[1] != len(bones):
            raise ValueError(f"{psa}: {keys.shape[1]} bones for {len(bones)}")
        lt, lq = local_trs(keys, parents)
        times = g.accessor((np.arange(len(keys)) * dt).astype(np.float32), minmax=True)
        samplers, channels = [], []
        for j, node in enumerate(nodes):
            for path, values in (("translation", lt[:, j]), ("rotation", _hemisphere(lq[:, j]))):
                if path == "rotation":
                    values = np.clip(values / np.linalg.norm(values, axis=1, keepdims=True), -1, 1)
                samplers.append({"input": times, "output": g.accessor(values.astype(np.float32)),
                                 "interpolation": "LINEAR"})
                channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})
        g.add("animations", {"name": clip, "samplers": samplers, "channels": channels})
    g.write(out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("pmd", type=Path)
    ap.add_argument("skeleton", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--anim", action="append", default=[], metavar="CLIP=FILE.psa")
    ap.add_argument("--name", default=None)
    args = ap.parse_args(argv)
    anims = [(a.split("=", 1)[0], Path(a.split("=", 1)[1])) for a in args.anim]
    convert(args.pmd, args.skeleton, args.output, anims, args.name or args.pmd.name.split(".")[0])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
