"""Hostile pipelines and inputs read by pipelines: one line and exit 2, outputs untouched.

Covers the YAML loader (aliases, nesting, duplicate keys, binary files),
parameter types, TGF skeletons, degenerate meshes for the Laplacian-based
solvers, libigl's own stderr, non-finite animations (strict metrics JSON)
and warnings printed before an error.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest
from support.bad_input import DATA, assert_one_line, assert_unchanged, run_cli, run_cli_subprocess, snapshot

CHEB = """\
inputs:
  mesh: {mesh}
  skeleton: {skeleton}
  animation: {animation}
poses:
  examples: "0:40:6"
  test: "1:40:6"
steps:
{steps}
"""
K_LARGEST = """\
  - generate: bone-heat
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms]
  - write: out/weights.npz
"""


@pytest.fixture
def project(tmp_path):
    """A folder with the Cheburashka inputs and old outputs (out/weights.npz, out/metrics.json)."""
    for name in ("cheburashka.off", "cheburashka.tgf", "cheburashka-anim.dmat"):
        shutil.copy(DATA / name, tmp_path / name)
    (tmp_path / "out").mkdir()
    (tmp_path / "out" / "weights.npz").write_bytes(b"old weights")
    (tmp_path / "out" / "metrics.json").write_text('{"old": true}\n')
    return tmp_path


def _pipeline(folder: Path, text: str | None = None, *, mesh="cheburashka.off", skeleton="cheburashka.tgf",
              animation="cheburashka-anim.dmat", steps=K_LARGEST, name="pipeline.yaml") -> Path:
    p = folder / name
    p.write_text(text if text is not None else CHEB.format(mesh=mesh, skeleton=skeleton, animation=animation,
                                                           steps=steps.rstrip("\n")))
    return p


def _bad(project: Path, capfd, pipeline: Path, *must, subprocess=False):
    before = snapshot(project / "out")
    args = ["run", pipeline, "--metrics", project / "out" / "metrics.json", "-q"]
    code, lines = run_cli_subprocess(args, timeout=120) if subprocess else run_cli(args, capfd)
    line = assert_one_line(code, lines, *must)
    assert_unchanged(project / "out", before)
    return line


# --------------------------------------------------------------------------- the YAML document


def test_alias_bomb(project, capfd):
    lines = ['a0: &a0 ["lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol", "lol"]']
    lines += [f"a{i}: &a{i} [" + ", ".join([f"*a{i - 1}"] * 9) + "]" for i in range(1, 10)]
    text = "\n".join(lines) + "\nsteps:\n  - select: k-largest\n    k: *a9\n"
    line = _bad(project, capfd, _pipeline(project, text), "pipeline.yaml", subprocess=True)
    assert "aliases" in line


def test_alias_bomb_inside_a_parameter_value(project, capfd):
    lines = ["x0: &x0 [1, 2, 3, 4, 5, 6, 7, 8]"]
    lines += [f"x{i}: &x{i} [*x{i - 1}, *x{i - 1}, *x{i - 1}, *x{i - 1}, *x{i - 1}, *x{i - 1}]" for i in range(1, 12)]
    text = "inputs:\n  mesh: cheburashka.off\nsteps:\n  - select: k-largest\n    k: 1\n"
    text = "\n".join(["defs:"] + ["  " + x for x in lines]) + "\n" + text
    _bad(project, capfd, _pipeline(project, text), "pipeline.yaml", subprocess=True)


def test_recursive_alias(project, capfd):
    text = "inputs: &a {mesh: cheburashka.off, again: *a}\nsteps: [{select: k-largest, k: 1}]\n"
    _bad(project, capfd, _pipeline(project, text), "pipeline.yaml")


def test_deep_nesting(project, capfd):
    text = "steps:\n  - select: k-largest\n    k: " + "[" * 10_000 + "]" * 10_000 + "\n"
    line = _bad(project, capfd, _pipeline(project, text), "pipeline.yaml")
    assert "nested" in line


def test_deep_block_nesting(project, capfd):
    text = "".join(" " * i + f"k{i}:\n" for i in range(2000)) + " " * 2000 + "x: 1\n"
    _bad(project, capfd, _pipeline(project, text), "pipeline.yaml")


def test_binary_file_as_pipeline(project, capfd):
    p = project / "pipeline.yaml"
    p.write_bytes((DATA / "cheburashka-anim.dmat").read_bytes()[:4096])
    assert "not UTF-8 text" in _bad(project, capfd, p, "pipeline.yaml", "path")


def test_png_as_pipeline(project, capfd):
    p = project / "pipeline.yaml"
    p.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(range(256)) * 4)
    assert "UTF-8" in _bad(project, capfd, p, "pipeline.yaml")


def test_nul_bytes_in_pipeline(project, capfd):
    p = project / "pipeline.yaml"
    p.write_bytes(b"steps:\n  - select: k-largest\x00\x00\n")
    _bad(project, capfd, p, "pipeline.yaml")


def test_duplicate_top_level_key(project, capfd):
    text = CHEB.format(mesh="cheburashka.off", skeleton="cheburashka.tgf", animation="cheburashka-anim.dmat",
                       steps=K_LARGEST.rstrip("\n")) + "steps:\n  - generate: bone-heat\n"
    line = _bad(project, capfd, _pipeline(project, text), "pipeline.yaml", "'steps'", "twice")
    assert "first on line 8" in line and "line 15" in line


def test_duplicate_parameter_key(project, capfd):
    steps = "  - generate: bone-heat\n  - select: k-largest\n    k: 2\n    k: 3\n  - solve: k-largest\n"
    _bad(project, capfd, _pipeline(project, steps=steps), "pipeline.yaml", "'k'", "twice")


def test_merge_keys_still_work(project, capfd):
    text = CHEB.format(
        mesh="cheburashka.off", skeleton="cheburashka.tgf", animation="cheburashka-anim.dmat",
        steps="  - generate: bone-heat\n  - select: k-largest\n    <<: {k: 2}\n  - solve: k-largest")
    code, lines = run_cli(["run", _pipeline(project, text), "-q"], capfd)
    assert code == 0, lines


# --------------------------------------------------------------------------- parameters


def test_bool_is_not_an_int(project, capfd):
    steps = "  - generate: bone-heat\n  - select: k-largest\n    k: true\n  - solve: k-largest\n"
    line = _bad(project, capfd, _pipeline(project, steps=steps), "pipeline.yaml", "steps[2].k")
    assert "yes/no" in line


def test_bool_still_fine_for_bool_parameters(project, capfd):
    steps = "  - generate: bone-heat\n    visibility: false\n  - select: k-largest\n    k: 2\n  - solve: k-largest\n"
    code, lines = run_cli(["run", _pipeline(project, steps=steps), "-q"], capfd)
    assert code == 0, lines


def test_metric_parameters_not_a_mapping(project, capfd):
    steps = "  - generate: bone-heat\n  - evaluate: {position-rms: [1, 2]}\n"
    _bad(project, capfd, _pipeline(project, steps=steps), "pipeline.yaml", "steps[2].evaluate")


def test_huge_parameter_value_is_clipped(project, capfd):
    steps = "  - generate: bone-heat\n  - select: k-largest\n    k: '" + "9" * 4_000_000 + "'\n"
    _bad(project, capfd, _pipeline(project, steps=steps), "pipeline.yaml", "steps[2].k")


# --------------------------------------------------------------------------- skeletons


def _tgf(project: Path, joints: int, bones) -> str:
    lines = [f"{i + 1} {i * 0.1} 0 0" for i in range(joints)] + ["#"] + [f"{a} {b}" for a, b in bones] + ["#"]
    (project / "bad.tgf").write_text("\n".join(lines) + "\n")
    return "bad.tgf"


@pytest.mark.parametrize("bones, what", [([(1, 2), (2, 3), (3, 1)], "cycle"), ([(1, 2), (2, 2)], "itself"),
                                         ([(1, 3), (2, 3)], "two parents")])
def test_tgf_not_a_forest(project, capfd, bones, what):
    skeleton = _tgf(project, 3, bones)
    line = _bad(project, capfd, _pipeline(project, skeleton=skeleton), "bad.tgf", subprocess=True)
    assert what in line


# --------------------------------------------------------------------------- degenerate meshes


def _off(project: Path, V, F, name="bad.off") -> str:
    lines = ["OFF", f"{len(V)} {len(F)} 0"] + [" ".join(repr(float(x)) for x in v) for v in V]
    lines += ["3 " + " ".join(str(int(i)) for i in f) for f in F]
    (project / name).write_text("\n".join(lines) + "\n")
    return name


def _grid(n=6):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.c_[x.ravel(), y.ravel(), 0.1 * np.sin(3 * x.ravel())]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            F += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return V, np.array(F)


def _poisson_project(project: Path, V, F, k: int = 2) -> Path:
    """A two-bone skeleton along x, weights generated (bone heat), solved with Poisson."""
    from rigslim.io import write_dmat
    from rigslim.io.animation import transforms_to_stacked

    mesh = _off(project, V, F)
    (project / "two.tgf").write_text("1 0 0 0\n2 0.35 0 0\n3 0.7 0 0\n4 1 0 0\n#\n1 2\n2 3\n3 4\n#\n")
    T = np.zeros((6, 3, 3, 4))
    T[:, :, :, :3] = np.eye(3)
    for f in range(6):  # the last two bones bend about z around joint 2
        c, s = np.cos(0.2 * f), np.sin(0.2 * f)
        for b in (1, 2):
            T[f, b, :, :3] = [[c, -s, 0], [s, c, 0], [0, 0, 1]]
            T[f, b, :, 3] = np.array([0.35, 0, 0]) - T[f, b, :, :3] @ [0.35, 0, 0]
    write_dmat(project / "two.dmat", transforms_to_stacked(T))
    steps = f"  - generate: bone-heat\n  - select: k-largest\n    k: {k}\n  - solve: poisson\n"
    return _pipeline(project, "inputs:\n  mesh: " + mesh + "\n  skeleton: two.tgf\n  animation: two.dmat\n"
                     "poses:\n  examples: \"0:6:2\"\n  test: \"1:6:2\"\nsteps:\n" + steps)


@pytest.mark.parametrize("k", [1, 2])
def test_poisson_unreferenced_vertex_is_handled(project, capfd, k):
    V, F = _grid()
    V = np.vstack([V, [[5.0, 5.0, 5.0]]])  # referenced by no face
    code, lines = run_cli(["run", _poisson_project(project, V, F, k), "-q"], capfd)
    assert code == 0, lines


@pytest.mark.parametrize("case", ["zero-area", "collinear", "coincident", "huge"])
def test_poisson_degenerate_mesh(project, capfd, case):
    V, F = _grid()
    if case == "zero-area":
        F = F.copy()
        F[:, 2] = F[:, 0]  # every triangle repeats a corner
    elif case == "collinear":
        V[:, 1] = V[:, 2] = 0.0
    elif case == "coincident":
        V[:] = 0.25
    else:
        V = V * 1e200
    line = _bad(project, capfd, _poisson_project(project, V, F), "bad.off")
    assert "face" in line or "vertices" in line or "coordinates" in line


def test_poisson_some_zero_area_faces_are_handled(project, capfd):
    V, F = _grid()
    F = np.vstack([F, [[0, 0, 1], [3, 3, 3]]])  # two degenerate triangles among good ones
    code, lines = run_cli(["run", _poisson_project(project, V, F), "-q"], capfd)
    assert code == 0, lines


# --------------------------------------------------------------------------- native messages, numbers


def test_libigl_stderr_not_glued_to_the_line(project, capfd):
    (project / "broken.obj").write_text("v 0 0 0\nv 1 0 0\nf 1 2 7 9 x\nthis is not obj\n")
    line = _bad(project, capfd, _pipeline(project, mesh="broken.obj"), "broken.obj", subprocess=True)
    assert line.count("rigslim: error:") == 1


def test_animation_of_huge_values_gives_strict_json_or_an_error(project, capfd):
    from rigslim.io import read_dmat, write_dmat

    D = read_dmat(project / "cheburashka-anim.dmat")
    D[:, 7] = 1e300
    write_dmat(project / "huge.dmat", D)
    out = project / "out" / "metrics.json"
    code, lines = run_cli(["run", _pipeline(project, animation="huge.dmat"), "--metrics", out, "-q"], capfd)
    assert "Traceback" not in "\n".join(lines)
    if code == 0:
        doc = json.loads(out.read_text(), parse_constant=lambda c: pytest.fail(f"{c} in the metrics JSON"))
        assert doc["notes"], "non-finite values must be noted"
    else:
        assert_one_line(code, lines, "huge.dmat")


def test_no_runtime_warning_before_an_error(project, capfd):
    V, F = _grid()
    V = V * 1e200
    code, lines = run_cli_subprocess(["run", _poisson_project(project, V, F), "-q"], cwd=project)
    assert_one_line(code, lines, "bad.off")


def test_warnings_are_dropped_when_an_error_follows(project, capfd, monkeypatch):
    import warnings

    import rigslim.runtime.run

    real = rigslim.runtime.run.load_pipeline

    def noisy(*args, **kwargs):
        warnings.warn("overflow encountered in square", RuntimeWarning, stacklevel=2)
        return real(*args, **kwargs)

    monkeypatch.setattr(rigslim.runtime.run, "load_pipeline", noisy)
    steps = "  - generate: bone-heat\n  - select: k-largest\n    k: true\n"
    _bad(project, capfd, _pipeline(project, steps=steps), "pipeline.yaml", "steps[2].k")


@pytest.mark.parametrize("name, text", [
    ("one-corner.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\nf 1"),  # libigl 2.6 corrupts its heap on this
    ("two-corners.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2\nf 1 2 3\n"),  # libigl would drop it silently
    ("one-corner.off", "OFF\n3 2 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n1 0\n"),
])
def test_faces_with_fewer_than_three_corners(project, capfd, name, text):
    (project / name).write_text(text)
    line = _bad(project, capfd, _pipeline(project, mesh=name), name, "line", subprocess=True)
    assert "corner" in line


def test_libigl_stdout_diagnosis_goes_into_the_line(project, capfd):
    (project / "short.off").write_text("OFF\n4 2 0\n0 0 0\n1 0 0\n0 1 0\n1 1 0\n3 0 1 2\n")  # a face missing
    code, lines = run_cli_subprocess(["run", _pipeline(project, mesh="short.off"), "-q"], cwd=project)
    assert_one_line(code, lines, "short.off", "bad line")


def test_nul_byte_in_a_face_line(project, capfd):
    # libigl reads the last face as 'f 2' (one corner) and aborts
    (project / "nul.obj").write_bytes(b"v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2\x00 4 3\n")
    line = _bad(project, capfd, _pipeline(project, mesh="nul.obj"), "nul.obj", "line 6", subprocess=True)
    assert "NUL" in line


@pytest.mark.parametrize("text, field", [("1: x\nsteps:\n  - select: k-largest\n", "top level"),
                                         ("!!binary AAAA: true\nsteps:\n  - select: k-largest\n", "top level"),
                                         ("steps:\n  - 1: 2\n    select: k-largest\n", "steps.0.1")])
def test_keys_that_are_not_names(project, capfd, text, field):
    _bad(project, capfd, _pipeline(project, text), "pipeline.yaml", field)


@pytest.mark.parametrize("body", [
    b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1\n3 0 1 2\n",
    b"plx\nformat ascii 1.0\n",
    b"ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n"
    b"property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" + bytes(40),
])
def test_malformed_ply(project, capfd, body):
    """libigl 2.6 frees memory twice (abort) on each of these; plyfile reads PLY instead."""
    (project / "bad.ply").write_bytes(body)
    _bad(project, capfd, _pipeline(project, mesh="bad.ply"), "bad.ply", subprocess=True)


def test_ply_reads_like_libigl(tmp_path):
    import igl

    from rigslim.io.meshfile import read_mesh

    V, F = igl.read_triangle_mesh(str(DATA / "armadillo-cage.obj"))
    for binary in (False, True):
        path = tmp_path / f"cage{int(binary)}.ply"
        igl.write_triangle_mesh(str(path), V, F, igl.FileEncoding.Binary if binary else igl.FileEncoding.Ascii)
        mesh = read_mesh(path)
        assert np.allclose(mesh.V, V) and (mesh.F == F).all()


def test_medit_tetrahedron_index_out_of_range(project, capfd):
    (project / "bad.mesh").write_text("MeshVersionFormatted 1\nDimension 3\nVertices\n4\n0 0 0 0\n1 0 0 0\n0 1 0 0\n"
                                      "0 0 1 0\nTetrahedra\n1\n1 2 3 2082712575 0\nEnd\n")
    _bad(project, capfd, _pipeline(project, mesh="bad.mesh"), "bad.mesh", "Tetrahedra")


# --------------------------------------------------------------------------- poses: (a union of forms)

FORMS = "{clip: NAME, frames: SPEC} or {clips: all or [NAMES], count: N}"


@pytest.mark.parametrize(("poses", "field", "words"), [
    ("{examples: 1.5, test: 1}", "poses.examples", ["1.5 is none of the accepted forms", FORMS]),
    ("{examples: [1.5], test: 1}", "poses.examples", ["[1.5] is none of the accepted forms", FORMS]),
    ("{examples: null, test: 1}", "poses.examples", ["None is none of the accepted forms", FORMS]),
    ("{examples: true, test: 1}", "poses.examples", ["true/false is not a frame number", FORMS]),
    ("{examples: 5}", "poses.test", ["'test' is missing", FORMS]),
    ("5", "poses", ["poses is 5, not a mapping of 'examples' and 'test'"]),
    ("{examples: 1, test: 2, tset: 3}", "poses", ["unknown key 'tset'", "did you mean 'test'"]),
    ("{examples: {clip: 0, frames: {x: 1}}, test: 1}", "poses.examples.frames",
     ["{'x': 1} is none of the accepted forms", "a frame spec ('0:60:5'"]),
    ("{examples: {clip: [1]}, test: 1}", "poses.examples.clip", ["[1] is none", "a clip name or index"]),
    ("{examples: {clips: some}, test: {clips: all}}", "poses.examples.clips",
     ["'some' is none", "all or a list of clip names"]),
    ("{examples: {clips: all, count: 0}, test: {clips: all}}", "poses.examples.count",
     ["greater than or equal to 1 (got 0)"]),
    ("{examples: {clip: 0, frames: 1, fps: 3}, test: 1}", "poses.examples", ["unknown key 'fps'"]),
])
def test_poses_union_errors_name_the_users_field(project, capfd, poses, field, words):
    """A malformed poses: side failed every branch of the union and the line named the first branch
    (poses.examples.str: input should be a valid string); it names the field written and the accepted forms."""
    text = CHEB.format(mesh="cheburashka.off", skeleton="cheburashka.tgf", animation="cheburashka-anim.dmat",
                       steps=K_LARGEST.rstrip("\n"))
    text = text.replace('poses:\n  examples: "0:40:6"\n  test: "1:40:6"\n', f"poses: {poses}\n")
    line = _bad(project, capfd, _pipeline(project, text), "pipeline.yaml", f"{field}: ", *words)
    for branch in (".str", ".int", "ClipFrames", "list[", "literal[", "PoseSpec", "Field required"):
        assert branch not in line, line
