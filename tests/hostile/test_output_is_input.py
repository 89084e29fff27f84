"""No command and no pipeline may write over a file it reads (rigslim.io.atomic.refuse_input_as_output).

Each case names the input as an output in one of five ways (the same path, ``./x``, ``sub/../x``, a
symbolic link, a hard link) and expects exit 2, one line on stderr saying which option names which
input, and the input byte-identical (its SHA-256 before and after).
"""

from __future__ import annotations

import hashlib
import os
import shutil
from pathlib import Path

import pytest

from rigslim.commands.cli import main
from rigslim.io.atomic import OutputError, refuse_input_as_output

GLTF = Path(__file__).resolve().parents[2] / "examples" / "data" / "gltf"
#: A small skinned, animated glTF (9 joints, 120 faces).
SOURCE = GLTF / "huesitos.glb"
FORMS = ["same", "dot", "dotdot", "symlink", "hardlink"]


def _sha(path: Path) -> str:
    return hashlib.sha256(Path(path).read_bytes()).hexdigest()


def _name(tmp: Path, target: str, form: str) -> str:
    """A way to write ``tmp/target`` (an existing file) as an output argument, relative to ``tmp``."""
    if form == "same":
        return str(tmp / target)
    if form == "dot":
        return f"./{target}"
    if form == "dotdot":
        (tmp / "sub").mkdir(exist_ok=True)
        return f"sub/../{target}"
    link = tmp / f"{form}-{target}"
    if form == "symlink":
        link.symlink_to(target)
    else:
        os.link(tmp / target, link)
    return link.name


@pytest.fixture
def work(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    shutil.copy(SOURCE, tmp_path / "in.glb")
    return tmp_path


def _refused(argv, files, capsys, option: str) -> None:
    before = {f: _sha(f) for f in files}
    assert main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    assert err[0].startswith(f"rigslim: error: {option}") and "is the input" in err[0] and \
        "(same file)" in err[0] and "write to another path" in err[0], err[0]
    assert {f: _sha(f) for f in files} == before


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("command", ["reduce", "lod"])
def test_output_naming_the_input_is_refused(command, form, work, capsys):
    out = _name(work, "in.glb", form)
    _refused([command, "in.glb", "-o", out], [work / "in.glb"], capsys, "-o")
    assert not list(work.glob(".*rigslim-tmp*"))


@pytest.mark.parametrize("form", ["same", "symlink", "hardlink"])
def test_lod_split_level_naming_the_input_is_refused(form, work, capsys):
    """``lod -o c.glb --split --ratios 0.5`` writes c-50.glb: refused when that is the input."""
    if form == "same":
        shutil.copy(SOURCE, work / "c-50.glb")
        src = "c-50.glb"
    else:
        src = "in.glb"
        (work / "c-50.glb").symlink_to("in.glb") if form == "symlink" else os.link(work / "in.glb", work / "c-50.glb")
    _refused(["lod", src, "-o", "c.glb", "--split", "--ratios", "0.5"], [work / "in.glb", work / "c-50.glb"],
             capsys, "--split (level 0.5)")


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("option", ["--report", "--save-pipeline"])
def test_report_or_saved_pipeline_naming_the_input_is_refused(option, form, work, capsys):
    _refused(["reduce", "in.glb", "-o", "out.glb", option, _name(work, "in.glb", form)], [work / "in.glb"],
             capsys, option)
    assert not (work / "out.glb").exists()


@pytest.mark.parametrize("form", FORMS)
def test_inspect_report_naming_the_input_is_refused(form, work, capsys):
    _refused(["inspect", "in.glb", "--report", _name(work, "in.glb", form)], [work / "in.glb"], capsys, "--report")


def _pipeline(work: Path, write: str) -> Path:
    p = work / "p.yaml"
    p.write_text(f"inputs:\n  gltf: in.glb\nposes: {{examples: '0:40:4', test: '1:40:4'}}\n"
                 f"steps:\n  - select: k-largest\n    k: 2\n  - solve: geometric\n  - write: {write}\n")
    return p


@pytest.mark.parametrize("form", FORMS)
def test_pipeline_write_step_naming_its_gltf_input_is_refused(form, work, capsys):
    p = _pipeline(work, _name(work, "in.glb", form))
    _refused(["run", str(p), "-q"], [work / "in.glb", p], capsys, f"{p}: steps[3].write")


@pytest.mark.parametrize("form", FORMS)
@pytest.mark.parametrize("target", ["p.yaml", "in.glb"])
def test_run_metrics_naming_the_pipeline_or_an_input_is_refused(target, form, work, capsys):
    p = _pipeline(work, "out.glb")
    _refused(["run", str(p), "-q", "--metrics", _name(work, target, form)], [work / "in.glb", p], capsys,
             "--metrics")
    assert not (work / "out.glb").exists()


def test_gltf_output_whose_buffer_is_the_inputs_buffer_is_refused(tmp_path, capsys):
    """``-o RiggedFigure0.gltf`` would write RiggedFigure0.bin, the buffer RiggedFigure.gltf reads."""
    shutil.copytree(GLTF / "RiggedFigure", tmp_path / "fig")
    src, buf = tmp_path / "fig" / "RiggedFigure.gltf", tmp_path / "fig" / "RiggedFigure0.bin"
    _refused(["reduce", str(src), "-o", str(tmp_path / "fig" / "RiggedFigure0.gltf")], [src, buf], capsys,
             "-o (its buffer)")
    assert not (tmp_path / "fig" / "RiggedFigure0.gltf").exists()


def test_rigslim_report_output_naming_a_metrics_document_is_refused(tmp_path, capsys):
    doc = tmp_path / "m.json"
    doc.write_text('{"evaluations": []}\n')
    _refused(["report", str(doc), "-o", str(tmp_path / "." / "m.json")], [doc], capsys, "-o")


def test_refuse_input_as_output_compares_real_paths_and_inodes(tmp_path):
    a = tmp_path / "a.glb"
    a.write_bytes(b"x")
    os.link(a, tmp_path / "b.glb")
    (tmp_path / "c.glb").symlink_to(a)
    for same in (a, tmp_path / "b.glb", tmp_path / "c.glb", tmp_path / "d" / ".." / "a.glb"):
        with pytest.raises(OutputError, match="is the input"):
            refuse_input_as_output({"-o": same}, [a])
    refuse_input_as_output({"-o": tmp_path / "new.glb", "--report": tmp_path / "r.json"}, [a])   # no clash
    with pytest.raises(OutputError, match="also the -o output"):
        refuse_input_as_output({"-o": tmp_path / "x.glb", "--report": tmp_path / "x.glb"}, [a])
    refuse_input_as_output({"-o": tmp_path / "x.glb", "--report": tmp_path / "x.glb"}, [a], distinct=False)
    refuse_input_as_output({"--report": "/dev/null", "--save-pipeline": "/dev/null"}, [a])   # written through



def _split_pipeline(work: Path, src: str, targets: str) -> Path:
    p = work / "p.yaml"
    p.write_text(f"inputs:\n  gltf: {src}\nposes: {{examples: '0:40:4', test: '1:40:4'}}\n"
                 f"steps:\n  - decimate: quartic\n    {targets}\n"
                 f"  - write: c.glb\n    lod: true\n    split: true\n    clamp_negative: true\n")
    return p


@pytest.mark.parametrize("form", ["same", "symlink", "hardlink"])
def test_pipeline_split_level_naming_the_input_is_refused(form, work, capsys):
    """``write: c.glb`` with ``split: true`` after ``targets: [0.5]`` writes c-50.glb: refused before the
    decimation runs when that is the input (or a link to it)."""
    src = "c-50.glb" if form == "same" else "in.glb"
    if form == "same":
        os.replace(work / "in.glb", work / src)
    elif form == "symlink":
        (work / "c-50.glb").symlink_to("in.glb")
    else:
        os.link(work / "in.glb", work / "c-50.glb")
    p = _split_pipeline(work, src, "targets: [0.5]")
    _refused(["run", str(p), "-q"], [work / src, p], capsys, f"{p}: steps[2].write (split, target 0.5)")
    assert not (work / "c.lod.json").exists()


def test_pipeline_split_level_named_by_its_label_is_checked_by_the_writer(work, capsys):
    """A level made for an error target is named after its label (c-quartic-err0.5.glb), which the pipeline
    does not predict: the writer refuses it before it writes any file."""
    os.replace(work / "in.glb", work / "c-quartic-err0.5.glb")
    p = _split_pipeline(work, "c-quartic-err0.5.glb", "error_targets: [0.5]")
    before = _sha(work / "c-quartic-err0.5.glb")
    assert main(["run", str(p), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "steps[2] (write): split (c-quart" in err[0] and "(same file)" in err[0], err
    assert _sha(work / "c-quartic-err0.5.glb") == before and not (work / "c.lod.json").exists()
