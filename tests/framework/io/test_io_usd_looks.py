"""glTF -> USD -> glTF keeps the look: materials, base colour textures, UVs, normals, the primitive split."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pxr")

from rigslim.commands.cli import main  # noqa: E402
from rigslim.io.gltf.document import load_gltf, read_accessor  # noqa: E402

SUITE = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "suite"


def _corners(path):
    """Per primitive: material, and {sorted face positions: (positions, normals, uvs)} of every triangle."""
    doc = load_gltf(path)
    out = []
    for prim in doc.json["meshes"][0]["primitives"]:
        a = prim["attributes"]
        P = read_accessor(doc, a["POSITION"])
        N = read_accessor(doc, a["NORMAL"])
        T = read_accessor(doc, a["TEXCOORD_0"]) if "TEXCOORD_0" in a else None
        F = read_accessor(doc, prim["indices"]).astype(np.int64).reshape(-1, 3)
        faces = {}
        for f in F:
            order = np.lexsort(P[f].T[::-1])
            key = tuple(np.round(P[f][order], 5).ravel())
            faces[key] = (N[f][order], None if T is None else T[f][order])
        out.append((prim.get("material"), faces))
    return doc, out


@pytest.fixture(scope="module")
def frankie_round_trip(tmp_path_factory):
    """frankie (two textured primitives, one MASK and double-sided) reduced to .usda, then back to .glb."""
    tmp = tmp_path_factory.mktemp("looks")
    usd, back = tmp / "frankie.usda", tmp / "frankie.glb"
    assert main(["reduce", str(SUITE / "frankie.glb"), "-k", "4", "-o", str(usd)]) == 0
    assert main(["reduce", str(usd), "-k", "4", "-o", str(back)]) == 0
    return usd, back


def test_round_trip_keeps_materials_textures_uvs_normals(frankie_round_trip):
    _, back = frankie_round_trip
    src_doc, src = _corners(SUITE / "frankie.glb")
    out_doc, out = _corners(back)
    sj, oj = src_doc.json, out_doc.json
    assert len(oj["materials"]) == len(sj["materials"]) == 2
    assert len(out) == len(src) == 2                                  # the primitive split
    for (ms, fs), (mo, fo) in zip(src, out, strict=True):
        a, b = sj["materials"][ms], oj["materials"][mo]
        assert b["name"] == a["name"]
        assert b.get("alphaMode", "OPAQUE") == a.get("alphaMode", "OPAQUE")
        assert b.get("doubleSided", False) == a.get("doubleSided", False)
        assert b["pbrMetallicRoughness"]["metallicFactor"] == pytest.approx(a["pbrMetallicRoughness"]["metallicFactor"])
        ta = sj["textures"][a["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]
        tb = oj["textures"][b["pbrMetallicRoughness"]["baseColorTexture"]["index"]]["source"]
        assert out_doc.buffer_view_bytes(oj["images"][tb]["bufferView"]) == \
            src_doc.buffer_view_bytes(sj["images"][ta]["bufferView"])
        assert fs.keys() == fo.keys()
        n_err = max(np.abs(fs[k][0] - fo[k][0]).max() for k in fs)
        uv_err = max(np.abs(fs[k][1] - fo[k][1]).max() for k in fs)
        assert n_err < 1e-5 and uv_err < 1e-6


def test_round_trip_usd_has_preview_surface_with_texture(frankie_round_trip):
    from pxr import Usd, UsdGeom, UsdShade

    from rigslim.io.usd.check import check_usd

    usd, _ = frankie_round_trip
    stage = Usd.Stage.Open(str(usd))
    files = []
    for prim in stage.Traverse():
        if prim.IsA(UsdShade.Shader) and UsdShade.Shader(prim).GetIdAttr().Get() == "UsdUVTexture":
            asset = UsdShade.Shader(prim).GetInput("file").Get()
            assert asset.path.startswith("./frankie_textures/") and Path(asset.resolvedPath).is_file()
            files.append(asset.path)
    assert len(files) == 2
    mesh = next(p for p in stage.Traverse() if p.IsA(UsdGeom.Mesh))
    normals = UsdGeom.PrimvarsAPI(mesh).GetPrimvar("normals")
    assert normals.GetInterpolation() == "faceVarying" and normals.IsIndexed()
    assert check_usd(usd) == []


def test_round_trip_output_passes_the_validator(frankie_round_trip):
    from support.gltf_validator import validate_gltf, validator_available

    if not validator_available():
        pytest.skip("glTF-Validator is not installed (make test-tools)")
    report = validate_gltf(frankie_round_trip[1])
    assert report["issues"]["numErrors"] == 0


def test_lod_levels_from_usd_keep_materials_and_uvs(frankie_round_trip, tmp_path):
    usd, _ = frankie_round_trip
    out = tmp_path / "lod.glb"
    assert main(["lod", str(usd), "-o", str(out), "--ratios", "0.5"]) == 0
    js = load_gltf(out).json
    assert len(js["meshes"]) == 2
    for mesh in js["meshes"]:
        assert sorted(p["material"] for p in mesh["primitives"]) == [0, 1]
        assert all("TEXCOORD_0" in p["attributes"] and "NORMAL" in p["attributes"] for p in mesh["primitives"])


def test_usd_without_material_gets_a_non_metallic_fallback(tmp_path):
    """A mesh bound to no material is written with USD's fallback look, not glTF's metallic default."""
    from pxr import Usd, UsdGeom

    usd = tmp_path / "plain.usda"
    assert main(["reduce", str(SUITE / "wuson.glb"), "-k", "4", "-o", str(usd)]) == 0
    stage = Usd.Stage.Open(str(usd))
    for prim in list(stage.Traverse()):
        if prim.IsA(UsdGeom.Subset):
            stage.RemovePrim(prim.GetPath())
    stage.GetRootLayer().Save()
    out = tmp_path / "plain.glb"
    assert main(["reduce", str(usd), "-k", "4", "-o", str(out)]) == 0
    js = load_gltf(out).json
    (mat,) = js["materials"]
    assert mat["pbrMetallicRoughness"]["metallicFactor"] == 0.0
    assert js["meshes"][0]["primitives"][0]["material"] == 0
