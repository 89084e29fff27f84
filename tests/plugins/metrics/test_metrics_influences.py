"""max-influences: reduced weights, and every level of a decimate-only run."""

from __future__ import annotations

PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:150"}
steps:
STEPS
  - evaluate: [max-influences]
"""


def test_reduced_weights(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    steps = "  - select: k-largest\n    k: 3\n  - solve: k-largest"
    metrics = run_pipeline(write_pipeline(PIPELINE.replace("STEPS", steps))).evaluations[0]["metrics"]
    assert metrics["max_influences"] == 3
    assert metrics["input_max_influences"] > 3
    assert 1 <= metrics["mean_influences"] <= 3


def test_decimate_only_run_counts_every_level(write_pipeline):
    """Was an AttributeError traceback: a decimate-only run has no reduced weights, only levels."""
    from rigslim.runtime.run import run_pipeline

    steps = "  - decimate: quartic\n    targets: [0.2, 0.05]\n    max_bones: 2"
    result = run_pipeline(write_pipeline(PIPELINE.replace("STEPS", steps)))
    metrics = result.evaluations[0]["metrics"]
    levels = result.asset.levels
    expected = max(int(level.weights.influence_counts().max()) for level in levels)
    assert metrics["max_influences"] == expected <= 2
    assert metrics["input_max_influences"] > 2
