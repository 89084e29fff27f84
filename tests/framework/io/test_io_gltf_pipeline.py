"""glTF in pipelines: the example pipelines, the short input form, export from libigl data, errors."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.gltf_validator import validate_gltf, validation_errors, validator_available

from rigslim.errors import RigslimError
from rigslim.io.gltf.skin import read_gltf_skin, skinning_sets
from rigslim.runtime.run import run_pipeline

EXAMPLES = Path(__file__).resolve().parents[3] / "examples"


@pytest.fixture(scope="module")
def valid():
    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")

    def check(path):
        errors = validation_errors(validate_gltf(path))
        assert not errors, f"{path}: {errors[:5]}"

    return check


def test_example_gltf_reduce(write_pipeline, valid):
    path = write_pipeline((EXAMPLES / "gltf-reduce.yaml").read_text())
    result = run_pipeline(path, metrics_path=path.parent / "m.json")
    out = path.parent / "out" / "animation_with_skeleton-k2.glb"
    valid(out)
    back = read_gltf_skin(out)
    assert np.diff(back.weights.indptr).max() == 2
    assert result.document["inputs"]["gltf"].endswith("animation_with_skeleton.glb")
    assert result.asset.provenance["gltf"]["animation"] == "Armature|ArmatureAction"
    assert result.document["frames"]["examples"] == [0, 4, 8, 12, 16, 20, 24]
    assert result.document["frames"]["dropped_from_test"] == []
    metrics = result.evaluations[0]["metrics"]
    assert metrics["max_influences"] == 2 and metrics["input_max_influences"] == 4
    # the file's weights are written as normalized unsigned bytes that sum to 255 per vertex
    from rigslim.io.gltf.document import load_gltf, read_accessor

    doc = load_gltf(out)
    attrs = doc.json["meshes"][0]["primitives"][0]["attributes"]
    assert skinning_sets(attrs) == [0]
    w = read_accessor(doc, attrs["WEIGHTS_0"], normalize=False)
    assert w.dtype == np.uint8 and (w.astype(int).sum(axis=1) == 255).all()


def test_gltf_round_trip_gives_the_same_errors_as_the_libigl_inputs(write_pipeline, valid):
    """Elephant -> glTF (export) -> k=4 reduction: the metrics equal those of the OBJ/TGF/DMAT pipeline."""
    export = write_pipeline((EXAMPLES / "gltf-export-elephant.yaml").read_text(), "export.yaml")
    run_pipeline(export)
    glb = export.parent / "out" / "elephant.glb"
    valid(glb)
    text = (EXAMPLES / "gltf-reduce-elephant.yaml").read_text()
    via_gltf = run_pipeline(write_pipeline(text, "reduce.yaml"))
    valid(export.parent / "out" / "elephant-k4.glb")
    # the demo's pipeline with the steps of gltf-reduce-elephant.yaml (k-largest, the baseline)
    demo = (EXAMPLES / "elephant-k4.yaml").read_text().replace("select: best-fit", "select: k-largest")
    demo = demo.replace("    by: error\n", "").replace("solve: geometric", "solve: k-largest")
    assert "select: k-largest" in text and "solve: k-largest" in text
    direct = run_pipeline(write_pipeline(demo, "direct.yaml"))
    a, b = via_gltf.evaluations[0]["metrics"], direct.evaluations[0]["metrics"]
    assert via_gltf.document["frames"] == direct.document["frames"]
    assert abs(a["position_rms_pct"]["mean"] - b["position_rms_pct"]["mean"]) < 1e-5 * b["position_rms_pct"]["mean"]
    assert abs(a["normal_rms_rad"]["mean"] - b["normal_rms_rad"]["mean"]) < 1e-4 * b["normal_rms_rad"]["mean"]


def test_long_form_and_options(write_pipeline, valid):
    path = write_pipeline("""
inputs:
  gltf: {path: data/gltf/huesitos.glb, animation: 0, fps: 10}
poses: {examples: "0:16:3", test: "1:16:3"}
steps:
  - select: k-largest
    k: 3
  - solve: k-largest
  - write: out/h.gltf
    quantize: ushort
    embed: true
""")
    result = run_pipeline(path)
    assert len(result.asset.poses) == 16          # 1.5 s at 10 fps
    out = path.parent / "out" / "h.gltf"
    valid(out)
    assert not (path.parent / "out" / "h.bin").exists()
    assert np.diff(read_gltf_skin(out).weights.indptr).max() <= 3


@pytest.mark.parametrize("inputs, match", [
    ("gltf: data/gltf/huesitos.glb\n  animation: Wakl", "no animation named 'Wakl'"),
    ("gltf: {path: data/gltf/huesitos.glb, frames: 3}", "unknown parameter .frames."),
    ("gltf: data/gltf/nothere.glb", "input file not found"),
])
def test_bad_gltf_inputs_are_one_line_errors(write_pipeline, inputs, match):
    path = write_pipeline(f"inputs:\n  {inputs}\nsteps:\n  - write: out/x.glb\n")
    with pytest.raises(RigslimError, match=match) as err:
        run_pipeline(path)
    assert "\n" not in str(err.value) and err.value.fix
    assert not (path.parent / "out" / "x.glb").exists()


#: huesitos at 10 fps with example and test frames, then a decimation to 60 % and 30 % (the write step follows).
HUESITOS_DECIMATED = """
inputs:
  gltf: data/gltf/huesitos.glb
  fps: 10
poses: {examples: "0:16:3", test: "1:16:3"}
steps:
  - decimate: quartic
    targets: [0.6, 0.3]
"""


def test_simplify_a_gltf_into_lod_levels(write_pipeline, valid):
    """decimate + write: the original and two levels in one .glb, linked with MSFT_lod, valid."""
    path = write_pipeline(HUESITOS_DECIMATED + """    max_bones: 2
  - write: out/lod.glb
    quantize: ushort
    lod: true
    clamp_negative: true
    keep_input_weights: false
""")
    result = run_pipeline(path)
    assert result.asset.mesh.n_vertices < 128             # welded: the cylinder's seams are closed
    out = path.parent / "out" / "lod.glb"
    valid(out)
    levels = result.asset.levels
    from rigslim.io.gltf.document import load_gltf

    doc = load_gltf(out)
    names = [m.get("name") for m in doc.json["meshes"][1:]]
    assert len(names) == len(levels) and all(n.endswith(lv.label) for n, lv in zip(names, levels, strict=False))
    for i, level in enumerate(levels, 1):
        back = read_gltf_skin(out, mesh=i)
        assert back.mesh.n_faces == level.n_faces
        assert np.diff(back.weights.indptr).max() <= 2
    report = result.document["steps"][-1]["report"]
    assert report["mode"] == "rewrite" and report["levels"] == 2


def test_split_writes_each_level_and_the_sidecar(write_pipeline, valid):
    """``split: true``: OUT-60.glb and OUT-30.glb (one level each, no MSFT_lod) and OUT.lod.json; OUT itself is
    not written. Without levels only the sidecar; ``split`` without ``lod`` is one line."""
    import json

    from rigslim.io.gltf.document import load_gltf

    text = HUESITOS_DECIMATED + """  - write: out/lod.glb
    lod: true
    split: true
    clamp_negative: true
"""
    result = run_pipeline(write_pipeline(text))
    folder = Path(result.document["pipeline"]).parent / "out"
    assert sorted(p.name for p in folder.iterdir()) == ["lod-30.glb", "lod-60.glb", "lod.lod.json"]
    levels = result.asset.levels
    for name, level in zip(("lod-60.glb", "lod-30.glb"), levels, strict=True):
        valid(folder / name)
        assert "MSFT_lod" not in json.dumps(load_gltf(folder / name).json)
        assert read_gltf_skin(folder / name).mesh.n_faces == level.n_faces
    side = json.loads((folder / "lod.lod.json").read_text())
    assert side["sidecar_schema"] == "rigslim-lod-sidecar"
    assert [lv["file"] for lv in side["levels"][1:]] == ["lod-60.glb", "lod-30.glb"]
    source = Path(result.document["pipeline"]).parent / "data" / "gltf" / "huesitos.glb"
    assert (folder / side["levels"][0]["file"]).resolve() == source.resolve()
    assert [lv["faces"] for lv in side["levels"][1:]] == [lv.n_faces for lv in levels]
    cov = [lv["min_coverage"] for lv in side["levels"]]       # the coarsest shows down to coverage 0
    assert all(c is not None and c > 0 for c in cov[:-1]) and cov[:-1] == sorted(cov[:-1], reverse=True), cov
    assert cov[-1] == 0.0 and side["levels"][2]["max_coverage"] == cov[1]
    report = result.document["steps"][-1]["report"]
    assert report["split"]["files"] == [str(folder / "lod-60.glb"), str(folder / "lod-30.glb")]

    for p in folder.iterdir():
        p.unlink()
    undecimated = text.replace("  - decimate: quartic\n    targets: [0.6, 0.3]\n", "")
    run_pipeline(write_pipeline(undecimated, "undecimated.yaml"))
    side = json.loads((folder / "lod.lod.json").read_text())
    assert [p.name for p in folder.iterdir()] == ["lod.lod.json"] and len(side["levels"]) == 1

    with pytest.raises(RigslimError, match="split: true needs lod: true and levels: true") as err:
        run_pipeline(write_pipeline(text.replace("lod: true", "lod: false"), "nolod.yaml"))
    assert "\n" not in str(err.value) and "lod: true" in err.value.fix
