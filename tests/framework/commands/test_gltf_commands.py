"""The one-command glTF front ends: rigslim reduce, lod, compare, inspect (rigslim.commands)."""

from __future__ import annotations

import json
import struct
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import pytest
from support.gltf_validator import validate_gltf, validation_errors, validator_available

from rigslim.commands.cli import main
from rigslim.io.gltf.document import load_gltf, read_accessor
from rigslim.io.gltf.skin import skinning_sets

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"
#: Every skinned glTF character bundled in examples/data/gltf (assimp conversions, Khronos samples, the tube).
CHARACTERS = sorted(p for p in list(GLTF.glob("*.gl*")) + list(GLTF.glob("*/*.gltf")))


@pytest.fixture(scope="module")
def valid():
    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")

    def check(path):
        errors = validation_errors(validate_gltf(path))
        assert not errors, f"{path}: {errors[:5]}"

    return check


def _skin_rows(doc, prim) -> tuple[np.ndarray, np.ndarray]:
    """Decoded weights (v, 4 * sets) and the integer codes' row sums check of one primitive."""
    attrs = prim["attributes"]
    Ws = [np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"]), float) for s in skinning_sets(attrs)]
    raw = [np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"], normalize=False)) for s in skinning_sets(attrs)]
    return np.hstack(Ws), np.hstack(raw)


def check_no_empty_set(path: Path) -> int:
    """Every skinned primitive's last WEIGHTS_n has a non-zero weight (a set of zeros is dead weight); returns
    the most sets a primitive has."""
    doc = load_gltf(path)
    most = 0
    for mesh in doc.json["meshes"]:
        for prim in mesh["primitives"]:
            sets = skinning_sets(prim["attributes"])
            if sets:
                W, _ = _skin_rows(doc, prim)
                assert W[:, -4:].any(), f"{path}: {mesh.get('name')} has a WEIGHTS_{sets[-1]} of zeros"
                most = max(most, len(sets))
    return most


def check_lod_structure(source: Path, out: Path, levels: int) -> None:
    """Each original node links its own level nodes; each level mesh keeps the primitives, materials, UVs."""
    src, doc = load_gltf(source).json, load_gltf(out)
    js = doc.json
    if levels == 0:         # every target ended at the source (simple_skin's 8 faces at 1 %): the source alone
        assert not any("MSFT_lod" in (n.get("extensions") or {}) for n in js["nodes"])
        assert "MSFT_lod" not in js.get("extensionsUsed", []) and len(js["meshes"]) == len(src["meshes"])
        return
    skinned = [i for i, n in enumerate(js["nodes"]) if "skin" in n and "mesh" in n and i < len(src["nodes"])]
    seen = set()
    for i in skinned:
        node = js["nodes"][i]
        ids = node["extensions"]["MSFT_lod"]["ids"]
        assert len(ids) == levels
        assert not seen & set(ids), "a level node is shared between two original nodes"
        seen |= set(ids)
        assert len(node["extras"]["MSFT_screencoverage"]) == levels + 1
        orig = js["meshes"][node["mesh"]]
        for j in ids:
            lvl_node = js["nodes"][j]
            # the source skin, or a skin of its own with the joints its vertices use (level_skins)
            assert set(js["skins"][lvl_node["skin"]]["joints"]) <= set(js["skins"][node["skin"]]["joints"])
            mesh = js["meshes"][lvl_node["mesh"]]
            assert len(mesh["primitives"]) == len(orig["primitives"])
            for p_src, p in zip(orig["primitives"], mesh["primitives"], strict=False):
                assert p.get("material") == p_src.get("material")
                assert set(p_src["attributes"]) <= set(p["attributes"]) | {"JOINTS_1", "WEIGHTS_1"}
                assert len(p.get("targets", [])) == len(p_src.get("targets", []))
                W, raw = _skin_rows(doc, p)
                assert (W >= 0).all() and ((W > 0).sum(axis=1) <= 4).all()
                if raw.dtype == np.uint8:
                    assert (raw.astype(int).sum(axis=1) == 255).all()          # exactly one after decoding
                elif raw.dtype == np.uint16:
                    assert (raw.astype(int).sum(axis=1) == 65535).all()
    assert "MSFT_lod" in js["extensionsUsed"]
    check_no_empty_set(out)


@pytest.mark.parametrize("path", CHARACTERS, ids=lambda p: p.name)
def test_lod_on_every_bundled_character(path, tmp_path, valid):
    out = tmp_path / "lod.glb"
    assert main(["lod", str(path), "-o", str(out), "--ratios", "0.5,0.25", "--report", str(tmp_path / "r.json")]) == 0
    valid(out)            # the sources' unnormalised weights are written normalised: 0 errors
    report = json.loads((tmp_path / "r.json").read_text())
    step = next(s for s in report["run"]["steps"] if s["stage"] == "decimate")["report"]
    distinct = [t for t in step["targets"] if t["same_as"] is None]
    check_lod_structure(path, out, len(distinct))       # a target that ends where a finer one did: no level
    assert report["schema"] == "rigslim-gltf-command" and report["schema_version"] == 1
    assert [r["ratio"] for r in report["levels"]] == [0.5, 0.25][:len(distinct)]
    assert report["pipeline"]["steps"][0]["decimate"] == "quartic"
    faces = [r["faces"] for r in report["levels"]]
    assert all(a > b for a, b in zip(faces, faces[1:], strict=False))          # strictly decreasing
    assert not faces or faces[0] < report["input_faces"]       # never a "level" with the source's faces
    for t in step["targets"]:                           # unreached targets are named by their real faces
        assert (t["label"].endswith(f"-{t['faces']}f")) == (t["faces"] > 1.03 * t["target_faces"])


def test_lod_split_writes_one_pruned_file_per_level(tmp_path, valid):
    src = GLTF / "tube_two_materials.glb"
    out = tmp_path / "tube.glb"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.25", "--split"]) == 0
    assert not out.exists()
    sizes = []
    for name in ("tube-50.glb", "tube-25.glb"):
        f = tmp_path / name
        valid(f)
        js = load_gltf(f).json
        assert "MSFT_lod" not in json.dumps(js)
        assert len(js["meshes"]) == 2 and [len(m["primitives"]) for m in js["meshes"]] == [1, 2]
        assert len(js["nodes"]) == len(load_gltf(src).json["nodes"])
        sizes.append(f.stat().st_size)
    assert sizes[0] > sizes[1]


def test_lod_split_saved_pipeline_writes_the_same_files(tmp_path):
    """``lod --split --save-pipeline p.yaml``: the saved pipeline names -o with ``split: true`` (not the
    command's scratch file), and ``rigslim run p.yaml`` writes the same level files, byte for byte, and the
    same sidecar levels."""
    import yaml

    src, out, saved = GLTF / "huesitos.glb", tmp_path / "h.glb", tmp_path / "p.yaml"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.25", "--max-error", "none", "--split",
                 "--save-pipeline", str(saved)]) == 0
    write = yaml.safe_load(saved.read_text())["steps"][-1]
    assert write["write"] == str(out) and write["split"] is True and write["lod"] is True
    files = ["h-50.glb", "h-25.glb"]
    by_command = {f: (tmp_path / f).read_bytes() for f in files}
    side = json.loads((tmp_path / "h.lod.json").read_text())
    for f in [*files, "h.lod.json"]:
        (tmp_path / f).unlink()
    assert main(["run", str(saved), "-q"]) == 0
    assert {f: (tmp_path / f).read_bytes() for f in files} == by_command and not out.exists()
    again = json.loads((tmp_path / "h.lod.json").read_text())
    assert again["levels"] == side["levels"] and again["camera"] == side["camera"]


def test_tube_levels_keep_seams_materials_and_morph_targets(tmp_path):
    """Per primitive: level UVs come from the source's range, seam vertices keep both UVs, morphs carried."""
    src = GLTF / "tube_two_materials.glb"
    out = tmp_path / "tube.glb"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5"]) == 0
    doc = load_gltf(out)
    js = doc.json
    level_mesh = js["meshes"][js["nodes"][js["nodes"][1]["extensions"]["MSFT_lod"]["ids"][0]]["mesh"]]
    assert level_mesh["weights"] == [0.0] and level_mesh["extras"]["targetNames"] == ["bulge"]
    for p_src, p in zip(js["meshes"][1]["primitives"], level_mesh["primitives"], strict=False):
        uv_src = read_accessor(doc, p_src["attributes"]["TEXCOORD_0"])
        uv = read_accessor(doc, p["attributes"]["TEXCOORD_0"])
        assert uv[:, 0].min() >= uv_src[:, 0].min() - 1e-6 and uv[:, 0].max() <= uv_src[:, 0].max() + 1e-6
        P = read_accessor(doc, p["attributes"]["POSITION"])
        # a vertex on the tube's surface: radius 0.3 (collapses stay near the surface)
        assert np.abs(np.hypot(P[:, 0], P[:, 2]) - 0.3).max() < 0.02
        # the UV seam (u = 0 and u = 1 at the same position) survives: both ends of u are present
        assert np.isclose(uv[:, 0].min(), uv_src[:, 0].min()) and np.isclose(uv[:, 0].max(), uv_src[:, 0].max())
        # the morph target moves the level like the source: bulge at y = 1.5 is 0.1 outwards
        d = read_accessor(doc, p["targets"][0]["POSITION"])
        assert np.abs(d).max() <= 0.1 + 1e-6 and np.abs(d).max() > 0.05
        N = read_accessor(doc, p["attributes"]["NORMAL"])
        assert np.allclose(np.linalg.norm(N, axis=1), 1, atol=1e-5)
    # the morph weights animation plays on the level nodes too
    targets = [c["target"] for c in js["animations"][0]["channels"] if c["target"]["path"] == "weights"]
    assert len(targets) == 2


@pytest.mark.parametrize("path", [GLTF / "animation_with_skeleton.glb", GLTF / "RiggedFigure" / "RiggedFigure.gltf",
                                  GLTF / "tube_two_materials.glb"], ids=lambda p: p.name)
def test_reduce(path, tmp_path, valid):
    out = tmp_path / "k2.glb"
    assert main(["reduce", str(path), "-o", str(out), "-k", "2", "--solve", "k-largest",
                 "--report", str(tmp_path / "r.json")]) == 0
    valid(out)
    doc = load_gltf(out)
    for mesh in doc.json["meshes"]:
        for prim in mesh["primitives"]:
            W, raw = _skin_rows(doc, prim)
            assert ((W > 0).sum(axis=1) <= 2).all()
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["command"] == "reduce" and report["world"]["position_rms_m"] >= 0


def test_k8_writes_only_the_sets_the_widest_vertex_needs(tmp_path, valid):
    """RiggedFigure has at most 4 influences per vertex: reduce -k 8 writes JOINTS_0/WEIGHTS_0 only (it once added
    a WEIGHTS_1 of zeros); a lod --max-bones 8 --split level whose collapses blend 5 (a quarter of the faces, no
    error bound) keeps a second set."""
    src = GLTF / "RiggedFigure" / "RiggedFigure.gltf"
    out = tmp_path / "k8.glb"
    assert main(["reduce", str(src), "-o", str(out), "-k", "8", "--report", str(tmp_path / "r.json")]) == 0
    valid(out)
    assert check_no_empty_set(out) == 1
    step = next(s for s in json.loads((tmp_path / "r.json").read_text())["run"]["steps"] if s["stage"] == "write")
    assert step["report"]["sets"] == 1
    assert main(["lod", str(src), "-o", str(tmp_path / "rf.glb"), "--ratios", "0.25", "--max-bones", "8",
                 "--quantize", "ubyte", "--split", "--max-error", "none"]) == 0
    valid(tmp_path / "rf-25.glb")
    assert check_no_empty_set(tmp_path / "rf-25.glb") == 2


def test_reduce_says_when_every_vertex_passes_through(tmp_path, capsys):
    """RiggedFigure has at most 4 influences per vertex (19 joints): -k 4 keeps every vertex's weights, and the
    line says so instead of counting guard fall-backs; -k 3 reduces and counts them."""
    src = GLTF / "RiggedFigure" / "RiggedFigure.gltf"
    assert main(["reduce", str(src), "-o", str(tmp_path / "k4.glb"), "-k", "4"]) == 0
    line = capsys.readouterr().out
    assert "every vertex has at most 4 influences, so the weights pass through unchanged" in line
    assert "fell back" not in line
    assert main(["reduce", str(src), "-o", str(tmp_path / "k3.glb"), "-k", "3"]) == 0
    line = capsys.readouterr().out
    assert "pass through" not in line and "vertices fell back to k-largest" in line


def test_reduce_defaults_to_best_fit_by_error_fitted_on_every_clip(tmp_path, capsys):
    """No options: best-fit by error + geometric, examples from both of wuson's clips, the guard's count
    in the report and the line; --select k-largest / --by / --clip reach the other choices."""
    src = GLTF / "suite" / "wuson.glb"
    out, report = tmp_path / "k2.glb", tmp_path / "r.json"
    assert main(["reduce", str(src), "-o", str(out), "-k", "2", "--report", str(report)]) == 0
    line = capsys.readouterr().out
    doc = json.loads(report.read_text())
    assert doc["pipeline"]["steps"][:2] == [{"select": "best-fit", "k": 2, "by": "error"}, {"solve": "geometric"}]
    assert doc["pipeline"]["poses"] == {"examples": {"clips": "all", "count": 24}, "test": {"clips": "all"}}
    clips = doc["run"]["frames"]["clips"]
    assert {c["clip"] for c in clips["examples"]} == {c["clip"] for c in clips["test"]} == {"Wuson_Run", "Wuson_Walk"}
    solver = next(s for s in doc["run"]["steps"] if s["stage"] == "solve")["solver"]
    assert solver["guard"] == "k-largest" and solver["fallback_vertices"] == doc["guard_fallback_vertices"] > 0
    assert f"{doc['guard_fallback_vertices']} vertices fell back to k-largest" in line and "over 2 clips" in line
    # the validated reweighting's solves, in the report and (when any) on the line
    assert doc["reweight_rounds"] == solver["reweight_rounds"] >= 0
    assert ("re-solve" in line) == (doc["reweight_rounds"] > 0)
    best = doc["world"]["position_rms_m"]
    assert main(["reduce", str(src), "-o", str(tmp_path / "kl.glb"), "-k", "2", "--select", "k-largest",
                 "--solve", "k-largest", "--report", str(report)]) == 0
    assert best < json.loads(report.read_text())["world"]["position_rms_m"]
    assert main(["reduce", str(src), "-o", str(tmp_path / "w.glb"), "-k", "2", "--select", "best-fit", "--by",
                 "weight", "--clip", "Wuson_Walk", "--report", str(report)]) == 0
    doc = json.loads(report.read_text())
    assert doc["pipeline"]["steps"][0] == {"select": "best-fit", "k": 2, "by": "weight"}
    assert [c["clip"] for c in doc["run"]["frames"]["clips"]["test"]] == ["Wuson_Walk"]


def _without(path: Path, out: Path, *keys: str) -> Path:
    """A copy of the .glb ``path`` with the top-level JSON ``keys`` removed (its binary chunk unchanged)."""
    src = load_gltf(path)
    js = {k: v for k, v in src.json.items() if k not in keys}
    for node in js.get("nodes", []):
        if "skins" in keys:
            node.pop("skin", None)
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    binary = src.buffers[0]
    binary += b"\0" * ((-len(binary)) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    out.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return out


def test_reduce_without_animation_falls_back_to_k_largest(tmp_path, valid, capsys):
    """RiggedSimple-like input without clips: a file with its animations removed."""
    f = _without(GLTF / "huesitos.glb", tmp_path / "still.glb", "animations")
    assert main(["reduce", str(f), "-o", str(tmp_path / "o.glb"), "-k", "2"]) == 0
    assert "falling back to k-largest" in capsys.readouterr().err
    valid(tmp_path / "o.glb")


def test_lod_refuses_a_mesh_without_skin_before_any_note(tmp_path, capsys):
    """A static prop (no skin, no clip; assimp's Collada duck is one): one error line, not first the note
    "simplifying for the rest pose only" and then the error."""
    f = _without(GLTF / "huesitos.glb", tmp_path / "prop.glb", "animations", "skins")
    assert main(["lod", str(f), "-o", str(tmp_path / "o.glb")]) == 2
    err = capsys.readouterr().err.strip()
    assert "skins: the file has no skin" in err and "\n" not in err and "rest pose" not in err
    assert not (tmp_path / "o.glb").exists()


@pytest.mark.parametrize("argv, match", [
    (["lod", "missing.glb", "-o", "x.glb"], "file not found"),
    (["lod", "{src}", "-o", "x.obj"], "not a .glb"),
    (["lod", "{src}", "-o", "x.glb", "--ratios", "0.25,0.5"], "decreasing"),
    (["lod", "{src}", "-o", "x.glb", "--max-bones", "9"], "1 to 8"),
    (["lod", "{src}", "-o", "x.glb", "--max-error", "2cm"], "--max-error"),
    (["lod", "{src}", "-o", "x.glb", "--max-error", "-1"], "--max-error"),
    (["reduce", "{src}", "-o", "x.glb", "-k", "0"], "1 to 8"),
    (["reduce", "{src}", "-o", "x.glb", "--clip", "nope"], "no animation named"),
    (["compare", "{src}", "{src}", "--level", "1"], "no LOD level 1"),
    (["compare", "{src}", "{src}", "--frames", "x:y"], "--frames"),
    (["inspect", "README.md"], "not a glTF"),
])
def test_bad_input_is_one_line_and_exit_2(argv, match, tmp_path, capsys):
    src = str(GLTF / "huesitos.glb")
    argv = [a.replace("{src}", src) for a in argv]
    argv = [str(tmp_path / a) if a in ("x.glb", "x.obj") else a for a in argv]
    assert main(argv) == 2
    err = capsys.readouterr().err.strip()
    assert match in err and "\n" not in err and "Traceback" not in err
    assert not (tmp_path / "x.glb").exists()


def test_lod_max_error_stops_levels_and_says_so(tmp_path, capsys):
    """A level that reaches --max-error stops there: stderr and the report say target, faces and error."""
    src = GLTF / "animation_with_skeleton.glb"
    out, rep = tmp_path / "a.glb", tmp_path / "a.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.1", "--max-error", "none",
                 "--report", str(rep)]) == 0
    free = json.loads(rep.read_text())
    assert free["max_error"] is None and [t["stopped"] for t in free["targets"]] == [None, None]
    assert all(t["max_error"] is None for t in free["targets"])
    capsys.readouterr()
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.1", "--max-error", "0.05",
                 "--report", str(rep)]) == 0
    err = capsys.readouterr().err
    doc = json.loads(rep.read_text())
    t = doc["targets"][-1]
    assert doc["max_error"] == "0.05%" and t["stopped"] == "max_error"
    assert t["faces"] > free["targets"][-1]["faces"] and t["error"] <= t["max_error"]
    assert f"stopped at {t['faces']} faces" in err and "--max-error 0.05%" in err
    assert doc["levels"][-1]["faces"] == t["faces"] and doc["levels"][-1]["stopped"] == "max_error"
    check_lod_structure(src, out, len([x for x in doc["targets"] if x["same_as"] is None]))


def test_lod_joint_budget_stays_within_max_error_and_says_so(tmp_path, capsys):
    """wuson at half its faces: 8 of 37 joints reach an example-pose displacement of 0.19 m (over both of its
    clips' example poses; 0.24 m over the first clip's) against the 1 % bound (0.033 m), once shipped without a
    word. Now the merges stop inside the bound, the level keeps more
    joints and one stderr line names the level, the error the next merge would reach, the bound and the fix;
    --max-error none still meets the budget."""
    src = GLTF / "suite" / "wuson.glb"
    out, rep = tmp_path / "w.glb", tmp_path / "w.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5", "--max-joints", "8", "--report", str(rep)]) == 0
    err = capsys.readouterr().err
    doc = json.loads(rep.read_text())
    row, t = doc["levels"][0], doc["targets"][0]
    b = row["joint_budget"]
    assert b["stopped"] == "max_error" and not b["met"] and row["joints"] > 8
    assert b["max_error"] == t["max_error"] and t["error"] <= b["error"] == row["error"] <= b["max_error"]
    assert b["next_error"] > b["max_error"]
    line = next(x for x in err.splitlines() if "--max-joints" in x)
    assert line == (f"rigslim lod: level {row['label']} keeps {row['joints']} joints, above --max-joints 8: merging "
                    f"one more would reach error {b['next_error']:.4g} m, above --max-error 1% "
                    f"({b['max_error']:.4g} m; the level is at {b['error']:.4g} m); raise --max-joints or --max-error")
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5", "--max-joints", "8", "--max-error", "none",
                 "--report", str(rep)]) == 0
    assert "--max-joints" not in capsys.readouterr().err
    b = json.loads(rep.read_text())["levels"][0]["joint_budget"]
    assert b["met"] and b["stopped"] is None and b["max_error"] is None and b["error"] > 0.15


def test_lod_says_why_no_collapse_was_left(tmp_path, capsys):
    """mangonel (37 wooden parts) cannot reach 5 % without removing parts: with --keep-parts the report counts
    the parts left whole at 4 faces or fewer, and stderr says so (it once printed "None seam vertices")."""
    src = GLTF / "suite" / "mangonel.glb"
    out, rep = tmp_path / "m.glb", tmp_path / "m.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.05", "--max-error", "none", "--keep-parts",
                 "--report", str(rep)]) == 0
    t = json.loads(rep.read_text())["targets"][0]
    assert t["stopped"] == "no collapse" and t["faces"] > 1.03 * t["target_faces"]
    assert 0 < t["minimal_parts"] <= t["parts"]
    err = capsys.readouterr().err
    assert f"{t['minimal_parts']} of its {t['parts']} parts are at 4 faces or fewer" in err and "None" not in err
    assert t["parts_removed"] == 0


def test_lod_removes_whole_parts_where_no_collapse_is_left(tmp_path, capsys):
    """Without --keep-parts mangonel's 10 % level (116 faces) is reached by removing parts whole, the nearest
    to the rest first, and lands within 3 % of its target (parts that fit in the last removal's overshoot are
    put back); the level says how many went. Within the default bound (1 %) no part goes: the level stops
    where the collapses stop and stderr says why."""
    src = GLTF / "suite" / "mangonel.glb"
    out, rep = tmp_path / "m.glb", tmp_path / "m.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.25,0.1", "--max-error", "none",
                 "--report", str(rep)]) == 0
    doc = json.loads(rep.read_text())
    t = doc["targets"][1]
    assert t["stopped"] is None and t["same_as"] is None and t["label"] == "quartic-10pct"
    assert 0.97 * t["target_faces"] <= t["faces"] <= t["target_faces"]
    assert t["parts_removed"] > 0 and t["removal_distance"] > 0
    assert [lv["faces"] for lv in doc["levels"]] == [doc["targets"][0]["faces"], t["faces"]]
    assert t["faces_collapsed"] > t["target_faces"]
    assert (f"level quartic-10pct: no collapse was left at {t['faces_collapsed']} faces, so {t['parts_removed']} "
            f"parts were removed whole") in capsys.readouterr().err
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.1", "--report", str(rep)]) == 0
    t = json.loads(rep.read_text())["targets"][0]
    assert t["stopped"] == "max_error" and t["faces"] > t["target_faces"]


def test_lod_writes_no_level_where_the_first_collapse_exceeds_the_bound(tmp_path, capsys):
    """minetest_character's seven boxes: every collapse exceeds the default 1 % bound. The file holds the source
    alone (it once held a "level" of the source's 84 faces) and stderr says why, per target."""
    src = GLTF / "suite" / "minetest_character.glb"
    out, rep = tmp_path / "m.glb", tmp_path / "m.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.25", "--report", str(rep)]) == 0
    std = capsys.readouterr()
    doc = json.loads(rep.read_text())
    assert doc["levels"] == [] and [t["same_as"] for t in doc["targets"]] == ["source", "source"]
    assert all(t["faces"] == 84 and t["stopped"] == "max_error" for t in doc["targets"])
    assert "no level (every target ends at the source's 84 faces)" in std.out
    assert std.err.count("the first collapse already exceeds --max-error 1%") == 2
    gltf = load_gltf(out)
    assert not any("MSFT_lod" in (n.get("extensions") or {}) for n in gltf.json.get("nodes", []))
    assert main(["lod", str(src), "-o", str(tmp_path / "s.glb"), "--ratios", "0.5", "--split"]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == ["m.glb", "m.json", "s.lod.json"]


def test_lod_target_the_source_already_meets_is_no_level(tmp_path, capsys):
    """simple_skin's 8 faces at 0.95 (the target rounds to 8): once a "level" with the source's faces."""
    out, rep = tmp_path / "s.glb", tmp_path / "s.json"
    assert main(["lod", str(GLTF / "simple_skin.gltf"), "-o", str(out), "--ratios", "0.95", "--max-error", "none",
                 "--report", str(rep)]) == 0
    t = json.loads(rep.read_text())["targets"][0]
    assert t["same_as"] == "source" and t["stopped"] is None and t["faces"] == t["target_faces"] == 8
    assert "target 0.95 (8 faces): the source's own 8 faces meet it, so it has no level" in capsys.readouterr().err


def test_weights_that_do_not_sum_to_one_are_noted(tmp_path, capsys):
    """assimp's FBX conversion (sums 0.82..1.38) gets one stderr line from lod and reduce; bcn_epileptic, whose
    sums are 1 +- 1e-6 (a validator error, no visible change), gets none."""
    src = GLTF / "animation_with_skeleton.glb"
    assert main(["reduce", str(src), "-o", str(tmp_path / "r.glb"), "-k", "2"]) == 0
    err = capsys.readouterr().err
    assert "animation_with_skeleton.glb: the skin weights of 2462 vertices do not sum to 1 (0.8244 to 1.377)" in err
    assert main(["lod", str(GLTF / "suite" / "bcn_epileptic.glb"), "-o", str(tmp_path / "b.glb"),
                 "--ratios", "0.5"]) == 0
    assert "do not sum to 1" not in capsys.readouterr().err


def test_reduce_select_by_and_clip_index(tmp_path, capsys):
    """--by weight is what the line and the report say (it once said best-fit:error); a contradicting pair is
    refused; --clip 0 is the first clip, as for lod and compare (it was looked up as a name)."""
    src = GLTF / "huesitos.glb"
    rep = tmp_path / "r.json"
    assert main(["reduce", str(src), "-o", str(tmp_path / "w.glb"), "-k", "2", "--by", "weight",
                 "--report", str(rep)]) == 0
    assert "best-fit:weight/geometric" in capsys.readouterr().out
    doc = json.loads(rep.read_text())
    assert doc["select"] == "best-fit:weight"
    assert next(s for s in doc["pipeline"]["steps"] if "select" in s)["by"] == "weight"
    assert main(["reduce", str(src), "-o", str(tmp_path / "x.glb"), "-k", "2", "--select", "best-fit:error",
                 "--by", "weight"]) == 2
    assert "name two criteria" in capsys.readouterr().err and not (tmp_path / "x.glb").exists()
    assert main(["reduce", str(src), "-o", str(tmp_path / "c.glb"), "-k", "2", "--select", "best-fit",
                 "--clip", "0"]) == 0
    assert "best-fit:error/geometric" in capsys.readouterr().out


def test_lod_static_qslim_has_no_error_bound(tmp_path, capsys):
    src = GLTF / "huesitos.glb"
    assert main(["lod", str(src), "-o", str(tmp_path / "s.glb"), "--ratios", "0.5", "--method", "static-qslim"]) == 0
    assert "static-qslim-50pct" in capsys.readouterr().out
    assert main(["lod", str(src), "-o", str(tmp_path / "t.glb"), "--ratios", "0.5", "--method", "static-qslim",
                 "--max-error", "2"]) == 2
    assert "--method static-qslim has no error bound" in capsys.readouterr().err


def test_split_levels_link_images_from_their_own_folder(tmp_path):
    """--split writes each level from the scratch folder's full file: a .tga link was once left relative to
    that folder (IO_ERROR in the validator); it must lead to the source's image from the level's folder."""
    from rigslim.io.gltf.write import _write_document

    doc = load_gltf(GLTF / "huesitos.glb")
    js = json.loads(json.dumps(doc.json))
    js["images"] = [{"uri": "skin.tga"}]
    js["textures"] = [{"source": 0}]
    src_dir = tmp_path / "src"
    src_dir.mkdir()
    (src_dir / "skin.tga").write_bytes(b"\x00\x00\x02" + bytes(15))
    _write_document(src_dir / "textured.glb", js, doc.buffers[0])
    for out in (tmp_path / "out" / "deep" / "t.glb", tmp_path / "out" / "t.gltf"):
        assert main(["lod", str(src_dir / "textured.glb"), "-o", str(out), "--ratios", "0.5", "--split",
                     "--max-error", "none"]) == 0
        level = out.with_name(f"{out.stem}-50{out.suffix}")
        uri = load_gltf(level).json["images"][0]["uri"]
        assert (level.parent / uri).resolve() == (src_dir / "skin.tga").resolve(), uri


def test_no_motion_says_which():
    from rigslim.commands.gltf_common import no_motion

    assert no_motion("a.glb", None, 0.0) == "a.glb has no animation"
    assert no_motion("t.glb", "anim", 0.0) == "t.glb's clip 'anim' holds one pose only (0 s long)"
    three = SimpleNamespace(json={"animations": [{}, {}, {}]})
    assert no_motion("t.glb", "anim", 0.0, three, searched=True) == (
        "each of t.glb's 3 clips holds one pose only (the first, 'anim', is 0 s long)")
    assert no_motion("t.glb", "anim", 0.0, three) == "t.glb's clip 'anim' holds one pose only (0 s long)"


def test_inspect_json(capsys):
    assert main(["inspect", str(GLTF / "animation_with_skeleton.glb"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["schema_version"] == 1 and info["skins"][0]["joints"] == 14
    assert info["animations"][0]["name"] == "Armature|ArmatureAction" and info["animations"][0]["seconds"] > 0.8
    prim = info["meshes"][0]["primitives"][0]
    assert sum(prim["influences_histogram"]) == 2464 and "TEXCOORD_0" in prim["attributes"]
    assert prim["weight_sums"]["off_by_more_than_1e-3"] > 0 and prim["weight_sums"]["max"] > 1.2


# --------------------------------------------------------------------------- compare against a known answer


def _sheet_glb(path: Path, offset: float) -> None:
    """A hand-made skinned sheet (5x5 grid, z = offset), one joint that rotates it about x over 1 s."""
    xs = np.linspace(-1.0, 1.0, 5)
    X, Y = np.meshgrid(xs, xs * 0.5, indexing="ij")
    P = np.stack([X.ravel(), Y.ravel(), np.full(X.size, offset)], 1).astype(np.float32)
    idx = np.arange(25).reshape(5, 5)
    a, b, c, d = idx[:-1, :-1], idx[:-1, 1:], idx[1:, :-1], idx[1:, 1:]
    F = np.concatenate([np.stack([a, c, b], -1).reshape(-1, 3), np.stack([b, c, d], -1).reshape(-1, 3)])
    J = np.zeros((25, 4), np.uint8)
    W = np.zeros((25, 4), np.float32)
    W[:, 0] = 1
    times = np.linspace(0, 1, 5, dtype=np.float32)
    ang = np.radians(40.0) * times
    rot = np.stack([np.sin(ang / 2), 0 * ang, 0 * ang, np.cos(ang / 2)], 1).astype(np.float32)
    ibm = np.eye(4, dtype=np.float32).reshape(1, 16)
    parts, views, accs = [], [], []

    def add(arr, ctype, type_, minmax=False):
        off = sum(len(p) for p in parts)
        data = np.ascontiguousarray(arr).tobytes()
        parts.append(data + b"\0" * ((-len(data)) % 4))
        views.append({"buffer": 0, "byteOffset": off, "byteLength": len(data)})
        acc = {"bufferView": len(views) - 1, "componentType": ctype, "count": len(arr), "type": type_}
        if minmax:
            acc["min"] = [float(v) for v in arr.reshape(len(arr), -1).min(0)]
            acc["max"] = [float(v) for v in arr.reshape(len(arr), -1).max(0)]
        accs.append(acc)
        return len(accs) - 1

    prim = {"attributes": {"POSITION": add(P, 5126, "VEC3", True), "JOINTS_0": add(J, 5121, "VEC4"),
                           "WEIGHTS_0": add(W, 5126, "VEC4")},
            "indices": add(F.astype(np.uint16).ravel(), 5123, "SCALAR")}
    js = {"asset": {"version": "2.0"}, "scene": 0, "scenes": [{"nodes": [0, 1]}],
          "nodes": [{"mesh": 0, "skin": 0}, {"name": "joint", "translation": [0.0, 0.0, 0.0]}],
          "meshes": [{"primitives": [prim]}],
          "skins": [{"joints": [1], "inverseBindMatrices": add(ibm, 5126, "MAT4")}],
          "animations": [{"name": "tilt", "samplers": [{"input": add(times, 5126, "SCALAR", True),
                                                        "output": add(rot, 5126, "VEC4"),
                                                        "interpolation": "LINEAR"}],
                          "channels": [{"sampler": 0, "target": {"node": 1, "path": "rotation"}}]}]}
    binary = b"".join(parts)
    js["bufferViews"], js["accessors"], js["buffers"] = views, accs, [{"byteLength": len(binary)}]
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def test_compare_known_offset(tmp_path, capsys):
    """Two parallel sheets 0.03 apart, moved rigidly: every sample is 0.03 from the other sheet."""
    ref, cand = tmp_path / "ref.glb", tmp_path / "cand.glb"
    _sheet_glb(ref, 0.0)
    _sheet_glb(cand, 0.03)
    assert main(["compare", str(ref), str(cand), "--frames", "0:31:5", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    # independent answer: the sheet's world bounding box in the first frame (rotation 0): 2 x 1 x 0
    diag = float(np.hypot(2.0, 1.0))
    assert res["reference_diagonal_m"] == pytest.approx(diag, rel=1e-6)
    assert res["hausdorff_rms_m"] == pytest.approx(0.03, rel=1e-4)
    assert res["hausdorff_max_m"] == pytest.approx(0.03, rel=1e-4)
    assert res["hausdorff_rms_pct"] == pytest.approx(100 * 0.03 / diag, rel=1e-4)
    assert res["faces"] == 32 and res["frames"] == [0, 5, 10, 15, 20, 25, 30]
    assert res["normal_rms_rad"] == pytest.approx(0.0, abs=1e-6)     # same topology, parallel
    assert res["position_rms_m"] == pytest.approx(0.03, rel=1e-5)


def test_compare_measures_lod_levels(tmp_path, capsys):
    src = GLTF / "tube_two_materials.glb"
    out = tmp_path / "tube.glb"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.2"]) == 0
    capsys.readouterr()
    res = []
    for level in (0, 1, 2):
        assert main(["compare", str(src), str(out), "--level", str(level), "--frames", "1:31:10", "--json",
                     "--samples", "4000"]) == 0
        res.append(json.loads(capsys.readouterr().out))
    # level 0: the original primitives, their weights as ubyte codes (quantisation error only)
    assert res[0]["faces"] == 1536 and res[0]["hausdorff_max_pct"] < 0.05 and "normal_rms_rad" in res[0]
    assert res[1]["faces"] < 1536 and res[2]["faces"] < res[1]["faces"]
    assert 0 < res[1]["hausdorff_rms_pct"] < res[2]["hausdorff_rms_pct"] < 1.0


ASSIMP_FBX = Path("/usr/share/assimp/models/FBX")


@pytest.mark.skipif(not (ASSIMP_FBX / "huesitos.fbx").exists() or __import__("shutil").which("assimp") is None,
                    reason="assimp-utils / assimp-testmodels missing (tools/setup-testmodels.sh)")
@pytest.mark.parametrize("name", ["huesitos.fbx", "animation_with_skeleton.fbx"])
def test_lod_on_freshly_converted_assimp_characters(name, tmp_path, valid):
    """The FBX characters converted by this machine's assimp (`assimp export ... -fglb2`), as a user would."""
    import subprocess

    glb = tmp_path / (Path(name).stem + ".glb")
    subprocess.run(["assimp", "export", str(ASSIMP_FBX / name), str(glb), "-fglb2"], check=True,
                   capture_output=True, timeout=120)
    out = tmp_path / "lod.glb"
    assert main(["lod", str(glb), "-o", str(out), "--report", str(tmp_path / "r.json")]) == 0
    valid(out)
    targets = json.loads((tmp_path / "r.json").read_text())["targets"]   # --max-error 1 % may stop the 25 %
    check_lod_structure(glb, out, len([t for t in targets if t["same_as"] is None]))
    assert main(["reduce", str(glb), "-o", str(tmp_path / "k2.glb"), "-k", "2", "--solve", "k-largest"]) == 0
    valid(tmp_path / "k2.glb")


def test_lod_is_a_pipeline_rigslim_run_can_run(tmp_path):
    """--save-pipeline writes the YAML the command ran; `rigslim run` on it writes the same levels."""
    src = GLTF / "tube_two_materials.glb"
    assert main(["lod", str(src), "-o", str(tmp_path / "a.glb"), "--ratios", "0.5,0.25",
                 "--save-pipeline", str(tmp_path / "lod.yaml")]) == 0
    text = (tmp_path / "lod.yaml").read_text().replace(str(tmp_path / "a.glb"), str(tmp_path / "b.glb"))
    (tmp_path / "lod.yaml").write_text(text)
    assert main(["run", str(tmp_path / "lod.yaml"), "-q"]) == 0
    a, b = load_gltf(tmp_path / "a.glb").json, load_gltf(tmp_path / "b.glb").json
    assert [m["name"] for m in a["meshes"]] == [m["name"] for m in b["meshes"]]
    assert a["accessors"] == b["accessors"]


def _two_skin_tube(path: Path) -> None:
    """The tube with a second skin (same joints) for the Torso node: reduce and lod must handle every skin."""
    src = load_gltf(GLTF / "tube_two_materials.glb")
    js = json.loads(json.dumps(src.json))
    js["skins"].append(dict(js["skins"][0], name="torso"))
    js["nodes"][1]["skin"] = 1
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    binary = src.buffers[0] + b"\0" * ((-len(src.buffers[0])) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)


def test_commands_handle_every_skin(tmp_path, valid):
    src = tmp_path / "two-skins.glb"
    _two_skin_tube(src)
    assert main(["reduce", str(src), "-o", str(tmp_path / "k1.glb"), "-k", "1", "--solve", "k-largest",
                 "--report", str(tmp_path / "r.json")]) == 0
    valid(tmp_path / "k1.glb")
    doc = load_gltf(tmp_path / "k1.glb")
    for mesh in doc.json["meshes"]:
        for prim in mesh["primitives"]:
            W, _ = _skin_rows(doc, prim)
            assert ((W > 0).sum(axis=1) <= 1).all()              # both skins' meshes reduced
    assert [s["skin"] for s in json.loads((tmp_path / "r.json").read_text())["per_skin"]] == [0, 1]
    out = tmp_path / "lod.glb"
    assert main(["lod", str(src), "-o", str(out)]) == 0
    valid(out)
    check_lod_structure(src, out, 2)
    js = load_gltf(out).json
    assert [js["nodes"][j]["skin"] for j in js["nodes"][1]["extensions"]["MSFT_lod"]["ids"]] == [1, 1]
    assert main(["compare", str(src), str(out), "--level", "1", "--frames", "1:31:10", "--json",
                 "--samples", "2000"]) == 0


def test_lod_keeps_a_large_part_among_near_ones_when_it_removes_parts(tmp_path):
    """minetest_character at 25 % with no bound: its seven boxes end as tetrahedra (28 faces), so two parts go.
    The torso, a tetrahedron between the limbs and as near to them as they are to it, has the most area and
    stays (measured at its corners and ranked by distance alone, it went first); the head's overlay goes."""
    from rigslim.plugins.decimation.prune import face_parts

    src = GLTF / "suite" / "minetest_character.glb"
    out, rep = tmp_path / "m.glb", tmp_path / "m.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.25", "--max-error", "none", "--split",
                 "--report", str(rep)]) == 0
    t = json.loads(rep.read_text())["targets"][0]
    assert t["parts_removed"] == 2 and t["faces"] == 20
    doc = load_gltf(tmp_path / "m-25.glb")
    prim = doc.json["meshes"][0]["primitives"][0]
    V = read_accessor(doc, prim["attributes"]["POSITION"])
    F = read_accessor(doc, prim["indices"]).reshape(-1, 3).astype(np.int64)
    _, weld = np.unique(np.round(V, 6), axis=0, return_inverse=True)
    n, part = face_parts(weld.ravel()[F])
    centres = np.array([V[F[part == p]].reshape(-1, 3).mean(axis=0) for p in range(n)])
    assert np.linalg.norm(centres - [0.0, 9.45, 0.0], axis=1).min() < 0.5       # the torso
