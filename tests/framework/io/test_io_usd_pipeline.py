"""USD inputs and outputs in pipelines: reduce and simplify a UsdSkel character, write it back, check the files.

The written levels are read back level by level (``lod=``), posed by UsdSkel
and by rigslim, and compared with the levels the decimation step made; the
carried UVs, material subsets and blend shapes are checked on each level;
every written file passes the USD validators in every LOD variant.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from test_io_usd import make_character

from rigslim.io.usd.check import check_usd
from rigslim.io.usd.read import read_usd_skin
from rigslim.io.usd.skinning import usdskel_points
from rigslim.numerics.blend import linear_blend
from rigslim.runtime.run import run_pipeline

PIPELINE = """\
name: usd-lod
inputs:
  usd:
    path: hero.usda
    fps: 24
poses:
  examples: "0:25:3"
  test: "1:25:3"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - decimate: quartic
    targets: [0.5, 0.25]
    max_bones: 2
  - evaluate: [position-rms]
  - write: out/hero-variant.usda
  - write: out/hero-prims.usdc
    lod: prims
  - write: out/hero.usdz
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory):
    folder = tmp_path_factory.mktemp("usd-lod")
    make_character(folder / "hero.usda")
    before = (folder / "hero.usda").read_bytes()
    (folder / "pipeline.yaml").write_text(PIPELINE)
    result = run_pipeline(folder / "pipeline.yaml")
    assert (folder / "hero.usda").read_bytes() == before
    return folder, result


@pytest.mark.parametrize("name", ["hero-variant.usda", "hero-prims.usdc", "hero.usdz"])
def test_levels_pass_the_validators(run, name):
    folder, _ = run
    assert check_usd(folder / "out" / name) == []


@pytest.mark.parametrize("name", ["hero-variant.usda", "hero-prims.usdc", "hero.usdz"])
def test_each_level_reads_back_as_the_decimation_made_it(run, name):
    folder, result = run
    asset = result.asset
    levels = asset.levels
    assert len(levels) == 2
    for i in range(3):
        u = read_usd_skin(folder / "out" / name, lod=i, fps=24)
        V = asset.mesh.V if i == 0 else levels[i - 1].mesh.V
        W = asset.reduced.to_sparse() if i == 0 else levels[i - 1].weights.to_sparse()
        assert u.mesh.n_faces == (asset.mesh.n_faces if i == 0 else levels[i - 1].n_faces)
        # the same rest points, each with its own weights (matched by position)
        order = np.lexsort(np.round(u.mesh.V, 5).T)
        ref_order = np.lexsort(np.round(V, 5).T)
        assert u.mesh.n_vertices == len(V)
        np.testing.assert_allclose(u.mesh.V[order], V[ref_order], atol=1e-5)
        assert abs(u.weights[order] - W[ref_order]).max() < 1e-6
        assert all(p.element_size == 2 for p in u.parts)
        ref = usdskel_points(u)
        for f in (0, 6, 13):
            mine = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
            assert np.abs(mine - ref[f]).max() < 1e-5
            asset_posed = linear_blend(V, W, asset.poses.T[f])
            np.testing.assert_allclose(mine[order], asset_posed[ref_order], atol=1e-4)


def test_levels_carry_uvs_subsets_and_blend_shapes(run):
    from pxr import Usd, UsdGeom, UsdSkel

    folder, result = run
    stage = Usd.Stage.Open(str(folder / "out" / "hero-variant.usda"))
    root = stage.GetPrimAtPath("/Hero")
    vset = root.GetVariantSets().GetVariantSet("LOD")
    assert vset.GetVariantNames() == ["LOD0", "LOD1", "LOD2"] and vset.GetVariantSelection() == "LOD0"
    for name in ("LOD1", "LOD2"):
        vset.SetVariantSelection(name)
        strip = UsdGeom.Mesh(stage.GetPrimAtPath("/Hero/Geo/Strip"))
        faces = len(strip.GetFaceVertexCountsAttr().Get())
        assert set(strip.GetFaceVertexCountsAttr().Get()) == {3}
        st = UsdGeom.PrimvarsAPI(strip).GetPrimvar("st")
        assert st.GetInterpolation() == "faceVarying"
        uv = np.array(st.ComputeFlattened())
        assert uv.shape == (3 * faces, 2)
        # each face keeps its own chart: all three corners in the same one (u < 1.5 or u >= 1.5)
        chart = uv[:, 0].reshape(-1, 3) >= 1.5
        assert (chart.all(axis=1) | ~chart.any(axis=1)).all()
        assert uv[:, 1].min() >= -1e-6 and uv[:, 1].max() <= 1 + 1e-6
        subsets = UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(strip))
        members = np.sort(np.concatenate([np.array(s.GetIndicesAttr().Get()) for s in subsets]))
        np.testing.assert_array_equal(members, np.arange(faces))     # still a partition of the faces
        shape = UsdSkel.BlendShape(stage.GetPrimAtPath("/Hero/Geo/Strip/Bulge"))
        idx = np.array(shape.GetPointIndicesAttr().Get())
        offsets = np.array(shape.GetOffsetsAttr().Get())
        assert len(idx) == len(offsets) > 0
        assert idx.max() < len(strip.GetPointsAttr().Get())
        hat = stage.GetPrimAtPath("/Hero/Geo/Hat")
        assert UsdSkel.BindingAPI(hat).GetJointIndicesPrimvar().GetElementSize() == 2


def test_prims_layout_is_a_usdlod_root_with_hidden_levels(run):
    from pxr import Usd, UsdGeom, UsdLod

    folder, _ = run
    stage = Usd.Stage.Open(str(folder / "out" / "hero-prims.usdc"))
    lods = stage.GetPrimAtPath("/Hero/LODs")
    assert lods.HasAPI(UsdLod.RootAPI)
    assert [c.GetName() for c in lods.GetChildren()] == ["LOD0", "LOD1", "LOD2"]
    assert UsdGeom.Imageable(lods.GetChild("LOD0")).ComputeVisibility() == "inherited"
    assert UsdGeom.Imageable(lods.GetChild("LOD2")).ComputeVisibility() == "invisible"
    assert not stage.GetPrimAtPath("/Hero/Geo/Strip")
    # the default read takes item lod:default:index only, not every level merged
    u = read_usd_skin(folder / "out" / "hero-prims.usdc")
    assert u.mesh.n_faces == 2 * 88 + 1


def test_a_gltf_input_is_written_as_usd_with_levels_and_read_back(tmp_path):
    from pathlib import Path

    gltf = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "huesitos.glb"
    (tmp_path / "to-usd.yaml").write_text(f"""\
inputs:
  gltf: {gltf}
poses:
  examples: "0:40:4"
  test: "2:40:4"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - decimate: quartic
    targets: [0.5]
    max_bones: 2
  - write: huesitos.usda
""")
    result = run_pipeline(tmp_path / "to-usd.yaml")
    assert check_usd(tmp_path / "huesitos.usda") == []
    u = read_usd_skin(tmp_path / "huesitos.usda")
    asset = result.asset
    assert u.mesh.n_vertices == asset.mesh.n_vertices and all(p.element_size == 2 for p in u.parts)
    for f in (0, 10, 30):
        mine = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
        theirs = linear_blend(asset.mesh.V, asset.reduced.to_sparse(), asset.poses.T[f])
        scale = np.linalg.norm(theirs.max(axis=0) - theirs.min(axis=0))
        assert np.abs(mine - theirs).max() < 2e-5 * scale
    assert read_usd_skin(tmp_path / "huesitos.usda", lod=1).mesh.n_faces == asset.levels[0].n_faces
    (tmp_path / "again.yaml").write_text("""\
inputs:
  usd: huesitos.usda
poses:
  examples: "0:40:4"
  test: "2:40:4"
steps:
  - select: k-largest
    k: 1
  - solve: k-largest
  - write: back.usdc
  - write: back.npz
""")
    back = run_pipeline(tmp_path / "again.yaml")
    assert read_usd_skin(tmp_path / "back.usdc").parts[0].element_size == 1 and back.asset.reduced.k == 1
    assert check_usd(tmp_path / "back.usdc") == []


def test_the_usd_examples_run_and_validate(tmp_path):
    """examples/usd-export-huesitos.yaml then examples/usd-simplify.yaml, from a copy of examples/."""
    import shutil
    from pathlib import Path

    examples = Path(__file__).resolve().parents[3] / "examples"
    (tmp_path / "data").symlink_to(examples / "data", target_is_directory=True)
    for name in ("usd-export-huesitos.yaml", "usd-simplify.yaml"):
        shutil.copy(examples / name, tmp_path / name)
        run_pipeline(tmp_path / name)
    for name in ("huesitos.usdc", "huesitos-lod.usdc", "huesitos-lod-prims.usda"):
        assert check_usd(tmp_path / "out" / name) == [], name
    for lod in (0, 1, 2):
        u = read_usd_skin(tmp_path / "out" / "huesitos-lod.usdc", lod=lod)
        assert all(p.element_size == 2 for p in u.parts) and (u.weights.getnnz(axis=1) <= 2).all()


def test_every_clip_of_a_multi_clip_character_is_exported(tmp_path):
    """A glTF input's other clips become SkelAnimations named after them; each poses like the glTF's."""
    from pathlib import Path

    from rigslim.io.gltf.skin import read_gltf_skin

    gltf = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "suite" / "wuson.glb"
    (tmp_path / "export.yaml").write_text(f"inputs:\n  gltf: {gltf}\nsteps:\n  - write: wuson.usdc\n")
    run_pipeline(tmp_path / "export.yaml")
    out = tmp_path / "wuson.usdc"
    assert check_usd(out) == []
    names = [a.get("name") for a in read_gltf_skin(gltf, times=[0.0]).document.json["animations"]]
    assert len(names) == 2
    for i, name in enumerate(names):
        g = read_gltf_skin(gltf, animation=i, weld=True)
        u = read_usd_skin(out, animation=name)
        assert u.animation.endswith(name) and len(u.poses) == len(g.poses)
        for f in range(0, len(g.poses), 9):
            a = linear_blend(g.mesh.V, g.weights, g.poses.T[f])
            b = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
            assert np.abs(a - b).max() <= 2e-5 * np.linalg.norm(a.max(axis=0) - a.min(axis=0)), (name, f)


def test_a_gltf_export_carries_uvs_and_material_slots(tmp_path):
    """tube_two_materials.glb (3 primitives, 2 materials, a UV seam): st per face corner, one subset per primitive."""
    from pathlib import Path

    from pxr import Usd, UsdGeom, UsdShade

    from rigslim.io.gltf.primitives import primitive_data, welded_faces
    from rigslim.io.gltf.skin import read_gltf_skin

    gltf = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "tube_two_materials.glb"
    (tmp_path / "export.yaml").write_text(f"""\
inputs:
  gltf: {gltf}
poses:
  examples: "0:31:3"
  test: "1:31:3"
steps:
  - decimate: quartic
    targets: [0.5]
  - write: tube.usda
""")
    run_pipeline(tmp_path / "export.yaml")
    out = tmp_path / "tube.usda"
    assert check_usd(out) == []
    skin = read_gltf_skin(gltf, weld=True)
    data = primitive_data(skin)
    corners = np.concatenate([d.attributes["TEXCOORD_0"][Ff - sl.start]
                              for d, sl, (_, Ff) in zip(data, skin.slices, welded_faces(skin, data), strict=True)]
                             ).reshape(-1, 2)
    stage = Usd.Stage.Open(str(out))
    body = stage.GetPrimAtPath("/tube_two_materials/Body")
    st = UsdGeom.PrimvarsAPI(body).GetPrimvar("st")
    assert st.GetInterpolation() == "faceVarying"
    uv = np.array(st.ComputeFlattened()).reshape(-1, 2)
    np.testing.assert_allclose(uv, np.stack([corners[:, 0], 1 - corners[:, 1]], 1), atol=1e-6)
    subsets = UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(body))
    assert len(subsets) == 3
    bound = {str(UsdShade.MaterialBindingAPI(s.GetPrim()).GetDirectBinding().GetMaterialPath()) for s in subsets}
    assert len(bound) == 2                      # three primitives, two materials
    vset = stage.GetPrimAtPath("/tube_two_materials").GetVariantSets().GetVariantSet("LOD")
    vset.SetVariantSelection("LOD1")
    level = stage.GetPrimAtPath("/tube_two_materials/Body")
    n = len(level.GetAttribute("faceVertexCounts").Get())
    members = np.sort(np.concatenate([np.array(s.GetIndicesAttr().Get())
                                      for s in UsdGeom.Subset.GetAllGeomSubsets(UsdGeom.Imageable(level))]))
    np.testing.assert_array_equal(members, np.arange(n))
    assert np.array(UsdGeom.PrimvarsAPI(level).GetPrimvar("st").ComputeFlattened()).shape == (3 * n, 2)


SUITE_WUSON = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "suite" / "wuson.glb"


def _clip_lengths(path) -> dict[str, int]:
    """``{SkelAnimation name: time samples}`` of every animation of a USD file, and the bound one's path."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    return {p.GetName(): len(UsdSkel.Animation(p).GetRotationsAttr().GetTimeSamples())
            for p in stage.Traverse() if p.IsA(UsdSkel.Animation)}


def _bound(path) -> tuple[str, float, float]:
    """The bound SkelAnimation's name and the stage's start and end time codes."""
    from pxr import Usd, UsdSkel

    stage = Usd.Stage.Open(str(path))
    skel = next(p for p in stage.Traverse() if p.IsA(UsdSkel.Skeleton))
    (target,) = UsdSkel.BindingAPI(skel).GetAnimationSourceRel().GetTargets()
    return target.name, stage.GetStartTimeCode(), stage.GetEndTimeCode()


def _assert_same_clip(g, u, scale: float, what) -> None:
    """Two reads of one clip pose their (index-matched) rest points alike, frame for frame."""
    assert len(u.poses) == len(g.poses), what
    for f in range(0, len(g.poses), 7):
        a = linear_blend(g.mesh.V, g.weights, g.poses.T[f])
        b = linear_blend(u.mesh.V, u.weights, u.poses.T[f])
        assert np.abs(a - b).max() <= 1e-4 * scale, (what, f)


@pytest.mark.parametrize("command, suffix", [("reduce", ".usda"), ("reduce", ".usdc"), ("lod", ".usdz")])
def test_each_exported_clip_holds_only_its_own_frames(tmp_path, command, suffix):
    """``rigslim reduce``/``lod`` stack every clip of the glTF for the fit; the bound SkelAnimation holds the
    read clip's frames alone (it held all 139 of both clips, endTimeCode 138) and each other clip its own."""
    from rigslim.commands.cli import main
    from rigslim.io.gltf.skin import read_gltf_skin

    out = tmp_path / f"wuson{suffix}"
    extra = ["--ratios", "0.5"] if command == "lod" else ["-k", "4"]
    assert main([command, str(SUITE_WUSON), "-o", str(out), *extra]) == 0
    names = [a["name"] for a in read_gltf_skin(SUITE_WUSON, times=[0.0]).document.json["animations"]]
    reads = [read_gltf_skin(SUITE_WUSON, animation=i, weld=True) for i in range(len(names))]
    assert _clip_lengths(out) == {n: len(g.poses) for n, g in zip(names, reads, strict=True)} \
        == {"Wuson_Run": 30, "Wuson_Walk": 109}
    assert _bound(out) == ("Wuson_Run", 0.0, 29.0)
    scale = float(np.linalg.norm(reads[0].mesh.V.max(axis=0) - reads[0].mesh.V.min(axis=0)))
    for name, g in zip(names, reads, strict=True):
        _assert_same_clip(g, read_usd_skin(out, animation=name), scale, name)
    assert check_usd(out) == []


def _without_animations(src, dst) -> None:
    """A copy of the .glb ``src`` with its animations taken out."""
    import json
    import struct

    from rigslim.io.gltf.document import load_gltf

    doc = load_gltf(src)
    js = dict(doc.json)
    js.pop("animations")
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    binary = doc.buffers[0] + b"\0" * ((-len(doc.buffers[0])) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    dst.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def test_one_clip_and_still_inputs_export_their_own_frames(tmp_path):
    """A one-clip glTF keeps its clip alone; a glTF without animations gets its rest pose (which the commands
    read twice, as one example and one test frame: ``times: [0, 0]``)."""
    from rigslim.commands.cli import main
    from rigslim.io.gltf.skin import read_gltf_skin

    gltf = SUITE_WUSON.parents[1] / "huesitos.glb"
    out = tmp_path / "huesitos.usda"
    assert main(["reduce", str(gltf), "-o", str(out), "-k", "2"]) == 0
    g = read_gltf_skin(gltf)
    (name,) = _clip_lengths(out)
    assert _clip_lengths(out) == {name: len(g.poses)} and _bound(out) == (name, 0.0, len(g.poses) - 1.0)
    still = tmp_path / "still.glb"
    _without_animations(SUITE_WUSON, still)
    out = tmp_path / "still.usdc"
    assert main(["lod", str(still), "-o", str(out), "--ratios", "0.5"]) == 0
    assert _clip_lengths(out) == {"Animation": 2} and _bound(out) == ("Animation", 0.0, 1.0)
    assert check_usd(out) == []


def test_usd_to_gltf_keeps_every_clip_by_name(tmp_path):
    """glTF -> USD -> glTF: the glTF written from the USD file has the bound clip and the SkelAnimation beside
    it, each under its name with its own frames posing like the source's (it had one clip, 'animation')."""
    from rigslim.commands.cli import main
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.skin import read_gltf_skin

    usd, back = tmp_path / "w.usda", tmp_path / "back.glb"
    assert main(["reduce", str(SUITE_WUSON), "-k", "4", "-o", str(usd)]) == 0
    assert main(["reduce", str(usd), "-k", "4", "-o", str(back)]) == 0
    assert [a["name"] for a in load_gltf(back).json["animations"]] == ["Wuson_Run", "Wuson_Walk"]
    for i, name in enumerate(("Wuson_Run", "Wuson_Walk")):
        g, b = read_gltf_skin(SUITE_WUSON, animation=i), read_gltf_skin(back, animation=name)
        assert len(b.poses) == len(g.poses), name
        scale = float(np.linalg.norm(g.mesh.V.max(axis=0) - g.mesh.V.min(axis=0)))
        at = {n: j for j, n in enumerate(b.handles.names)}
        order = [at[n] for n in g.handles.names]
        Tg, Tb = g.poses.T, b.poses.T[:, order]
        np.testing.assert_allclose(Tb[..., :3], Tg[..., :3], atol=1e-4, err_msg=name)
        np.testing.assert_allclose(Tb[..., 3], Tg[..., 3], atol=1e-5 * scale, err_msg=name)
