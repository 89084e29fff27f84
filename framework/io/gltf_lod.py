"""Levels of detail of a skinned glTF: per-primitive meshes with every vertex attribute, and MSFT_lod views.

The decimators work on the welded mesh of every skinned primitive
(:func:`rigslim.io.gltf.read_gltf_skin` with ``weld=True``): one vertex per
position, so that the surface is connected. A glTF file, however, splits a
position into several file vertices ("wedges", Hoppe 1999) wherever an
attribute (UV, colour, normal) or the primitive (material) changes. This
module maps a :class:`rigslim.hierarchy.ProgressiveHierarchy` of the welded
mesh back onto the file's primitives:

- :func:`seam_vertices` marks the welded vertices where a UV (``TEXCOORD_n``),
  ``COLOR_n``, a custom attribute, a morph target or the primitive differs
  between wedges. The decimators lock them (no collapse moves them), so UV
  seams and material boundaries are kept exactly. ``NORMAL`` and
  ``TANGENT`` do not lock a vertex: flat-shaded exports split every vertex
  by its normals, and locking those would forbid every collapse.
- :func:`level_primitives` gives, for one level, one primitive per source
  primitive: its faces (the source faces that survive, in order), positions
  and weights of the level, and every attribute and morph target. A vertex
  the level did not move keeps its file vertex (all its attributes, byte
  for byte after decoding); a vertex made by collapses gets the attributes
  interpolated along its collapses (below).
- :func:`level_document` is the view of a written file at one level (each
  node's mesh replaced by its ``MSFT_lod`` level node's), used by
  ``rigslim compare --level`` and ``rigslim lod --split``.

Attributes along collapses: collapse ``i`` merges a and b into ``c = m + i``
at position ``v_c``. With ``t = clamp(((v_c - v_a) . (v_b - v_a)) / |v_b - v_a|^2, 0, 1)``
(the projection of the new position onto the edge), every attribute is
``x_c = (1 - t) x_a + t x_b``; NORMAL is renormalised, TANGENT's xyz too
(its w, the handedness, is the sign of the interpolated w). An original
vertex's value for a primitive is the mean of its wedges in that primitive
(only normals and tangents can differ there, since other differences lock
the vertex).
"""

from __future__ import annotations

import copy
from dataclasses import dataclass, field

import numpy as np

from rigslim.errors import InputError, StepError
from rigslim.io.gltf import GltfDocument, GltfSkin, _triangles, read_accessor, skinning_sets

#: Attributes that never lock a vertex (hard edges are interpolated, not kept).
SOFT_ATTRIBUTES = ("NORMAL", "TANGENT")


@dataclass
class PrimitiveData:
    """The carried attributes of one source primitive, decoded to float64.

    Attributes
    ----------
    index : int
        Position in ``GltfSkin.slices``.
    attributes : dict name -> (count, c) array
        Every attribute but POSITION, JOINTS_n and WEIGHTS_n.
    targets : list of dict name -> (count, c) array
        Morph target deltas (POSITION, NORMAL, TANGENT, ...).
    faces : (f, 3) int64 array
        Triangles in the primitive's own vertex numbering.
    """

    index: int
    count: int
    attributes: dict[str, np.ndarray]
    targets: list[dict[str, np.ndarray]] = field(default_factory=list)
    faces: np.ndarray | None = None

    def columns(self) -> list[tuple[str, int]]:
        """``(key, width)`` of every carried column block: attributes, then ``"t{j}/{name}"`` target blocks."""
        out = [(k, v.shape[1]) for k, v in self.attributes.items()]
        for j, t in enumerate(self.targets):
            out += [(f"t{j}/{k}", v.shape[1]) for k, v in t.items()]
        return out

    def matrix(self) -> np.ndarray:
        """(count, C) the column blocks side by side, in :meth:`columns` order."""
        blocks = list(self.attributes.values()) + [v for t in self.targets for v in t.values()]
        return np.hstack(blocks) if blocks else np.zeros((self.count, 0))


def primitive_data(skin: GltfSkin) -> list[PrimitiveData]:
    """Decode the carried attributes, morph targets and triangles of every primitive the skin reader used."""
    doc, js = skin.document, skin.document.json
    out = []
    for i, sl in enumerate(skin.slices):
        prim = js["meshes"][sl.mesh]["primitives"][sl.primitive]
        attrs = prim.get("attributes", {})
        sets = skinning_sets(attrs)
        skip = {"POSITION"} | {f"JOINTS_{s}" for s in sets} | {f"WEIGHTS_{s}" for s in sets}
        values = {}
        for name in sorted(attrs):
            if name in skip:
                continue
            a = np.asarray(read_accessor(doc, attrs[name]), np.float64).reshape(sl.count, -1)
            if len(a) != sl.count:
                raise InputError(f"attribute {name} has {len(a)} elements, POSITION {sl.count}", source=doc.path,
                                 field=f"meshes[{sl.mesh}].primitives[{sl.primitive}].attributes.{name}",
                                 fix="re-export the file")
            values[name] = a
        targets = []
        for _j, t in enumerate(prim.get("targets", [])):
            targets.append({name: np.asarray(read_accessor(doc, t[name]), np.float64).reshape(sl.count, -1)
                            for name in sorted(t)})
        idx = (np.asarray(read_accessor(doc, prim["indices"]), np.int64) if "indices" in prim
               else np.arange(sl.count, dtype=np.int64))
        out.append(PrimitiveData(i, sl.count, values, targets, _triangles(prim.get("mode", 4), idx)))
    return out


def _vertex_map(skin: GltfSkin) -> np.ndarray:
    total = sum(s.count for s in skin.slices)
    return np.arange(total) if skin.vertex_map is None else np.asarray(skin.vertex_map, np.int64)


def seam_vertices(skin: GltfSkin, data: list[PrimitiveData] | None = None) -> np.ndarray:
    """Welded vertices whose wedges differ in primitive, UV, colour, custom attribute or morph target.

    Returns
    -------
    (m,) bool array over ``skin.mesh`` vertices
        True where two file vertices at this position belong to different
        primitives or carry different values of any attribute except
        NORMAL/TANGENT (or different morph target deltas).
    """
    data = primitive_data(skin) if data is None else data
    vmap = _vertex_map(skin)
    m = skin.mesh.n_vertices
    keys = []
    for d, sl in zip(data, skin.slices, strict=False):
        cols = [v for k, v in d.attributes.items() if k not in SOFT_ATTRIBUTES]
        cols += [v for t in d.targets for v in t.values()]
        keys.append((sl, np.hstack(cols) if cols else np.zeros((sl.count, 0))))
    width = max(k.shape[1] for _, k in keys)
    rows = []
    for i, (sl, k) in enumerate(keys):
        pad = np.full((sl.count, width - k.shape[1]), np.nan)
        w = vmap[sl.start:sl.start + sl.count]
        rows.append(np.hstack([w[:, None].astype(float), np.full((sl.count, 1), float(i)), k, pad]))
    R = np.nan_to_num(np.vstack(rows), nan=-1e300)
    uniq = np.unique(R, axis=0)
    counts = np.bincount(uniq[:, 0].astype(np.int64), minlength=m)
    return counts > 1


def input_weights_normalized(skin: GltfSkin, tolerance: float = 5e-4) -> bool:
    """Whether every file vertex's decoded weights (all sets) sum to one within ``tolerance``.

    Checked as ``|sum - 1| <= tolerance`` after decoding: a normalized byte
    code is 1/255 = 3.9e-3, so an integer file off by one code fails, while
    float32 round-off passes. Files that fail get their weights rewritten
    (normalised) by the glTF writer.
    """
    doc, js = skin.document, skin.document.json
    for sl in skin.slices:
        attrs = js["meshes"][sl.mesh]["primitives"][sl.primitive]["attributes"]
        total = np.zeros(sl.count)
        for s in skinning_sets(attrs):
            total += np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"]), np.float64).reshape(sl.count, -1).sum(1)
        if sl.count and np.abs(total - 1.0).max() > tolerance:
            return False
    return True


# --------------------------------------------------------------------------- levels


@dataclass
class LevelPrimitive:
    """One primitive of one level, ready to be written.

    Attributes
    ----------
    slice_index : int
        The source primitive (``GltfSkin.slices`` index).
    positions : (v, 3), faces : (f, 3)
    weight_rows : (v,) int
        Row of the level's ``weights`` (``SimplifiedLevel.weights``) of each vertex.
    attributes : dict name -> (v, c) array
    targets : list of dict name -> (v, c) array
    """

    slice_index: int
    positions: np.ndarray
    faces: np.ndarray
    weight_rows: np.ndarray
    attributes: dict[str, np.ndarray]
    targets: list[dict[str, np.ndarray]]


def welded_faces(skin: GltfSkin, data: list[PrimitiveData]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per primitive: the welded faces the reader kept and their file-vertex corners (global file ids)."""
    vmap = _vertex_map(skin)
    out = []
    for d, sl in zip(data, skin.slices, strict=False):
        Ff = d.faces + sl.start
        Fw = vmap[Ff]
        keep = (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 2] != Fw[:, 0])
        out.append((Fw[keep], Ff[keep]))
    F = np.concatenate([w for w, _ in out]) if out else np.zeros((0, 3), np.int64)
    if F.shape != skin.mesh.F.shape or not np.array_equal(F, skin.mesh.F):
        raise StepError("the simplified mesh is not the one read from this glTF file's skinned primitives",
                        field="levels", fix="simplify the mesh read from this file (no step may replace it)")
    return out


def _normalise_blocks(X: np.ndarray, columns: list[tuple[str, int]]) -> None:
    """Renormalise NORMAL (and target-free TANGENT xyz, w = sign) column blocks of X in place."""
    c = 0
    for key, width in columns:
        if key == "NORMAL" and width == 3:
            n = np.linalg.norm(X[:, c:c + 3], axis=1, keepdims=True)
            X[:, c:c + 3] = np.where(n > 0, X[:, c:c + 3] / np.where(n > 0, n, 1), [0.0, 0.0, 1.0])
        elif key == "TANGENT" and width == 4:
            n = np.linalg.norm(X[:, c:c + 3], axis=1, keepdims=True)
            X[:, c:c + 3] = np.where(n > 0, X[:, c:c + 3] / np.where(n > 0, n, 1), [1.0, 0.0, 0.0])
            X[:, c + 3] = np.where(X[:, c + 3] < 0, -1.0, 1.0)
        c += width


def collapse_parameters(hier) -> np.ndarray:
    """``t_i``: where collapse i's new vertex projects onto its edge (0 at a, 1 at b), clamped to [0, 1]."""
    m = hier.n_original
    if not hier.n_collapses:
        return np.zeros(0)
    a, b = hier.collapses[:, 0], hier.collapses[:, 1]
    va, vb, vc = hier.V[a], hier.V[b], hier.V[m + np.arange(hier.n_collapses)]
    e = vb - va
    den = (e * e).sum(axis=1)
    t = np.where(den > 0, ((vc - va) * e).sum(axis=1) / np.where(den > 0, den, 1.0), 0.5)
    return np.clip(t, 0.0, 1.0)


def hierarchy_attributes(skin: GltfSkin, hier, data: list[PrimitiveData]) -> list[np.ndarray]:
    """Per primitive, the (N, C) carried attributes of every hierarchy vertex (NaN where it has no wedge).

    Rows ``0..m-1`` hold the mean of each welded vertex's wedges in that
    primitive; row ``m + i`` interpolates collapse i's endpoints with
    :func:`collapse_parameters` (an endpoint without a value gives the other's).
    """
    vmap = _vertex_map(skin)
    m, N = hier.n_original, len(hier.V)
    blocks, widths = [], []
    for d, sl in zip(data, skin.slices, strict=False):
        X = d.matrix()
        w = vmap[sl.start:sl.start + sl.count]
        S = np.zeros((m, X.shape[1]))
        np.add.at(S, w, X)
        cnt = np.bincount(w, minlength=m).astype(float)
        A = np.full((N, X.shape[1]), np.nan)
        has = cnt > 0
        A[:m][has] = S[has] / cnt[has, None]
        _normalise_blocks(A[:m], d.columns())
        blocks.append(A)
        widths.append(X.shape[1])
    if not hier.n_collapses:
        return blocks
    A = np.hstack(blocks)
    t = collapse_parameters(hier)
    col = hier.collapses
    for i in range(hier.n_collapses):
        xa, xb = A[col[i, 0]], A[col[i, 1]]
        x = (1.0 - t[i]) * xa + t[i] * xb
        A[m + i] = np.where(np.isnan(xa), xb, np.where(np.isnan(xb), xa, x))
    out, c = [], 0
    for d, w in zip(data, widths, strict=False):
        B = A[:, c:c + w].copy()
        _normalise_blocks(B[m:], d.columns())
        out.append(B)
        c += w
    return out


def closest_point_barycentric(p: np.ndarray, a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Barycentric coordinates (n, 3) of the closest point of triangle (a, b, c) to p, row by row.

    Ericson, Real-Time Collision Detection (2005), sec. 5.1.5: the Voronoi regions of the
    vertices, then the edges, then the face; degenerate triangles fall back to the nearest vertex.
    """
    ab, ac, ap = b - a, c - a, p - a
    d1, d2 = (ab * ap).sum(1), (ac * ap).sum(1)
    bp = p - b
    d3, d4 = (ab * bp).sum(1), (ac * bp).sum(1)
    cp = p - c
    d5, d6 = (ab * cp).sum(1), (ac * cp).sum(1)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    out = np.empty((len(p), 3))
    den = va + vb + vc
    safe = np.where(np.abs(den) > 0, den, 1.0)
    v, w = vb / safe, vc / safe
    out[:] = np.stack([1 - v - w, v, w], 1)                                           # inside the face
    tiny = np.finfo(float).tiny

    def put(mask, bary):
        out[mask] = bary[mask]

    e_bc = (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)
    t = (d4 - d3) / np.maximum((d4 - d3) + (d5 - d6), tiny)
    put(e_bc, np.stack([0 * t, 1 - t, t], 1))
    e_ac = (vb <= 0) & (d2 >= 0) & (d6 <= 0)
    t = d2 / np.maximum(d2 - d6, tiny)
    put(e_ac, np.stack([1 - t, 0 * t, t], 1))
    e_ab = (vc <= 0) & (d1 >= 0) & (d3 <= 0)
    t = d1 / np.maximum(d1 - d3, tiny)
    put(e_ab, np.stack([1 - t, t, 0 * t], 1))
    one = np.ones(len(p))
    zero = np.zeros(len(p))
    put((d6 >= 0) & (d5 <= d6), np.stack([zero, zero, one], 1))
    put((d3 >= 0) & (d4 <= d3), np.stack([zero, one, zero], 1))
    put((d1 <= 0) & (d2 <= 0), np.stack([one, zero, zero], 1))
    bad = ~np.isfinite(out).all(axis=1) | (np.abs(den) <= 0) & ~(e_bc | e_ac | e_ab)
    if bad.any():                                                                     # degenerate: nearest corner
        dist = np.stack([np.linalg.norm(q[bad] - p[bad], axis=1) for q in (a, b, c)], 1)
        out[bad] = np.eye(3)[np.argmin(dist, axis=1)]
    return out


def level_representatives(hier, vertex_ids: np.ndarray) -> np.ndarray:
    """(m,) the level vertex (hierarchy id) that stands for each original vertex (-1 if none).

    Each original vertex walks up its collapses (``parent[a] = parent[b] = m + i``)
    until it reaches a vertex of the level.
    """
    m, N = hier.n_original, len(hier.V)
    parent = np.arange(N, dtype=np.int64)
    parent[hier.collapses[:, 0]] = m + np.arange(hier.n_collapses)
    parent[hier.collapses[:, 1]] = m + np.arange(hier.n_collapses)
    present = np.zeros(N, bool)
    present[np.asarray(vertex_ids, np.int64)] = True
    cur = np.arange(m, dtype=np.int64)
    while True:
        move = ~present[cur] & (parent[cur] != cur)
        if not move.any():
            break
        cur[move] = parent[cur[move]]
    return np.where(present[cur], cur, -1)


def projected_attributes(points: np.ndarray, owners: np.ndarray, V: np.ndarray, Fw: np.ndarray, Ff: np.ndarray,
                         corner_keys: np.ndarray, X: np.ndarray, start: int) -> np.ndarray:
    """Attributes of new level vertices by projection onto the source faces they replace.

    Parameters
    ----------
    points : (q, 3) rest positions of the new vertices; owners : (q,) their keys (hierarchy id and chart).
    V : (m, 3) welded rest positions; Fw, Ff : (f, 3) a primitive's faces (welded / file corners).
    corner_keys : (f, 3) the key of the level vertex each corner maps to (hierarchy id and the face's
        chart, as ``owners``); X : (count, C) the primitive's file attributes.

    Returns
    -------
    (q, C) array (NaN where a vertex has no face in this primitive)

    Notes
    -----
    The candidates of new vertex c in chart k are the source faces of chart k
    with a corner that c replaced: the patch c stands for on that side of a
    seam (a vertex made by collapses along a seam has one value per side). Its value is
    the barycentric interpolation of the file corners' attributes at the
    closest point of the closest candidate face (Cignoni et al. 1998's
    attribute resampling, restricted to the patch so that it never crosses a
    locked UV seam).
    """
    out = np.full((len(points), X.shape[1]), np.nan)
    if not len(points) or not len(Fw):
        return out
    slot = {int(h): i for i, h in enumerate(owners)}
    R = corner_keys
    pf, pq = [], []
    for corner in range(3):
        hit = np.flatnonzero(np.isin(R[:, corner], owners))
        pf.append(hit)
        pq.append(np.fromiter((slot[int(h)] for h in R[hit, corner]), np.int64, len(hit)))
    pf, pq = np.concatenate(pf), np.concatenate(pq)
    if not len(pf):
        return out
    a, b, c = V[Fw[pf, 0]], V[Fw[pf, 1]], V[Fw[pf, 2]]
    p = points[pq]
    bary = closest_point_barycentric(p, a, b, c)
    closest = bary[:, :1] * a + bary[:, 1:2] * b + bary[:, 2:] * c
    d2 = ((closest - p) ** 2).sum(axis=1)
    order = np.lexsort((pf, d2, pq))                       # per vertex: nearest face first (ties: lowest face)
    first = order[np.r_[True, pq[order][1:] != pq[order][:-1]]]
    corners = Ff[pf[first]] - start
    vals = np.einsum("qk,qkc->qc", bary[first], X[corners])
    out[pq[first]] = vals
    return out


def level_primitives(skin: GltfSkin, hier, level, data: list[PrimitiveData] | None = None,
                     attributes: list[np.ndarray] | None = None, transfer: str = "project"
                     ) -> list[LevelPrimitive]:
    """One :class:`LevelPrimitive` per source primitive for a level taken from ``hier``.

    Parameters
    ----------
    skin : GltfSkin
        The source (read with ``weld=True`` or not).
    hier : ProgressiveHierarchy
        Built on ``skin.mesh``.
    level : SimplifiedLevel
        With ``vertex_ids`` into ``hier``.
    data, attributes :
        :func:`primitive_data` and :func:`hierarchy_attributes`, when several levels share them.
    transfer : {"project", "collapse"}
        Attributes of vertices made by collapses: ``project`` (default)
        interpolates the source corners at the closest point of the source
        faces the vertex replaced (:func:`projected_attributes`);
        ``collapse`` interpolates along the collapses
        (:func:`hierarchy_attributes`).

    Notes
    -----
    A level face is a source face whose three corners map to three distinct
    level vertices; it stays in its source primitive. A corner whose vertex
    the level kept (an original vertex) keeps its file vertex; a corner at a
    vertex made by collapses uses that vertex's interpolated attributes.
    Faces that fold onto another face (two faces with the same three
    vertices, from selective refinement) are dropped like the level does.
    """
    if level.vertex_ids is None:
        raise StepError(f"level '{level.label}' was not taken from a progressive hierarchy", field="levels",
                        fix="use a hierarchy decimator (quartic, mohr-gleicher, decoro-rusinkiewicz) for glTF LODs")
    if transfer not in ("project", "collapse"):
        raise StepError(f"unknown attribute transfer '{transfer}'", field="transfer", fix="use project or collapse")
    data = primitive_data(skin) if data is None else data
    if transfer == "collapse" and attributes is None:
        attributes = hierarchy_attributes(skin, hier, data)
    attributes = attributes if attributes is not None else [None] * len(data)
    m = hier.n_original
    ids = np.asarray(level.vertex_ids, np.int64)
    rep = level_representatives(hier, ids)
    level_keys = set(map(tuple, np.sort(ids[np.asarray(level.mesh.F)], axis=1).tolist()))
    vmap = _vertex_map(skin)
    charts = face_charts(skin, data)
    C = int(charts.max(initial=0)) + 1
    out = []
    offset = 0
    for d, sl, (Fw, Ff), A in zip(data, skin.slices, welded_faces(skin, data), attributes, strict=False):
        Ff_all_slice = Ff
        ch_all = charts[offset:offset + len(Fw)]
        offset += len(Fw)
        R = rep[Fw]
        corner_keys = R * C + ch_all[:, None]
        keep = (R >= 0).all(axis=1) & (R[:, 0] != R[:, 1]) & (R[:, 1] != R[:, 2]) & (R[:, 2] != R[:, 0])
        R, Ff, ch = R[keep], Ff[keep], ch_all[keep]
        if len(R) and len(level_keys) < len(hier.F):
            inlevel = np.array([tuple(r) in level_keys for r in np.sort(R, axis=1).tolist()], bool)
            R, Ff, ch = R[inlevel], Ff[inlevel], ch[inlevel]
        # output vertex key: the file vertex where the level kept the vertex, else (hierarchy vertex, chart):
        # a vertex made by collapses along a seam gets one output vertex per side
        key = np.where(R < m, Ff - sl.start, -1 - (R * C + ch[:, None]))
        uniq, inv = np.unique(key.ravel(), return_inverse=True)
        faces = inv.reshape(-1, 3).astype(np.int64)
        orig = uniq >= 0
        local = np.where(orig, uniq, 0)
        # hierarchy id: an original vertex's is its welded id (the level kept it), a new one's from its key
        hv = np.where(orig, vmap[sl.start + local], (-1 - uniq) // C)
        rows = np.searchsorted(ids, hv)
        if len(hv) and not np.array_equal(ids[np.minimum(rows, len(ids) - 1)], hv):
            raise StepError(f"level '{level.label}' does not match its hierarchy", field="levels",
                            fix="write levels of the hierarchy the same step built")
        cols = d.columns()
        X = np.empty((len(uniq), sum(w for _, w in cols)))
        if X.shape[1]:
            X[orig] = d.matrix()[local[orig]]
            if transfer == "collapse":
                X[~orig] = A[hv[~orig]]
            else:
                Y = projected_attributes(hier.V[hv[~orig]], (-1 - uniq)[~orig], hier.V[:m], Fw, Ff_all_slice,
                                         corner_keys, d.matrix(), sl.start)
                _normalise_blocks(Y, cols)
                X[~orig] = Y
        if np.isnan(X).any():
            raise StepError(f"level '{level.label}': a vertex of primitive {d.index} has no attribute value",
                            field="levels", fix="report this file; simplify with seams locked")
        attrs, targets, c = {}, [dict() for _ in d.targets], 0
        for k, w in cols:
            block = X[:, c:c + w]
            if k.startswith("t") and "/" in k:
                j, name = k[1:].split("/", 1)
                targets[int(j)][name] = block
            else:
                attrs[k] = block
            c += w
        out.append(LevelPrimitive(d.index, hier.V[hv], faces, rows, attrs, targets))
    return out


# --------------------------------------------------------------------------- reading levels back


def lod_nodes(js: dict) -> dict[int, list[int]]:
    """Node index -> its ``MSFT_lod`` level node ids, for every node that has the extension."""
    out = {}
    for i, node in enumerate(js.get("nodes", [])):
        ext = node.get("extensions", {}).get("MSFT_lod")
        if ext is not None:
            out[i] = [int(x) for x in ext.get("ids", [])]
    return out


def lod_level_count(js: dict) -> int:
    """Number of LOD levels (the most ``MSFT_lod`` ids of any node; 0 without the extension)."""
    return max((len(v) for v in lod_nodes(js).values()), default=0)


def level_document(doc: GltfDocument, level: int) -> GltfDocument:
    """The document as a viewer shows it at LOD ``level`` (0: the full meshes).

    Every node with ``MSFT_lod`` gets the mesh (and skin) of its level
    node ``ids[level - 1]``; nodes with fewer levels show their coarsest one.
    The buffers are shared with ``doc``.
    """
    if level == 0:
        return doc
    lods = lod_nodes(doc.json)
    if level < 0 or not lods or level > lod_level_count(doc.json):
        have = lod_level_count(doc.json)
        raise InputError(f"the file has no LOD level {level} (it has {have} MSFT_lod level(s))", source=doc.path,
                         field="--level", fix=f"give a level from 0 to {have}")
    js = copy.deepcopy(doc.json)
    nodes = js["nodes"]
    for i, ids in lods.items():
        if not ids:
            continue
        src = nodes[ids[min(level, len(ids)) - 1]]
        if "mesh" not in src:
            raise InputError(f"LOD node {ids[min(level, len(ids)) - 1]} has no mesh", source=doc.path,
                             field=f"nodes[{i}].extensions.MSFT_lod", fix="re-export the file")
        nodes[i]["mesh"] = src["mesh"]
        if "skin" in src:
            nodes[i]["skin"] = src["skin"]
    return GltfDocument(doc.path, js, doc.buffers)


def split_levels(path, outputs) -> None:
    """Write each ``MSFT_lod`` level of a file as a file of its own (the level's meshes on the original nodes).

    Parameters
    ----------
    path : path-like
        A file written with ``lod: true``.
    outputs : list of path-like
        One per level, finest first (``len(outputs)`` levels are written).
    """
    from rigslim.io.gltf import load_gltf
    from rigslim.io.gltf_write import write_pruned

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


# --------------------------------------------------------------------------- attribute quadrics


def _attribute_weight(name: str, weights: dict[str, float]) -> float:
    """Weight of an attribute: its full name (``TEXCOORD_1``) first, then its family (``TEXCOORD``)."""
    if name in weights:
        return float(weights[name])
    return float(weights.get(name.rsplit("_", 1)[0] if name[-1].isdigit() else name, 0.0))


def attribute_quadrics(skin: GltfSkin, weights: dict[str, float], data: list[PrimitiveData] | None = None
                       ) -> np.ndarray:
    """Per welded vertex, a 4x4 quadric of the rest position that measures attribute displacement.

    Parameters
    ----------
    skin : GltfSkin
        Read with ``weld=True`` (the mesh the decimators simplify).
    weights : dict
        Weight of each attribute, by name (``TEXCOORD_0``) or family
        (``TEXCOORD``, ``COLOR``, ``NORMAL``, ``TANGENT``, a custom ``_NAME``);
        missing ones weigh 0.

    Returns
    -------
    (m, 4, 4) array

    Notes
    -----
    Garland & Heckbert 1998 extend a face's plane quadric to attributes: on
    face f each attribute channel is the linear field ``s(p) = g_f . p + d_f``
    with ``g_f . n_f = 0`` and ``s(p_i) = s_i`` at the corners (a 4x4 solve
    per face and channel). Corner i of f adds
    ``lambda_a area_f (g_f . p + d_f - s_i)^2 = [p; 1]^T (area_f q q^T) [p; 1]``,
    ``q = [g_f; d_f - s_i]``, to its vertex: zero where the vertex is, and
    growing as a collapse slides the vertex along the surface away from where
    the texture (or colour, normal) had its value. Keeping the corner's value
    fixed, instead of optimising the attribute as GH98 and Hoppe 1999 do
    (a Schur complement at every edge), keeps it a 4x4 quadric of the rest
    position that sums under collapses like the plane quadrics, so the
    decimators carry it as one more "pose" with identity bone transforms.
    """
    data = primitive_data(skin) if data is None else data
    V = skin.mesh.V
    m = len(V)
    Q = np.zeros((m, 4, 4))
    for d, sl, (Fw, Ff) in zip(data, skin.slices, welded_faces(skin, data), strict=False):
        chans = []
        for name, arr in d.attributes.items():
            lam = _attribute_weight(name, weights)
            if lam > 0:
                chans.append(np.sqrt(lam) * arr)
        if not chans or not len(Fw):
            continue
        S = np.hstack(chans)[Ff - sl.start]                              # (f, 3, C) corner values
        P = V[Fw]                                                        # (f, 3, 3)
        n = np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0])
        area2 = np.linalg.norm(n, axis=1)
        ok = area2 > 1e-300 * max(1.0, float(np.abs(V).max()) ** 2)
        if not ok.any():
            continue
        P, S, Fw, n, area2 = P[ok], S[ok], Fw[ok], n[ok], area2[ok]
        n = n / area2[:, None]
        M = np.zeros((len(P), 4, 4))
        M[:, :3, :3] = P
        M[:, :3, 3] = 1.0
        M[:, 3, :3] = n
        rhs = np.concatenate([S, np.zeros((len(P), 1, S.shape[2]))], axis=1)   # (f, 4, C)
        gd = np.linalg.solve(M, rhs)                                     # (f, 4, C): g (3), d (1) per channel
        for i in range(3):
            q = gd.copy()
            q[:, 3, :] -= S[:, i, :]                                     # [g; d - s_i]
            Qi = 0.5 * area2[:, None, None] * np.einsum("fac,fbc->fab", q, q)
            np.add.at(Q, Fw[:, i], Qi)
    return Q


# --------------------------------------------------------------------------- charts and seams


def face_charts(skin: GltfSkin, data: list[PrimitiveData] | None = None) -> np.ndarray:
    """(f,) chart of every welded face: faces joined across edges where both corners' wedges agree.

    A wedge is (primitive, the corner's non-soft attribute values and morph deltas); two faces sharing
    a welded edge are in one chart when both endpoints have the same wedge in both faces. Charts are
    the connected components (scipy.sparse.csgraph), so UV seams and material boundaries separate them.
    """
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    data = primitive_data(skin) if data is None else data
    parts = welded_faces(skin, data)
    rows = []
    for i, (d, sl, (Fw, Ff)) in enumerate(zip(data, skin.slices, parts, strict=False)):
        cols = [v for k, v in d.attributes.items() if k not in SOFT_ATTRIBUTES]
        cols += [v for t in d.targets for v in t.values()]
        K = np.hstack(cols) if cols else np.zeros((sl.count, 0))
        rows.append((i, Fw, K[Ff - sl.start]))                       # (f, 3, C) corner keys
    width = max(k.shape[2] for _, _, k in rows) if rows else 0
    keys = []
    for i, Fw, K in rows:
        pad = np.full(K.shape[:2] + (width - K.shape[2],), np.nan)
        keys.append(np.concatenate([Fw[..., None].astype(float), np.full(Fw.shape + (1,), float(i)), K, pad], 2))
    Kall = np.nan_to_num(np.concatenate(keys).reshape(-1, width + 2), nan=-1e300)
    _, wedge = np.unique(Kall, axis=0, return_inverse=True)
    wedge = wedge.reshape(-1, 3)
    F = skin.mesh.F
    nf = len(F)
    # half-edges (u, v) of face f with wedges (wu, wv); faces sharing an undirected edge with equal wedges join
    he = np.concatenate([np.stack([F[:, i], F[:, (i + 1) % 3], wedge[:, i], wedge[:, (i + 1) % 3],
                                   np.arange(nf)], 1) for i in range(3)])
    lo = np.minimum(he[:, 0], he[:, 1])
    hi = np.maximum(he[:, 0], he[:, 1])
    wl = np.where(he[:, 0] < he[:, 1], he[:, 2], he[:, 3])
    wh = np.where(he[:, 0] < he[:, 1], he[:, 3], he[:, 2])
    order = np.lexsort((wh, wl, hi, lo))
    s = np.stack([lo, hi, wl, wh], 1)[order]
    same = np.flatnonzero((s[1:] == s[:-1]).all(axis=1))
    fa, fb = he[order[same], 4], he[order[same + 1], 4]
    G = sp.csr_matrix((np.ones(len(fa)), (fa, fb)), shape=(nf, nf))
    return connected_components(G, directed=False)[1].astype(np.int64)


def seam_structure(skin: GltfSkin, data: list[PrimitiveData] | None = None):
    """Locked vertices, the seam vertices that may collapse along their seam, and the face charts.

    Returns
    -------
    locked : (m,) bool
        :func:`seam_vertices`.
    along : (m,) bool
        Locked vertices on exactly one seam curve: their faces lie in exactly two charts, exactly two
        of their edges are seam edges (two faces of different charts), and none is a mesh boundary
        edge. They may collapse with each other along a seam edge; the merged vertex is such a vertex
        again. Seam corners (three charts, seam ends, boundaries) stay fixed.
    charts : (f,) int64
        :func:`face_charts`.
    """
    data = primitive_data(skin) if data is None else data
    locked = seam_vertices(skin, data)
    charts = face_charts(skin, data)
    return locked, seams_along(skin.mesh.F, charts, locked), charts


def seams_along(F: np.ndarray, charts: np.ndarray, locked: np.ndarray) -> np.ndarray:
    """Locked vertices on exactly one seam curve (see :func:`seam_structure`), from the face charts."""
    m = len(locked)
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    fid = np.tile(np.arange(len(F)), 3)
    order = np.lexsort((E[:, 1], E[:, 0]))
    E, fid = E[order], fid[order]
    key = E[:, 0] * m + E[:, 1]
    uniq, start, count = np.unique(key, return_index=True, return_counts=True)
    pairs = count == 2
    ea, eb = uniq[pairs] // m, uniq[pairs] % m
    seam_edge = charts[fid[start[pairs]]] != charts[fid[start[pairs] + 1]]
    n_seam = np.bincount(np.concatenate([ea[seam_edge], eb[seam_edge]]), minlength=m)
    bnd = np.zeros(m, bool)
    bnd[np.concatenate([uniq[count == 1] // m, uniq[count == 1] % m])] = True
    bnd[np.concatenate([uniq[count > 2] // m, uniq[count > 2] % m])] = True
    vf = np.repeat(F.ravel(), 1)
    vc = np.repeat(charts, 3)
    pairs_vc = np.unique(np.stack([vf, vc], 1), axis=0)
    n_charts = np.bincount(pairs_vc[:, 0], minlength=m)
    return locked & (n_charts == 2) & (n_seam == 2) & ~bnd
