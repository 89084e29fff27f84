"""Metrics document schema versions (rigslim.runtime.metrics_document): version 2 written, version 1 still read."""

from __future__ import annotations

import copy

from rigslim.runtime.metrics_document import SCHEMA_VERSION, flat_metrics, merge_levels, upgrade

AGG = {"mean": 0.2, "max": 0.3, "per_frame": [0.1, 0.3, 0.2]}

V1 = {"name": "run", "evaluations": [
    {"name": "quartic-levels", "step": 2, "metrics": {
        "hausdorff_rms_pct": AGG, "hausdorff_max_pct@10%": {"mean": 1.0}, "hausdorff_rms_pct@10%": AGG,
        "faces@10%": 1206, "hausdorff_rms_pct@2%": {"mean": 0.9}, "faces@2%": 241}},
    {"name": "k-largest-k4", "step": 4, "metrics": {"position_rms_pct": AGG}}]}


def test_upgrade_moves_level_keys_into_level_records():
    original = copy.deepcopy(V1)
    v2 = upgrade(V1)
    assert V1 == original  # the input is not modified
    assert v2["schema_version"] == SCHEMA_VERSION == 3
    assert v2["units"]["pct"].startswith("percent of the rest")  # old percentages keep their definition
    first, second = v2["evaluations"]
    assert first["metrics"] == {"hausdorff_rms_pct": AGG}
    assert first["levels"] == [
        {"name": "10%", "hausdorff_max_pct": {"mean": 1.0}, "hausdorff_rms_pct": AGG, "faces": 1206},
        {"name": "2%", "hausdorff_rms_pct": {"mean": 0.9}, "faces": 241}]
    assert "levels" not in second and second["metrics"] == {"position_rms_pct": AGG}


def test_upgrade_of_version_2_is_the_identity_and_flat_metrics_inverts_it():
    v2 = upgrade(V1)
    assert upgrade(v2) == v2
    assert flat_metrics(v2["evaluations"][0]) == V1["evaluations"][0]["metrics"]
    assert flat_metrics(v2["evaluations"][1]) == V1["evaluations"][1]["metrics"]


def test_merge_levels_joins_records_by_name_in_first_seen_order():
    levels = [{"name": "a", "x": 1}]
    merge_levels(levels, [{"name": "b", "x": 2}, {"name": "a", "y": 3}])
    assert levels == [{"name": "a", "x": 1, "y": 3}, {"name": "b", "x": 2}]


def test_pipeline_writes_version_2(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs: {mesh: data/elephant.obj, skeleton: data/elephant.tgf, weights: data/elephant-weights.dmat,
         animation: data/elephant-anim.dmat}
poses: {examples: "0:457:45", test: "5:457:50"}
steps:
  - select: k-largest
    k: 4
  - solve: k-largest
  - evaluate: [position-rms]
""")
    document = run_pipeline(path).document
    assert document["schema_version"] == 3
    assert all("@" not in key for ev in document["evaluations"] for key in ev["metrics"])
