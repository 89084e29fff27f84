"""USD / UsdSkel in and out (rigslim.io.usd): glTF -> USD -> posed points, against rigslim and UsdSkel.

Every skinned glTF of examples/data/gltf (and of the real-character suite
when tools/setup-suite has fetched it) is exported to UsdSkel, read back, and
posed three ways on every frame: rigslim's linear blend of the glTF reading,
rigslim's of the USD reading, and UsdSkel's own ``SkinningQuery`` (USD's C++
skinning). They agree to float32 precision, relative to the posed size.
A hand-made character covers what the exporter never writes: polygons,
several meshes, ``skel:joints`` subsets, constant influences, a
``geomBindTransform``, faceVarying UVs, material subsets and blend shapes.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from rigslim.io.gltf.skin import read_gltf_skin
from rigslim.io.usd.check import check_usd
from rigslim.io.usd.export import bind_transforms, build_stage
from rigslim.io.usd.read import read_usd_skin, triangulate
from rigslim.io.usd.skinning import usdskel_points
from rigslim.io.usd.write import save_stage, write_usd
from rigslim.numerics.blend import linear_blend

ROOT = Path(__file__).resolve().parents[3]
GLTF = ROOT / "examples" / "data" / "gltf"
#: Largest posed-point difference, relative to the posed bounding-box diagonal, of two float32 pipelines.
RELATIVE = 2e-5


def assimp_characters() -> list[Path]:
    """assimp's animated test characters converted to .glb once per session (none without assimp's test models)."""
    import shutil
    import subprocess
    import tempfile

    models = Path("/usr/share/assimp/models/X")
    if shutil.which("assimp") is None or not models.is_dir():
        return []
    folder = Path(tempfile.mkdtemp(prefix="rigslim-usd-assimp-"))
    out = []
    for name in ("BCN_Epileptic", "Testwuson"):
        dst = folder / f"{name}.glb"
        cmd = ["assimp", "export", str(models / f"{name}.X"), str(dst), "-fglb2"]
        if (models / f"{name}.X").exists() and subprocess.run(cmd, capture_output=True).returncode == 0:
            out.append(dst)
    return out


def suite_characters() -> list[Path]:
    """The bundled skinned glTFs, assimp's two animated characters, and the real-character suite where fetched."""
    files = sorted(p for p in GLTF.rglob("*") if p.suffix in (".glb", ".gltf")) + assimp_characters()
    suite = ROOT / "examples" / "data" / "suite"
    if suite.is_dir():
        files += sorted(p for p in suite.rglob("*") if p.suffix in (".glb", ".gltf"))
    out = []
    for p in files:
        try:
            read_gltf_skin(p, times=[0.0])
        except Exception:  # noqa: BLE001 - an unskinned or multi-skin file is no round-trip case
            continue
        out.append(p)
    return out


CHARACTERS = suite_characters()


def _diag(P: np.ndarray) -> float:
    return float(np.linalg.norm(P.reshape(-1, 3).max(axis=0) - P.reshape(-1, 3).min(axis=0)))


def _export(gltf: Path, out: Path):
    skin = read_gltf_skin(gltf, weld=True)
    stage = build_stage(skin.mesh, skin.handles, skin.weights, skin.poses, fps=skin.fps,
                        bind=bind_transforms(skin.handles, skin), name=gltf.stem)
    save_stage(stage, out)
    return skin


def test_the_round_trip_has_characters():
    assert len(CHARACTERS) >= 4, CHARACTERS


@pytest.mark.parametrize("gltf", CHARACTERS, ids=lambda p: p.name)
def test_gltf_to_usd_poses_equal_rigslim_and_usdskel(gltf, tmp_path):
    out = tmp_path / f"{gltf.stem}.usdc"
    g = _export(gltf, out)
    u = read_usd_skin(out, fps=g.fps)
    assert u.mesh.n_vertices == g.mesh.n_vertices and u.mesh.n_faces == g.mesh.n_faces
    np.testing.assert_array_equal(u.mesh.F, g.mesh.F)
    np.testing.assert_allclose(u.mesh.V, g.mesh.V, atol=1e-6 * max(_diag(g.mesh.V), 1e-9))
    # joints are listed parents first in USD: handle i of the glTF is the USD joint named by its token
    from rigslim.io.usd.export import joint_tokens

    tokens = joint_tokens(list(g.handles.names), np.asarray(g.handles.parents))
    perm = [u.joints.index(t) for t in tokens]
    assert abs(u.weights[:, perm] - g.weights).max() < 1e-6
    assert len(u.poses) == len(g.poses)
    ref = usdskel_points(u)
    frames = np.unique(np.linspace(0, len(g.poses) - 1, min(len(g.poses), 12)).astype(int))
    for f in frames:
        gl = linear_blend(g.mesh.V, g.weights, g.poses.T[f])
        us = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
        scale = max(_diag(gl), 1e-9)
        assert np.abs(us - gl).max() <= RELATIVE * scale, (f, np.abs(us - gl).max() / scale)
        assert np.abs(ref[f] - us).max() <= RELATIVE * scale, (f, np.abs(ref[f] - us).max() / scale)
    assert check_usd(out) == []


def test_triangulate_fans_polygons_skips_holes_and_flips_left_handed():
    counts = np.array([3, 4, 2, 5])
    idx = np.arange(14)
    F, poly, corners = triangulate(counts, idx, holes=[3])
    np.testing.assert_array_equal(F, [[0, 1, 2], [3, 4, 5], [3, 5, 6]])
    np.testing.assert_array_equal(poly, [0, 1, 1])
    F2, _, _ = triangulate(counts, idx, left_handed=True)
    np.testing.assert_array_equal(F2[:3], [[0, 2, 1], [3, 5, 4], [3, 6, 5]])
    assert len(F2) == 1 + 2 + 3


# --------------------------------------------------------------------------- a hand-made character


def make_character(path: Path, *, blend: bool = True) -> Path:
    """Two meshes under one SkelRoot: a quad strip (faceVarying UVs, two material subsets, a blend shape,
    ``skel:joints`` in its own order, a geomBindTransform) and a rigidly bound triangle."""
    from pxr import Gf, Sdf, Usd, UsdGeom, UsdShade, UsdSkel, Vt

    stage = Usd.Stage.CreateNew(str(path))
    UsdGeom.SetStageUpAxis(stage, UsdGeom.Tokens.z)
    UsdGeom.SetStageMetersPerUnit(stage, 0.01)
    root = UsdSkel.Root.Define(stage, "/Hero")
    stage.SetDefaultPrim(root.GetPrim())
    skel = UsdSkel.Skeleton.Define(stage, "/Hero/Rig")
    joints = ["root", "root/mid", "root/mid/tip"]
    skel.CreateJointsAttr(joints)
    bind = [Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, z)) for z in (0, 2, 4)]
    skel.CreateBindTransformsAttr(bind)
    skel.CreateRestTransformsAttr([Gf.Matrix4d(1), Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 2)),
                                   Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, 2))])
    anim = UsdSkel.Animation.Define(stage, "/Hero/Rig/Bend")
    anim.CreateJointsAttr(["root/mid/tip", "root/mid"])     # a subset, in another order
    for t in range(0, 25, 4):
        a = 40.0 * np.sin(t / 6.0)
        anim.CreateTranslationsAttr().Set(Vt.Vec3fArray([(0, 0, 2), (0, 0, 2)]), t)
        anim.CreateRotationsAttr().Set(Vt.QuatfArray([Gf.Quatf(Gf.Rotation(Gf.Vec3d(1, 0, 0), a).GetQuat()),
                                                      Gf.Quatf(Gf.Rotation(Gf.Vec3d(0, 1, 0), a / 2).GetQuat())]), t)
        anim.CreateScalesAttr().Set(Vt.Vec3hArray([(1, 1, 1), (1, 1, 1.5)]), t)
    UsdSkel.BindingAPI.Apply(skel.GetPrim()).CreateAnimationSourceRel().SetTargets([anim.GetPath()])
    stage.SetStartTimeCode(0)
    stage.SetEndTimeCode(24)
    stage.SetTimeCodesPerSecond(24)
    # a tube of quads from z = 0 to 4 (8 around, 12 rows), modelled 1 unit up (the geomBindTransform moves it down)
    UsdGeom.Xform.Define(stage, "/Hero/Geo")
    rows, around = 12, 8
    ang = 2 * np.pi * np.arange(around) / around
    P = np.array([(0.5 * np.cos(a), 0.5 * np.sin(a), 4.0 * r / (rows - 1) + 1.0) for r in range(rows) for a in ang])
    quads = [[r * around + i, r * around + (i + 1) % around, (r + 1) * around + (i + 1) % around,
              (r + 1) * around + i] for r in range(rows - 1) for i in range(around)]
    strip = UsdGeom.Mesh.Define(stage, "/Hero/Geo/Strip")
    strip.CreatePointsAttr(Vt.Vec3fArray.FromNumpy(P.astype(np.float32)))
    strip.CreateFaceVertexCountsAttr([4] * len(quads))
    strip.CreateFaceVertexIndicesAttr([i for q in quads for i in q])
    strip.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(strip.GetPointsAttr().Get()))
    st = UsdGeom.PrimvarsAPI(strip).CreatePrimvar("st", Sdf.ValueTypeNames.TexCoord2fArray,
                                                  UsdGeom.Tokens.faceVarying)
    half = len(quads) // 2
    # u goes around (the wrap-around column is a seam), v up; the upper half is a second chart, 2 units over
    uv = [((i % around + (1 if c in (1, 2) else 0)) / around + (0.0 if f < half else 2.0), (P[q[c], 2] - 1) / 4)
          for f, q in enumerate(quads) for c, i in enumerate([quads[f][0] % around] * 4)]
    st.Set(Vt.Vec2fArray(uv))
    mats = []
    for name in ("Skin", "Cloth"):
        mat = UsdShade.Material.Define(stage, f"/Hero/Looks/{name}")
        mats.append(mat)
    for name, faces, mat in (("skin", range(0, half), mats[0]), ("cloth", range(half, len(quads)), mats[1])):
        subset = UsdGeom.Subset.CreateGeomSubset(UsdGeom.Imageable(strip), name, UsdGeom.Tokens.face,
                                                 Vt.IntArray(list(faces)), "materialBind", "partition")
        UsdShade.MaterialBindingAPI.Apply(subset.GetPrim()).Bind(mat)
    binding = UsdSkel.BindingAPI.Apply(strip.GetPrim())
    binding.CreateSkeletonRel().SetTargets([skel.GetPath()])
    binding.CreateJointsAttr(["root/mid/tip", "root", "root/mid"])      # the mesh's own joint order
    binding.CreateGeomBindTransformAttr(Gf.Matrix4d(1).SetTranslate(Gf.Vec3d(0, 0, -1)))
    z = P[:, 2] - 1.0
    w_tip = np.clip((z - 2.0) / 2.0, 0, 1)
    w_root = np.clip(1.0 - z / 2.0, 0, 1)
    w_mid = 1.0 - w_tip - w_root
    binding.CreateJointIndicesPrimvar(False, 3).Set([i for _ in range(len(P)) for i in (0, 1, 2)])
    binding.CreateJointWeightsPrimvar(False, 3).Set([float(w) for r in zip(w_tip, w_root, w_mid, strict=True)
                                                     for w in r])
    if blend:
        shape = UsdSkel.BlendShape.Define(stage, "/Hero/Geo/Strip/Bulge")
        ring = np.arange(5 * around, 7 * around)
        shape.CreateOffsetsAttr(Vt.Vec3fArray.FromNumpy((0.2 * P[ring] * [1, 1, 0]).astype(np.float32)))
        shape.CreatePointIndicesAttr(Vt.IntArray.FromNumpy(ring.astype(np.int32)))
        binding.CreateBlendShapesAttr(["bulge"])
        binding.CreateBlendShapeTargetsRel().SetTargets([shape.GetPath()])
    tri = UsdGeom.Mesh.Define(stage, "/Hero/Geo/Hat")
    tri.CreatePointsAttr([(0, 0, 4.2), (0.3, 0, 4.5), (-0.3, 0, 4.5)])
    tri.CreateFaceVertexCountsAttr([3])
    tri.CreateFaceVertexIndicesAttr([0, 1, 2])
    tri.CreateExtentAttr(UsdGeom.PointBased.ComputeExtent(tri.GetPointsAttr().Get()))
    hat = UsdSkel.BindingAPI.Apply(tri.GetPrim())
    hat.CreateSkeletonRel().SetTargets([skel.GetPath()])
    ji = hat.CreateJointIndicesPrimvar(True, 1)     # constant: the whole mesh follows the tip
    ji.Set([2])
    hat.CreateJointWeightsPrimvar(True, 1).Set([1.0])
    stage.GetRootLayer().Save()
    return path


def top_k(W, k: int):
    """The k largest weights of every row, renormalised, as ReducedWeights (a k-largest reduction)."""
    from rigslim.model.weights import ReducedWeights

    D = W.toarray()
    idx = np.argsort(-D, axis=1)[:, :k]
    val = np.take_along_axis(D, idx, axis=1)
    return ReducedWeights(idx.astype(np.int32), val / val.sum(axis=1, keepdims=True), W.shape[1])


@pytest.fixture
def hero(tmp_path):
    return make_character(tmp_path / "hero.usda")


def test_hand_made_character_reads_and_poses_like_usdskel(hero):
    u = read_usd_skin(hero, fps=24)
    assert [p.path for p in u.parts] == ["/Hero/Geo/Strip", "/Hero/Geo/Hat"]
    assert u.mesh.n_vertices == 96 + 3 and u.mesh.n_faces == 2 * 88 + 1
    assert u.parts[1].rigid and u.parts[0].element_size == 3
    assert u.parts[0].blend_shapes == ["bulge"] and any("blend shapes" in n for n in u.notes)
    # geomBindTransform applied: the strip starts at z = 0 in skeleton space
    assert abs(u.mesh.V[:96, 2].min()) < 1e-6
    # skel:joints order mapped onto the skeleton's: point 0 (z = 0) is all root, the last ring all tip
    assert u.weights[0, 0] == pytest.approx(1.0) and u.weights[95, 2] == pytest.approx(1.0)
    assert len(u.poses) == 25
    ref = usdskel_points(u)
    for f in range(len(u.poses)):
        mine = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
        assert np.abs(mine - ref[f]).max() < 1e-5
    assert np.abs(ref[0] - ref[12]).max() > 0.5        # it moves


def test_sampling_follows_fps_times_and_named_animation(hero):
    u = read_usd_skin(hero, fps=12)
    np.testing.assert_allclose(u.time_codes, np.arange(13) * 2.0)
    u = read_usd_skin(hero, times=[0.5, 0.25])
    np.testing.assert_allclose(u.time_codes, [12.0, 6.0])
    u = read_usd_skin(hero, animation="Bend", fps=24)
    assert u.animation == "/Hero/Rig/Bend"


def test_sibling_clips_are_the_other_animations_of_the_skeleton(hero):
    """The SkelAnimations beside the sampled one, each with its own frames; one over joints the skeleton
    lacks is left out with a note, and one elsewhere in the stage is not a sibling."""
    from pxr import Gf, Usd, UsdSkel, Vt

    from rigslim.io.usd.read import sibling_clips

    stage = Usd.Stage.Open(str(hero))
    wave = UsdSkel.Animation.Define(stage, "/Hero/Rig/Wave")
    wave.CreateJointsAttr(["root/mid"])
    alien = UsdSkel.Animation.Define(stage, "/Hero/Rig/Alien")
    alien.CreateJointsAttr(["root/elsewhere"])
    far = UsdSkel.Animation.Define(stage, "/Hero/Geo/Far")
    far.CreateJointsAttr(["root/mid"])
    for t in range(0, 13, 3):
        for anim in (wave, alien, far):
            anim.CreateTranslationsAttr().Set(Vt.Vec3fArray([(0, 0, 2)]), t)
            anim.CreateRotationsAttr().Set(Vt.QuatfArray([Gf.Quatf(Gf.Rotation(Gf.Vec3d(1, 0, 0), 5.0 * t)
                                                                    .GetQuat())]), t)
            anim.CreateScalesAttr().Set(Vt.Vec3hArray([(1, 1, 1)]), t)
    stage.GetRootLayer().Save()
    clips, notes = sibling_clips(read_usd_skin(hero, fps=24))
    assert [name for name, _ in clips] == ["Wave"]
    assert len(clips[0][1]) == 13
    np.testing.assert_allclose(clips[0][1].T, read_usd_skin(hero, animation="Wave", fps=24).poses.T)
    assert len(notes) == 1 and "/Hero/Rig/Alien" in notes[0] and "left out" in notes[0]
    clips, _ = sibling_clips(read_usd_skin(hero, animation="Wave", fps=24))
    assert [name for name, _ in clips] == ["Bend"] and len(clips[0][1]) == 25
    assert sibling_clips(read_usd_skin(hero, times=[0.0], animation="Wave"))[0][0][0] == "Bend"


def test_reduced_weights_are_written_with_element_size_k(hero, tmp_path):
    u = read_usd_skin(hero)
    reduced = top_k(u.weights, 2)
    before = hero.read_bytes()
    out = tmp_path / "out" / "hero-k2.usdc"
    stats = write_usd(out, u, reduced)
    assert hero.read_bytes() == before
    assert stats["element_size"] == 2
    r = read_usd_skin(out)
    assert all(p.element_size == 2 for p in r.parts)
    assert abs(r.weights - reduced.to_sparse()).max() < 1e-6
    assert (np.diff(r.weights.indptr) <= 2).all()
    assert check_usd(out) == []
    # everything else is kept: UVs, subsets, blend shapes, the mesh's skel:joints now the skeleton's order
    from pxr import Usd, UsdGeom, UsdSkel

    stage = Usd.Stage.Open(str(out))
    strip = stage.GetPrimAtPath("/Hero/Geo/Strip")
    assert UsdGeom.PrimvarsAPI(strip).GetPrimvar("st").GetInterpolation() == "faceVarying"
    assert len(UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(strip))) == 2
    assert list(UsdSkel.BindingAPI(strip).GetJointsAttr().Get()) == r.joints
    assert stage.GetPrimAtPath("/Hero/Geo/Strip/Bulge")
    assert UsdGeom.GetStageUpAxis(stage) == "Z" and UsdGeom.GetStageMetersPerUnit(stage) == 0.01
    ref = usdskel_points(r)
    for f in (0, 7, 20):
        assert np.abs(linear_blend(r.mesh.V, r.weights, r.poses.T[f]) - ref[f]).max() < 1e-5
