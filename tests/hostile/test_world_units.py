"""Issue 21 item 5: one unit everywhere. Position and Hausdorff errors are given in world units (metres for glTF)
and in % of the world-space bounding-box diagonal of the reference in the first test frame, whatever unit the
bind-space mesh is in (assimp's centimetre FBX conversions scale their joints by 0.01: dividing by the
bind-space diagonal made the batch summary read 822 % where ``compare`` read 8.4 %)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.hostile_gltf import build_gltf, posed_file_positions, random_parts, smooth_tube

from rigslim.runtime.run import run_pipeline

PIPELINE = """
inputs:
  gltf: {src}
  fps: 8
poses: {{examples: "0:9:2", test: "1:9:2"}}
steps:
  - select: k-largest
    k: 1
  - solve: k-largest
  - evaluate: [position-rms{metro}]
"""


def _run(tmp_path, name, root_scale, metro=False):
    parts = random_parts(np.random.default_rng(5), 2, 3, 4)
    src = build_gltf(tmp_path / f"{name}.glb", parts, n_joints=4, root_scale=root_scale)
    yml = tmp_path / f"{name}.yaml"
    yml.write_text(PIPELINE.format(src=src, metro=", metro" if metro else ""))
    run_pipeline(yml, metrics_path=tmp_path / f"{name}.json")
    return src, json.loads((tmp_path / f"{name}.json").read_text())


def test_percentages_do_not_depend_on_the_bind_space_unit(tmp_path):
    pytest.importorskip("pymeshlab")
    _, metres = _run(tmp_path, "m", 1.0, metro=True)
    src, centi = _run(tmp_path, "cm", 0.01, metro=True)
    assert centi["schema_version"] == 3 and "world-space" in centi["units"]["pct"]
    a, b = metres["evaluations"][0]["metrics"], centi["evaluations"][0]["metrics"]
    # the reference: the world diagonal of the input posed at the first test frame (frame 1 at 8 fps)
    first = posed_file_positions(src, [1 / 8])[0]
    D = float(np.linalg.norm(first.max(axis=0) - first.min(axis=0)))
    assert b["reference_diagonal_m"] == pytest.approx(D, rel=1e-9)
    assert a["reference_diagonal_m"] == pytest.approx(D, rel=1e-6)
    for key in ("position_rms_pct", "position_rms_m"):
        assert b[key]["mean"] == pytest.approx(a[key]["mean"], rel=1e-5), key
        assert b[key]["mean"] > 0
    assert b["position_rms_m"]["mean"] == pytest.approx(b["position_rms_pct"]["mean"] * D / 100, rel=1e-12)
    # Hausdorff: sampled, so the two files agree to the sampling's noise, and each is consistent in itself
    assert b["hausdorff_rms_pct"]["mean"] == pytest.approx(a["hausdorff_rms_pct"]["mean"], rel=0.1)
    assert b["hausdorff_max_m"]["max"] == pytest.approx(b["hausdorff_max_pct"]["max"] * D / 100, rel=1e-12)
    assert b["hausdorff_rms_pct"]["mean"] < 100     # not the bind-space 100x


def _lod(tmp_path, name, **build):
    from rigslim.commands.cli import main

    src = build_gltf(tmp_path / f"{name}.glb", [smooth_tube()], n_joints=4, **build)
    report = tmp_path / f"{name}.json"
    assert main(["lod", str(src), "-o", str(tmp_path / f"{name}-lod.glb"), "--ratios", "0.5,0.25,0.1",
                 "--report", str(report)]) == 0
    return json.loads(report.read_text())


def test_lod_does_not_depend_on_the_bind_space_unit(tmp_path):
    """``rigslim lod`` makes the same levels, with the same test-pose errors and the same stops at the default
    ``--max-error``, from a file in metres, one in centimetres under a 0.01 root (assimp's FBX conversion) and
    one with KHR_mesh_quantization's integer positions: the collapse costs are in posed units
    (``rest_scale``). Before, the face-side error was measured in bind-space units squared, 10,000 times too
    large in centimetres, and gltfpack's quantised wolf stopped before its first collapse."""
    metres = _lod(tmp_path, "m")
    assert [t["stopped"] for t in metres["targets"]] == [None, None, "max_error"]
    centimetres = _lod(tmp_path, "cm", root_scale=0.01)        # the same posed floats: the same levels
    assert [t["faces"] for t in centimetres["targets"]] == [t["faces"] for t in metres["targets"]]
    assert [t["stopped"] for t in centimetres["targets"]] == [t["stopped"] for t in metres["targets"]]
    for a, b in zip(metres["levels"], centimetres["levels"], strict=True):
        assert b["error_rms_m"] == pytest.approx(a["error_rms_m"], rel=1e-6)
    # positions rounded to int16's grid: the same face targets reached, the bound met a few collapses apart
    quantised = _lod(tmp_path, "i16", positions="i16")
    assert [t["stopped"] for t in quantised["targets"]] == [t["stopped"] for t in metres["targets"]]
    for a, b in zip(metres["targets"], quantised["targets"], strict=True):
        assert b["faces"] == a["faces"] if a["stopped"] is None else abs(b["faces"] - a["faces"]) < 0.2 * a["faces"]
    for a, b in zip(metres["levels"][:2], quantised["levels"][:2], strict=True):
        assert b["error_rms_m"] == pytest.approx(a["error_rms_m"], rel=0.05)
