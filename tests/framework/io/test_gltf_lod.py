"""Per-primitive glTF levels of detail (rigslim.io.gltf.lod): seams, attributes along collapses, backends."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigslim.io.gltf.lod import (
    collapse_parameters,
    hierarchy_attributes,
    input_weights_normalized,
    level_primitives,
    level_representatives,
)
from rigslim.io.gltf.primitives import primitive_data
from rigslim.io.gltf.seams import seam_vertices
from rigslim.io.gltf.skin import read_gltf_skin

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"
TUBE = GLTF / "tube_two_materials.glb"


@pytest.fixture(scope="module")
def tube():
    return read_gltf_skin(TUBE, weld=True, fps=10)


def _decimate(skin, backend="numba", lock=True, targets=(0.5, 0.25), **extra):
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    asset = Asset(mesh=skin.mesh, handles=skin.handles, weights=skin.weights, poses=skin.poses,
                  split=FrameSplit.from_specs(f"0:{len(skin.poses)}:2", f"1:{len(skin.poses)}:2", len(skin.poses)))
    asset.extras["gltf"] = skin
    plugin = get_host().get("articulated-decimation", "quartic")
    ctx = StepContext()
    seams = {True: "lock", False: "free", None: "move"}[lock]
    plugin.apply(asset, plugin.parse_params({"targets": list(targets), "max_bones": 4, "backend": backend,
                                             "seams": seams} | extra), ctx)
    return asset.hierarchy, asset.levels, ctx.report


def test_seams_are_the_uv_seam_and_the_material_boundaries(tube):
    locked = seam_vertices(tube)
    V = tube.mesh.V
    theta = np.mod(np.arctan2(V[:, 2], V[:, 0]), 2 * np.pi)
    on_u_seam = np.isclose(theta, 0, atol=1e-6) | np.isclose(theta, 2 * np.pi, atol=1e-6)
    on_ring_12 = np.isclose(V[:, 1], 1.0)                              # Legs mesh | Torso mesh
    front_back = np.isclose(theta, np.pi, atol=1e-6) & (V[:, 1] >= 1.0 - 1e-9)   # Skin | Cloth primitives
    expected = on_u_seam | on_ring_12 | front_back
    assert np.array_equal(locked, expected)


def _fixed_classes(hier, locked, along):
    """Per hierarchy vertex: fixed, and on a seam curve, replayed through the collapses; checks each collapse."""
    m = hier.n_original
    N = len(hier.V)
    fixed = np.zeros(N, bool)
    seam = np.zeros(N, bool)
    fixed[:m], seam[:m] = locked, along
    W = hier.weights.to_sparse().toarray()
    for i, (a, b) in enumerate(hier.collapses):
        c = m + i
        if fixed[a] and fixed[b]:
            # two fixed ends: along one seam, or a seam vertex slid onto a corner (which stays put)
            assert seam[a] or seam[b], "two seam corners merged"
            if not (seam[a] and seam[b]):
                keep = b if seam[a] else a
                assert np.array_equal(hier.V[c], hier.V[keep])
            seam[c] = seam[a] and seam[b]
        elif fixed[a] or fixed[b]:
            keep = a if fixed[a] else b           # a half-edge collapse: position and weights stay
            assert np.array_equal(hier.V[c], hier.V[keep]) and np.allclose(W[c], W[keep], atol=1e-12)
            seam[c] = seam[keep]
        fixed[c] = fixed[a] or fixed[b]
    return fixed, seam


def test_locked_vertices_never_move(tube):
    """Without seam collapses no locked vertex moves: free vertices collapse onto them, two never merge."""
    hier, levels, report = _decimate(tube, seams_collapse_along=False)
    locked = seam_vertices(tube)
    assert report["locked_seam_vertices"] == int(locked.sum())
    m = hier.n_original
    fixed, _ = _fixed_classes(hier, locked, np.zeros_like(locked))
    assert not (fixed[hier.collapses[:, 0]] & fixed[hier.collapses[:, 1]]).any()
    for level in levels:
        rep = level_representatives(hier, level.vertex_ids)
        ids = np.flatnonzero(locked)
        assert len(np.unique(rep[ids])) == len(ids)           # each still stands alone
        np.testing.assert_array_equal(hier.V[rep[ids]], hier.V[ids])
    assert hier.n_collapses and fixed[m:].any()                # half-edge collapses onto them happened


def test_seams_collapse_only_along_themselves(tube):
    """Seam vertices merge only along their seam (or onto a corner along it); corners never move; more faces go."""
    from rigslim.io.gltf.seams import seam_structure

    locked, along, charts = seam_structure(tube)
    assert along.sum() > 0 and (along <= locked).all()
    hier, levels, report = _decimate(tube)
    kept, _, _ = _decimate(tube, seams_collapse_along=False)
    assert report["seam_vertices_collapsing_along"] == int(along.sum())
    _fixed_classes(hier, locked, along)
    corners = np.flatnonzero(locked & ~along)
    for level in levels:
        rep = level_representatives(hier, level.vertex_ids)
        np.testing.assert_array_equal(hier.V[rep[corners]], hier.V[corners])
    assert hier.faces_after(hier.n_collapses) <= kept.faces_after(kept.n_collapses)


@pytest.mark.parametrize("seamed", [False, True], ids=["locked", "seams-along"])
def test_backends_agree_with_locked_vertices(elephant, monkeypatch, seamed):
    """The numpy reference loop and the compiled loop make the same collapses when vertices are locked.

    On a real piece of the elephant (as tests/plugins/decimation/test_decimation_compiled.py; the glTF samples
    are mirror symmetric, so equal costs would tie-break by heap order), with a random fifth of the vertices locked.
    """
    import scipy.sparse as sp

    import rigslim.plugins.decimation.articulated as articulated
    from rigslim.model.asset import Asset
    from rigslim.model.mesh import Mesh

    V, F = elephant.mesh.V, elephant.mesh.F                 # the 900 faces nearest the busiest vertex
    W = elephant.weights.toarray()
    c = V[int(np.argmax((W > 0).sum(axis=1)))]
    far = np.linalg.norm(V - c, axis=1)[F].max(axis=1)
    Fk = F[far <= np.sort(far)[900]]
    used = np.unique(Fk)
    remap = np.full(len(V), -1)
    remap[used] = np.arange(len(used))
    piece = Asset(mesh=Mesh(V[used], remap[Fk]), weights=sp.csr_matrix(W[used]), poses=elephant.poses,
                  split=elephant.split)
    locked = np.random.default_rng(3).random(piece.mesh.n_vertices) < 0.2
    seams = None
    if seamed:          # two charts split by a plane through the piece: a seam curve across it
        from rigslim.io.gltf.seams import seams_along

        Vp, Fp = piece.mesh.V, piece.mesh.F
        cen = Vp[Fp].mean(axis=1)
        charts = (cen[:, 0] > np.median(cen[:, 0])).astype(np.int64)
        counts = np.zeros((len(Vp), 2), int)
        np.add.at(counts, (Fp.ravel(), np.repeat(charts, 3)), 1)
        locked = (counts > 0).all(axis=1)
        seams = (seams_along(Fp, charts, locked), charts)
        assert seams[0].sum() > 10
    monkeypatch.setattr(articulated, "seam_lock", lambda asset, along=True, mode="lock": (locked, seams))
    # the loops are compared with the same per-edge costs: with 4 bones about 1% of the edges take another
    # branch in the numpy cost path (docs/simplification.md, "Speed"), which the face-side error can rank first
    from rigslim.plugins.decimation import models

    monkeypatch.setattr(models.QuarticModel, "costs", lambda self, st, ea, eb: models.compiled_costs(self, st, ea, eb))
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    plugin = get_host().get("articulated-decimation", "quartic")
    hs = []
    for backend in ("numpy", "numba"):
        piece.extras.clear()
        ctx = StepContext()
        plugin.apply(piece, plugin.parse_params({"backend": backend, "min_faces": 100, "max_bones": 4,
                                                 "seams": "lock"}), ctx)
        assert ctx.report["locked_seam_vertices"] == int(locked.sum())
        hs.append(piece.hierarchy)
    assert hs[0].n_collapses > 200
    np.testing.assert_array_equal(hs[0].collapses, hs[1].collapses)
    if not seamed:          # half-edge collapses onto locked vertices, never two locked ones merged
        fixed, _ = _fixed_classes(hs[0], locked, np.zeros_like(locked))
        assert not (fixed[hs[0].collapses[:, 0]] & fixed[hs[0].collapses[:, 1]]).any()
    else:
        assert np.isin(hs[0].collapses, np.flatnonzero(seams[0])).any()      # some seam collapses happened


def test_attributes_interpolate_along_collapses(tube):
    """x_c = (1 - t) x_a + t x_b with t the projection of v_c onto the edge, recursively; normals unit."""
    hier, levels, _ = _decimate(tube)
    data = primitive_data(tube)
    A = hierarchy_attributes(tube, hier, data)
    t = collapse_parameters(hier)
    m = hier.n_original
    cols = data[0].columns()
    assert [k for k, _ in cols] == ["NORMAL", "TEXCOORD_0"]
    for i in range(0, hier.n_collapses, 37):
        a, b = hier.collapses[i]
        p = A[0]                                 # the legs primitive
        if np.isnan(p[a]).any() or np.isnan(p[b]).any():
            continue
        uv = (1 - t[i]) * p[a, 3:5] + t[i] * p[b, 3:5]
        assert np.allclose(p[m + i, 3:5], uv)
        assert np.isclose(np.linalg.norm(p[m + i, :3]), 1.0)
        e = hier.V[b] - hier.V[a]
        assert np.isclose(t[i], np.clip((hier.V[m + i] - hier.V[a]) @ e / (e @ e), 0, 1))


def test_level_uvs_follow_the_surface(tube):
    """On the tube, u = angle / 2 pi and v = 1 - y / 2: the level's interpolated UVs stay close to that."""
    hier, levels, _ = _decimate(tube)
    for level in levels:
        for part in level_primitives(tube, hier, level):
            P, uv = part.positions, part.attributes["TEXCOORD_0"]
            assert np.abs(uv[:, 1] - (1 - P[:, 1] / 2)).max() < 0.02
            ang = np.mod(np.arctan2(P[:, 2], P[:, 0]), 2 * np.pi) / (2 * np.pi)
            du = np.abs(uv[:, 0] - ang)
            du = np.minimum(du, 1 - du)                  # the seam: u = 0 and u = 1 at one position
            assert du.max() < 0.03
            assert part.faces.max() < len(P) and len(part.weight_rows) == len(P)


def test_level_faces_partition_the_level(tube):
    hier, levels, _ = _decimate(tube)
    for level in levels:
        parts = level_primitives(tube, hier, level)
        assert sum(len(p.faces) for p in parts) == level.n_faces
        assert [p.slice_index for p in parts] == [0, 1, 2]


def test_input_weights_normalized(tmp_path):
    assert not input_weights_normalized(read_gltf_skin(GLTF / "animation_with_skeleton.glb"))
    assert not input_weights_normalized(read_gltf_skin(TUBE))
    assert input_weights_normalized(read_gltf_skin(GLTF / "simple_skin.gltf"))


@pytest.mark.parametrize(("name", "normalized"), [("bcn_epileptic", False), ("wuson", False), ("frankie", True)])
def test_input_weights_normalized_is_the_validators_rule(name, normalized):
    """Float32 sums of 1 + 2^-20 (bcn_epileptic: 12 validator errors, wuson: 52) fail the validator's
    |sum - 1| <= 2e-7 per non-zero weight, so level 0 must be rewritten; frankie's pass and are kept."""
    assert input_weights_normalized(read_gltf_skin(GLTF / "suite" / f"{name}.glb")) is normalized


def test_closest_point_barycentric_matches_libigl():
    """Every Voronoi region (vertices, edges, face) against igl.point_mesh_squared_distance, one triangle each."""
    import igl

    from rigslim.io.gltf.lod import closest_point_barycentric

    rng = np.random.default_rng(5)
    T = rng.normal(size=(300, 3, 3))
    p = rng.normal(size=(300, 3)) * 1.5
    bary = closest_point_barycentric(p, T[:, 0], T[:, 1], T[:, 2])
    assert (bary >= -1e-12).all() and np.allclose(bary.sum(axis=1), 1)
    mine = np.einsum("qk,qkc->qc", bary, T)
    for i in range(len(p)):
        d2, _, C = igl.point_mesh_squared_distance(p[i:i + 1], T[i], np.array([[0, 1, 2]]))
        assert np.allclose(mine[i], C[0], atol=1e-9)


@pytest.mark.parametrize("transfer, tol_v, tol_u", [("project", 0.01, 0.01), ("collapse", 0.05, 0.05)])
def test_transfers_against_the_tube_parametrisation(tube, transfer, tol_v, tol_u):
    """Projection onto the replaced source faces follows u = angle / 2 pi, v = 1 - y / 2 closely; the
    interpolation along collapses less so (the quartic optimum slides off the collapsed edges)."""
    hier, levels, _ = _decimate(tube)
    worst = 0.0
    for level in levels:
        for part in level_primitives(tube, hier, level, transfer=transfer):
            P, uv = part.positions, part.attributes["TEXCOORD_0"]
            ang = np.mod(np.arctan2(P[:, 2], P[:, 0]), 2 * np.pi) / (2 * np.pi)
            du = np.abs(uv[:, 0] - ang)
            worst = max(worst, np.abs(uv[:, 1] - (1 - P[:, 1] / 2)).max() / tol_v,
                        np.minimum(du, 1 - du).max() / tol_u)
    assert worst < 1.0


def test_attribute_quadrics_measure_displacement_along_the_uv_field(tube):
    """Zero at every vertex's own position; grows with the UV change when the vertex slides along the tube."""
    from rigslim.io.gltf.seams import attribute_quadrics

    Q = attribute_quadrics(tube, {"TEXCOORD": 1.0})
    V = tube.mesh.V
    h = np.c_[V, np.ones(len(V))]
    assert np.abs(np.einsum("vi,vij,vj->v", h, Q, h)).max() < 1e-12
    assert not attribute_quadrics(tube, {"COLOR": 1.0}).any()          # no colours: no term
    # an interior vertex moved along y by dy changes v = 1 - y/2 by dy/2: cost = sum area (dy/2)^2 over its faces
    locked = seam_vertices(tube)
    i = int(np.flatnonzero(~locked & (np.abs(V[:, 1] - 0.5) < 1e-9))[0])
    dy = 1e-3
    p = np.r_[V[i] + [0, dy, 0], 1.0]
    faces = np.flatnonzero((tube.mesh.F == i).any(axis=1))
    P = V[tube.mesh.F[faces]]
    area = 0.5 * np.linalg.norm(np.cross(P[:, 1] - P[:, 0], P[:, 2] - P[:, 0]), axis=1).sum()
    assert p @ Q[i] @ p == pytest.approx(area * (dy / 2) ** 2, rel=1e-3)


def test_attribute_term_is_one_more_pose(tube):
    """With weights, the decimator appends the term (report ``attribute_term``) and every level stays valid."""
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    n = len(tube.poses)
    asset = Asset(mesh=tube.mesh, handles=tube.handles, weights=tube.weights, poses=tube.poses,
                  split=FrameSplit.from_specs(f"0:{n}:2", f"1:{n}:2", n))
    asset.extras["gltf"] = tube
    plugin = get_host().get("articulated-decimation", "quartic")
    ctx = StepContext()
    # the attribute term adds to every collapse's error, so the error bound would stop the level early
    plugin.apply(asset, plugin.parse_params({"targets": [0.5], "attribute_weights": {"TEXCOORD": 1.0},
                                             "max_error": "none"}), ctx)
    assert ctx.report["attribute_term"] is True
    level = asset.levels[0]
    assert level.n_faces <= 0.5 * tube.mesh.n_faces + 2
    assert np.allclose(level.weights.values.sum(axis=1), 1)
    ctx = StepContext()
    plugin.apply(asset, plugin.parse_params({"targets": [0.5]}), ctx)
    assert ctx.report["attribute_term"] is False


def test_corner_sides_split_a_fan_at_its_seams():
    """Six faces around a vertex made by collapses (id 9 >= m = 8): one side while every edge between
    neighbours is seam-free; a slit (one seam edge) still leaves one side, joined around the fan; a second
    seam edge makes two sides, and each corner keeps the side of its own faces."""
    from rigslim.io.gltf.lod import corner_sides

    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 4], [0, 4, 5], [0, 5, 6], [0, 6, 1]])
    R = np.where(F == 0, 9, F)
    ring = [(i, (i + 1) % 6) for i in range(6)]
    for cut, n_sides in [((), 1), (((5, 0),), 1), (((5, 0), (2, 3)), 2)]:
        pairs = np.array([p for p in ring if p not in cut])
        side, vertex = corner_sides(F, R, pairs[:, 0], pairs[:, 1], 8)
        assert (side[:, 1:] == -1).all() and len(vertex) == n_sides and (vertex == 9).all()
        if n_sides == 2:
            assert len(set(side[:3, 0])) == 1 and len(set(side[3:, 0])) == 1 and side[0, 0] != side[3, 0]


def test_moving_seams_keep_each_side_of_the_uv_seam(tube):
    """``seams: move`` (the default): seam vertices move, held by the seam planes; no level face mixes
    the two sides of the tube's u = 0 | 1 seam (a face spanning it would have corners near u = 0 and u = 1),
    and the UVs still follow the surface."""
    hier, levels, report = _decimate(tube, lock=None, targets=(0.5, 0.25))
    assert report["seams"] == "move" and "locked_seam_vertices" not in report
    locked = seam_vertices(tube)
    moved = False
    for level in levels:
        rep = level_representatives(hier, level.vertex_ids)
        moved |= bool((rep[locked] >= hier.n_original).any())
        for part in level_primitives(tube, hier, level):
            P, uv = part.positions, part.attributes["TEXCOORD_0"]
            span = np.ptp(uv[part.faces][..., 0], axis=1)
            assert span.max() < 0.5
            assert np.abs(uv[:, 1] - (1 - P[:, 1] / 2)).max() < 0.03
    assert moved


def test_texcoords_read_by_the_material():
    """Texture references anywhere in the material (extensions and KHR_texture_transform included) say which
    UV sets show; a primitive without a material, or an untextured one, reads none."""
    from rigslim.io.gltf.primitives import texcoords_read

    js = {"materials": [
        {"pbrMetallicRoughness": {"baseColorFactor": [1, 1, 1, 1]}},
        {"pbrMetallicRoughness": {"baseColorTexture": {"index": 0}}, "normalTexture": {"index": 1, "texCoord": 1}},
        {"emissiveTexture": {"index": 0, "extensions": {"KHR_texture_transform": {"texCoord": 2}}}},
    ]}
    assert texcoords_read(js, {}) == set()
    assert texcoords_read(js, {"material": 0}) == set()
    assert texcoords_read(js, {"material": 1}) == {0, 1}
    assert texcoords_read(js, {"material": 2}) == {0, 2}


@pytest.mark.parametrize(("name", "seams"), [("bcn_epileptic", 0), ("wuson", 0), ("re_player", 523)])
def test_unseen_uv_sets_make_no_seams(name, seams):
    """bcn_epileptic's and wuson's materials read no texture: their UV seams (323 and 839 vertices) show nowhere,
    so nothing is held to them; re_player's textured seams stay."""
    skin = read_gltf_skin(GLTF / "suite" / f"{name}.glb", weld=True)
    assert int(seam_vertices(skin).sum()) == seams
    if not seams:
        assert all(d.unseen == {"TEXCOORD_0"} for d in primitive_data(skin))


def test_a_level_without_collapses_keeps_every_file_vertex(tube):
    """A level before any collapse (a level stopped by max_error at once) has no vertex made by collapses:
    every corner keeps its file vertex (minetest_character at --max-error 1 % ended in an IndexError)."""
    hier, _, _ = _decimate(tube, lock=None, targets=(0.5,))
    parts = level_primitives(tube, hier, hier.prefix(0))
    assert sum(len(p.faces) for p in parts) == len(tube.mesh.F)
    data = primitive_data(tube)
    for p, d in zip(parts, data, strict=True):
        np.testing.assert_array_equal(np.sort(p.attributes["TEXCOORD_0"], axis=0),
                                      np.sort(d.attributes["TEXCOORD_0"][np.unique(d.faces)], axis=0))
