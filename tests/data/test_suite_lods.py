"""Issue 25: every suite character's LOD chain, as a user gets it, is valid, honest and within its error bound.

For each character of the real-character suite (examples/data/gltf/suite/),
``rigslim lod CHAR.glb -o OUT.glb --ratios 0.5,0.25,0.1 --report R.json``
(the default ``--max-error 1%``) and the same with ``--split``:

- the levels' face counts strictly decrease, each is named after its target
  (and its real face count where it is more than 3 % above it), and a target
  that could not be reached says why (``stopped``) or which level it ended at
  (``same_as``);
- glTF-Validator finds no error in the MSFT_lod file nor in any ``--split`` file, but those the source
  itself has where the output keeps its data as it is (re_drone's skin has 3 inverse bind matrices whose last
  row is 1 +- 1.2e-7; its level skins are written exact);
- ``rigslim compare`` of every level on the held-out frames of every clip (the
  report's ``clips.test``; the collapses fit example frames of every clip): the
  test-pose Hausdorff RMS of each clip stays within the bound (1 % of the world
  diagonal; the bound is on the area-weighted RMS distance over the example
  poses, docs/simplification.md).
"""

from __future__ import annotations

import json

import pytest
from support.gltf_validator import validate_gltf, validation_errors, validator_available

from benchmarks.datasets import suite
from rigslim.cli import main as rigslim
from rigslim.io.gltf.document import load_gltf
from rigslim.io.gltf.scene import animation_duration

RATIOS = (0.5, 0.25, 0.1)
BOUND_PCT = 1.0


@pytest.fixture(scope="module", autouse=True)
def _validator():
    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")


def _errors(path) -> list:
    return validation_errors(validate_gltf(path))


@pytest.mark.slow
@pytest.mark.parametrize("character", suite(group="all"), ids=lambda c: c.name)
def test_lod_chain_is_valid_honest_and_bounded(character, tmp_path, capsys):
    out, report = tmp_path / f"{character.name}.glb", tmp_path / "r.json"
    ratios = ",".join(f"{r:g}" for r in RATIOS)
    assert rigslim(["lod", str(character.path), "-o", str(out), "--ratios", ratios, "--report", str(report)]) == 0
    doc = json.loads(report.read_text())
    levels, targets = doc["levels"], doc["targets"]
    faces = [lv["faces"] for lv in levels]
    assert faces == sorted(set(faces), reverse=True), faces               # strictly decreasing
    assert len(targets) == len(RATIOS)
    for t in targets:
        if t["same_as"] == "source":                  # not one collapse within the bound: no level
            assert t["faces"] == doc["input_faces"] and t["stopped"] in ("max_error", "no collapse")
            continue
        if t["same_as"] is not None:
            assert t["same_as"] in {lv["label"] for lv in levels}
            continue
        level = next(lv for lv in levels if lv["label"] == t["label"])
        assert level["faces"] == t["faces"] and f"{round(t['target'] * 100):d}pct" in t["label"]
        if t["faces"] > 1.03 * t["target_faces"]:
            assert t["label"].endswith(f"-{t['faces']}f") and t["stopped"] in ("max_error", "no collapse")
    known = set(_errors(character.path))
    assert set(_errors(out)) <= known
    held_out = [(c["clip"], c["frames"][::max(1, len(c["frames"]) // 4)]) for c in doc["clips"]["test"]]
    gltf = load_gltf(character.path)
    moving = [a.get("name", str(i)) for i, a in enumerate(gltf.json.get("animations", []))
              if animation_duration(gltf, i) * 30.0 >= 1.0 - 1e-3]          # 2 frames or more at 30 fps
    assert [c for c, _ in held_out] == moving                            # every clip that moves is measured
    for i, lv in enumerate(levels, start=1):
        for clip, frames in held_out:
            capsys.readouterr()
            assert rigslim(["compare", str(character.path), str(out), "--level", str(i), "--json", "--clip", clip,
                            "--frames", ",".join(map(str, frames)), "--samples", "4000"]) == 0
            measured = json.loads(capsys.readouterr().out)
            assert measured["faces"] == lv["faces"]
            assert measured["hausdorff_rms_pct"] <= BOUND_PCT, (lv["label"], clip, measured["hausdorff_rms_pct"])
    split = tmp_path / "split" / f"{character.name}.glb"
    split.parent.mkdir()
    assert rigslim(["lod", str(character.path), "-o", str(split), "--ratios", ratios, "--split"]) == 0
    files = sorted(split.parent.glob("*.glb"))
    assert len(files) == len(levels)
    for f in files:
        assert set(_errors(f)) <= known, f.name


def test_wolf_far_level_keeps_its_double_sided_sheets_paired(tmp_path):
    """wolf.glb stores 20 triangles twice, once per side (its ears): at 10 % (70 faces) they were left whole
    (no edge of such a sheet could collapse) and its max error was 13.05 %. Now the sheets are simplified once
    (plugins/decimation/twins.py): the level reaches its target, the sheets are simplified (fewer than their 40
    faces), every triangle it keeps from a sheet is there with its back face, and the file validates."""
    import numpy as np

    from rigslim.io.gltf.skin import read_gltf_skin
    from rigslim.plugins.decimation.twins import back_faces

    wolf = next(c for c in suite(group="all") if c.name == "wolf")
    src = read_gltf_skin(wolf.path, weld=True).mesh
    assert back_faces(src.F).sum() == 20
    out = tmp_path / "w.glb"
    assert rigslim(["lod", str(wolf.path), "-o", str(out), "--ratios", "0.1", "--split", "--max-error", "none"]) == 0
    (level,) = sorted(tmp_path.glob("w-*.glb"))
    mesh = read_gltf_skin(level, weld=True).mesh
    assert abs(mesh.n_faces - 70) <= 2
    key = np.sort(mesh.F, axis=1)
    _, inv, counts = np.unique(key, axis=0, return_inverse=True, return_counts=True)
    twice = counts[inv.ravel()] == 2
    assert 0 < twice.sum() < 40 and (counts <= 2).all()
    assert back_faces(mesh.F).sum() == twice.sum() // 2                 # every pair has opposite windings
    assert not set(_errors(level)) - set(_errors(wolf.path))
