"""Convert Inter-Quake Models (IQM v2: skinned mesh, skeleton, animations) to glTF 2.0 binary.

assimp 5.2 reads an IQM file's mesh but not its skeleton or animations, so the
suite's IQM characters (Sauerbraten / cube2-data) are converted by this script,
which follows the IQM v2 specification (``iqm.txt`` of the IQM SDK):

- header: 16-byte magic ``INTERQUAKEMODEL\\0``, version 2, then 27 uint32 counts
  and offsets (text, meshes, vertex arrays, triangles, joints, poses, anims,
  frames, bounds, comments, extensions);
- vertex arrays: POSITION, TEXCOORD, NORMAL (float), BLENDINDEXES, BLENDWEIGHTS
  (4 x ubyte, weights normalised by 255);
- joints: name, parent, translate[3], rotate[4] (x, y, z, w), scale[3], the
  bind pose relative to the parent; positions are given in the bind pose;
- poses and frames: each frame holds, for every pose (joint) and each of its 10
  channels (translate, rotate, scale) whose mask bit is set, one uint16 ``v``;
  the channel's value is ``offset + v * scale``; unset channels are ``offset``.

The glTF: one node per joint (the bind TRS as its rest transform), a skin with
inverse bind matrices ``inv(G_j)`` of the joints' global bind transforms, one
primitive per IQM mesh with its material's texture (given on the command
line), LINEAR channels per joint at ``k / framerate`` (constant channels as a
single key), clips named by the IQM anim names or ``--clip NAME=FILE``.
IQM is z-up: a root node rotates the model by -90 degrees about x (y-up), and
triangle winding is flipped where the face normals disagree with the vertex
normals (IQM stores clockwise triangles).

Usage::

    python tools/suite/iqm2gltf.py Frankie.iqm -o frankie.glb \\
        --texture Body=flyingsquirrel_skin_col.jpg --texture Tail=frankie_tail2.png \\
        --anim run=Frankie_Run.iqm --anim idle=Frankie_Idle1.iqm --max-texture 512
"""

from __future__ import annotations

import argparse
import io
import struct
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from glb import ARRAY_BUFFER, ELEMENT_ARRAY_BUFFER, GlbBuilder  # noqa: E402

_HEADER = struct.Struct("<16s27I")
_FORMATS = {0: np.int8, 1: np.uint8, 2: np.int16, 3: np.uint16, 4: np.int32, 5: np.uint32, 6: np.float16,
            7: np.float32, 8: np.float64}
POSITION, TEXCOORD, NORMAL, TANGENT, BLENDINDEXES, BLENDWEIGHTS = range(6)


@dataclass
class Iqm:
    """What one IQM file holds (arrays in IQM's own axes)."""

    meshes: list = field(default_factory=list)          # (name, material, first_vertex, n, first_tri, ntri)
    arrays: dict = field(default_factory=dict)          # vertex array type -> (n, width) array
    triangles: np.ndarray | None = None
    joints: list = field(default_factory=list)          # (name, parent, t[3], q[4] xyzw, s[3])
    poses: list = field(default_factory=list)           # (parent, mask, offset[10], scale[10])
    anims: list = field(default_factory=list)           # (name, first_frame, n_frames, framerate)
    frames: np.ndarray | None = None                    # (num_frames, num_framechannels) uint16


def _text(blob: bytes, ofs_text: int, index: int) -> str:
    end = blob.index(b"\0", ofs_text + index)
    return blob[ofs_text + index:end].decode("utf-8", errors="replace")


def read_iqm(path: Path) -> Iqm:
    """Parse an IQM v2 file."""
    blob = Path(path).read_bytes()
    h = _HEADER.unpack_from(blob, 0)
    if h[0] != b"INTERQUAKEMODEL\0" or h[1] != 2:
        raise ValueError(f"{path}: not an IQM v2 file")
    (_, _, _, _, _, ofs_text, n_meshes, ofs_meshes, n_va, n_vert, ofs_va, n_tri, ofs_tri, _,
     n_joints, ofs_joints, n_poses, ofs_poses, n_anims, ofs_anims, n_frames, n_fch, ofs_frames, *_rest) = h
    out = Iqm()
    for i in range(n_meshes):
        name, mat, fv, nv, ft, nt = struct.unpack_from("<6I", blob, ofs_meshes + 24 * i)
        out.meshes.append((_text(blob, ofs_text, name), _text(blob, ofs_text, mat), fv, nv, ft, nt))
    for i in range(n_va):
        kind, _flags, fmt, size, offset = struct.unpack_from("<5I", blob, ofs_va + 20 * i)
        dt = np.dtype(_FORMATS[fmt])
        out.arrays[kind] = np.frombuffer(blob, dt, count=n_vert * size, offset=offset).reshape(n_vert, size)
    if n_tri:
        out.triangles = np.frombuffer(blob, np.uint32, count=3 * n_tri, offset=ofs_tri).reshape(n_tri, 3)
    for i in range(n_joints):
        name, parent = struct.unpack_from("<Ii", blob, ofs_joints + 48 * i)
        v = struct.unpack_from("<10f", blob, ofs_joints + 48 * i + 8)
        out.joints.append((_text(blob, ofs_text, name), parent, v[0:3], v[3:7], v[7:10]))
    for i in range(n_poses):
        parent, mask = struct.unpack_from("<iI", blob, ofs_poses + 88 * i)
        v = struct.unpack_from("<20f", blob, ofs_poses + 88 * i + 8)
        out.poses.append((parent, mask, v[:10], v[10:]))
    for i in range(n_anims):
        name, first, count, rate, _flags = struct.unpack_from("<3IfI", blob, ofs_anims + 20 * i)
        out.anims.append((_text(blob, ofs_text, name), first, count, rate))
    if n_frames:
        out.frames = np.frombuffer(blob, np.uint16, count=n_frames * n_fch, offset=ofs_frames).reshape(n_frames, n_fch)
    return out


def decode_frames(iqm: Iqm) -> np.ndarray:
    """Every frame's local TRS per pose: (num_frames, num_poses, 10) = translate, rotate (xyzw), scale."""
    n_frames = 0 if iqm.frames is None else iqm.frames.shape[0]
    out = np.zeros((n_frames, len(iqm.poses), 10))
    col = 0
    for j, (_parent, mask, offset, scale) in enumerate(iqm.poses):
        for c in range(10):
            out[:, j, c] = offset[c]
            if mask & (1 << c):
                out[:, j, c] += iqm.frames[:, col].astype(np.float64) * scale[c]
                col += 1
    q = out[:, :, 3:7]
    out[:, :, 3:7] = q / np.linalg.norm(q, axis=-1, keepdims=True)
    return out


def _matrix(t, q, s) -> np.ndarray:
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    R = np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
                  [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
                  [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)]])
    M = np.eye(4)
    M[:3, :3] = R * np.asarray(s, dtype=np.float64)[None, :]
    M[:3, 3] = t
    return M


def global_bind(joints: list) -> np.ndarray:
    """Global bind matrices ``G_j = G_parent(j) L_j`` (parents come before children in IQM)."""
    G = np.zeros((len(joints), 4, 4))
    for j, (_name, parent, t, q, s) in enumerate(joints):
        L = _matrix(t, q, s)
        G[j] = L if parent < 0 else G[parent] @ L
    return G


def _unit(q) -> list:
    """A unit quaternion whose float32 components stay within [-1, 1]."""
    q = np.asarray(q, dtype=np.float64)
    q = np.clip(q / np.linalg.norm(q), -1.0, 1.0).astype(np.float32)
    return [float(x) for x in q]


def _image(path: Path, max_size: int) -> tuple[bytes, str]:
    from PIL import Image

    img = Image.open(path)
    img.load()
    if max(img.size) > max_size:
        f = max_size / max(img.size)
        img = img.resize((max(1, round(img.size[0] * f)), max(1, round(img.size[1] * f))), Image.LANCZOS)
    buf = io.BytesIO()
    if img.mode in ("RGBA", "LA", "P"):
        img.convert("RGBA").save(buf, format="PNG", optimize=True)
        return buf.getvalue(), "image/png"
    img.convert("RGB").save(buf, format="JPEG", quality=88)
    return buf.getvalue(), "image/jpeg"


def _oriented(tris: np.ndarray, P: np.ndarray, N: np.ndarray | None) -> np.ndarray:
    """Triangles wound counter-clockwise around the vertex normals (majority vote over faces)."""
    if N is None:
        return tris[:, ::-1].copy()
    a, b, c = P[tris[:, 0]], P[tris[:, 1]], P[tris[:, 2]]
    fn = np.cross(b - a, c - a)
    agree = np.einsum("ij,ij->i", fn, N[tris].sum(axis=1))
    return tris.copy() if (agree > 0).sum() >= (agree < 0).sum() else tris[:, ::-1].copy()


def _primitives(g: GlbBuilder, iqm: Iqm, textures: dict, max_texture: int, alpha: set) -> list:
    P = iqm.arrays[POSITION].astype(np.float32)
    N = iqm.arrays.get(NORMAL)
    UV = iqm.arrays.get(TEXCOORD)
    J = iqm.arrays[BLENDINDEXES].astype(np.uint16)
    W = iqm.arrays[BLENDWEIGHTS].astype(np.float64)
    W = W / 255.0 if iqm.arrays[BLENDWEIGHTS].dtype == np.uint8 else W
    W = W / np.maximum(W.sum(axis=1, keepdims=True), 1e-12)
    W[np.isclose(W, 0.0)] = 0.0
    J[W == 0.0] = 0
    tris = _oriented(iqm.triangles.astype(np.int64), P.astype(np.float64), None if N is None else N)
    prims, materials = [], {}
    for name, material, fv, nv, ft, nt in iqm.meshes:
        key = material or name
        if key not in materials:
            mat = {"name": key, "pbrMetallicRoughness": {"metallicFactor": 0.0, "roughnessFactor": 0.9}}
            tex = textures.get(name) or textures.get(material)
            if tex:
                data, mime = _image(Path(tex), max_texture)
                image = g.image(data, mime)
                sampler = g.add("samplers", {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497})
                texture = g.add("textures", {"source": image, "sampler": sampler})
                mat["pbrMetallicRoughness"]["baseColorTexture"] = {"index": texture}
            if name in alpha or material in alpha:
                mat.update(alphaMode="MASK", alphaCutoff=0.5, doubleSided=True)
            materials[key] = g.add("materials", mat)
        local = tris[ft:ft + nt] - fv
        attrs = {"POSITION": g.accessor(P[fv:fv + nv], target=ARRAY_BUFFER, minmax=True),
                 "JOINTS_0": g.accessor(J[fv:fv + nv], target=ARRAY_BUFFER),
                 "WEIGHTS_0": g.accessor(W[fv:fv + nv].astype(np.float32), target=ARRAY_BUFFER)}
        if N is not None:
            n = N[fv:fv + nv].astype(np.float64)
            n = n / np.maximum(np.linalg.norm(n, axis=1, keepdims=True), 1e-12)
            attrs["NORMAL"] = g.accessor(n.astype(np.float32), target=ARRAY_BUFFER)
        if UV is not None:
            attrs["TEXCOORD_0"] = g.accessor(UV[fv:fv + nv].astype(np.float32), target=ARRAY_BUFFER)
        idx = g.accessor(local.reshape(-1).astype(np.uint32 if nv > 65535 else np.uint16),
                         target=ELEMENT_ARRAY_BUFFER)
        prims.append({"attributes": attrs, "indices": idx, "material": materials[key], "mode": 4,
                      "extras": {"iqm_mesh": name}})
    return prims


def _channels(g: GlbBuilder, anim_index: int, frames: np.ndarray, rate: float, joint_nodes: list,
              bind: list) -> dict:
    """One glTF animation from decoded frames (n, poses, 10)."""
    rate = rate if rate > 0 else 24.0
    n = frames.shape[0]
    times = g.accessor((np.arange(n) / rate).astype(np.float32), minmax=True)
    single = g.accessor(np.zeros(1, np.float32), minmax=True)
    samplers, channels = [], []
    for j, node in enumerate(joint_nodes):
        rest = bind[j]
        for path, sl in (("translation", slice(0, 3)), ("rotation", slice(3, 7)), ("scale", slice(7, 10))):
            values = frames[:, j, sl]
            if path == "rotation":          # keep consecutive quaternions in one hemisphere
                for k in range(1, n):
                    if np.dot(values[k], values[k - 1]) < 0:
                        values[k] = -values[k]
            const = np.allclose(values, values[0], atol=1e-6)
            if const and np.allclose(values[0], rest[sl], atol=1e-6):
                continue
            out = values[:1] if const else values
            if path == "rotation":
                out = np.clip(out / np.linalg.norm(out, axis=1, keepdims=True), -1.0, 1.0)
            samplers.append({"input": single if const else times,
                             "output": g.accessor(out.astype(np.float32)), "interpolation": "LINEAR"})
            channels.append({"sampler": len(samplers) - 1, "target": {"node": node, "path": path}})
    return {"samplers": samplers, "channels": channels}


def _root_rotation(yaw: float) -> list:
    """Quaternion (x, y, z, w) of ``R_y(yaw) R_x(-90 deg)``: IQM's z-up to glTF's y-up, then a turn about y."""
    h = np.radians(yaw) / 2
    qy = np.array([0.0, np.sin(h), 0.0, np.cos(h)])
    qx = np.array([-np.sqrt(0.5), 0.0, 0.0, np.sqrt(0.5)])
    (x1, y1, z1, w1), (x2, y2, z2, w2) = qy, qx
    q = np.array([w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2, w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
                  w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2, w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2])
    return _unit(q)


def convert(mesh_path: Path, out: Path, textures: dict, anims: list, max_texture: int, alpha: set,
            fps: float | None = None, yaw: float = 0.0) -> None:
    """Write ``out`` from an IQM mesh file and (name, IQM file, fps or None) animation sources."""
    iqm = read_iqm(mesh_path)
    if not iqm.joints or BLENDINDEXES not in iqm.arrays:
        raise ValueError(f"{mesh_path}: no skeleton or blend weights")
    g = GlbBuilder(f"rigslim tools/suite/iqm2gltf.py from {mesh_path.name}")
    root = g.add("nodes", {"name": f"{mesh_path.stem}_zup", "rotation": _root_rotation(yaw), "children": []})
    joint_nodes = []
    bind = []
    for name, parent, t, q, s in iqm.joints:
        q = _unit(q)
        node = g.add("nodes", {"name": name, "translation": list(t), "rotation": q, "scale": list(s)})
        joint_nodes.append(node)
        bind.append(np.array(list(t) + list(q) + list(s)))
        if parent < 0:
            g.doc["nodes"][root]["children"].append(node)
        else:
            g.doc["nodes"][joint_nodes[parent]].setdefault("children", []).append(node)
    G = global_bind(iqm.joints)
    ibm = np.linalg.inv(G).transpose(0, 2, 1).reshape(-1, 16).astype(np.float32)   # column-major
    skin = g.add("skins", {"joints": joint_nodes, "inverseBindMatrices": g.accessor(ibm, matrix=True),
                           "skeleton": root})
    mesh = g.add("meshes", {"name": mesh_path.stem, "primitives": _primitives(g, iqm, textures, max_texture,
                                                                              alpha)})
    mesh_node = g.add("nodes", {"name": mesh_path.stem, "mesh": mesh, "skin": skin})
    g.doc["scenes"] = [{"nodes": [root, mesh_node]}]
    g.doc["scene"] = 0
    names = [j[0] for j in iqm.joints]
    sources = anims or [(None, mesh_path, None)]
    for clip_name, path, clip_fps in sources:
        src = iqm if Path(path) == mesh_path else read_iqm(Path(path))
        frames = decode_frames(src)
        order = _pose_order(src, names, path)
        for name, first, count, rate in src.anims:
            block = frames[first:first + count][:, order]
            anim = _channels(g, len(g.doc.get("animations", [])), block, clip_fps or fps or rate, joint_nodes, bind)
            anim["name"] = clip_name if (clip_name and len(src.anims) == 1) else \
                (f"{clip_name}:{name}" if clip_name else name)
            g.add("animations", anim)
    g.write(out)


def _pose_order(src: Iqm, names: list, path) -> np.ndarray:
    """Index of the source pose for each mesh joint (by joint name when the source names them)."""
    if len(src.poses) != len(names):
        if not src.joints:
            raise ValueError(f"{path}: {len(src.poses)} poses for {len(names)} joints and no joint names")
    if src.joints:
        src_names = [j[0] for j in src.joints]
        missing = [n for n in names if n not in src_names]
        if missing:
            raise ValueError(f"{path}: joints {missing[:5]} have no pose")
        return np.array([src_names.index(n) for n in names])
    return np.arange(len(names))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("mesh", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--texture", action="append", default=[], metavar="MESH_OR_MATERIAL=IMAGE")
    ap.add_argument("--alpha", action="append", default=[], metavar="MESH_OR_MATERIAL",
                    help="alpha-tested material (alphaMode MASK, double-sided)")
    ap.add_argument("--anim", action="append", default=[], metavar="CLIP=FILE.iqm[@FPS]",
                    help="a clip from an IQM animation file, at FPS frames per second (default: the file's)")
    ap.add_argument("--fps", type=float, default=None, help="frame rate where the file's is 0 or to override it")
    ap.add_argument("--yaw", type=float, default=0.0,
                    help="turn the character about +y by this many degrees (to face +z, the glTF front)")
    ap.add_argument("--max-texture", type=int, default=512, help="downscale textures to at most this size")
    args = ap.parse_args(argv)
    textures = dict(t.split("=", 1) for t in args.texture)
    anims = []
    for spec in args.anim:
        name, _, rest = spec.partition("=")
        path, _, rate = rest.partition("@")
        anims.append((name, Path(path), float(rate) if rate else None))
    convert(args.mesh, args.output, textures, anims, args.max_texture, set(args.alpha), args.fps, args.yaw)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
