"""rigslim report on runs whose outputs are glTF: reduced weights read from the .glb, MSFT_lod levels listed."""

from __future__ import annotations

from pathlib import Path

import pytest

from rigslim.commands.cli import main

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"


def test_report_renders_a_run_that_wrote_only_a_glb(tmp_path, capsys):
    yml = tmp_path / "k2.yaml"
    yml.write_text(f"""
inputs:
  gltf: {GLTF / 'animation_with_skeleton.glb'}
  fps: 30
poses: {{examples: "0:26:4", test: "1:26:2"}}
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms]
  - write: out/k2.glb
    quantize: ubyte
""")
    assert main(["run", str(yml), "--metrics", str(tmp_path / "m.json"), "-q"]) == 0
    out = tmp_path / "report.html"
    assert main(["report", str(tmp_path / "m.json"), "-o", str(out), "--size", "96x80", "--backend", "numpy",
                 "-q"]) == 0
    text = out.read_text()
    assert "no reduced weights found" not in text and "not rendered" not in text
    # the full weights, then the reduced deformation read back from the .glb and its normal-deviation map
    assert "<figcaption>full weights" in text and "<figcaption>k-largest-k2</figcaption>" in text
    assert "<figcaption>k-largest-k2: normal deviation" in text


def test_report_lists_the_lod_levels(tmp_path):
    yml = tmp_path / "lod.yaml"
    yml.write_text(f"""
inputs:
  gltf: {GLTF / 'tube_two_materials.glb'}
  fps: 30
poses: {{examples: "0:31:4", test: "2:31:4"}}
steps:
  - decimate: quartic
    targets: [0.5, 0.25]
    max_bones: 4
  - evaluate:
      - metro: {{samples: 1000}}
  - write: out/tube-lod.glb
    lod: true
    quantize: ubyte
""")
    assert main(["run", str(yml), "--metrics", str(tmp_path / "m.json"), "-q"]) == 0
    out = tmp_path / "report.html"
    assert main(["report", str(tmp_path / "m.json"), "-o", str(out), "--no-renders", "-q"]) == 0
    text = out.read_text()
    assert "<h2>Levels of detail</h2>" in text
    assert "<td>Torso</td><td>2</td><td>Torso-quartic-25pct</td><td>2</td><td>0, 1</td>" in text
    assert "<td>Legs</td><td>1</td><td>Legs-quartic-50pct</td><td>1</td><td>0</td>" in text


def test_lod_rows_of_a_file_without_lod_is_empty():
    from rigslim.report.gltf import lod_rows

    assert lod_rows(GLTF / "huesitos.glb") == []
    from rigslim.errors import InputError

    with pytest.raises(InputError):
        lod_rows(GLTF / "missing.glb")


def test_report_gives_errors_in_world_units(tmp_path):
    """assimp's character: joints scale by 100, so % of the bind diagonal overstates the error 100 times."""
    import json
    import re

    yml = tmp_path / "k2.yaml"
    yml.write_text(f"""
inputs:
  gltf: {GLTF / 'animation_with_skeleton.glb'}
  fps: 30
poses: {{examples: "0:26:4", test: "1:26:2"}}
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms]
""")
    assert main(["run", str(yml), "--metrics", str(tmp_path / "m.json"), "-q"]) == 0
    doc = json.loads((tmp_path / "m.json").read_text())
    from rigslim.report.gltf import world_diagonal

    world = world_diagonal(GLTF / "animation_with_skeleton.glb")
    assert world > 50 * doc["mesh"]["bbox_diagonal"]                    # the x100 joint scale
    # schema 3 records world units: % of the world diagonal and metres, so the report needs no conversion
    assert doc["schema_version"] >= 3
    metrics = doc["evaluations"][-1]["metrics"]
    assert metrics["reference_diagonal_m"] == pytest.approx(world, rel=1e-3)
    pct, metres = metrics["position_rms_pct"]["mean"], metrics["position_rms_m"]["mean"]
    assert metres == pytest.approx(pct / 100 * metrics["reference_diagonal_m"], rel=1e-6)
    out = tmp_path / "report.html"
    assert main(["report", str(tmp_path / "m.json"), "-o", str(out), "--no-renders", "-q"]) == 0
    assert "<h2>World units</h2>" not in out.read_text()

    # a schema 2 document (% of the bind-space diagonal) gets the World units table, converted
    old = dict(doc, schema_version=2)
    old["evaluations"] = [dict(ev, metrics={"position_rms_pct": {"mean": 0.4, "max": 0.5}})
                          for ev in doc["evaluations"]]
    (tmp_path / "v2.json").write_text(json.dumps(old))
    assert main(["report", str(tmp_path / "v2.json"), "-o", str(out), "--no-renders", "-q"]) == 0
    text = out.read_text()
    row = re.search(r"<td>position_rms_pct</td><td>([^<]+)</td><td>([^<]+)</td><td>([^<]+)</td><td>([^<]+)</td>",
                    text)
    assert row, "no world-units row"
    pct_bind, metres, pct_world, world_row = (float(x) for x in row.groups())
    assert world_row == pytest.approx(world, rel=1e-3)
    assert metres == pytest.approx(pct_bind / 100 * doc["mesh"]["bbox_diagonal"], rel=1e-3)
    assert pct_world == pytest.approx(100 * metres / world, rel=1e-3)


SUITE = GLTF / "suite"


@pytest.fixture(scope="module")
def wuson_runs(tmp_path_factory):
    """wuson (clips Wuson_Run, Wuson_Walk) reduced to k = 2: the command's --report and its pipeline run again
    with --metrics (every clip, stacked: the run numbers its frames over both)."""
    import json

    folder = tmp_path_factory.mktemp("wuson")
    assert main(["reduce", str(SUITE / "wuson.glb"), "-k", "2", "-o", str(folder / "w2.glb"),
                 "--report", str(folder / "r.json"), "--save-pipeline", str(folder / "w2.yaml")]) == 0
    assert main(["run", str(folder / "w2.yaml"), "--metrics", str(folder / "m.json"), "-q"]) == 0
    return folder, json.loads((folder / "m.json").read_text())


def _headings(text: str) -> list[str]:
    import re

    return re.findall(r"<div class=\"frame\"><h3>([^<]*)</h3>", text)


def test_report_of_a_multi_clip_run_renders_its_default_frame(wuson_runs, capsys):
    """The default frame (the worst test frame, numbered over both clips) is rendered with its reduced weights,
    and its heading names its clip and its frame in the clip."""
    import html

    folder, doc = wuson_runs
    assert [c["clip"] for c in doc["frames"]["clips"]["test"]] == ["Wuson_Run", "Wuson_Walk"]
    out = folder / "default.html"
    assert main(["report", str(folder / "m.json"), "-o", str(out), "--size", "64x48", "--backend", "numpy",
                 "-q"]) == 0
    text = out.read_text()
    assert "not rendered" not in text and "no reduced weights found" not in text    # the .glb's weights matched
    heading = html.unescape(_headings(text)[0])
    assert heading.startswith("reduce-wuson, frame ") and "(clip 'Wuson_" in heading


def test_report_frames_use_the_run_numbering(wuson_runs, capsys):
    """--frames takes the run's (stacked) numbers: a test frame of the second clip is a test frame, named by its
    clip and its frame in the clip; a frame past the stack is refused with the clips' ranges."""
    import html

    folder, doc = wuson_runs
    walk = next(c for c in doc["frames"]["clips"]["test"] if c["clip"] == "Wuson_Walk")["frames"][0]
    stacked = next(f for f in doc["frames"]["test"] if f > max(doc["frames"]["clips"]["test"][0]["frames"]))
    out = folder / "frames.html"
    capsys.readouterr()
    assert main(["report", str(folder / "m.json"), "-o", str(out), "--size", "64x48", "--backend", "numpy",
                 "--frames", str(stacked)]) == 0
    assert "is not a test frame" not in capsys.readouterr().err
    assert [html.unescape(h) for h in _headings(out.read_text())] == \
        [f"reduce-wuson, frame {stacked} (clip 'Wuson_Walk', frame {walk})"]
    assert main(["report", str(folder / "m.json"), "-o", str(out), "--frames", "100000", "-q"]) == 2
    err = capsys.readouterr().err
    assert "frame 100000 is outside the animation" in err and "clips stacked: 'Wuson_Run' 0.." in err


def test_report_reads_the_report_of_rigslim_reduce(wuson_runs, capsys):
    """reduce --report holds the run (``run``) and its pipeline: the report renders it like the metrics JSON."""
    folder, _ = wuson_runs
    out = folder / "command.html"
    assert main(["report", str(folder / "r.json"), "-o", str(out), "--size", "64x48", "--backend", "numpy",
                 "-q"]) == 0
    text = out.read_text()
    assert "<figcaption>geometric-k2</figcaption>" in text and "not rendered" not in text
    assert "pipeline file not found" not in text        # read with the pipeline the command ran
    assert "(clip &#x27;Wuson_" in _headings(text)[0]


def test_report_of_a_lod_report_without_measure_names_the_option(tmp_path, capsys):
    src = GLTF / "tube_two_materials.glb"
    assert main(["lod", str(src), "-o", str(tmp_path / "a.glb"), "--ratios", "0.5", "--report",
                 str(tmp_path / "plain.json")]) == 0
    capsys.readouterr()
    assert main(["report", str(tmp_path / "plain.json"), "-o", str(tmp_path / "r.html"), "-q"]) == 2
    assert "--measure" in capsys.readouterr().err
    assert main(["lod", str(src), "-o", str(tmp_path / "b.glb"), "--ratios", "0.5", "--measure", "--report",
                 str(tmp_path / "measured.json")]) == 0
    assert main(["report", str(tmp_path / "measured.json"), "-o", str(tmp_path / "m.html"), "--no-renders",
                 "-q"]) == 0
    assert "<h2>Levels of detail</h2>" in (tmp_path / "m.html").read_text()


def test_report_of_a_two_skin_reduce_says_how_to_render(tmp_path, capsys):
    """Several skins: the run of the last skin read an intermediate file; table and plots, and a note naming the
    way to render a skin."""
    from test_gltf_commands import _two_skin_tube

    src = tmp_path / "two-skins.glb"
    _two_skin_tube(src)
    assert main(["reduce", str(src), "-o", str(tmp_path / "k1.glb"), "-k", "1", "--solve", "k-largest",
                 "--report", str(tmp_path / "r.json")]) == 0
    assert main(["report", str(tmp_path / "r.json"), "-o", str(tmp_path / "r.html"), "-q"]) == 0
    text = (tmp_path / "r.html").read_text()
    assert "ran one pipeline per skin (2)" in text and "rigslim run --metrics" in text
