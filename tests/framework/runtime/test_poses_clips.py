"""Two-clip poses: fit on one clip, test on another; clear errors for a missing clip."""

import json
from pathlib import Path

import numpy as np
import pytest

from rigslim.commands.cli import main
from rigslim.errors import InputError, PipelineError
from rigslim.io import read_dmat
from rigslim.io.dmat import write_dmat
from rigslim.runtime.run import run_pipeline

HEAD = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
"""
STEPS = """
steps:
  - select: k-largest
    k: 4
  - solve: geometric
  - evaluate: [position-rms]
"""


@pytest.fixture
def clips(write_pipeline, data_dir):
    """The elephant animation cut in two clip files: rom.dmat (frames 0..199), run.dmat (200..456)."""
    D = read_dmat(data_dir / "elephant-anim.dmat")
    path = write_pipeline("steps: []\n", "unused.yaml")
    write_dmat(path.parent / "rom.dmat", D[:, :200])
    write_dmat(path.parent / "run.dmat", D[:, 200:])
    return D


def test_fit_on_one_clip_test_on_another(write_pipeline, clips):
    path = write_pipeline(HEAD + 'poses:\n  examples: {clip: rom.dmat, frames: "0:200:20"}\n'
                          "  test: {clip: run.dmat}\n" + STEPS)
    result = run_pipeline(path)
    asset, doc = result.asset, result.document
    assert len(asset.poses) == 200 + 257
    assert asset.split.examples == list(range(0, 200, 20))
    assert asset.split.test == list(range(200, 457))
    assert doc["frames"]["clips"] == {"examples": {"clip": "rom.dmat", "frames": list(range(0, 200, 20))},
                                      "test": {"clip": "run.dmat", "frames": list(range(257))}}
    # the stacked poses are the original animation's frames
    full = run_pipeline(write_pipeline(HEAD + 'poses: {examples: "0:200:20", test: "200:457"}\n' + STEPS, "one.yaml"))
    np.testing.assert_array_equal(asset.poses.T, full.asset.poses.T)
    a = doc["evaluations"][0]["metrics"]["position_rms_pct"]["per_frame"]
    b = full.document["evaluations"][0]["metrics"]["position_rms_pct"]["per_frame"]
    np.testing.assert_allclose(a, b, rtol=1e-12)


def test_input_animation_on_one_side_and_same_clip_overlap(write_pipeline, clips):
    path = write_pipeline(HEAD + 'poses:\n  examples: "0:457:45"\n  test: {clip: run.dmat, frames: "0:10"}\n' + STEPS)
    asset = run_pipeline(path).asset
    assert len(asset.poses) == 457 + 257 and asset.split.test == list(range(457, 467))
    path = write_pipeline(HEAD + 'poses:\n  examples: {clip: rom.dmat, frames: "0:10"}\n'
                          '  test: {clip: rom.dmat, frames: "5:15"}\n' + STEPS, "same.yaml")
    split = run_pipeline(path).asset.split
    assert split.examples == list(range(10)) and split.test == list(range(10, 15))
    assert split.dropped == list(range(5, 10))
    assert split.clips["test"]["frames"] == list(range(10, 15))


@pytest.mark.parametrize("poses,message,field", [
    ("  examples: {clip: ROM}\n  test: {clip: run.dmat}\n", "no clip 'ROM'", "poses.examples.clip"),
    ("  examples: {clip: rom.dmat}\n  test: {clip: missing.dmat}\n", "clip file 'missing.dmat' not found",
     "poses.test.clip"),
    ('  examples: {clip: rom.dmat, frames: "0:300"}\n  test: {clip: run.dmat}\n', "runs past the last frame",
     "poses.examples.frames"),
    ("  examples: {clip: rom.dmat, frame: 3}\n  test: {clip: run.dmat}\n", "", "poses.examples"),
])
def test_clip_errors(write_pipeline, clips, capsys, poses, message, field):
    path = write_pipeline(HEAD + "poses:\n" + poses + STEPS)
    with pytest.raises((InputError, PipelineError)) as err:
        run_pipeline(path)
    assert message in str(err.value) and field in str(err.value)
    code = main(["run", "-q", str(path)])
    _, out = capsys.readouterr()
    assert code == 2 and len(out.strip().splitlines()) == 1 and "Traceback" not in out


def test_gltf_clip_names_are_listed(tmp_path, data_dir, capsys):
    path = tmp_path / "g.yaml"
    path.write_text(f"inputs:\n  gltf: {data_dir / 'gltf' / 'huesitos.glb'}\n"
                    "poses:\n  examples: {clip: 0, frames: \"0:10\"}\n  test: {clip: Walk}\n" + STEPS)
    with pytest.raises(InputError, match=r"no clip 'Walk' \(the glTF input's animations are 'Armature\|Action'\)"):
        run_pipeline(path)


def test_gltf_clip_by_name(tmp_path, data_dir):
    path = tmp_path / "g.yaml"
    path.write_text(f"inputs:\n  gltf: {data_dir / 'gltf' / 'huesitos.glb'}\n"
                    "poses:\n  examples: {clip: 'Armature|Action', frames: \"0:20:2\"}\n"
                    "  test: {clip: 0, frames: \"1:20:2\"}\n" + STEPS.replace("k: 4", "k: 2"))
    result = run_pipeline(path)
    # the same animation by name and by index is one clip: its frames are not stacked twice
    assert result.document["frames"]["clips"]["examples"]["clip"] == "Armature|Action"
    assert result.asset.split.test == list(range(1, 20, 2))
    assert json.dumps(result.document["frames"])


def test_several_clips_examples_validation_and_test(write_pipeline, clips):
    """clips: [rom, run]: 20 examples shared out by length, validation and test frames between them."""
    path = write_pipeline(HEAD + "poses:\n  examples: {clips: [rom.dmat, run.dmat], count: 20}\n"
                          "  test: {clips: [rom.dmat, run.dmat]}\n" + STEPS.replace("k-largest", "best-fit"))
    result = run_pipeline(path)
    split, doc = result.asset.split, result.document
    assert len(result.asset.poses) == 457
    assert split.segments == [{"clip": "rom.dmat", "start": 0, "frames": 200},
                              {"clip": "run.dmat", "start": 200, "frames": 257}]
    # rom: 9 examples (200 / 9 -> step 23), run: 11 (257 / 11 -> step 24)
    assert split.examples == list(range(0, 200, 23)) + list(range(200, 457, 24))
    # the other frames of each clip, in time order, alternately validation and test
    rest = [[f for f in range(200) if f % 23], [200 + f for f in range(257) if f % 24]]
    assert split.validation == rest[0][0::2] + rest[1][0::2]
    assert split.test == rest[0][1::2] + rest[1][1::2]
    assert not set(split.examples) & set(split.validation) and not set(split.test) & set(split.validation)
    frames = doc["frames"]["clips"]
    assert [c["clip"] for c in frames["validation"]] == ["rom.dmat", "run.dmat"]
    solve = next(s for s in doc["steps"] if s["stage"] == "solve")["solver"]
    assert solve["guard"] == "k-largest" and solve["validation_frames"] == len(split.validation)
    assert len(solve["validation_clips"]) == 2
    for c in solve["validation_clips"]:
        assert c["rms_pct"] <= c["rms_pct_k_largest"]


def test_held_out_clip_and_clips_all_of_a_gltf(tmp_path):
    suite = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "suite"
    path = tmp_path / "g.yaml"
    path.write_text(f"inputs:\n  gltf: {suite / 'wuson.glb'}\n  fps: 30\n"
                    "poses:\n  examples: {clips: [Wuson_Walk], count: 12}\n  test: {clips: all}\n"
                    + STEPS.replace("k: 4", "k: 2"))
    split = run_pipeline(path).asset.split
    walk, run = split.segments
    assert (walk["clip"], run["clip"]) == ("Wuson_Walk", "Wuson_Run")
    assert all(walk["start"] <= f < walk["start"] + walk["frames"] for f in split.examples + split.validation)
    # the held-out clip is tested on every frame, and gives no validation frame
    tested = {c["clip"]: c["frames"] for c in split.clips["test"]}
    assert tested["Wuson_Run"] == list(range(run["frames"]))
    assert len(split.examples) == 11 and len(tested["Wuson_Walk"]) == (walk["frames"] - 11) // 2
    assert [c["clip"] for c in split.clips["validation"]] == ["Wuson_Walk"]


@pytest.mark.parametrize("poses,message,field", [
    ("  examples: {clip: rom.dmat, clips: all}\n  test: {clips: all}\n", "either 'clip'", "poses.examples"),
    ("  examples: {clips: [rom.dmat]}\n  test: {clip: run.dmat}\n", "one side of 'poses' gives 'clips'",
     "poses.test"),
    ("  examples: {clips: [rom.dmat], frames: '0:10'}\n  test: {clips: all}\n", "'frames' goes with 'clip'",
     "poses.examples"),
    ("  examples: {clips: [nope.dmat]}\n  test: {clips: all}\n", "clip file 'nope.dmat' not found",
     "poses.examples.clips"),
])
def test_several_clips_errors(write_pipeline, clips, capsys, poses, message, field):
    path = write_pipeline(HEAD + "poses:\n" + poses + STEPS)
    with pytest.raises((InputError, PipelineError)) as err:
        run_pipeline(path)
    assert message in str(err.value) and field in str(err.value)
    code = main(["run", "-q", str(path)])
    _, out = capsys.readouterr()
    assert code == 2 and len(out.strip().splitlines()) == 1 and "Traceback" not in out
