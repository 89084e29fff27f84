"""The OpenCL deformer (kernels/blend.cl) against the numpy reference.

Positions within 1e-5 of the bounding-box diagonal and normals within 1e-4 rad
(float32 on the device), for skeletons and cages, full sparse (CSR) and
fixed-k weights, the int32/float32 and the compact uint16/float16 layouts.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.device.opencl import OpenCLUnavailable, get_runtime
from rigslim.model.handles import Handles, cage_transforms
from rigslim.model.mesh import Mesh
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer
from rigslim.plugins.solvers.renormalised import renormalised_weights

pytestmark = pytest.mark.opencl

POSITION_TOL = 1e-5      # fraction of the bounding-box diagonal
NORMAL_TOL = 1e-4        # radians


@pytest.fixture(scope="module", autouse=True)
def runtime():
    try:
        return get_runtime()
    except OpenCLUnavailable as e:
        pytest.skip(f"no OpenCL device: {e}")


def reduce_to(W, k):
    return renormalised_weights(W, k_largest(W, k))


def jittered_box_cage(mesh: Mesh, jitter: float = 0.1) -> Handles:
    """A box around the mesh, subdivided once (26 vertices), vertices moved randomly by up to 10%."""
    import igl

    lo, hi = mesh.V.min(axis=0), mesh.V.max(axis=0)
    lo, hi = lo - 0.15 * (hi - lo), hi + 0.15 * (hi - lo)
    corners = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]], dtype=np.int64)
    V, F = igl.upsample(lo + corners * (hi - lo), F, 1)
    V = V + jitter * (hi - lo) * np.random.default_rng(0).uniform(-1, 1, V.shape)
    return Handles.from_cage(Mesh(V, F, source="jittered box cage"))


def idw_weights(V, C, power=2.0):
    """Normalised inverse-distance weights (a stand-in for mean value coordinates)."""
    D = np.linalg.norm(V[:, None, :] - C[None, :, :], axis=2)
    W = 1.0 / np.maximum(D, 1e-12) ** power
    return sp.csr_matrix(W / W.sum(axis=1, keepdims=True))


def cage_poses(handles, rng, count=2):
    """A smooth non-affine cage motion (twist + random affine), as (count, n, 3, 4) transforms."""
    C0 = handles.cage.V
    out = []
    for _ in range(count):
        A = np.eye(3) + 0.3 * rng.standard_normal((3, 3))
        x = (C0[:, 0] - C0[:, 0].mean()) / np.ptp(C0[:, 0])
        angle = 0.8 * x
        C = C0.copy()
        C[:, 1] = np.cos(angle) * C0[:, 1] - np.sin(angle) * C0[:, 2]
        C[:, 2] = np.sin(angle) * C0[:, 1] + np.cos(angle) * C0[:, 2]
        out.append(cage_transforms((C @ A.T + rng.standard_normal(3))[None])[0])
    return np.stack(out)


@pytest.fixture(scope="module")
def skeleton(elephant):
    return elephant.mesh, elephant.handles, elephant.poses.T[[40, 229]]


@pytest.fixture(scope="module")
def cage(elephant):
    handles = jittered_box_cage(elephant.mesh)
    W = idw_weights(elephant.mesh.V, handles.cage.V)
    return elephant.mesh, handles, W, cage_poses(handles, np.random.default_rng(3))


def angles(N, M):
    return np.arctan2(np.linalg.norm(np.cross(N, M), axis=1), np.einsum("ij,ij->i", N, M))


def check_against_numpy(mesh, weights, handles, poses, layout, normals=True):
    bound = OpenCLDeformer().bind(mesh, weights, OpenCLDeformer.Params(layout=layout), handles=handles)
    ref = NumpyDeformer().bind(mesh, bound.packed.effective, NumpyDeformer.Params(), handles=handles)
    diag = mesh.bbox_diagonal
    worst_p, worst_n = 0.0, 0.0
    for T in poses:
        P, N = bound.deform(T, normals=True)
        P0, N0 = ref.deform(T, normals=True)
        assert P.shape == (mesh.n_vertices, 3) and N.shape == (mesh.n_vertices, 3)
        worst_p = max(worst_p, np.linalg.norm(P - P0, axis=1).max() / diag)
        worst_n = max(worst_n, angles(N, N0).max())
        np.testing.assert_allclose(bound(T), P)                       # positions-only kernel agrees too
    assert worst_p < POSITION_TOL, f"{layout}: position error {worst_p:.2e} of the diagonal"
    assert worst_n < NORMAL_TOL, f"{layout}: normal error {worst_n:.2e} rad"
    assert bound.last_seconds > 0
    bound.close()
    return bound


@pytest.mark.parametrize("k,layout", [(None, "csr"), (None, "fixed"), (4, "fixed"), (4, "compact"), (4, "csr"),
                                      (8, "fixed")])
def test_skeleton_matches_numpy(elephant, skeleton, k, layout):
    mesh, handles, poses = skeleton
    weights = elephant.weights if k is None else reduce_to(elephant.weights, k)
    bound = check_against_numpy(mesh, weights, handles, poses, layout)
    assert bound.layout == layout and bound.normals_mode == "blended-matrix"


@pytest.mark.parametrize("k,layout", [(None, "auto"), (4, "fixed"), (4, "compact")])
def test_cage_matches_numpy(cage, k, layout):
    mesh, handles, W, poses = cage
    weights = W if k is None else reduce_to(W, k)
    bound = check_against_numpy(mesh, weights, handles, poses, layout)
    assert bound.normals_mode == "approximate-affine"


def test_compact_layout_error_against_float_weights(elephant, skeleton):
    """The compact layout's float16 weights cost accuracy; measured against the unrounded weights."""
    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 4)
    bound = OpenCLDeformer().bind(mesh, reduced, OpenCLDeformer.Params(layout="compact", normals="none"))
    ref = NumpyDeformer().bind(mesh, reduced, NumpyDeformer.Params(normals="none"))
    err = max(np.linalg.norm(bound(T) - ref(T), axis=1).max() for T in poses) / mesh.bbox_diagonal
    print(f"\ncompact layout (float16 weights) vs float64 weights: max position error {err:.2e} of the diagonal")
    assert err < 1e-3


def test_buffers_are_reused_across_frames(elephant, skeleton):
    mesh, handles, poses = skeleton
    bound = OpenCLDeformer().bind(mesh, reduce_to(elephant.weights, 4), OpenCLDeformer.Params(), handles=handles)
    ptrs = [b.int_ptr for b in (bound._rest, bound._indices, bound._weights, bound._handles, bound._positions)]
    first = bound(poses[0]).copy()
    second = bound(poses[1]).copy()
    bound.deform(poses[0], normals=True)
    again = bound(poses[0])
    assert [b.int_ptr for b in (bound._rest, bound._indices, bound._weights, bound._handles, bound._positions)] == ptrs
    assert len(bound._kernels) == 2
    assert np.abs(first - second).max() > 1e-3 and np.array_equal(first, again)


def test_work_group_size_and_vertex_count_not_a_multiple(elephant, skeleton):
    mesh, handles, poses = skeleton
    assert mesh.n_vertices % 64 != 0
    reduced = reduce_to(elephant.weights, 4)
    a = OpenCLDeformer().bind(mesh, reduced, OpenCLDeformer.Params(local_size=64, normals="none"))
    b = NumpyDeformer().bind(mesh, reduced, NumpyDeformer.Params(normals="none"))
    assert np.linalg.norm(a(poses[0]) - b(poses[0]), axis=1).max() < POSITION_TOL * mesh.bbox_diagonal


def test_normal_estimators_on_the_opencl_backend(elephant, skeleton, cage):
    from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
    from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals

    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 8)
    for est, (est_mesh, est_handles, weights, est_poses) in ((BlendedMatrixNormals(), (mesh, handles, reduced, poses)),
                                                 (ApproximateAffineNormals(), cage)):
        for T in est_poses:
            ref = est.estimate(est_mesh, weights, est_handles, T, None, est.Params())
            dev = est.estimate(est_mesh, weights, est_handles, T, None, est.Params(backend="opencl"))
            assert angles(dev, ref).max() < NORMAL_TOL


PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {{examples: "0:457:45", test: "5:457:91"}}
steps:
  - select: k-largest
    k: 4
  - solve: k-largest
{extra}
  - evaluate: [position-rms, normal-deviation]
"""


def test_yaml_deform_and_normals_steps_use_opencl(write_pipeline, tmp_path, capsys):
    from rigslim.commands.cli import main

    results = {}
    for label, extra in (("numpy", "  - normals: blended-matrix"),
                         ("opencl", "  - deform: opencl\n    layout: compact\n"
                                    "  - normals: blended-matrix\n    backend: opencl")):
        path = write_pipeline(PIPELINE.format(extra=extra), name=f"{label}.yaml")
        out = tmp_path / f"{label}.json"
        assert main(["run", "-q", str(path), "--metrics", str(out)]) == 0
        doc = json.loads(out.read_text())
        results[label] = doc["evaluations"][0]["metrics"]
        plugins = [s["plugin"] for s in doc["steps"]]
        assert ("opencl" in plugins) == (label == "opencl")
    capsys.readouterr()
    a, b = results["numpy"], results["opencl"]
    # compact float16 weights: positions differ by < 1e-3 % of the diagonal; normals by far less than their error
    assert a["position_rms_pct"]["mean"] == pytest.approx(b["position_rms_pct"]["mean"], abs=5e-3)
    assert a["normal_rms_rad"]["mean"] == pytest.approx(b["normal_rms_rad"]["mean"], abs=1e-3)


def test_single_precision_fit_error_is_reported(cage):
    """float32 approximate-affine fit: error grows like cond(P) * 6e-8 rad; measured and loosely bounded."""
    mesh, handles, W, poses = cage
    reduced = reduce_to(W, 4)
    bound = OpenCLDeformer().bind(mesh, reduced, OpenCLDeformer.Params(fit_precision="single"), handles=handles)
    ref = NumpyDeformer().bind(mesh, bound.packed.effective, NumpyDeformer.Params(), handles=handles)
    assert not bound.fit_double
    err = max(angles(bound.deform(T, normals=True)[1], ref.deform(T, normals=True)[1]).max() for T in poses)
    print(f"\nOpenCL approximate-affine normals, float32 fit, k=4 IDW cage: max {err:.2e} rad from numpy")
    assert err < 1e-3


def test_work_group_size_the_device_refuses_is_a_step_error(elephant, skeleton, runtime):
    """A local_size above what the device (and the kernel on it) runs was INVALID_WORK_GROUP_SIZE from the launch,
    a 'bug in rigslim'; it is refused at bind, naming the field and the range; the largest size still runs."""
    from rigslim.device.opencl import max_local_size
    from rigslim.errors import StepError

    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 4)
    limit = max_local_size(runtime)
    for size in (limit + 1, 2 * limit, 10**6):
        with pytest.raises(StepError, match=rf"local_size: .*outside 1\.\.{limit}.*give local_size from 1 to {limit}"):
            OpenCLDeformer().bind(mesh, reduced, OpenCLDeformer.Params(local_size=size, normals="none"))
    bound = OpenCLDeformer().bind(mesh, reduced, OpenCLDeformer.Params(local_size=limit, normals="none"))
    ref = NumpyDeformer().bind(mesh, reduced, NumpyDeformer.Params(normals="none"))
    assert np.linalg.norm(bound(poses[0]) - ref(poses[0]), axis=1).max() < POSITION_TOL * mesh.bbox_diagonal


def test_work_group_size_in_a_pipeline_is_one_line(write_pipeline, tmp_path, capfd, runtime):
    """Through `rigslim run`: beyond the device, zero and negative sizes are one line naming the field, exit 2."""
    from support.bad_input import assert_one_line, run_cli

    from rigslim.device.opencl import max_local_size

    limit = max_local_size(runtime)
    for size, words in ((limit * 2, f"give local_size from 1 to {limit}"),
                        (0, "steps[3].local_size: input should be greater than or equal to 1"),
                        (-4, "steps[3].local_size: input should be greater than or equal to 1")):
        path = write_pipeline(PIPELINE.format(extra=f"  - deform: opencl\n    local_size: {size}"))
        code, lines = run_cli(["run", "-q", path, "--metrics", tmp_path / "m.json"], capfd)
        assert_one_line(code, lines, "local_size", words)
        assert not (tmp_path / "m.json").exists()
