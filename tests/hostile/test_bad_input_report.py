"""Hostile inputs of ``rigslim report``: one line and exit 2, the old report untouched."""

from __future__ import annotations

import copy
import json

import pytest
from support.bad_input import DATA, assert_one_line, assert_unchanged, run_cli, run_cli_subprocess, snapshot, write_json

PIPELINE = """\
inputs:
  gltf: model.gltf
  fps: 2
poses:
  examples: "0:12:2"
  test: "1:12:2"
steps:
  - select: k-largest
    k: 1
  - solve: k-largest
  - evaluate: [position-rms, max-influences]
"""


@pytest.fixture(scope="module")
def metrics(tmp_path_factory):
    """A real metrics document (a small glTF run) and its folder."""
    from rigslim.commands.cli import main

    folder = tmp_path_factory.mktemp("report")
    (folder / "model.gltf").write_bytes((DATA / "gltf" / "simple_skin.gltf").read_bytes())
    (folder / "pipeline.yaml").write_text(PIPELINE)
    assert main(["run", str(folder / "pipeline.yaml"), "--metrics", str(folder / "metrics.json"), "-q"]) == 0
    return folder, json.loads((folder / "metrics.json").read_text())


@pytest.fixture
def out(tmp_path):
    """An output folder holding an earlier report."""
    folder = tmp_path / "out"
    folder.mkdir()
    (folder / "report.html").write_text("<html>old report</html>\n")
    return folder


def _bad(capfd, out, inputs, *must, extra=(), subprocess=False):
    before = snapshot(out)
    args = ["report", *inputs, "-o", out / "report.html", "--no-renders", "-q", *extra]
    code, lines = run_cli_subprocess(args) if subprocess else run_cli(args, capfd)
    line = assert_one_line(code, lines, *must)
    assert_unchanged(out, before)
    return line


def test_good_document_still_reports(metrics, out, capfd):
    folder, _ = metrics
    code, lines = run_cli(["report", folder / "metrics.json", "-o", out / "new.html", "--no-renders", "-q"], capfd)
    assert code == 0, lines


def test_binary_file(metrics, out, capfd, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_bytes((DATA / "gltf" / "huesitos.glb").read_bytes())
    assert "UTF-8" in _bad(capfd, out, [bad], "bad.json")


def test_evaluations_not_objects(metrics, out, capfd, tmp_path):
    _, doc = metrics
    doc = copy.deepcopy(doc)
    doc["evaluations"] = [42]
    _bad(capfd, out, [write_json(tmp_path / "bad.json", doc)], "bad.json", "evaluations[0]")


@pytest.mark.parametrize("value, where", [
    ("abc", "position_rms_pct"),
    ({"mean": "abc", "max": 1.0}, "position_rms_pct.mean"),
    ({"mean": 1.0, "max": 2.0, "per_frame": [1.0, "x"]}, "position_rms_pct.per_frame[1]"),
    ({"mean": 1.0, "max": 2.0, "per_frame": 7}, "position_rms_pct.per_frame"),
])
def test_wrong_typed_metric(metrics, out, capfd, tmp_path, value, where):
    _, doc = metrics
    doc = copy.deepcopy(doc)
    doc["evaluations"][0]["metrics"]["position_rms_pct"] = value
    if isinstance(value, str):
        value = {"nested": [{"deep": value}]}
        doc["evaluations"][0]["metrics"]["position_rms_pct"] = value
        where = "position_rms_pct"
    _bad(capfd, out, [write_json(tmp_path / "bad.json", doc)], "bad.json", f"evaluations[0].metrics.{where}")


def test_wrong_typed_steps_and_frames(metrics, out, capfd, tmp_path):
    _, doc = metrics
    for key, value, where in (("steps", [{"seconds": "fast"}], "steps[0].seconds"),
                              ("frames", {"test": "all"}, "frames.test")):
        bad = copy.deepcopy(doc)
        bad[key] = value
        _bad(capfd, out, [write_json(tmp_path / "bad.json", bad)], "bad.json", where)


def test_deeply_nested_json(metrics, out, capfd, tmp_path):
    bad = tmp_path / "bad.json"
    bad.write_text('{"evaluations": ' + "[" * 100_000 + "]" * 100_000 + "}")
    _bad(capfd, out, [bad], "bad.json")


def test_non_finite_values_read_as_missing(metrics, out, capfd, tmp_path):
    folder, doc = metrics
    doc = copy.deepcopy(doc)
    m = doc["evaluations"][0]["metrics"]["position_rms_pct"]
    m["mean"], m["per_frame"][0] = float("inf"), float("nan")
    bad = tmp_path / "nonfinite.json"
    bad.write_text(json.dumps(doc))  # Python writes Infinity / NaN
    nulls = tmp_path / "nulls.json"
    m["mean"], m["per_frame"][0] = None, None
    nulls.write_text(json.dumps(doc, allow_nan=False))
    for path in (bad, nulls):
        code, lines = run_cli(["report", path, "-o", out / "new.html", "--no-renders", "-q"], capfd)
        assert code == 0, lines


@pytest.mark.parametrize("size", ["100000x100000", "0x10", "-5x5"])
def test_render_size_bounded(metrics, out, capfd, size):
    folder, _ = metrics
    line = _bad(capfd, out, [folder / "metrics.json"], "size", extra=[f"--size={size}"], subprocess=True)
    assert "8192" in line


def test_command_report_without_a_run(out, capfd, tmp_path):
    """The report of a command that runs no pipeline (rigslim inspect): one line naming the command and the
    reports that work."""
    bad = write_json(tmp_path / "inspect.json", {"schema": "rigslim-gltf-command", "schema_version": 1,
                                                 "command": "inspect", "path": "x.glb"})
    line = _bad(capfd, out, [bad], "inspect.json", "command", "rigslim inspect", "rigslim reduce")
    assert "no 'evaluations' list" not in line


def test_command_report_that_measured_nothing(metrics, out, capfd, tmp_path):
    """A rigslim lod run without --measure has no evaluation: the fix names --measure."""
    _, doc = metrics
    report = {"schema": "rigslim-gltf-command", "schema_version": 1, "command": "lod",
              "run": dict(copy.deepcopy(doc), evaluations=[]), "pipeline": {}}
    _bad(capfd, out, [write_json(tmp_path / "lod.json", report)], "lod.json", "run.evaluations", "--measure")
