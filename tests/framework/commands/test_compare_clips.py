"""Which clips ``rigslim compare`` poses: the reference's clip against the candidate's clip of the same name
(wherever it lies), else the candidate's first clip with one stderr line; ``--clip`` names a clip of both."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support.hostile_gltf import write_glb

from rigslim.commands.cli import main
from rigslim.io.gltf.document import load_gltf

pytest.importorskip("pymeshlab")

TUBE = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "tube_two_materials.glb"


def _tube_with(path: Path, animations) -> Path:
    """The tube with its animations replaced by ``animations(bend)`` (``bend``: its one clip, a JSON copy)."""
    src = load_gltf(TUBE)
    js = json.loads(json.dumps(src.json))
    js["animations"] = animations(js["animations"][0])
    return write_glb(path, js, src.buffers[0])


def _still(bend: dict) -> dict:
    """A clip of the tube's that does not bend: only the morph-weight channel of ``bend``, named ``still``."""
    return dict(json.loads(json.dumps(bend)), name="still", channels=bend["channels"][1:])


def _compare(capfd, *args) -> tuple[int, dict | None, list[str]]:
    capfd.readouterr()
    code = main(["compare", str(TUBE), *map(str, args), "--samples", "1000", "--frames", "0:31:10", "--json"])
    out, err = capfd.readouterr()
    return code, json.loads(out) if code == 0 else None, [line for line in err.splitlines() if line.strip()]


def test_the_candidate_clip_of_the_same_name_is_compared(tmp_path, capfd):
    """The candidate's first clip is another one (``still``); its ``bend`` is the reference's: no error at all."""
    cand = _tube_with(tmp_path / "second.glb", lambda bend: [_still(bend), bend])
    code, res, err = _compare(capfd, cand)
    assert code == 0 and err == []
    assert res["clip"] == res["candidate_clip"] == "bend" and "clip_note" not in res
    assert res["position_max_m"] == 0.0


def test_a_differently_named_clip_is_compared_and_said(tmp_path, capfd):
    """The candidate's only clip is ``animation``: compared with the reference's ``bend``, in one stderr line
    naming both clips and --clip."""
    cand = _tube_with(tmp_path / "renamed.glb", lambda bend: [dict(bend, name="animation")])
    code, res, err = _compare(capfd, cand)
    assert code == 0 and res["candidate_clip"] == "animation" and res["position_max_m"] == 0.0
    assert len(err) == 1 and "'bend'" in err[0] and "'animation'" in err[0] and "--clip" in err[0]
    assert res["clip_note"] == err[0]


def test_clip_names_a_clip_of_both_files(tmp_path, capfd):
    cand = _tube_with(tmp_path / "renamed.glb", lambda bend: [dict(bend, name="animation")])
    code, _, err = _compare(capfd, cand, "--clip", "bend")
    assert code == 2 and len(err) == 1
    assert "renamed.glb" in err[0] and "--clip" in err[0] and "'animation'" in err[0]
    second = _tube_with(tmp_path / "second.glb", lambda bend: [_still(bend), bend])
    code, res, err = _compare(capfd, second, "--clip", "bend")
    assert code == 0 and res["candidate_clip"] == "bend" and res["position_max_m"] == 0.0 and err == []


def test_an_unnamed_clip_is_named_as_it_is_listed(tmp_path, capfd):
    """Unnamed clips are listed (and labelled in lod's report) as ``#i``: ``--clip '#0'`` names the first of
    both files. It was refused with "the candidate has no clip '#0' (its clips: #0)"."""
    def unnamed(bend):
        return [{k: v for k, v in bend.items() if k != "name"}]
    ref = _tube_with(tmp_path / "ref.glb", unnamed)
    cand = _tube_with(tmp_path / "cand.glb", unnamed)
    capfd.readouterr()
    assert main(["compare", str(ref), str(cand), "--clip", "#0", "--samples", "500", "--frames", "0:31:10",
                 "--json"]) == 0
    res = json.loads(capfd.readouterr().out)
    assert res["position_max_m"] == 0.0
    assert main(["compare", str(ref), str(cand), "--clip", "#1"]) == 2
    assert "#1" in capfd.readouterr().err
