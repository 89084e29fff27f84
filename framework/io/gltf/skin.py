"""Skinned glTF meshes read into mesh, joints, weights and poses (:func:`read_gltf_skin`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError
from rigslim.io.gltf.document import (
    MAX_FRAME_NODES,
    MAX_FRAMES,
    GltfDocument,
    expect_accessor_type,
    load_gltf,
    read_accessor,
)
from rigslim.io.gltf.scene import animation_duration, find_animation, local_matrices, node_parents, world_matrices
from rigslim.model.handles import Handles
from rigslim.model.mesh import Mesh
from rigslim.model.poses import Poses
from rigslim.model.weights import validate_weights


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


def joint_indices(doc: GltfDocument, index: int, where: str) -> np.ndarray:
    """A JOINTS_n accessor as joint numbers: its stored values, never normalized.

    The specification allows only unsigned byte or short, not ``normalized`` (a normalized JOINTS_0 read as
    fractions bound every vertex to joint 0); such files and float joints are read by their stored numbers,
    which must then be whole (the writer rewrites them as unsigned integers). Anything else is refused.
    """
    raw = np.asarray(read_accessor(doc, index, normalize=False))
    if raw.dtype.kind == "f":
        bad = ~np.isfinite(raw) | (raw != np.rint(raw))
        if bad.any():
            v = int(np.argmax(bad.any(axis=-1))) if raw.ndim > 1 else int(np.argmax(bad))
            raise InputError(f"float joint index {raw.reshape(len(raw), -1)[v].tolist()} of vertex {v} is not a "
                             "whole number", source=doc.path, field=where,
                             fix="re-export with UNSIGNED_BYTE or UNSIGNED_SHORT joints")
        raw = np.rint(raw)
    return raw.astype(np.int64)


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


def primitive_triangles(mode: int, idx: np.ndarray) -> np.ndarray:
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


def weight_sums(doc: GltfDocument, attributes: dict) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex of a primitive, the sum of its decoded weights over every ``WEIGHTS_n`` set and its count of
    non-zero weights (empty arrays without skinning attributes)."""
    sets = skinning_sets(attributes)
    if not sets or "POSITION" not in attributes:
        return np.zeros(0), np.zeros(0, np.int64)
    count = doc.json["accessors"][attributes["POSITION"]]["count"]
    total, nz = np.zeros(count), np.zeros(count, np.int64)
    for s in sets:
        W = np.asarray(read_accessor(doc, attributes[f"WEIGHTS_{s}"]), float).reshape(count, -1)
        total += W.sum(axis=1)
        nz += (W != 0).sum(axis=1)
    return total, nz


def unnormalised_weights(doc: GltfDocument, tolerance: float = 1e-3) -> dict | None:
    """Where a file's skin weights do not sum to 1: ``{"vertices", "min", "max"}`` over every skinned primitive
    (vertices whose sum is off by more than ``tolerance``), or None. rigslim reads such weights normalised (glTF
    requires sums of 1), which moves those vertices against a viewer that draws the raw sums."""
    lo, hi, off = np.inf, -np.inf, 0
    for mesh in doc.json.get("meshes", []):
        for prim in mesh.get("primitives", []):
            total, _ = weight_sums(doc, prim.get("attributes", {}))
            bad = np.abs(total - 1.0) > tolerance
            if bad.any():
                off += int(bad.sum())
                lo, hi = min(lo, float(total.min())), max(hi, float(total.max()))
    return {"vertices": off, "min": lo, "max": hi} if off else None


def skinning_sets(attributes: dict) -> list[int]:
    """Set numbers n for which a primitive has both ``JOINTS_n`` and ``WEIGHTS_n``."""
    sets = sorted(int(k.split("_")[1]) for k in attributes if k.startswith("JOINTS_") and k.split("_")[1].isdigit())
    return [n for n in sets if f"WEIGHTS_{n}" in attributes]


def _choose_skin(doc: GltfDocument, skin, mesh) -> tuple[int, list[int]]:
    js = doc.json
    skins = js.get("skins", [])
    if not skins:
        raise InputError("the file has no skin", source=doc.path, field="skins",
                         fix="give a skinned glTF (a mesh node with 'skin')")
    users: dict[int, list[int]] = {}  # skin -> ordered unique mesh indices
    nodes = js.get("nodes", [])
    shown: list[int] | range
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
                             fix="choose one with 'skin: INDEX' (or a mesh with 'mesh:'), and run the pipeline once "
                                 "per skin; rigslim reduce and rigslim lod do every skin in one command")
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
    return skin_from_document(doc, animation=animation, fps=fps, mesh=mesh, skin=skin, normalize=normalize,
                              weld=weld, times=times)


def skin_from_document(doc: GltfDocument, *, animation=None, fps: float = 30.0, mesh=None, skin=None,
                       normalize: bool = True, weld: bool = False, times=None) -> GltfSkin:
    """:func:`read_gltf_skin` of a document already loaded (:func:`~rigslim.io.gltf.document.load_gltf`).

    The parameters after ``doc`` are :func:`read_gltf_skin`'s, keyword-only. The read runs in four phases:
    the skin and its meshes (``_choose_skin``), the inverse bind matrices, the skinned primitives merged
    into one mesh with its weights, then the joints as handles and the clip's sampled poses.
    """
    try:
        return _skin_from_document(doc, animation, fps, mesh, skin, normalize, weld, times)
    except (KeyError, IndexError) as e:
        raise InputError(f"malformed document: a required property or index is missing or out of range ({e!r})",
                         source=doc.path, field="json", fix="re-export the file; check it with the glTF-Validator"
                         ) from None


def _skin_from_document(doc: GltfDocument, animation, fps, mesh, skin, normalize, weld, times) -> GltfSkin:
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps {fps} is not a positive number", source=doc.path, field="fps", fix="give e.g. fps: 30")
    skin_index, mesh_indices = _choose_skin(doc, skin, mesh)
    joints = [int(j) for j in doc.json["skins"][skin_index]["joints"]]
    ibm = inverse_bind_matrices(doc, skin_index)
    V, F, A, slices = _merged_primitives(doc, mesh_indices, len(joints))
    weights = validate_weights(A, len(V), n_handles=len(joints), normalize=normalize,
                               source=f"{doc.path} (WEIGHTS_n)")
    vertex_map = None
    if weld:
        vertex_map, V, F, weights = weld_vertices(V, F, weights)
    mesh_obj = Mesh(V, F, source=str(doc.path))
    handles = _joint_handles(doc, joints, ibm)
    anim = find_animation(doc, animation)
    poses = _clip_poses(doc, anim, _sample_times(doc, anim, fps, times), joints, ibm)
    return GltfSkin(doc, skin_index, joints, slices, mesh_obj, handles, weights, poses, anim, float(fps), vertex_map)


def inverse_bind_matrices(doc: GltfDocument, skin_index: int) -> np.ndarray:
    """(n, 4, 4) ``skins[skin_index].inverseBindMatrices`` as column-vector matrices (identity when absent).

    Refused with the joint named: fewer matrices than joints, NaN/inf, a last row other than
    ``[0, 0, 0, 1]`` (relative 1e-6), a singular 3x3 part (``|det| <= 1e-12 scale^3``).
    """
    sk = doc.json["skins"][skin_index]
    joints = [int(j) for j in sk["joints"]]
    n = len(joints)
    if "inverseBindMatrices" not in sk:
        return np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    expect_accessor_type(doc, sk["inverseBindMatrices"], ("MAT4",), f"skins[{skin_index}].inverseBindMatrices")
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
    return ibm


def _merged_primitives(doc: GltfDocument, mesh_indices: list[int], n: int):
    """The skinned primitives of ``mesh_indices`` merged in order: positions (N, 3), triangles, the (N, n)
    weights ``A[v, JOINTS_s[v, c]] += WEIGHTS_s[v, c]`` and each primitive's :class:`PrimitiveSlice`."""
    js = doc.json
    Vs, Fs, rows, cols, vals, slices = [], [], [], [], [], []
    start = 0
    for mi in mesh_indices:
        for pi, prim in enumerate(js["meshes"][mi]["primitives"]):
            attrs = prim.get("attributes", {})
            where = f"meshes[{mi}].primitives[{pi}]"
            sets = skinning_sets(attrs)
            if "POSITION" not in attrs or not sets:
                continue
            expect_accessor_type(doc, attrs["POSITION"], ("VEC3",), f"{where}.attributes.POSITION")
            for s_ in sets:
                expect_accessor_type(doc, attrs[f"JOINTS_{s_}"], ("VEC4",), f"{where}.attributes.JOINTS_{s_}")
                expect_accessor_type(doc, attrs[f"WEIGHTS_{s_}"], ("VEC4",), f"{where}.attributes.WEIGHTS_{s_}")
            if "indices" in prim:
                expect_accessor_type(doc, prim["indices"], ("SCALAR",), f"{where}.indices")
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
            F = primitive_triangles(prim.get("mode", 4), idx)
            for s in sets:
                J = joint_indices(doc, attrs[f"JOINTS_{s}"], f"{where}.attributes.JOINTS_{s}").reshape(m, -1)
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
    return V, F, A, slices


def _joint_handles(doc: GltfDocument, joints: list[int], ibm: np.ndarray) -> Handles:
    """One handle per joint at its bind position ``(IBM_i^-1)[:3, 3]``; a joint's parent is its nearest
    ancestor node that is a joint, its bone runs to its first child joint."""
    js = doc.json
    n = len(joints)
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
    first_child: dict[int, int] = {}
    for i in range(n):
        if parents[i] >= 0:
            first_child.setdefault(int(parents[i]), i)
    bones = np.array([[i, first_child.get(i, i)] for i in range(n)], np.int64)
    handles = Handles("skeleton", names, joints=position, bones=bones, parents=parents, source=str(doc.path))
    return handles


def _sample_times(doc: GltfDocument, anim: int | None, fps: float, times) -> np.ndarray:
    """The sample times in seconds: ``times`` as given, else ``f / fps`` for ``f = 0 .. floor(duration * fps +
    0.001)`` (the rest pose alone without a clip); bounded by MAX_FRAMES and MAX_FRAME_NODES."""
    nodes = doc.json.get("nodes", [])
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
    return t


def _clip_poses(doc: GltfDocument, anim: int | None, t: np.ndarray, joints: list[int], ibm: np.ndarray) -> Poses:
    """``T_i^f = (G_f(joint_i) @ IBM_i)[:3, :]`` at the times ``t``: node transforms composed from the roots."""
    js = doc.json
    parent = node_parents(js)
    local = local_matrices(doc, anim, t)
    world = world_matrices(local, parent) if len(js.get("nodes", [])) else local
    T = np.einsum("jpab,jbc->pjac", world[joints], ibm)[:, :, :3, :]
    label = str(doc.path) if anim is None else f"{doc.path} animation {js['animations'][anim].get('name', anim)}"
    poses = Poses(T, np.arange(len(t)), source=label)
    return poses
