"""Hostile USD inputs: each ends in one line and exit 2, never a traceback, and earlier outputs stay as they were.

Every case edits the hand-made character of tests/test_io_usd.py (text
``.usda``, edited through USD's own API or as text) in ``tmp_path`` and runs
``rigslim run`` on a pipeline that reads it, after a good run left outputs
there.
"""

from __future__ import annotations

import pytest
from support.bad_input import assert_one_line, assert_unchanged, run_cli, snapshot

from tests.framework.io.test_io_usd import make_character

PIPELINE = """\
inputs:
  usd:
    path: {model}
    fps: 24
poses:
  examples: "0:25:3"
  test: "1:25:3"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - write: out/model.usda
"""


@pytest.fixture
def project(tmp_path, capfd):
    make_character(tmp_path / "model.usda")
    (tmp_path / "pipeline.yaml").write_text(PIPELINE.format(model="model.usda"))
    code, lines = run_cli(["run", tmp_path / "pipeline.yaml"], capfd)
    assert code == 0, lines
    return tmp_path


def _edit(folder, fn):
    from pxr import Usd

    stage = Usd.Stage.Open(str(folder / "model.usda"))
    fn(stage)
    stage.GetRootLayer().Save()


def _fails(folder, capfd, *must):
    before = snapshot(folder / "out")
    code, lines = run_cli(["run", folder / "pipeline.yaml"], capfd)
    line = assert_one_line(code, lines, *must)
    assert_unchanged(folder / "out", before)
    return line


def _attr(path, name):
    def fn(stage):
        return stage.GetPrimAtPath(path).GetAttribute(name)
    return fn


STRIP = "/Hero/Geo/Strip"


def test_missing_joints_in_skel_joints(project, capfd):
    _edit(project, lambda s: _attr(STRIP, "skel:joints")(s).Set(["root/mid/tip", "root/gone", "root/mid"]))
    line = _fails(project, capfd, "model.usda", "skel:joints", "root/gone")
    assert "lacks" in line


def test_skeleton_without_joints(project, capfd):
    _edit(project, lambda s: _attr("/Hero/Rig", "joints")(s).Set([]))
    _fails(project, capfd, "model.usda", "/Hero/Rig")


def test_joints_listed_child_before_parent(project, capfd):
    _edit(project, lambda s: _attr("/Hero/Rig", "joints")(s).Set(["root/mid", "root", "root/mid/tip"]))
    _fails(project, capfd, "model.usda", "/Hero/Rig.joints", "parent")


def test_wrong_element_size(project, capfd):
    def fn(stage):
        from pxr import UsdSkel

        api = UsdSkel.BindingAPI(stage.GetPrimAtPath(STRIP))
        api.GetJointIndicesPrimvar().SetElementSize(4)
        api.GetJointWeightsPrimvar().SetElementSize(4)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "primvars:skel:jointIndices:elementSize", "elementSize 3 would fit")


def test_element_sizes_that_differ(project, capfd):
    def fn(stage):
        from pxr import UsdSkel

        UsdSkel.BindingAPI(stage.GetPrimAtPath(STRIP)).GetJointWeightsPrimvar().SetElementSize(2)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "jointWeights", "elementSize")


def test_nan_weights(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "primvars:skel:jointWeights")(stage)
        w = list(attr.Get())
        w[7] = float("nan")
        attr.Set(w)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "jointWeights", "NaN")


def test_joint_index_out_of_range(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "primvars:skel:jointIndices")(stage)
        ji = list(attr.Get())
        ji[4] = 9
        attr.Set(ji)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "jointIndices", "joint 9")


def test_too_few_weights(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "primvars:skel:jointWeights")(stage)
        attr.Set(list(attr.Get())[:-3])
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "jointWeights")


def test_bind_transforms_count(project, capfd):
    def fn(stage):
        attr = _attr("/Hero/Rig", "bindTransforms")(stage)
        attr.Set(list(attr.Get())[:2])
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "bindTransforms", "3 joints")


def test_singular_bind_transform(project, capfd):
    def fn(stage):
        from pxr import Gf

        attr = _attr("/Hero/Rig", "bindTransforms")(stage)
        m = list(attr.Get())
        m[1] = Gf.Matrix4d(0.0)
        attr.Set(m)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "bindTransforms[1]")


def test_nan_points(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "points")(stage)
        p = list(attr.Get())
        p[3] = (float("nan"), 0, 0)
        attr.Set(p)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "points", "NaN")


def test_face_index_out_of_range(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "faceVertexIndices")(stage)
        f = list(attr.Get())
        f[5] = 10_000
        attr.Set(f)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "faceVertexIndices")


def test_face_counts_that_do_not_add_up(project, capfd):
    def fn(stage):
        attr = _attr(STRIP, "faceVertexCounts")(stage)
        attr.Set(list(attr.Get())[:-1])
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "faceVertexCounts")


def test_mesh_outside_any_skel_root(project, capfd):
    text = (project / "model.usda").read_text().replace('def SkelRoot "Hero"', 'def Xform "Hero"')
    (project / "model.usda").write_text(text)
    _fails(project, capfd, "model.usda", "SkelRoot")


def test_mesh_below_an_untyped_prim(project, capfd):
    text = (project / "model.usda").read_text().replace('def Xform "Geo"', 'def "Geo"')
    (project / "model.usda").write_text(text)
    _fails(project, capfd, "model.usda", "/Hero/Geo", "Imageable")


def test_mesh_bound_to_nothing(project, capfd):
    def fn(stage):
        stage.GetPrimAtPath(STRIP).GetRelationship("skel:skeleton").ClearTargets(True)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "skel:skeleton")


def test_animation_that_does_not_exist(project, capfd):
    (project / "pipeline.yaml").write_text(PIPELINE.format(model="model.usda").replace(
        "    fps: 24\n", "    fps: 24\n    animation: Walk\n"))
    _fails(project, capfd, "model.usda", "animation", "Walk")


def test_animation_with_too_few_rotations(project, capfd):
    def fn(stage):
        attr = _attr("/Hero/Rig/Bend", "rotations")(stage)
        for t in attr.GetTimeSamples():
            attr.Set(list(attr.Get(t))[:1], t)
    _edit(project, fn)
    _fails(project, capfd, "model.usda", "animation")


def test_not_a_usd_file(project, capfd):
    (project / "model.usda").write_text("#usda 1.0\ndef Mesh {{{\n")
    _fails(project, capfd, "model.usda", "layer")


def test_binary_garbage_as_usdc(project, capfd):
    (project / "model.usdc").write_bytes(b"PXR-USDC" + bytes(range(256)) * 8)
    (project / "pipeline.yaml").write_text(PIPELINE.format(model="model.usdc"))
    _fails(project, capfd, "model.usdc")


def test_no_skinned_mesh(project, capfd):
    from pxr import Usd, UsdGeom

    stage = Usd.Stage.CreateNew(str(project / "plain.usda"))
    UsdGeom.Mesh.Define(stage, "/Plain").CreatePointsAttr([(0, 0, 0)])
    stage.GetRootLayer().Save()
    (project / "pipeline.yaml").write_text(PIPELINE.format(model="plain.usda"))
    _fails(project, capfd, "plain.usda", "skinned")


def test_writing_a_usd_over_its_input_is_refused(project, capfd):
    (project / "pipeline.yaml").write_text(PIPELINE.format(model="out/model.usda"))
    before = snapshot(project / "out")
    code, lines = run_cli(["run", project / "pipeline.yaml"], capfd)
    errors = [line for line in lines if line.startswith("rigslim: error: ")]   # after the progress of the steps
    assert_one_line(code, errors, "model.usda", "is the input")
    assert "Traceback" not in "\n".join(lines)
    assert_unchanged(project / "out", before)
