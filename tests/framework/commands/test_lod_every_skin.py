"""``rigslim lod`` on a file whose meshes use several skins (assimp's conversions give every mesh its own): one
decimation per skin, each skin's levels and stops said apart, and ``--split`` files (and their sidecar) for
every target that any skin reached, not only the first skin's."""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
from support.hostile_gltf import Part, _grid_box, build_gltf, smooth_tube

from rigslim.commands.cli import main
from rigslim.io.gltf.document import load_gltf


def rigid_box() -> Part:
    """A flat-sided box on joint 0: lossless down to 12 faces, then no collapse within the default bound."""
    V, F = _grid_box(0.0, 1.0, 7)
    J = np.zeros((len(V), 4), np.int64)
    W = np.zeros((len(V), 4))
    W[:, 0] = 1.0
    return Part(V + [0.0, 2.0, 0.0], F, J, W)


def octahedron() -> Part:
    """Eight faces on joint 0: its first collapse already exceeds the default bound, so it has no level."""
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float) * 0.3 + [0.5, 2, 0]
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    J = np.zeros((6, 4), np.int64)
    W = np.zeros((6, 4))
    W[:, 0] = 1.0
    return Part(V, F, J, W)


def two_skins(path: Path, first: Part | None = None) -> Path:
    """The box (mesh ``part0``, skin 0; or ``first``) and the tube (``part1``) drawn with a second skin of the same
    joints: the first skin has fewer levels than the second (the files used to follow the first skin's)."""
    build_gltf(path, [first or rigid_box(), smooth_tube()], n_joints=4, separate_meshes=True)
    doc = load_gltf(path)
    js = json.loads(json.dumps(doc.json))
    js["skins"].append(dict(js["skins"][0], name="box"))
    node = next(n for n in js["nodes"] if n.get("mesh") == 1)
    node["skin"] = 1
    text = json.dumps(js).encode()
    text += b" " * ((-len(text)) % 4)
    binary = doc.buffers[0] + b"\0" * ((-len(doc.buffers[0])) % 4)
    body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(binary), 0x004E4942) + binary
    path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
    return path


def triangles(path: Path) -> list[int]:
    js = load_gltf(path).json
    return [js["accessors"][p["indices"]]["count"] // 3 for m in js["meshes"] for p in m["primitives"]]


def test_every_skin_is_reported_and_split(tmp_path, capsys):
    src = two_skins(tmp_path / "two.glb")
    out = tmp_path / "lod" / "c.glb"
    out.parent.mkdir()
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.25,0.1", "--split", "--measure",
                 "--report", str(tmp_path / "r.json")]) == 0
    captured = capsys.readouterr()
    report = json.loads((tmp_path / "r.json").read_text())
    box, tube = report["per_skin"]
    assert (box["skin"], box["meshes"], tube["skin"], tube["meshes"]) == (0, ["part0"], 1, ["part1"])
    assert len(tube["levels"]) == 3 and len(box["levels"]) == 2           # the box ends at its 12-face level
    assert box["levels"][-1] == 12
    for skin in (box, tube):            # --measure: each skin's own metro figures, per level
        assert any(k.startswith("hausdorff_rms_pct@") for k in skin["metrics"]), skin["metrics"].keys()
    # stdout names both skins and their levels; stderr says where the box's last target ended, for the box
    assert "2 skins, each simplified on its own" in captured.out
    assert "skin 0 (part0): 2 levels (26, 12 faces of 52)" in captured.out
    assert f"skin 1 (part1): 3 levels ({', '.join(map(str, tube['levels']))} faces of 600)" in captured.out
    assert "rigslim lod: skin 0 (part0): target 0.1" in captured.err
    # three files: the 10 % file shows the tube's 10 % level and the box's coarsest
    files = [tmp_path / "lod" / f"c-{p}.glb" for p in (50, 25, 10)]
    assert [f.name for f in sorted((tmp_path / "lod").glob("c-*.glb"))] == sorted(f.name for f in files)
    for i, f in enumerate(files):
        assert triangles(f) == [box["levels"][min(i, 1)], tube["levels"][i]]
    side = json.loads((tmp_path / "lod" / "c.lod.json").read_text())
    faces = [lv["faces"] for lv in side["levels"]]
    assert faces == [652] + [t + b for t, b in zip(tube["levels"], [26, 12, 12], strict=True)]
    assert [lv["file"] for lv in side["levels"][1:]] == [f.name for f in files]
    assert [s["faces"] for s in side["levels"][3]["skins"]] == [12, tube["levels"][2]]
    d = [lv["switch_distance_m"] for lv in side["levels"]]
    assert d == sorted(d)                                                 # coarser files switch in farther
    cov = [lv["min_coverage"] for lv in side["levels"]]
    assert cov == sorted(cov, reverse=True) and cov[-1] == 0.0


def test_a_skin_without_levels_shows_its_source_in_every_file(tmp_path, capsys):
    """The first skin (an octahedron) has no level within the default bound: the tube's levels still get their
    files, the octahedron shows its 8 source faces in each, and the sidecar's camera comes from the tube's run
    (it raised KeyError: 'pixel_error')."""
    src = two_skins(tmp_path / "two.glb", octahedron())
    out = tmp_path / "o.glb"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5,0.25", "--split"]) == 0
    captured = capsys.readouterr()
    assert "skin 0 (part0): no level (every target ends at the source's 8 faces)" in captured.out
    assert "skin 1 (part1): 2 levels (300, 150 faces of 600)" in captured.out
    assert triangles(tmp_path / "o-50.glb") == [8, 300] and triangles(tmp_path / "o-25.glb") == [8, 150]
    side = json.loads((tmp_path / "o.lod.json").read_text())
    assert [lv["faces"] for lv in side["levels"]] == [608, 308, 158]
    assert side["camera"]["pixel_error"] == 1.0
    assert [s["label"] for s in side["levels"][2]["skins"]] == ["input", "quartic-25pct"]


def test_a_pipeline_names_the_commands_that_do_every_skin(tmp_path, capsys):
    """A pipeline reads one skin: on a file with two it stops with one line naming the field and both ways on."""
    src = two_skins(tmp_path / "two.glb")
    yml = tmp_path / "p.yaml"
    yml.write_text(f"inputs:\n  gltf: {src}\nsteps:\n  - decimate: quartic\n    targets: [0.5]\n")
    assert main(["run", str(yml)]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "skin: 2 skins are used by mesh nodes" in err[0]
    assert "'skin: INDEX'" in err[0] and "rigslim lod do every skin in one command" in err[0]
