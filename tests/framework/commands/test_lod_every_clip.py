"""``rigslim lod`` fits its collapses to example frames of every clip and measures the levels on held-out frames
of each (``--clip`` restricts both); a file whose first clip holds one pose takes its motion from the others.

The tube's clips here are ``still`` (its morph weights only: the joint never turns) and then ``bend``. Fitted to
the first clip alone, as ``lod`` did before, the collapses never see the bend, and the level is far off in it.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest
from support.hostile_gltf import write_glb

from rigslim.commands.cli import main
from rigslim.io.gltf.document import load_gltf

pytest.importorskip("pymeshlab")

TUBE = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "tube_two_materials.glb"


def _tube(path: Path, first: str) -> Path:
    """The tube with two clips: ``first`` (``still``: the bend's morph channel only; ``pose``: the joint's rotation
    at its first key only, a clip of one pose, 0 s long) and then ``bend``."""
    src = load_gltf(TUBE)
    js = json.loads(json.dumps(src.json))
    bend = js["animations"][0]
    if first == "still":
        clip = dict(json.loads(json.dumps(bend)), name="still", channels=bend["channels"][1:])
    else:                          # one key: new accessors over the first element of the bend's time and rotation
        acc = js["accessors"]
        smp = bend["samplers"][0]
        acc.append(dict(acc[smp["input"]], count=1, max=acc[smp["input"]]["min"]))
        acc.append(dict(acc[smp["output"]], count=1))
        clip = {"name": "pose", "samplers": [{"input": len(acc) - 2, "output": len(acc) - 1,
                                              "interpolation": "LINEAR"}],
                "channels": [dict(bend["channels"][0], sampler=0)]}
    js["animations"] = [clip, bend]
    return write_glb(path, js, src.buffers[0])


def _level_error(capfd, src: Path, out: Path, clip: str) -> dict:
    capfd.readouterr()
    assert main(["compare", str(src), str(out), "--clip", clip, "--level", "1", "--json", "--samples", "2000"]) == 0
    return json.loads(capfd.readouterr().out)


def test_lod_fits_every_clip_and_reports_the_frames_of_each(tmp_path, capfd):
    src = _tube(tmp_path / "still_bend.glb", "still")
    every, first = tmp_path / "every.glb", tmp_path / "first.glb"
    assert main(["lod", str(src), "-o", str(every), "--ratios", "0.25", "--max-error", "none",
                 "--report", str(tmp_path / "every.json")]) == 0
    assert main(["lod", str(src), "-o", str(first), "--ratios", "0.25", "--max-error", "none", "--clip", "still",
                 "--report", str(tmp_path / "first.json")]) == 0
    doc = json.loads((tmp_path / "every.json").read_text())
    assert [c["clip"] for c in doc["clips"]["examples"]] == [c["clip"] for c in doc["clips"]["test"]] == \
        ["still", "bend"]
    for ex, te in zip(doc["clips"]["examples"], doc["clips"]["test"], strict=True):
        assert ex["frames"] and te["frames"] and not set(ex["frames"]) & set(te["frames"])   # held out
        assert max(ex["frames"] + te["frames"]) <= 30                                    # 1 s at 30 fps
    only = json.loads((tmp_path / "first.json").read_text())["clips"]
    assert [c["clip"] for c in only["examples"]] == [c["clip"] for c in only["test"]] == ["still"]
    a, b = _level_error(capfd, src, every, "bend"), _level_error(capfd, src, first, "bend")
    assert a["faces"] == b["faces"] == 384
    # measured: 0.020 % / 0.28 % RMS / max fitted on both clips, 0.256 % / 3.52 % on the still clip alone
    assert a["hausdorff_rms_pct"] < 0.25 * b["hausdorff_rms_pct"] and a["hausdorff_max_pct"] < b["hausdorff_max_pct"]


def test_a_first_clip_of_one_pose_takes_the_motion_of_the_others(tmp_path, capfd):
    """A weapon's 0 s idle before its reload: ``lod`` once simplified such a file for its rest pose only and
    ``reduce`` fell back to k-largest; both now fit the clips that move."""
    src = _tube(tmp_path / "pose_bend.glb", "pose")
    assert [a["name"] for a in load_gltf(src).json["animations"]] == ["pose", "bend"]
    capfd.readouterr()
    assert main(["lod", str(src), "-o", str(tmp_path / "l.glb"), "--ratios", "0.5",
                 "--report", str(tmp_path / "l.json")]) == 0
    err = capfd.readouterr().err
    assert "rest pose only" not in err
    doc = json.loads((tmp_path / "l.json").read_text())
    assert doc["frames"] == 31 and doc["clip"] == "bend"
    assert "bend" in [c["clip"] for c in doc["clips"]["test"]]
    assert main(["reduce", str(src), "-o", str(tmp_path / "r.glb"), "-k", "1",
                 "--report", str(tmp_path / "r.json")]) == 0
    assert "falling back" not in capfd.readouterr().err
    rep = json.loads((tmp_path / "r.json").read_text())
    assert rep["world"]["clips"] >= 1 and rep["world"]["position_rms_m"] >= 0


def test_every_clip_of_one_pose_is_named_as_such(tmp_path, capfd):
    """Two clips, each one pose: ``lod`` simplifies for the rest pose and ``reduce`` falls back to k-largest, and
    both say that each of the clips holds one pose (they once named only the first); with ``--clip`` they name
    that one."""
    one = _tube(tmp_path / "pose_bend.glb", "pose")
    src = load_gltf(one)
    js = json.loads(json.dumps(src.json))
    js["animations"] = [js["animations"][0], dict(json.loads(json.dumps(js["animations"][0])), name="aim")]
    src = write_glb(tmp_path / "poses.glb", js, src.buffers[0])
    capfd.readouterr()
    assert main(["lod", str(src), "-o", str(tmp_path / "l.glb"), "--ratios", "0.5", "--max-error", "none"]) == 0
    err = capfd.readouterr().err
    assert "each of poses.glb's 2 clips holds one pose only (the first, 'pose', is 0 s long)" in err
    assert "simplifying for the rest pose only" in err
    assert main(["reduce", str(src), "-o", str(tmp_path / "r.glb"), "-k", "1"]) == 0
    err = capfd.readouterr().err
    assert "each of poses.glb's 2 clips holds one pose only" in err and "falling back to k-largest" in err
    assert main(["reduce", str(src), "-o", str(tmp_path / "r2.glb"), "-k", "1", "--clip", "aim"]) == 0
    assert "poses.glb's clip 'aim' holds one pose only" in capfd.readouterr().err


def test_a_first_clip_of_one_pose_reduced_into_usd(tmp_path, capfd):
    """The USD output is measured on its bound clip, the first: a clip of one pose has no held-out frame, so its
    one frame is compared (the fit's test frames are the bend's, which the USD side does not carry)."""
    src = _tube(tmp_path / "pose_bend.glb", "pose")
    assert main(["reduce", str(src), "-o", str(tmp_path / "r.usda"), "-k", "1",
                 "--report", str(tmp_path / "r.json")]) == 0
    doc = json.loads((tmp_path / "r.json").read_text())
    assert doc["clip"] == "bend" and not doc["fallback_k_largest"]          # fitted on the clip that moves
    assert doc["world"]["position_rms_m"] >= 0 and "clips" not in doc["world"]   # the USD side's one clip

