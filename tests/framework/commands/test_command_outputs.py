"""The one-command front ends as thin front ends (rigslim.commands.gltf_common): the pipeline runs in memory,
every file a command writes is committed in one transaction or not at all, errors name the option the user
typed, and the input is parsed once per command."""

from __future__ import annotations

import collections
import hashlib
import json
import shutil
from pathlib import Path

import pytest
import yaml

import rigslim.io.gltf.document as gltf_document
from rigslim.commands.cli import main
from rigslim.commands.gltf_common import option_for_field
from rigslim.errors import InputError

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"
SOURCE = GLTF / "huesitos.glb"          # 9 joints, 120 faces, one 1.56 s clip


def _sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


@pytest.fixture
def work(tmp_path, monkeypatch):
    """``in.glb`` and earlier outputs ``out.glb``, ``r.json``, ``p.yaml`` in the working folder."""
    monkeypatch.chdir(tmp_path)
    shutil.copy(SOURCE, tmp_path / "in.glb")
    shutil.copy(GLTF / "tube_two_materials.glb", tmp_path / "out.glb")
    (tmp_path / "r.json").write_text('{"old": true}\n')
    (tmp_path / "p.yaml").write_text("old: pipeline\n")
    return tmp_path


OLD = ["in.glb", "out.glb", "r.json", "p.yaml"]


def _unchanged(work: Path, argv, capsys) -> str:
    """Run ``argv`` expecting exit 2; check one stderr line, every old file byte-identical, no temporary file."""
    before = {n: _sha(work / n) for n in OLD}
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert {n: _sha(work / n) for n in OLD} == before
    assert not [p.name for p in work.rglob("*") if "rigslim-tmp" in p.name]
    return err[0]


OUTPUTS = ["-o", "out.glb", "--report", "r.json", "--save-pipeline", "p.yaml"]


@pytest.mark.parametrize(("argv", "option"), [
    (["reduce", "in.glb", "-k", "2", "--solve", "nosuch"], "--solve"),
    (["reduce", "in.glb", "-k", "2", "--select", "nosuch"], "--select"),
    (["reduce", "in.glb", "-k", "2", "--clip", "nosuch"], "--clip"),
    (["lod", "in.glb", "--method", "nosuch"], "--method"),
])
def test_bad_option_names_the_option_and_writes_nothing(argv, option, work, capsys):
    """No temporary YAML: the message names the option (not /tmp/rigslim-cmd-.../reduce-in.yaml: steps[2]...)."""
    line = _unchanged(work, argv + OUTPUTS, capsys)
    assert f"{option}:" in line and "rigslim-cmd" not in line and ".yaml" not in line and "steps[" not in line, line


@pytest.mark.parametrize("command", ["reduce", "lod"])
@pytest.mark.parametrize("report", ["folder", "under-a-file"])
def test_report_that_cannot_be_written_leaves_every_output(command, report, work, capsys):
    """``--report DIR`` (or a path under a file) fails before anything is committed: -o stays the old file."""
    (work / "folder").mkdir()
    target = "folder" if report == "folder" else "r.json/x.json"
    line = _unchanged(work, [command, "in.glb", "-o", "out.glb", "--save-pipeline", "p.yaml", "--report", target],
                      capsys)
    assert "cannot write output" in line


def test_failure_after_the_run_commits_nothing(work, capsys, monkeypatch):
    """The pipeline's write is staged with --report and --save-pipeline: a failure after the run (here in
    the world-space check of the written file) leaves all three as they were."""
    import rigslim.commands.reduce as reduce_module

    def failing(*args, **kwargs):
        raise InputError("measuring failed", field="--clip", fix="none")

    monkeypatch.setattr(reduce_module, "compare", failing)
    line = _unchanged(work, ["reduce", "in.glb", "-k", "2"] + OUTPUTS, capsys)
    assert "measuring failed" in line


def test_success_commits_every_output(work, capsys):
    assert main(["reduce", "in.glb", "-k", "2"] + OUTPUTS) == 0
    assert _sha(work / "out.glb") != _sha(GLTF / "tube_two_materials.glb")
    report = json.loads((work / "r.json").read_text(), parse_constant=lambda c: pytest.fail(f"non-JSON {c}"))
    assert report["output"] == str(work / "out.glb") and report["world"]["position_rms_m"] > 0
    saved = yaml.safe_load((work / "p.yaml").read_text())
    assert saved == report["pipeline"] and saved["steps"][-1]["write"] == str(work / "out.glb")
    assert report["run"]["pipeline_file"] is None          # run in memory: no pipeline file
    assert _sha(work / "in.glb") == _sha(SOURCE)


def test_option_for_field():
    pipeline = {"steps": [{"select": "k-largest", "k": 4}, {"solve": "geometric"}, {"write": "o.glb"}]}
    assert option_for_field("reduce", pipeline, "steps[2].solve") == "--solve"
    assert option_for_field("reduce", pipeline, "steps[1].k") == "-k"
    assert option_for_field("reduce", pipeline, "steps[1].select") == "--select"
    assert option_for_field("reduce", pipeline, "steps[3].quantize") == "--quantize"
    assert option_for_field("reduce", pipeline, "inputs.gltf.animation") == "--clip"
    assert option_for_field("reduce", pipeline, "inputs.gltf.fps") == "--fps"
    assert option_for_field("reduce", pipeline, "name") is None


def _count_parses(monkeypatch) -> collections.Counter:
    counts: collections.Counter = collections.Counter()
    parse = gltf_document.parse_glb

    def counting(data, path):
        counts[Path(path).name] += 1
        return parse(data, path)

    monkeypatch.setattr(gltf_document, "parse_glb", counting)
    return counts


def test_reduce_parses_its_input_once(work, monkeypatch, capsys):
    """``rigslim reduce`` parsed the input 6 times (load_gltf 5 times) before it read it once per command:
    once for the checks, the skin count, the clip and the pipeline's reader and the reference of the
    world-space check; the written file once for that check."""
    counts = _count_parses(monkeypatch)
    assert main(["reduce", "in.glb", "-o", "new.glb", "-k", "2"]) == 0
    assert counts == {"in.glb": 1, "new.glb": 1}


@pytest.mark.parametrize("split", [False, True])
def test_lod_parses_its_input_once(split, work, monkeypatch, capsys):
    counts = _count_parses(monkeypatch)
    assert main(["lod", "in.glb", "-o", "new.glb", "--ratios", "0.5"] + (["--split"] if split else [])) == 0
    assert counts["in.glb"] == 1
    assert sum(counts.values()) == (2 if split else 1)       # --split: the LOD file it cuts up, once


def test_compare_frames_use_the_one_frame_parser(work, capsys):
    assert main(["compare", "in.glb", "in.glb", "--frames", "1:2:3:4"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "--frames" in err[0] and "too many ':'" in err[0], err
