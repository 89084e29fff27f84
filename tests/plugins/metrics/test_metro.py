"""The metro metric: pymeshlab's two-sided Hausdorff distance, and simplification evaluated from YAML."""

from __future__ import annotations

import json

import numpy as np
import pytest

pytest.importorskip("pymeshlab")

from rigslim.io.hierarchy import read_hierarchy
from rigslim.numerics.surface_distance import metro_distance  # noqa: E402


def grid(n=20, z=0.0):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.c_[x.ravel(), y.ravel(), np.full(n * n, z)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            F += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return V, np.array(F)


def test_identical_meshes_are_at_distance_zero():
    V, F = grid()
    d = metro_distance(V, F, V, F, samples=2000)
    assert d["rms"] < 1e-9 and d["max"] < 1e-9


def test_parallel_planes_are_at_their_offset():
    V, F = grid()
    V2, F2 = grid(7, z=0.05)
    d = metro_distance(V, F, V2, F2, samples=5000)
    assert d["rms"] == pytest.approx(0.05, rel=1e-4)
    assert d["max"] == pytest.approx(0.05, rel=1e-4)


def test_max_is_two_sided():
    """A small patch inside a large one: one direction is 0, the other sees the uncovered part."""
    V, F = grid()
    Vs, Fs = grid(5)
    Vs = Vs * 0.5
    d = metro_distance(Vs, Fs, V, F, samples=5000)
    assert d["max"] == pytest.approx(np.sqrt(2) * 0.5, rel=0.02)
    assert 0 < d["rms"] < d["max"]


PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:90"}
steps:
  - decimate: METHOD
    targets: [0.1, 600]
    max_bones: 4
  - evaluate: [metro]
    name: simplified
  - write: out/levels
    writer: levels
"""

HIERARCHY_STEP = """
  - write: out/h.npz
    writer: hierarchy
"""


@pytest.mark.parametrize("method", ["quartic", "mohr-gleicher", "decoro-rusinkiewicz", "static-qslim"])
def test_simplification_from_yaml(write_pipeline, tmp_path, method):
    from rigslim.io import read_dmat, read_mesh
    from rigslim.runtime.run import run_pipeline

    text = PIPELINE.replace("METHOD", method) + ("" if method == "static-qslim" else HIERARCHY_STEP)
    result = run_pipeline(write_pipeline(text), metrics_path=tmp_path / "m.json")
    doc = json.loads((tmp_path / "m.json").read_text())
    metrics = doc["evaluations"][0]["metrics"]
    assert doc["evaluations"][0]["name"] == "simplified"
    for key in ("hausdorff_rms_pct", "hausdorff_max_pct"):
        assert set(metrics[key]) == {"mean", "max", "per_frame"}
        assert len(metrics[key]["per_frame"]) == len(doc["frames"]["test"])
    fine, coarse = f"{method}-10pct", f"{method}-600f"
    assert doc["schema_version"] == 3 and not any("@" in key for key in metrics)
    levels = {lv["name"]: lv for lv in doc["evaluations"][0]["levels"]}
    assert list(levels) == [fine, coarse]
    assert metrics["hausdorff_rms_pct"] == levels[fine]["hausdorff_rms_pct"]
    assert 0 < levels[fine]["hausdorff_rms_pct"]["mean"] < levels[coarse]["hausdorff_rms_pct"]["mean"]
    assert metrics["hausdorff_rms_pct"]["mean"] < 1.0               # % of the diagonal
    assert levels[coarse]["faces"] <= 600
    assert set(levels[coarse]) == {"name", "faces", "hausdorff_rms_pct", "hausdorff_max_pct", "hausdorff_rms_m",
                                   "hausdorff_max_m"}
    D = metrics["reference_diagonal_m"]    # the one unit: world units and % of the first test frame's diagonal
    assert levels[coarse]["hausdorff_rms_m"]["mean"] == pytest.approx(levels[coarse]["hausdorff_rms_pct"]["mean"]
                                                                      * D / 100, rel=1e-12)
    if method != "static-qslim":
        hier = read_hierarchy(tmp_path / "out" / "h.npz")
        assert hier.prefix(hier.n_collapses).n_faces == levels[coarse]["faces"]
    index = json.loads((tmp_path / "out" / "levels" / "levels.json").read_text())["levels"]
    assert [lv["label"] for lv in index] == [fine, coarse]
    for lv in index:
        mesh = read_mesh(tmp_path / "out" / "levels" / lv["mesh"])
        W = read_dmat(tmp_path / "out" / "levels" / lv["weights"])
        assert mesh.n_faces == lv["faces"] and W.shape == (mesh.n_vertices, 24)
        assert np.allclose(W.sum(axis=1), 1.0) and ((W != 0).sum(axis=1) <= 4).all()
    levels = result.asset.levels
    assert np.allclose(read_mesh(tmp_path / "out" / "levels" / f"{coarse}.obj").V, levels[1].mesh.V, atol=1e-6)


def test_metro_also_measures_a_weight_reduction(write_pipeline, tmp_path):
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:150"}
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [metro, position-rms]
""")
    ev = run_pipeline(path).evaluations[0]["metrics"]
    assert ev["hausdorff_rms_pct"]["mean"] > 0
    assert ev["hausdorff_max_pct"]["max"] >= ev["hausdorff_rms_pct"]["max"]


def test_writers_without_results_are_step_errors(write_pipeline):
    from rigslim.errors import StepError
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
steps:
  - write: out/h.npz
    writer: hierarchy
""")
    with pytest.raises(StepError, match="no progressive hierarchy"):
        run_pipeline(path)


def test_metro_frames_measures_that_many_test_frames_evenly(write_pipeline):
    """``frames: N``: N of the test frames, first and last among them (the same values there as measuring every
    frame); 0 is every frame."""
    from rigslim.model.poses import spread_frames
    from rigslim.runtime.run import run_pipeline

    assert spread_frames(10, 0) == list(range(10)) == spread_frames(10, 12)
    assert spread_frames(10, 3) == [0, 4, 9] and len(spread_frames(100, 24)) == 24
    text = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {{examples: "0:457:45", test: "5:457:90"}}
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: {{metro: {{samples: 2000{frames}}}}}
"""
    every = run_pipeline(write_pipeline(text.format(frames=""))).evaluations[0]["metrics"]
    two = run_pipeline(write_pipeline(text.format(frames=", frames: 2"))).evaluations[0]["metrics"]
    full, few = every["hausdorff_max_m"]["per_frame"], two["hausdorff_max_m"]["per_frame"]
    assert len(full) == 6 and len(few) == 2
    assert np.allclose(few, [full[0], full[-1]], rtol=1e-6)
