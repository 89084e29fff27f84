"""``rigslim reduce``/``lod``/``compare``/``inspect`` with USD files wherever they take glTF (docs/usd.md)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigslim.commands.cli import main
from rigslim.io.usd.check import check_usd
from rigslim.io.usd.read import read_usd_skin

ROOT = Path(__file__).resolve().parents[3]
HUESITOS = ROOT / "examples" / "data" / "gltf" / "huesitos.glb"


def run(argv, capsys):
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, out.out, out.err


@pytest.fixture(scope="module")
def exported(tmp_path_factory):
    """huesitos.glb as UsdSkel with its weights as they are (-k at least the joint count: no reduction)."""
    folder = tmp_path_factory.mktemp("usd-commands")
    out = folder / "huesitos.usdc"
    assert main(["reduce", str(HUESITOS), "-o", str(out), "-k", "9"]) == 0
    return out


def test_reduce_gltf_to_usd_keeps_the_motion(exported, capsys):
    assert check_usd(exported) == []
    code, out, _ = run(["compare", HUESITOS, exported, "--json"], capsys)
    assert code == 0
    res = json.loads(out)
    assert res["faces"] == res["reference_faces"] == 120
    # the glTF is posed unwelded (seam copies), the USD file welded: same surface, compared by Hausdorff
    assert res["hausdorff_rms_pct"] < 1e-4 and res["hausdorff_max_pct"] < 1e-3


def test_compare_matches_split_and_welded_vertices_corner_by_corner(exported, tmp_path, capsys):
    """glTF (seam copies) against its UsdSkel copy (welded points), both ways, and a USD -> glTF reduction: the
    faces correspond in order, so vertices are matched corner by corner and the vertex-to-vertex figures come
    back (``reduce`` prints its test-pose position RMS again for a USD input written as glTF)."""
    for ref, cand in ((HUESITOS, exported), (exported, HUESITOS)):
        code, out, _ = run(["compare", ref, cand, "--json"], capsys)
        res = json.loads(out)
        assert code == 0 and res["position_rms_pct"] < 1e-3 and res["normal_rms_rad"] < 1e-3     # float32 USD
        assert res["position_max_m"] < 1e-4 * res["reference_diagonal_m"]
        assert res["hausdorff_max_bound_m"] == res["position_max_m"]
    glb = tmp_path / "back.glb"
    code, text, err = run(["reduce", exported, "-o", glb, "-k", "2"], capsys)
    assert code == 0, err
    assert "test-pose position RMS" in text


def test_corner_map_needs_the_same_faces_in_the_same_order():
    """One reference vertex per candidate vertex, every candidate vertex used, ``map[Fc] == Fr``; otherwise None."""
    from rigslim.commands.compare import corner_map

    Fr = np.array([[0, 1, 2], [2, 1, 3]])
    Fc = np.array([[0, 1, 2], [4, 1, 3]])          # vertex 2 split into 2 and 4 (a seam)
    np.testing.assert_array_equal(corner_map(Fr, Fc, 5), [0, 1, 2, 3, 2])
    assert corner_map(Fc, Fr, 4) is None            # welded -> split is the other direction's map
    assert corner_map(Fr, np.array([[1, 2, 0], [4, 1, 3]]), 5) is None    # corners in another order
    assert corner_map(Fr, Fc, 6) is None            # an unused candidate vertex
    assert corner_map(Fr, Fc[:1], 5) is None        # other faces


def test_reduce_usd_to_usd_writes_element_size_k(exported, tmp_path, capsys):
    out = tmp_path / "k2.usda"
    report = tmp_path / "k2.json"
    code, text, err = run(["reduce", exported, "-o", out, "-k", "2", "--report", report], capsys)
    assert code == 0, err
    assert "test-pose position RMS" in text
    u = read_usd_skin(out)
    assert [p.element_size for p in u.parts] == [2] and (u.weights.getnnz(axis=1) <= 2).all()
    assert check_usd(out) == []
    doc = json.loads(report.read_text())
    assert doc["pipeline"]["inputs"]["usd"]["path"] == str(exported)
    assert doc["world"]["position_rms_pct"] < 5


def test_lod_usd_to_usdz_and_compare_a_level(exported, tmp_path, capsys):
    out = tmp_path / "lod.usdz"
    argv = ["lod", exported, "-o", out, "--ratios", "0.5,0.25", "--max-bones", "2", "--max-error", "none"]
    code, text, err = run(argv, capsys)
    assert code == 0, err
    assert check_usd(out) == []
    faces = [read_usd_skin(out, lod=i).mesh.n_faces for i in range(3)]
    assert faces[0] == 120 and faces[1] < 120 and faces[2] < faces[1]
    code, res, _ = run(["compare", exported, out, "--level", "2", "--json"], capsys)
    res = json.loads(res)
    assert code == 0 and res["faces"] == faces[2]
    assert 0 < res["hausdorff_rms_pct"] < 10


def test_inspect_usd(exported, capsys):
    code, text, _ = run(["inspect", exported], capsys)
    assert code == 0
    assert "skeleton /huesitos/Skeleton: 9 joints" in text and "passes every USD validator" in text
    code, text, _ = run(["inspect", exported, "--json"], capsys)
    info = json.loads(text)
    assert info["skeletons"][0]["meshes"][0]["element_size"] == 4 and info["validation"] == []
    assert np.isclose(info["meters_per_unit"], 1.0) and info["up_axis"] == "Y"


@pytest.mark.parametrize("argv, match", [
    (["lod", "{usd}", "-o", "{tmp}/x.usda", "--split", "--ratios", "0.5"], "--split"),
    (["reduce", "{usd}", "-o", "{usd}", "-k", "1"], "is the input"),
    (["reduce", "{tmp}/missing.usdc", "-o", "{tmp}/x.usdc", "-k", "1"], "file not found"),
    (["inspect", "{tmp}/notes.txt"], "not a glTF or USD file"),
    (["reduce", "{usd}", "-o", "{tmp}/x.usdc", "-k", "65"], "-k"),
])
def test_bad_usd_command_lines_are_one_line(argv, match, exported, tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("x")
    copy = tmp_path / "in.usdc"
    copy.write_bytes(exported.read_bytes())
    before = copy.read_bytes()
    code, _, err = run([a.format(usd=copy, tmp=tmp_path) for a in argv], capsys)
    lines = [line for line in err.splitlines() if line.startswith("rigslim: error: ")]
    assert code == 2 and len(lines) == 1 and match in lines[0], err
    assert "Traceback" not in err
    assert copy.read_bytes() == before
