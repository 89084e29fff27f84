"""UsdSkel skinned meshes and their animations, read into rigslim's data model.

UsdSkel (the ``UsdSkel`` schema's "Skinning" documentation) deforms a point
``p`` of a mesh bound to a ``Skeleton`` by linear blend skinning in the
skeleton's space. In rigslim's column convention (:mod:`rigslim.io.usd.stage`)::

    p_s = G p                                   G: primvars:skel:geomBindTransform
    p'  = sum_c w_c  S_{j_c}(t) B_{j_c}^{-1} p_s

where ``j_c``/``w_c`` are the ``elementSize`` slots of
``primvars:skel:jointIndices``/``jointWeights`` (interpolation ``vertex``,
or ``constant`` for one set shared by every point), ``B_j`` the skeleton's
``bindTransforms`` (skeleton space) and ``S_j(t)`` joint ``j``'s skeleton-space
transform at time ``t``: the ``SkelAnimation``'s local transforms (its
``translations``, ``rotations``, ``scales``; ``restTransforms`` for joints it
does not animate) concatenated from the roots, ``S_j = S_{parent(j)} L_j``.

That is rigslim's linear blend model (docs/algorithms.md section 1) with one
handle per joint, rest vertices ``v = G p`` and ``T_j = (S_j(t) B_j^{-1})[:3, :]``;
posed points are in the skeleton's space, as UsdSkel's own
``UsdSkelSkinningQuery.ComputeSkinnedPoints`` gives them.

:func:`read_usd_skin` returns every mesh bound to one skeleton merged into one
:class:`rigslim.model.mesh.Mesh` (polygons fan-triangulated), the skeleton's joints
as handles, the sparse weights and the poses of one ``SkelAnimation`` sampled
at a frame rate; the open stage travels with it for :mod:`rigslim.io.usd.write`.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError, brief, closest
from rigslim.io.usd import stage as usd_stage
from rigslim.io.usd.stage import diagnostics, open_stage, pxr_modules, time_codes_per_second, to_columns
from rigslim.model.handles import Handles
from rigslim.model.mesh import Mesh
from rigslim.model.poses import Poses
from rigslim.model.weights import validate_weights

#: Most frames :func:`read_usd_skin` samples (a longer clip or a higher fps is refused, not sampled).
MAX_FRAMES = 100_000
#: Most influences per point rigslim reads (``elementSize``); UsdSkel has no limit, real files use <= 16.
MAX_ELEMENT_SIZE = 256
JOINT_INDICES = "primvars:skel:jointIndices"
JOINT_WEIGHTS = "primvars:skel:jointWeights"


@dataclass(frozen=True, eq=False)
class MeshPart:
    """Where one USD mesh sits in the merged mesh, and how its polygons became triangles.

    Attributes
    ----------
    path : str
        The ``Mesh`` prim's path.
    start, count : int
        Rows ``start:start + count`` of the merged vertex array (the mesh's points, in order).
    face_start : int
        First row of the merged face array holding this mesh's triangles.
    polygon : (t,) int64 array
        The authored face (polygon) each triangle comes from.
    corners : (t, 3) int64 array
        The triangle's corners as positions in ``faceVertexIndices`` (for ``faceVarying`` primvars).
    geom_bind : (4, 4) float64 array
        ``primvars:skel:geomBindTransform`` (column convention; identity when unauthored).
    element_size : int
        The authored ``elementSize`` of the joint influences.
    rigid : bool
        Influences authored with ``constant`` interpolation (one set for every point).
    blend_shapes : list of str
        ``skel:blendShapes`` of the mesh (kept by the writer, not part of the linear blend fit).
    """

    path: str
    start: int
    count: int
    face_start: int
    polygon: np.ndarray
    corners: np.ndarray
    geom_bind: np.ndarray
    element_size: int
    rigid: bool = False
    blend_shapes: list[str] = field(default_factory=list)

    @property
    def n_triangles(self) -> int:
        return len(self.polygon)


@dataclass
class UsdSkin:
    """Everything :func:`read_usd_skin` extracts, plus what a writer needs.

    Attributes
    ----------
    path : Path
        The file read.
    stage : pxr.Usd.Stage
        The composed stage (kept open for writers).
    root, skeleton : str
        Paths of the ``SkelRoot`` and the ``Skeleton`` whose meshes were read.
    joints : list of str
        The skeleton's ``joints`` tokens: handle ``i`` is joint ``joints[i]``.
    parts : list of MeshPart
        The merged meshes, in order.
    mesh, handles, weights, poses :
        The rigslim inputs (vertices in the skeleton's space at bind time).
    bind : (n, 4, 4) array
        ``bindTransforms`` (column convention).
    animation : str or None
        Path of the sampled ``SkelAnimation`` (None: the rest pose).
    fps : float
        Frame rate of the samples; ``time_codes[f]`` is frame f's USD time code.
    time_codes : (p,) array
    notes : list of str
        What the reader noticed and worked around (shown by ``inspect``, kept in provenance).
    """

    path: Path
    stage: object
    root: str
    skeleton: str
    joints: list[str]
    parts: list[MeshPart]
    mesh: Mesh
    handles: Handles
    weights: sp.csr_matrix
    poses: Poses
    bind: np.ndarray
    animation: str | None
    fps: float
    time_codes: np.ndarray
    notes: list[str] = field(default_factory=list)


def values(raw, dtype, path: Path, where: str, width: int | None = None) -> np.ndarray:
    """An authored array value as numpy (empty when unauthored), or one line when it has the wrong type.

    ``width``: the elements' size (3 for points, 16 for matrices); the result is (n, width), else (n,).
    """
    if raw is None:
        return np.zeros((0, width) if width else 0, dtype)
    try:
        A = np.array(raw, dtype=dtype)
        if width:
            A = A.reshape(len(A), -1)
            if A.shape[1] != width:
                raise ValueError
        elif A.ndim != 1:
            raise ValueError
    except (TypeError, ValueError):
        kind = type(raw).__name__
        raise InputError(f"the value has the wrong type ({kind})", source=path, field=where,
                         fix="re-export the file (the property must hold an array of its declared type)") from None
    return A


def _tokens(raw, path: Path, where: str) -> list[str]:
    """A token[] value as strings (empty when unauthored), or one line when it is something else."""
    if raw is None:
        return []
    if isinstance(raw, (str, bytes)) or not hasattr(raw, "__len__"):
        raise InputError(f"the value has the wrong type ({type(raw).__name__})", source=path, field=where,
                         fix="author a token[] of joint paths")
    return [str(j) for j in raw]


# --------------------------------------------------------------------------- bindings


def skel_bindings(stage, path: Path) -> tuple[Any, list[Any]]:
    """``(UsdSkel.Cache, [UsdSkel.Binding, ...])`` of every ``SkelRoot`` of the stage, in traversal order.

    Raises one line when a mesh carries joint influences that UsdSkel would
    not skin (no ``SkelRoot`` above it, no ``skel:skeleton`` binding).
    """
    Usd, UsdGeom, UsdSkel, _, _, _ = pxr_modules()
    cache = UsdSkel.Cache()
    bindings = []
    predicate = Usd.TraverseInstanceProxies(Usd.PrimDefaultPredicate)
    it = iter(Usd.PrimRange.Stage(stage, predicate))
    roots = []
    for prim in it:
        if prim.IsA(UsdSkel.Root):
            roots.append(prim)
            it.PruneChildren()
    targets: set[str] = set()
    with diagnostics():
        for prim in roots:
            root = UsdSkel.Root(prim)
            cache.Populate(root, predicate)
            for b in cache.ComputeSkelBindings(root, predicate):
                bindings.append(b)
                targets.update(str(q.GetPrim().GetPath()) for q in b.GetSkinningTargets())
    for prim in stage.Traverse():
        if prim.IsA(UsdGeom.Mesh) and prim.HasAttribute(JOINT_INDICES) and str(prim.GetPath()) not in targets:
            inside = any(str(prim.GetPath()).startswith(str(r.GetPath()) + "/") for r in roots)
            if not inside:
                raise InputError(f"mesh {prim.GetPath()} has joint influences but no SkelRoot above it",
                                 source=path, field=str(prim.GetPath()),
                                 fix="put the mesh and its Skeleton under a SkelRoot prim")
            blocker = _untyped_ancestor(prim, UsdGeom)
            if blocker is not None:
                raise InputError(f"mesh {prim.GetPath()} is below {blocker.GetPath()}, which is not Imageable "
                                 f"('{blocker.GetTypeName() or 'def'}' without a type): UsdSkel skips it",
                                 source=path, field=str(blocker.GetPath()),
                                 fix=f"give {blocker.GetPath()} a type (def Xform or Scope)")
            raise InputError(f"mesh {prim.GetPath()} has joint influences but is bound to no Skeleton",
                             source=path, field=f"{prim.GetPath()}.skel:skeleton",
                             fix="bind it with the skel:skeleton relationship (UsdSkelBindingAPI)")
    if not bindings:
        raise InputError("the file has no skinned mesh (no Mesh under a SkelRoot bound to a Skeleton)",
                         source=path, field="SkelRoot", fix="give a UsdSkel character")
    return cache, bindings


def _untyped_ancestor(prim, UsdGeom):
    """The first ancestor below the SkelRoot that is not Imageable (UsdSkel does not look below it), or None."""
    p = prim.GetParent()
    while p and not p.IsPseudoRoot():
        if p.GetTypeName() == "SkelRoot":
            return None
        if not p.IsA(UsdGeom.Imageable):
            return p
        p = p.GetParent()
    return None


def _choose_binding(bindings, skeleton, mesh, path: Path):
    """The binding to read: the one named by ``skeleton`` (path or name), the one holding ``mesh``, or the only one."""
    skels = [str(b.GetSkeleton().GetPrim().GetPath()) for b in bindings]
    if skeleton is not None:
        hits = [i for i, s in enumerate(skels) if s == str(skeleton) or s.rsplit("/", 1)[-1] == str(skeleton)]
        if not hits:
            raise InputError(f"no skeleton {brief(skeleton)} has skinned meshes", source=path, field="skeleton",
                             fix=closest(str(skeleton), skels))
        return bindings[hits[0]]
    if mesh is not None:
        for b in bindings:
            if any(_matches(q.GetPrim(), mesh) for q in b.GetSkinningTargets()):
                return b
        names = [str(q.GetPrim().GetPath()) for b in bindings for q in b.GetSkinningTargets()]
        raise InputError(f"no skinned mesh {brief(mesh)}", source=path, field="mesh", fix=closest(str(mesh), names))
    if len(set(skels)) > 1:
        raise InputError(f"{len(set(skels))} skeletons have skinned meshes", source=path, field="skeleton",
                         fix="choose one with 'skeleton: " + skels[0] + "' (or a mesh with 'mesh:')")
    return bindings[0]


def _matches(prim, mesh) -> bool:
    p = str(prim.GetPath())
    return p == str(mesh) or prim.GetName() == str(mesh)


# --------------------------------------------------------------------------- skeleton


def check_joints(skel, path: Path, where: str) -> list[str]:
    """The skeleton's ``joints`` tokens, refused with one line when empty, repeated or not parents-first."""
    _, _, UsdSkel, _, _, _ = pxr_modules()
    joints = _tokens(skel.GetJointsAttr().Get(), path, f"{where}.joints")
    if not joints:
        raise InputError("the skeleton has no joints", source=path, field=f"{where}.joints",
                         fix="author the Skeleton's joints (token[] of joint paths)")
    if len(set(joints)) != len(joints):
        dup = next(j for j in joints if joints.count(j) > 1)
        raise InputError(f"joint {brief(dup)} is listed twice", source=path, field=f"{where}.joints",
                         fix="give every joint once")
    ok, why = UsdSkel.Topology(joints).Validate()
    if not ok:
        raise InputError(f"the joint hierarchy is invalid ({' '.join(str(why).split())})", source=path,
                         field=f"{where}.joints", fix="list every joint after its parent, as 'Parent/Child' paths")
    return joints


def _skeleton(skel_query, path: Path, where: str):
    """Joint tokens, parents, bind (column) and rest local transforms of a skeleton, checked."""
    skel = skel_query.GetSkeleton()
    joints = check_joints(skel, path, where)
    parents = np.asarray(skel_query.GetTopology().GetParentIndices(), np.int64)
    bind_raw = values(skel.GetBindTransformsAttr().Get(), np.float64, path, f"{where}.bindTransforms", 16)
    if len(bind_raw) != len(joints):
        raise InputError(f"{len(bind_raw)} bindTransforms for {len(joints)} joints",
                         source=path, field=f"{where}.bindTransforms",
                         fix="author one skeleton-space bind matrix per joint")
    bind = to_columns(bind_raw)
    _check_matrices(bind, path, f"{where}.bindTransforms", joints)
    rest_raw = values(skel.GetRestTransformsAttr().Get(), np.float64, path, f"{where}.restTransforms", 16)
    if len(rest_raw) == len(joints):
        rest = to_columns(rest_raw)
        _check_matrices(rest, path, f"{where}.restTransforms", joints)
    elif len(rest_raw):
        raise InputError(f"{len(rest_raw)} restTransforms for {len(joints)} joints", source=path,
                         field=f"{where}.restTransforms", fix="author one local rest matrix per joint, or none")
    else:   # unauthored: the bind pose, as local transforms
        inv = np.linalg.inv(bind)
        rest = np.array([bind[j] if p < 0 else inv[p] @ bind[j] for j, p in enumerate(parents)])
    return joints, parents, bind, rest


def _check_matrices(M: np.ndarray, path: Path, where: str, joints: list[str]) -> None:
    """Refuse NaN, non-affine or singular 4x4 (column) matrices, naming the joint."""
    finite = np.isfinite(M).all(axis=(1, 2))
    if not finite.all():
        j = int(np.argmin(finite))
        raise InputError(f"the matrix of joint {brief(joints[j])} contains NaN or inf", source=path,
                         field=f"{where}[{j}]", fix="re-export the skeleton")
    scale = np.maximum(np.abs(M[:, :3, :3]).max(axis=(1, 2)), 1e-300)
    affine = np.abs(M[:, 3, :] - [0.0, 0.0, 0.0, 1.0]).max(axis=1) <= 1e-6 * np.maximum(scale, 1.0)
    if not affine.all():
        j = int(np.argmin(affine))
        raise InputError(f"the matrix of joint {brief(joints[j])} is not affine (last column "
                         f"{np.round(M[j, 3], 6).tolist()})", source=path, field=f"{where}[{j}]",
                         fix="re-export the skeleton")
    det = np.abs(np.linalg.det(M[:, :3, :3]))
    singular = ~(det > 1e-12 * scale ** 3)
    if singular.any():
        j = int(np.argmax(singular))
        raise InputError(f"the matrix of joint {brief(joints[j])} is singular", source=path,
                         field=f"{where}[{j}]", fix="re-export the skeleton with invertible bind matrices")


def _handles(joints: list[str], parents: np.ndarray, bind: np.ndarray, path: Path) -> Handles:
    """One handle per joint, at its bind position; bones from each joint to its first child."""
    leaves = [j.rsplit("/", 1)[-1] for j in joints]
    names = leaves if len(set(leaves)) == len(leaves) else joints
    n = len(joints)
    first_child: dict[int, int] = {}
    for i in range(n):
        if parents[i] >= 0:
            first_child.setdefault(int(parents[i]), i)
    bones = np.array([[i, first_child.get(i, i)] for i in range(n)], np.int64)
    return Handles("skeleton", names, joints=bind[:, :3, 3].copy(), bones=bones, parents=parents.copy(),
                   source=str(path))


# --------------------------------------------------------------------------- meshes


def triangulate(counts: np.ndarray, indices: np.ndarray, holes=(), left_handed: bool = False):
    """Fan triangles of USD polygons.

    Parameters
    ----------
    counts : (f,) faceVertexCounts
    indices : (sum counts,) faceVertexIndices
    holes : faces to leave out (holeIndices)
    left_handed : bool
        ``orientation = "leftHanded"``: reverse each triangle so that all are counter-clockwise.

    Returns
    -------
    triangles : (t, 3) point indices; polygon : (t,) the face of each; corners : (t, 3) positions in ``indices``

    Notes
    -----
    Face ``i`` with ``c >= 3`` corners starting at ``s`` gives the ``c - 2`` triangles
    ``(s, s + k + 1, s + k + 2)``, ``k = 0 .. c - 3``; faces with fewer than 3 corners give none.
    """
    counts = np.asarray(counts, np.int64)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]]) if len(counts) else np.zeros(0, np.int64)
    keep = counts >= 3
    if len(holes):
        h = np.asarray(holes, np.int64)
        keep[h[(h >= 0) & (h < len(counts))]] = False
    faces = np.flatnonzero(keep)
    per = counts[faces] - 2
    polygon = np.repeat(faces, per)
    k = np.arange(int(per.sum())) - np.repeat(np.cumsum(per) - per, per)
    s = starts[polygon]
    corners = np.stack([s, s + k + 1, s + k + 2], axis=1)
    if left_handed:
        corners = corners[:, [0, 2, 1]]
    return np.asarray(indices, np.int64)[corners], polygon, corners


def _mesh_part(query, joint_index: dict[str, int], skel_joints: list[str], path: Path, start: int,
               face_start: int):
    """Rest points (skeleton space), triangles, sparse influences and the :class:`MeshPart` of one mesh."""
    Usd, UsdGeom, UsdSkel, _, _, _ = pxr_modules()
    prim = query.GetPrim()
    where = str(prim.GetPath())
    mesh = UsdGeom.Mesh(prim)
    t0 = Usd.TimeCode.EarliestTime()
    P = values(mesh.GetPointsAttr().Get(t0), np.float64, path, f"{where}.points", 3)
    if not len(P):
        raise InputError("the mesh has no points", source=path, field=f"{where}.points", fix="re-export the mesh")
    if not np.isfinite(P).all():
        raise InputError("points contain NaN or inf", source=path, field=f"{where}.points", fix="re-export the mesh")
    counts = values(mesh.GetFaceVertexCountsAttr().Get(t0), np.int64, path, f"{where}.faceVertexCounts")
    indices = values(mesh.GetFaceVertexIndicesAttr().Get(t0), np.int64, path, f"{where}.faceVertexIndices")
    if counts.sum() != len(indices) or (counts < 0).any():
        raise InputError(f"faceVertexCounts add up to {int(counts.sum())} but there are {len(indices)} "
                         "faceVertexIndices", source=path, field=f"{where}.faceVertexCounts", fix="re-export the mesh")
    if len(indices) and (indices.min() < 0 or indices.max() >= len(P)):
        raise InputError(f"faceVertexIndices name points outside 0..{len(P) - 1}", source=path,
                         field=f"{where}.faceVertexIndices", fix="re-export the mesh")
    holes = values(mesh.GetHoleIndicesAttr().Get(t0), np.int64, path, f"{where}.holeIndices")
    left = mesh.GetOrientationAttr().Get() == UsdGeom.Tokens.leftHanded
    F, polygon, corners = triangulate(counts, indices, holes, left)
    G = to_columns(values([query.GetGeomBindTransform()], np.float64, path,
                          f"{where}.primvars:skel:geomBindTransform", 16))[0]
    if not np.isfinite(G).all() or abs(np.linalg.det(G[:3, :3])) < 1e-300:
        raise InputError("geomBindTransform is singular or not finite", source=path,
                         field=f"{where}.primvars:skel:geomBindTransform", fix="re-export the skin binding")
    V = P @ G[:3, :3].T + G[:3, 3]
    rows, cols, vals, k, rigid = _influences(query, prim, len(P), joint_index, skel_joints, path)
    blend = _tokens(UsdSkel.BindingAPI(prim).GetBlendShapesAttr().Get(), path, f"{where}.skel:blendShapes")
    part = MeshPart(where, start, len(P), face_start, polygon, corners, G, k, rigid, blend)
    return V, F, (rows + start, cols, vals), part


def _influences(query, prim, m: int, joint_index: dict[str, int], skel_joints: list[str], path: Path):
    """``(rows, cols, values, elementSize, rigid)`` of a mesh's joint influences, in skeleton joint order."""
    _, _, UsdSkel, _, _, _ = pxr_modules()
    where = str(prim.GetPath())
    api = UsdSkel.BindingAPI(prim)
    ji_pv, jw_pv = api.GetJointIndicesPrimvar(), api.GetJointWeightsPrimvar()
    if not ji_pv.HasValue() or not jw_pv.HasValue():
        missing = JOINT_INDICES if not ji_pv.HasValue() else JOINT_WEIGHTS
        raise InputError("the mesh is bound to a skeleton but has no joint influences", source=path,
                         field=f"{where}.{missing}", fix="author jointIndices and jointWeights (UsdSkelBindingAPI)")
    ji = values(ji_pv.ComputeFlattened(), np.int64, path, f"{where}.{JOINT_INDICES}")
    jw = values(jw_pv.ComputeFlattened(), np.float64, path, f"{where}.{JOINT_WEIGHTS}")
    k, kw = int(ji_pv.GetElementSize()), int(jw_pv.GetElementSize())
    if k != kw:
        raise InputError(f"jointIndices have elementSize {k}, jointWeights {kw}", source=path,
                         field=f"{where}.{JOINT_WEIGHTS}:elementSize", fix="author the same elementSize on both")
    if not 1 <= k <= MAX_ELEMENT_SIZE:
        raise InputError(f"elementSize {k} is outside 1..{MAX_ELEMENT_SIZE}", source=path,
                         field=f"{where}.{JOINT_INDICES}:elementSize", fix="author the influences per point")
    if len(ji) != len(jw):
        raise InputError(f"{len(ji)} jointIndices but {len(jw)} jointWeights", source=path,
                         field=f"{where}.{JOINT_WEIGHTS}", fix="author one weight per joint index")
    interp = ji_pv.GetInterpolation()
    rigid = interp == "constant"
    expected = k if rigid else m * k
    if interp not in ("vertex", "constant") or len(ji) != expected:
        hint = f"; elementSize {len(ji) // m} would fit" if not rigid and m and len(ji) % m == 0 else ""
        raise InputError(f"{len(ji)} values, elementSize {k}, '{interp}': not {m} points{hint}", source=path,
                         field=f"{where}.{JOINT_INDICES}:elementSize",
                         fix="author elementSize = influences per point, interpolation vertex or constant")
    if not np.isfinite(jw).all():
        bad = int(np.flatnonzero(~np.isfinite(jw))[0])
        raise InputError(f"jointWeights contain NaN or inf (point {bad // k if not rigid else 0})", source=path,
                         field=f"{where}.{JOINT_WEIGHTS}", fix="re-export the skin weights")
    authored = query.GetJointOrder()
    if authored is not None:
        order = _tokens(authored, path, f"{where}.skel:joints")
        unknown = [j for j in order if j not in joint_index]
        if unknown:
            raise InputError(f"skel:joints names {len(unknown)} joints the skeleton lacks ({brief(unknown[0])})",
                             source=path, field=f"{where}.skel:joints",
                             fix=closest(unknown[0], skel_joints) if skel_joints else "list the skeleton's joints")
        mapping = np.array([joint_index[j] for j in order], np.int64)
    else:
        mapping = np.arange(len(skel_joints), dtype=np.int64)
    nz = jw != 0
    if nz.any() and (ji[nz].min() < 0 or ji[nz].max() >= len(mapping)):
        bad = int(ji[nz].max() if ji[nz].max() >= len(mapping) else ji[nz].min())
        raise InputError(f"jointIndices name joint {bad} but the mesh's joint order has {len(mapping)} joints",
                         source=path, field=f"{where}.{JOINT_INDICES}", fix="re-export the skin weights")
    slot = np.flatnonzero(nz)
    if rigid:
        rows = np.repeat(np.arange(m), len(slot))
        cols = np.tile(mapping[ji[slot]], m)
        vals = np.tile(jw[slot], m)
    else:
        rows, cols, vals = slot // k, mapping[ji[slot]], jw[slot]
    return rows, cols, vals, k, rigid


# --------------------------------------------------------------------------- animation


def _animation_query(cache, skel_query, animation, stage, path: Path):
    """The AnimQuery to sample and its prim path: the skeleton's ``skel:animationSource``, or ``animation``."""
    Usd, _, UsdSkel, _, _, _ = pxr_modules()
    if animation is None:
        q = skel_query.GetAnimQuery()
        return (q, str(q.GetPrim().GetPath())) if q else (None, None)
    anims = [p for p in stage.Traverse() if p.IsA(UsdSkel.Animation)]
    hits = [p for p in anims if str(p.GetPath()) == str(animation) or p.GetName() == str(animation)]
    if not hits:
        raise InputError(f"no SkelAnimation {brief(animation)}", source=path, field="animation",
                         fix=closest(str(animation), [str(p.GetPath()) for p in anims]) if anims
                         else "the file has no SkelAnimation; leave 'animation' out for the rest pose")
    q = cache.GetAnimQuery(hits[0])
    if not q:
        raise InputError(f"SkelAnimation {hits[0].GetPath()} cannot be read", source=path, field="animation",
                         fix="re-export the animation")
    return q, str(hits[0].GetPath())


def sample_time_codes(anim_query, stage, fps: float, times, path: Path) -> np.ndarray:
    """USD time codes of the frames: ``t0 + f * timeCodesPerSecond / fps`` over the clip, or at ``times`` seconds.

    ``t0`` is the animation's first time sample (its first key); a clip
    without time samples is one frame at its default value.
    """
    tcps = time_codes_per_second(stage)
    keys = np.array(anim_query.GetJointTransformTimeSamples(), np.float64) if anim_query else np.zeros(0)
    t0 = float(keys.min()) if len(keys) else 0.0
    if times is not None:
        t = np.asarray(times, dtype=np.float64).reshape(-1)
        if not len(t) or not np.isfinite(t).all() or (t < 0).any():
            raise InputError("times must be a non-empty list of non-negative seconds", source=path, field="times",
                             fix="give e.g. times: [0, 0.5, 1.25]")
        return t0 + t * tcps
    if not len(keys):
        return np.array([np.nan])       # one frame at the default time
    duration = (float(keys.max()) - t0) / tcps
    frames = np.floor(duration * fps + 1e-3) + 1
    if frames > MAX_FRAMES:
        raise InputError(f"{duration:.6g} s at {fps:g} fps is {frames:.6g} frames, more than {MAX_FRAMES}",
                         source=path, field="fps", fix="sample fewer frames: a lower fps or 'times:'")
    return t0 + np.arange(int(frames)) * tcps / fps


def skinning_transforms(anim_query, joints: list[str], parents: np.ndarray, bind: np.ndarray, rest: np.ndarray,
                        time_codes: np.ndarray, path: Path) -> np.ndarray:
    """(p, n, 3, 4) ``T_j = S_j B_j^{-1}`` at each time code (module docstring).

    Local transforms come from the animation for the joints it names (by
    token, in any order) and from ``rest`` for the others; NaN time codes
    mean the default (unanimated) value.
    """
    Usd = pxr_modules()[0]
    n = len(joints)
    index = {j: i for i, j in enumerate(joints)}
    inv_bind = np.linalg.inv(bind)
    out = np.empty((len(time_codes), n, 3, 4))
    if anim_query:
        anim_joints = _tokens(anim_query.GetJointOrder(), path, "animation.joints")
        src = np.array([i for i, j in enumerate(anim_joints) if j in index], np.int64)
        dst = np.array([index[anim_joints[i]] for i in src], np.int64)
    for f, tc in enumerate(time_codes):
        L = rest.copy()
        if anim_query:
            t = Usd.TimeCode.Default() if np.isnan(tc) else Usd.TimeCode(float(tc))
            with diagnostics() as found:
                A = anim_query.ComputeJointLocalTransforms(t)
            if found or A is None or len(A) != len(anim_joints):
                raise InputError(f"the animation's translations/rotations/scales do not hold one value per joint "
                                 f"({len(anim_joints)}) at time {tc:g}", source=path, field="animation",
                                 fix="author translations, rotations and scales for every joint the animation lists")
            A = to_columns(A)
            if not np.isfinite(A).all():
                raise InputError(f"the animation has NaN or inf at time {tc:g}", source=path, field="animation",
                                 fix="re-export the animation")
            L[dst] = A[src]
        S = np.empty_like(L)
        for j in range(n):     # UsdSkel.Topology.Validate: every parent comes before its children
            S[j] = L[j] if parents[j] < 0 else S[parents[j]] @ L[j]
        out[f] = (S @ inv_bind)[:, :3, :]
    return out


# --------------------------------------------------------------------------- levels of detail


def select_lod(stage, lod: int, path: Path) -> None:
    """Select variant ``LOD<lod>`` of every ``LOD`` variant set (in the session layer: the file is untouched)."""
    Usd = pxr_modules()[0]
    found = []
    with Usd.EditContext(stage, stage.GetSessionLayer()):
        for prim in list(stage.Traverse()):
            vsets = prim.GetVariantSets()
            if vsets.HasVariantSet("LOD"):
                names = vsets.GetVariantSet("LOD").GetVariantNames()
                found += names
                if f"LOD{lod}" not in names:
                    raise InputError(f"{prim.GetPath()} has no variant LOD{lod} (it has {', '.join(names)})",
                                     source=path, field="lod", fix="choose one of its LOD variants")
                vsets.GetVariantSet("LOD").SetVariantSelection(f"LOD{lod}")
    if not found and not any(_lod_roots(stage)):
        raise InputError("the file has no levels of detail (no LOD variant set, no UsdLod root)", source=path,
                         field="lod", fix="leave 'lod' out")


def _lod_roots(stage):
    from pxr import UsdLod

    return [p for p in stage.Traverse() if p.HasAPI(UsdLod.RootAPI)]


def unselected_lod_items(stage, lod: int | None) -> list:
    """Paths of the ``UsdLod`` items not selected (``lod``, else each root's ``lod:default:index``)."""
    try:
        from pxr import UsdLod
    except ImportError:     # usd-core before 26.x has no UsdLod schema
        return []
    out = []
    for root in _lod_roots(stage):
        items = list(root.GetChildren())
        pick = lod if lod is not None else UsdLod.RootAPI(root).GetLodDefaultIndexAttr().Get()
        pick = min(max(int(pick or 0), 0), len(items) - 1) if items else 0
        out += [c.GetPath() for i, c in enumerate(items) if i != pick]
    return out


# --------------------------------------------------------------------------- reader


def read_usd_skin(path, *, skeleton=None, mesh=None, animation=None, fps: float = 30.0, times=None,
                  normalize: bool = True, lod: int | None = None) -> UsdSkin:
    """Read a UsdSkel character: merged meshes, joints as handles, weights and sampled poses.

    Parameters
    ----------
    path : path-like
        ``.usd``, ``.usda``, ``.usdc`` or ``.usdz``.
    skeleton : str, optional
        Path or name of the ``Skeleton`` whose meshes to read, when several have meshes.
    mesh : str, optional
        Read only this ``Mesh`` (path or name); default every mesh bound to the skeleton, in
        traversal order.
    animation : str, optional
        Path or name of a ``SkelAnimation`` to sample (any animation over the skeleton's joints);
        default the skeleton's ``skel:animationSource`` (none: the rest pose as the only frame).
    fps : float
        Frame f is the pose at ``t0 + f * timeCodesPerSecond / fps`` (``t0`` the clip's first key),
        for ``f = 0 .. floor(duration * fps + 0.001)``.
    times : sequence of float, optional
        Sample at these times (seconds after ``t0``) instead.
    normalize : bool
        Divide each point's weights by their sum (UsdSkel itself does not normalise); otherwise
        rows must sum to 1 within 1e-6.
    lod : int, optional
        Read level ``lod`` of a file with levels of detail: variant ``LOD<lod>`` of every ``LOD``
        variant set, and item ``lod`` of every ``UsdLod`` root (default: the authored selection and
        each root's ``lod:default:index``; the other items are never merged in).

    Returns
    -------
    UsdSkin
    """
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"fps {fps} is not a positive number", source=path, field="fps", fix="give e.g. fps: 30")
    from pxr import Tf

    path = Path(path)
    with usd_stage.memory_budget(path):
        try:
            return _read_usd_skin(path, skeleton, mesh, animation, fps, times, normalize, lod)
        except Tf.ErrorException as e:
            why = usd_stage.tf_message(e)
            raise InputError(f"USD cannot read a value ({why})", source=path, field="layer",
                             fix="re-export the file; check it with usdchecker") from None


def _read_usd_skin(path: Path, skeleton, mesh, animation, fps, times, normalize, lod) -> UsdSkin:
    stage = open_stage(path)
    Usd, UsdGeom, UsdSkel, _, _, _ = pxr_modules()
    if lod is not None:
        select_lod(stage, int(lod), path)
    hidden = unselected_lod_items(stage, lod)
    cache, bindings = skel_bindings(stage, path)
    binding = _choose_binding(bindings, skeleton, mesh, path)
    skel_prim = binding.GetSkeleton().GetPrim()
    where = str(skel_prim.GetPath())
    check_joints(binding.GetSkeleton(), path, where)
    with diagnostics():
        skel_query = cache.GetSkelQuery(binding.GetSkeleton())
    if not skel_query:
        raise InputError("the skeleton cannot be read", source=path, field=where, fix="re-export the skeleton")
    joints, parents, bind, rest = _skeleton(skel_query, path, where)
    index = {j: i for i, j in enumerate(joints)}
    Vs, Fs, entries, parts, notes = [], [], [], [], []
    start = face_start = 0
    for q in binding.GetSkinningTargets():
        prim = q.GetPrim()
        if (mesh is not None and not _matches(prim, mesh)) or any(prim.GetPath().HasPrefix(h) for h in hidden):
            continue
        if not prim.IsA(UsdGeom.Mesh):
            notes.append(f"{prim.GetPath()} ({prim.GetTypeName()}) is skinned but not a Mesh: left out")
            continue
        V, F, entry, part = _mesh_part(q, index, joints, path, start, face_start)
        Vs.append(V)
        Fs.append(F + start)
        entries.append(entry)
        parts.append(part)
        if part.blend_shapes:
            notes.append(f"{part.path} has {len(part.blend_shapes)} blend shapes: kept in written files, "
                         "not part of the linear blend fit")
        start += part.count
        face_start += part.n_triangles
    if not parts:
        raise InputError("no Mesh is bound to the skeleton", source=path, field=where, fix="give a skinned Mesh")
    V = np.concatenate(Vs)
    F = np.concatenate(Fs)
    rows, cols, vals = (np.concatenate([e[i] for e in entries]) for i in range(3))
    A = sp.csr_matrix((vals, (rows, cols)), shape=(len(V), len(joints)))
    A.sum_duplicates()
    weights = validate_weights(A, len(V), n_handles=len(joints), normalize=normalize,
                               source=f"{path} ({JOINT_WEIGHTS})")
    mesh_obj = Mesh(V, F, source=str(path))
    handles = _handles(joints, parents, bind, path)
    anim_query, anim_path = _animation_query(cache, skel_query, animation, stage, path)
    codes = sample_time_codes(anim_query, stage, fps, times, path)
    T = skinning_transforms(anim_query, joints, parents, bind, rest, codes, path)
    label = str(path) if anim_path is None else f"{path} animation {anim_path}"
    poses = Poses(T, np.arange(len(codes)), source=label)
    root = str(binding.GetSkeleton().GetPrim().GetPath())
    for r in (p for p in stage.Traverse() if p.IsA(UsdSkel.Root)):
        if parts[0].path.startswith(str(r.GetPath()) + "/"):
            root = str(r.GetPath())
    return UsdSkin(path, stage, root, where, joints, parts, mesh_obj, handles, weights, poses, bind, anim_path,
                   float(fps), codes, notes)


def usd_skin_of_stage(stage, mesh: Mesh, handles: Handles, weights, poses, path) -> UsdSkin:
    """The :class:`UsdSkin` of a stage :func:`rigslim.io.usd.export.build_stage` just made from these inputs.

    Lets :func:`rigslim.io.usd.write.write_usd` add levels to an exported character: its one mesh is
    ``mesh`` itself (triangles in order, geomBindTransform the identity).
    """
    _, UsdGeom, UsdSkel, _, _, _ = pxr_modules()
    root = stage.GetDefaultPrim()
    skel = next(p for p in stage.Traverse() if p.IsA(UsdSkel.Skeleton))
    geom = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    t = mesh.n_faces
    part = MeshPart(str(geom.GetPath()), 0, mesh.n_vertices, 0, np.arange(t, dtype=np.int64),
                    np.arange(3 * t, dtype=np.int64).reshape(t, 3), np.eye(4), 0)
    joints = [str(j) for j in UsdSkel.Skeleton(skel).GetJointsAttr().Get()]
    bind = to_columns(UsdSkel.Skeleton(skel).GetBindTransformsAttr().Get())
    frames = len(poses) if poses is not None else 1
    return UsdSkin(Path(f"{path} (in memory)"), stage, str(root.GetPath()), str(skel.GetPath()), joints, [part],
                   mesh, handles, weights, poses, bind, None, 30.0, np.arange(frames, dtype=np.float64))


def sibling_clips(skin: UsdSkin) -> tuple[list[tuple[str, Poses]], list[str]]:
    """The other clips of a character: every ``SkelAnimation`` beside the one ``skin`` sampled.

    rigslim writes a character's clips as siblings of the bound ``SkelAnimation`` (docs/usd.md); each
    sibling whose joints are joints of ``skin``'s skeleton is sampled as :func:`read_usd_skin` samples a
    clip: at ``skin.fps`` from its first key to its last, joints it does not name at rest.

    Parameters
    ----------
    skin : UsdSkin
        A character read by :func:`read_usd_skin` (its stage still open).

    Returns
    -------
    clips : list of (str, Poses)
        Each sibling's prim name and its poses (its own frame count), in the stage's order; empty when
        ``skin`` sampled no animation.
    notes : list of str
        The siblings left out, each with why (joints of another skeleton, values that cannot be read).
    """
    if skin.animation is None:
        return [], []
    from pxr import Tf

    Usd, _, UsdSkel, _, _, _ = pxr_modules()
    stage: Any = skin.stage
    bound = stage.GetPrimAtPath(skin.animation)
    skel_prim = stage.GetPrimAtPath(skin.skeleton)
    if not bound or not skel_prim:
        return [], []
    cache = UsdSkel.Cache()
    with diagnostics():
        cache.Populate(UsdSkel.Root(stage.GetPrimAtPath(skin.root)), Usd.PrimDefaultPredicate)
        skel_query = cache.GetSkelQuery(UsdSkel.Skeleton(skel_prim))
    joints, parents, bind, rest = _skeleton(skel_query, skin.path, skin.skeleton)
    known = set(joints)
    clips, notes = [], []
    for prim in bound.GetParent().GetChildren():
        if prim == bound or not prim.IsA(UsdSkel.Animation):
            continue
        try:
            own = [str(j) for j in (UsdSkel.Animation(prim).GetJointsAttr().Get() or [])]
            if not own or not set(own) <= known:
                notes.append(f"SkelAnimation {prim.GetPath()} animates joints the skeleton {skin.skeleton} "
                             "lacks: left out")
                continue
            query = cache.GetAnimQuery(prim)
            codes = sample_time_codes(query, stage, skin.fps, None, skin.path)
            T = skinning_transforms(query, joints, parents, bind, rest, codes, skin.path)
        except (InputError, Tf.ErrorException) as e:
            why = e.problem if isinstance(e, InputError) else usd_stage.tf_message(e)
            notes.append(f"SkelAnimation {prim.GetPath()} cannot be read ({why}): left out")
            continue
        clips.append((prim.GetName(), Poses(T, np.arange(len(codes)), source=f"{skin.path} animation "
                                                                              f"{prim.GetPath()}")))
    return clips, notes
