"""``rigslim lod`` with joint budgets and switch coverage (framework/commands/lod_levels.py)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigslim.commands.cli import main
from rigslim.io.gltf.document import load_gltf, read_accessor
from rigslim.io.gltf.lod import lod_nodes
from rigslim.io.gltf.skin import skinning_sets

ROOT = Path(__file__).resolve().parents[3]
DRONE = ROOT / "examples" / "data" / "gltf" / "suite" / "re_drone.glb"
HUESITOS = ROOT / "examples" / "data" / "gltf" / "huesitos.glb"


@pytest.mark.parametrize("extra, match", [
    (["--max-joints", "12,6,3"], "one joint count"),
    (["--max-joints", "0"], "--max-joints"),
    (["--max-joints", "2.5"], "--max-joints"),
    (["--max-joints", "x"], "--max-joints"),
    (["--max-joints", "6", "--keep-joints", "Hand("], "regular expression"),
    (["--keep-joints", "Hand"], "needs --max-joints"),
    (["--joint-choice", "global"], "needs --max-joints"),
    (["--pixel-error", "0"], "--pixel-error"),
    (["--fov", "180"], "--fov"),
    (["--resolution", "0"], "--resolution"),
])
def test_bad_joint_and_coverage_options_are_one_line_and_exit_2(extra, match, tmp_path, capsys):
    out = tmp_path / "x.glb"
    assert main(["lod", str(HUESITOS), "-o", str(out), "--ratios", "0.5,0.25", *extra]) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "\n" not in err and "Traceback" not in err
    assert not out.exists()


@pytest.fixture(scope="module")
def drone(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("drone")
    out, rep = tmp / "drone.glb", tmp / "drone.json"
    assert main(["lod", str(DRONE), "-o", str(out), "--clip", "left", "--ratios", "0.5,0.25", "--max-error", "none",
                 "--max-joints", "10,5", "--keep-joints", "^Head$", "--report", str(rep)]) == 0
    return out, json.loads(rep.read_text())


def _weighted_nodes(doc, node) -> set[int]:
    """Nodes of the joints that carry weight in a node's mesh."""
    js = doc.json
    joints = js["skins"][js["nodes"][node]["skin"]]["joints"]
    out = set()
    for prim in js["meshes"][js["nodes"][node]["mesh"]]["primitives"]:
        a = prim["attributes"]
        for s in skinning_sets(a):
            J = np.asarray(read_accessor(doc, a[f"JOINTS_{s}"])).reshape(-1)
            W = np.asarray(read_accessor(doc, a[f"WEIGHTS_{s}"])).reshape(-1)
            out |= {joints[j] for j in J[W > 0]}
    return out


def test_levels_keep_the_needed_joints_and_meet_their_budgets(drone):
    out, report = drone
    doc = load_gltf(out)
    names = {i: n.get("name") for i, n in enumerate(doc.json["nodes"])}
    (node, ids), = lod_nodes(doc.json).items()
    full = _weighted_nodes(doc, node)
    budget = next(s for s in report["run"]["steps"] if s["stage"] == "decimate")["report"]["joint_budget"]
    assert "Hand.Left" in budget["required"] and budget["required"]["Head"] == "named"
    for nid, row, cap in zip(ids, report["levels"], (10, 5), strict=True):
        used = _weighted_nodes(doc, nid)
        kept = {names[j] for j in used}
        assert used <= full and len(used) == row["joints"] == len(doc.json["skins"][doc.json["nodes"][nid]["skin"]]
                                                                  ["joints"])
        needed = {n for n in budget["required"] if n in {names[j] for j in full}}
        assert needed <= kept                               # the hand holding the Weapon, and Head, stay
        assert row["joint_budget"]["met"] == (len(used) <= cap)
        if len(needed) <= cap:
            assert len(used) <= cap


def test_report_rows_say_faces_joints_influences_error_and_coverage(drone):
    out, report = drone
    js = load_gltf(out).json
    (node, ids), = lod_nodes(js).items()
    coverage = js["nodes"][node]["extras"]["MSFT_screencoverage"]
    assert report["switch"]["coverage"] == coverage and len(coverage) == 3 and coverage[-1] == 0.0
    assert coverage[0] >= coverage[1] >= coverage[2]
    for i, (nid, row) in enumerate(zip(ids, report["levels"], strict=True)):
        for key in ("faces", "vertices", "joints", "influences", "max_bones", "error_max_m", "error_rms_m",
                    "screen_coverage", "switch_distance_m", "joint_matrices_per_draw"):
            assert row[key] is not None, key
        assert row["influences"] <= row["vertices"] * row["max_bones"] and row["max_bones"] <= 4
        assert row["screen_coverage"] == coverage[i]
        extra = js["nodes"][nid]["extras"]["rigslim_lod"]
        assert extra["level"] == i + 1 and extra["error_max_m"] == row["error_max_m"]
    assert report["levels"][0]["error_max_m"] <= report["levels"][1]["error_max_m"] or \
        report["levels"][0]["switch_distance_m"] == report["levels"][1]["switch_distance_m"]


def test_the_report_shows_faces_joints_influences_error_and_coverage_per_level(tmp_path):
    """``rigslim report`` of a run on a suite character: one row per level with all five."""
    from rigslim.report.gltf import lod_rows

    yml = tmp_path / "drone.yaml"
    yml.write_text(f"""
inputs:
  gltf: {{path: {DRONE}, animation: left}}
poses: {{examples: "0::4", test: "2::4"}}
steps:
  - decimate: quartic
    targets: [0.5, 0.25]
    max_bones: 4
    joint_budget: [12, 6]
  - evaluate:
      - metro: {{samples: 1000}}
  - write: out/drone-lod.glb
    lod: true
    quantize: ubyte
""")
    assert main(["run", str(yml), "--metrics", str(tmp_path / "m.json"), "-q"]) == 0
    out = tmp_path / "report.html"
    assert main(["report", str(tmp_path / "m.json"), "-o", str(out), "--no-renders", "-q"]) == 0
    text = out.read_text()
    assert "<th>joints</th><th>influences</th><th>error max (m)</th><th>error RMS (m)</th><th>coverage</th>" in text
    rows = lod_rows(tmp_path / "out" / "drone-lod.glb")
    assert [r["level"] for r in rows] == [0, 1, 2]
    assert rows[0]["joints"] == 24 and rows[1]["joints"] <= 12 and rows[2]["joints"] <= 6
    assert rows[0]["error_max_m"] == 0.0 < rows[1]["error_max_m"] <= rows[2]["error_max_m"]
    assert rows[0]["coverage"] >= rows[1]["coverage"] >= rows[2]["coverage"] == 0.0
    assert rows[2]["influences"] <= rows[1]["influences"] <= rows[0]["influences"]
    for r in rows:
        assert f"<td>{r['triangles']}</td><td>{r['vertices']}</td><td>{r['joints']}</td><td>{r['influences']}</td>" \
            in text


def test_switch_error_rms_switches_no_later_than_max(tmp_path):
    """A smaller error (the RMS) shows at a larger coverage: nearer."""
    cov = {}
    for kind in ("max", "rms"):
        out, rep = tmp_path / f"{kind}.glb", tmp_path / f"{kind}.json"
        assert main(["lod", str(HUESITOS), "-o", str(out), "--ratios", "0.5,0.25", "--max-error", "none",
                     "--switch-error", kind, "--report", str(rep)]) == 0
        report = json.loads(rep.read_text())
        assert report["switch"]["error"] == kind
        cov[kind] = report["switch"]["coverage"]
        rows = report["levels"]
        assert all(r["error_rms_m"] <= r["error_max_m"] for r in rows)
    assert all(r >= m for r, m in zip(cov["rms"], cov["max"], strict=True))
    assert cov["rms"][0] > cov["max"][0]
