"""Issue 21 item 5: one unit everywhere. Position and Hausdorff errors are given in world units (metres for glTF)
and in % of the world-space bounding-box diagonal of the reference in the first test frame, whatever unit the
bind-space mesh is in (assimp's centimetre FBX conversions scale their joints by 0.01: dividing by the
bind-space diagonal made the batch summary read 822 % where ``compare`` read 8.4 %)."""

from __future__ import annotations

import json

import numpy as np
import pytest
from support.hostile_gltf import build_gltf, posed_file_positions, random_parts

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
