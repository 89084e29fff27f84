"""Hostile glTF inputs: each ends in one line and exit 2, never a traceback, a hang or a blow-up.

Every case mutates the bundled ``simple_skin.gltf`` (or a bundled ``.glb``)
in ``tmp_path`` and runs ``rigslim run`` on a pipeline that reads it, after
an earlier successful run left outputs there: those must stay byte-identical.
"""

from __future__ import annotations

import base64
import copy
import json
import os
import struct
from pathlib import Path

import numpy as np
import pytest
from support.bad_input import DATA, assert_one_line, assert_unchanged, run_cli, run_cli_subprocess, snapshot, write_json

SIMPLE = json.loads((DATA / "gltf" / "simple_skin.gltf").read_text())

PIPELINE = """\
inputs:
  gltf:
    path: {model}
{extra}  fps: {fps}
poses:
  examples: "0:12:2"
  test: "1:12:2"
steps:
  - select: k-largest
    k: 1
  - solve: k-largest
  - evaluate: [position-rms]
  - write: out/model.glb
"""


def _pipeline(folder: Path, model: str = "model.gltf", *, fps=2, extra: str = "") -> Path:
    p = folder / "pipeline.yaml"
    p.write_text(PIPELINE.format(model=model, fps=fps, extra=extra))
    return p


@pytest.fixture
def project(tmp_path, capfd):
    """A folder with a good model, a pipeline and the outputs of a good run (out/model.glb, out/metrics.json)."""
    write_json(tmp_path / "model.gltf", SIMPLE)
    pipeline = _pipeline(tmp_path)
    code, lines = run_cli(["run", pipeline, "--metrics", tmp_path / "out" / "metrics.json", "-q"], capfd)
    assert code == 0, lines
    return tmp_path


def _bad(project: Path, capfd, doc=None, *, model="model.gltf", fps=2, extra="", subprocess=False):
    """Write ``doc`` as the model, run the pipeline, check the one-line promise; returns the line."""
    if doc is not None:
        target = project / model
        if isinstance(doc, bytes):
            target.write_bytes(doc)
        else:
            write_json(target, doc)
    pipeline = _pipeline(project, model, fps=fps, extra=extra)
    before = snapshot(project / "out")
    args = ["run", pipeline, "--metrics", project / "out" / "metrics.json", "-q"]
    code, lines = run_cli_subprocess(args, timeout=120) if subprocess else run_cli(args, capfd)
    line = assert_one_line(code, lines, model)
    assert_unchanged(project / "out", before)
    return line


def _doc():
    return copy.deepcopy(SIMPLE)


# --------------------------------------------------------------------------- structure


def test_json_list(project, capfd):
    line = _bad(project, capfd, [1, 2, 3])
    assert "top level" in line


def test_json_scalar_members(project, capfd):
    doc = _doc()
    doc["nodes"] = "nodes"
    assert "nodes" in _bad(project, capfd, doc)


@pytest.mark.parametrize("key, value", [("materials", "materials"), ("textures", [1]), ("samplers", {"a": 1}),
                                        ("cameras", 3), ("extensionsUsed", [2]), ("extensions", [])])
def test_copied_members_of_the_wrong_type(project, capfd, key, value):
    """Top-level arrays no reader uses, but which every output copies, are type-checked too."""
    doc = _doc()
    doc[key] = value
    assert key in _bad(project, capfd, doc)


def test_node_cycle_refused_without_hanging(project, capfd):
    doc = _doc()
    doc["nodes"][2]["children"] = [1]  # 1 -> 2 -> 1
    line = _bad(project, capfd, doc, subprocess=True)
    assert "cycle" in line and "nodes[" in line


def test_node_own_child_refused_without_hanging(project, capfd):
    doc = _doc()
    doc["nodes"][2]["children"] = [2]
    line = _bad(project, capfd, doc, subprocess=True)
    assert "nodes[2].children" in line


def test_node_with_two_parents(project, capfd):
    doc = _doc()
    doc["nodes"][0]["children"] = [1, 2]
    assert "nodes[" in _bad(project, capfd, doc)


def test_child_index_out_of_range(project, capfd):
    doc = _doc()
    doc["nodes"][1]["children"] = [99]
    assert "nodes[1].children[0]" in _bad(project, capfd, doc)


def test_bad_base64(project, capfd):
    doc = _doc()
    doc["buffers"][0]["uri"] = "data:application/octet-stream;base64,@@@not base64@@@"
    assert "buffers[0].uri" in _bad(project, capfd, doc)


@pytest.mark.parametrize("count", [-1, "10", True, 2.5, None])
def test_accessor_count_wrong(project, capfd, count):
    doc = _doc()
    doc["accessors"][1]["count"] = count
    assert "accessors[1].count" in _bad(project, capfd, doc)


def test_accessor_huge_count_without_buffer_view(project, capfd):
    doc = _doc()
    acc = doc["accessors"][3]
    del acc["bufferView"], acc["byteOffset"]
    acc["count"] = 2 ** 31
    assert "accessors[3]" in _bad(project, capfd, doc, subprocess=True)


def test_accessor_past_its_view(project, capfd):
    doc = _doc()
    doc["accessors"][1]["count"] = 1000
    assert "accessors[1]" in _bad(project, capfd, doc)


def test_missing_byte_length(project, capfd):
    doc = _doc()
    del doc["buffers"][1]["byteLength"]
    assert "buffers[1].byteLength" in _bad(project, capfd, doc)


def test_view_past_its_buffer(project, capfd):
    doc = _doc()
    doc["bufferViews"][3]["byteLength"] = 10 ** 12
    assert "bufferViews[3]" in _bad(project, capfd, doc)


def test_interpolation_bogus(project, capfd):
    doc = _doc()
    doc["animations"][0]["samplers"][0]["interpolation"] = "BOGUS"
    assert "animations[0].samplers[0].interpolation" in _bad(project, capfd, doc)


def test_cubicspline_wrong_count(project, capfd):
    doc = _doc()
    doc["animations"][0]["samplers"][0]["interpolation"] = "CUBICSPLINE"  # needs 3 values per key
    assert "animations[0].samplers[0]" in _bad(project, capfd, doc)


def test_key_and_value_counts_differ(project, capfd):
    doc = _doc()
    doc["accessors"][6]["count"] = 11
    assert "animations[0].samplers[0]" in _bad(project, capfd, doc)


def _set_floats(doc, accessor: int, values):
    """Overwrite a float accessor's data (its data: URI buffer) with ``values``."""
    acc = doc["accessors"][accessor]
    view = doc["bufferViews"][acc["bufferView"]]
    buf = doc["buffers"][view["buffer"]]
    raw = bytearray(base64.b64decode(buf["uri"].split(",", 1)[1]))
    start = view.get("byteOffset", 0) + acc.get("byteOffset", 0)
    packed = np.asarray(values, "<f4").tobytes()
    raw[start:start + len(packed)] = packed
    buf["uri"] = "data:application/octet-stream;base64," + base64.b64encode(bytes(raw)).decode()


def test_nan_key_time(project, capfd):
    doc = _doc()
    times = np.arange(12, dtype=np.float32) * 0.5
    times[4] = np.nan
    _set_floats(doc, 5, times)
    assert "animations[0].samplers[0].input" in _bad(project, capfd, doc)


def test_non_monotonic_key_times(project, capfd):
    doc = _doc()
    times = np.arange(12, dtype=np.float32) * 0.5
    times[[3, 4]] = times[[4, 3]]
    _set_floats(doc, 5, times)
    line = _bad(project, capfd, doc)
    assert "animations[0].samplers[0].input" in line and "increasing" in line


def test_non_finite_key_value(project, capfd):
    doc = _doc()
    values = np.tile(np.float32([0, 0, 0, 1]), 12)
    values[9] = np.inf
    _set_floats(doc, 6, values)
    assert "animations[0].samplers[0].output" in _bad(project, capfd, doc)


def test_zero_quaternion_key_names_the_sampler(project, capfd):
    doc = _doc()
    values = np.tile(np.float32([0, 0, 0, 1]), 12)
    values[8:12] = 0
    _set_floats(doc, 6, values)
    line = _bad(project, capfd, doc)
    assert "animations[0].samplers[0].output" in line and "zero" in line


def test_zero_quaternion_node_rotation(project, capfd):
    doc = _doc()
    doc["nodes"][1]["rotation"] = [0, 0, 0, 0]
    line = _bad(project, capfd, doc)
    assert "nodes[1].rotation" in line and "animation" not in line.split("(fix:")[1]


def test_singular_inverse_bind_matrix(project, capfd):
    doc = _doc()
    _set_floats(doc, 4, np.zeros(32, np.float32))
    line = _bad(project, capfd, doc)
    assert "skins[0].inverseBindMatrices" in line and "singular" in line


def test_fps_huge(project, capfd):
    line = _bad(project, capfd, fps="1e9", subprocess=True)
    assert "fps" in line


def test_fps_not_finite(project, capfd):
    assert "fps" in _bad(project, capfd, fps=".inf")


def test_glb_truncated(project, capfd):
    data = (DATA / "gltf" / "huesitos.glb").read_bytes()
    _bad(project, capfd, data[:len(data) // 2], model="model.glb")


def test_glb_chunk_length_huge(project, capfd):
    data = bytearray((DATA / "gltf" / "huesitos.glb").read_bytes())
    struct.pack_into("<I", data, 12, 0xFFFFFFF0)  # JSON chunk length
    _bad(project, capfd, bytes(data), model="model.glb")


# --------------------------------------------------------------------------- URIs and the file system


def _external(doc, folder: Path, uri: str, index: int = 3):
    """Move buffer ``index`` into an external file named by ``uri`` (relative to ``folder``)."""
    raw = base64.b64decode(doc["buffers"][index]["uri"].split(",", 1)[1])
    target = folder / uri
    target.parent.mkdir(parents=True, exist_ok=True)
    target.write_bytes(raw)
    doc["buffers"][index]["uri"] = uri
    return doc


def test_external_buffer_inside_the_folder_is_read(project, capfd):
    doc = _external(_doc(), project, "bin/anim.bin")
    write_json(project / "model.gltf", doc)
    code, lines = run_cli(["run", _pipeline(project), "-q"], capfd)
    assert code == 0, lines


def test_buffer_outside_the_folder_refused(project, capfd):
    sub = project / "models"
    sub.mkdir()
    doc = _external(_doc(), sub, "../secret.bin")
    line = _bad(project, capfd, doc, model="models/model.gltf")
    assert "buffers[3].uri" in line and "allow_external_uris" in line


def test_buffer_outside_the_folder_allowed_explicitly(project, capfd):
    sub = project / "models"
    sub.mkdir()
    write_json(sub / "model.gltf", _external(_doc(), sub, "../secret.bin"))
    pipeline = _pipeline(project, "models/model.gltf", extra="    allow_external_uris: true\n")
    code, lines = run_cli(["run", pipeline, "-q"], capfd)
    assert code == 0, lines


def test_buffer_outside_the_folder_allowed_by_the_command_line(project, capfd, monkeypatch):
    import os

    sub = project / "models"
    sub.mkdir()
    write_json(sub / "model.gltf", _external(_doc(), sub, "../secret.bin"))
    pipeline = _pipeline(project, "models/model.gltf")
    monkeypatch.delenv("RIGSLIM_ALLOW_EXTERNAL_URIS", raising=False)
    code, lines = run_cli(["run", pipeline, "-q", "--allow-external-uris"], capfd)
    assert code == 0, lines
    assert "RIGSLIM_ALLOW_EXTERNAL_URIS" not in os.environ  # restored after the command
    code, lines = run_cli(["run", pipeline, "-q"], capfd)
    assert_one_line(code, lines, "buffers[3].uri", "--allow-external-uris")
    monkeypatch.setenv("RIGSLIM_ALLOW_EXTERNAL_URIS", "1")
    code, lines = run_cli(["run", pipeline, "-q"], capfd)
    assert code == 0, lines


def test_buffer_absolute_path_refused(project, capfd):
    doc = _doc()
    doc["buffers"][3]["uri"] = "/etc/passwd"
    assert "buffers[3].uri" in _bad(project, capfd, doc)


def test_buffer_file_uri_refused(project, capfd):
    doc = _doc()
    doc["buffers"][3]["uri"] = "file:///etc/passwd"
    assert "buffers[3].uri" in _bad(project, capfd, doc)


def test_buffer_symlink_leaving_the_folder_refused(project, capfd, tmp_path_factory):
    outside = tmp_path_factory.mktemp("outside")
    doc = _external(_doc(), outside, "anim.bin")
    os.symlink(outside / "anim.bin", project / "anim.bin")
    doc["buffers"][3]["uri"] = "anim.bin"
    assert "buffers[3].uri" in _bad(project, capfd, doc)


@pytest.mark.skipif(not Path("/dev/zero").exists(), reason="no /dev/zero")
def test_buffer_dev_zero_refused_without_reading(project, capfd):
    doc = _doc()
    doc["buffers"][3]["uri"] = "/dev/zero"
    extra = "    allow_external_uris: true\n"
    line = _bad(project, capfd, doc, extra=extra, subprocess=True)
    assert "buffers[3].uri" in line and "regular file" in line


def test_buffer_device_symlink_refused(project, capfd):
    doc = _doc()
    os.symlink("/dev/zero", project / "zero.bin")
    doc["buffers"][3]["uri"] = "zero.bin"
    line = _bad(project, capfd, doc, extra="    allow_external_uris: true\n", subprocess=True)
    assert "buffers[3].uri" in line


def test_buffer_file_shorter_than_byte_length(project, capfd):
    doc = _external(_doc(), project, "anim.bin")
    doc["buffers"][3]["byteLength"] = 10 ** 9
    line = _bad(project, capfd, doc)
    assert "buffers[3]" in line and "byteLength" in line


def test_non_affine_inverse_bind_matrix(project, capfd):
    doc = _doc()
    ibm = np.tile(np.eye(4, dtype=np.float32).T.ravel(), 2)
    ibm[15] = 0.0  # column-major: the last row of joint 0's matrix is (0, 0, 0, 0)
    _set_floats(doc, 4, ibm)
    line = _bad(project, capfd, doc)
    assert "skins[0].inverseBindMatrices[0]" in line and "affine" in line


def test_accessor_of_the_wrong_type(project, capfd):
    doc = _doc()
    doc["skins"][0]["inverseBindMatrices"] = 3  # a VEC4 accessor (the weights)
    assert "skins[0].inverseBindMatrices" in _bad(project, capfd, doc)
    doc = _doc()
    doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"] = 4  # a MAT4 accessor
    assert "attributes.POSITION" in _bad(project, capfd, doc)


@pytest.mark.parametrize("where", [("skins", 0, "inverseBindMatrices"), ("meshes", 0, "primitives", 0, "indices"),
                                   ("accessors", 1, "bufferView")])
def test_null_property(project, capfd, where):
    doc = _doc()
    target = doc
    for key in where[:-1]:
        target = target[key]
    target[where[-1]] = None
    line = _bad(project, capfd, doc)
    assert "is null" in line
