"""UV/normal seams and charts of a glTF skin, and the attribute quadrics the decimator weighs them with."""

from __future__ import annotations

import numpy as np

from rigslim.io.gltf.primitives import PrimitiveData, primitive_data, welded_faces, welded_vertex_map
from rigslim.io.gltf.skin import GltfSkin


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
    vmap = welded_vertex_map(skin)
    m = skin.mesh.n_vertices
    keys = []
    for d, sl in zip(data, skin.slices, strict=False):
        cols = d.seam_columns()
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


def face_charts(skin: GltfSkin, data: list[PrimitiveData] | None = None) -> np.ndarray:
    """(f,) chart of every welded face: faces joined across edges where both corners' wedges agree.

    A wedge is (primitive, the corner's non-soft attribute values and morph deltas); two faces sharing
    a welded edge are in one chart when both endpoints have the same wedge in both faces. Charts are
    the connected components (scipy.sparse.csgraph), so UV seams and material boundaries separate them.
    """
    return chart_wedges(skin, data)[0]


def chart_wedges(skin: GltfSkin, data: list[PrimitiveData] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(f,) face charts (:func:`face_charts`) and the (f, 3) wedge id of every face corner."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    wedge, fa, fb = wedge_adjacency(skin, data)
    nf = len(wedge)
    G = sp.csr_matrix((np.ones(len(fa)), (fa, fb)), shape=(nf, nf))
    return connected_components(G, directed=False)[1].astype(np.int64), wedge


def wedge_adjacency(skin: GltfSkin, data: list[PrimitiveData] | None = None
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The (f, 3) wedge id of every welded face corner, and the pairs of faces ``(fa, fb)`` that share an
    edge whose two endpoints carry the same wedge in both faces (no seam between them).

    A wedge is (welded vertex, primitive, the corner's non-soft attribute values and morph deltas), numbered
    densely; the faces are ``skin.mesh.F``, primitive after primitive (:func:`welded_faces`).
    """
    data = primitive_data(skin) if data is None else data
    parts = welded_faces(skin, data)
    rows = []
    for i, (d, sl, (Fw, Ff)) in enumerate(zip(data, skin.slices, parts, strict=False)):
        cols = d.seam_columns()
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
    return wedge, he[order[same], 4], he[order[same + 1], 4]


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
