"""The OpenGL deformer (GLSL vertex shader + transform feedback, headless EGL) against numpy.

Runs on Mesa's llvmpipe here and in CI; skips only where no EGL display can
give an OpenGL 4.3 core context (the reason is printed).
"""

from __future__ import annotations

import json

import numpy as np
import pytest
from test_deformers_opencl import angles, cage_poses, idw_weights, jittered_box_cage, reduce_to

from rigslim.device.egl import EGLUnavailable, shared_context
from rigslim.errors import StepError
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.deformers.opengl_deformer import OpenGLDeformer

pytestmark = pytest.mark.opengl

POSITION_TOL = 1e-5      # fraction of the bounding-box diagonal
NORMAL_TOL = 1e-4        # radians


@pytest.fixture(scope="module", autouse=True)
def gl_context():
    try:
        return shared_context()
    except EGLUnavailable as e:
        pytest.skip(f"no EGL display can give an OpenGL 4.3 core context: {e}")


@pytest.fixture(scope="module")
def skeleton(elephant):
    return elephant.mesh, elephant.handles, elephant.poses.T[[40, 229]]


@pytest.fixture(scope="module")
def cage(elephant):
    handles = jittered_box_cage(elephant.mesh)
    W = idw_weights(elephant.mesh.V, handles.cage.V)
    return elephant.mesh, handles, W, cage_poses(handles, np.random.default_rng(3))


def check_against_numpy(mesh, weights, handles, poses, **params):
    bound = OpenGLDeformer().bind(mesh, weights, OpenGLDeformer.Params(**params), handles=handles)
    ref = NumpyDeformer().bind(mesh, bound.packed.effective, NumpyDeformer.Params(), handles=handles)
    diag = mesh.bbox_diagonal
    worst_p, worst_n = 0.0, 0.0
    for T in poses:
        P, N = bound.deform(T, normals=True)
        P0, N0 = ref.deform(T, normals=True)
        worst_p = max(worst_p, np.linalg.norm(P - P0, axis=1).max() / diag)
        worst_n = max(worst_n, angles(N, N0).max())
        np.testing.assert_allclose(bound(T), P)
    bound.close()
    return bound, worst_p, worst_n


@pytest.mark.parametrize("k,layout", [(None, "auto"), (4, "fixed"), (4, "compact"), (8, "fixed")])
def test_skeleton_matches_numpy(elephant, skeleton, k, layout):
    mesh, handles, poses = skeleton
    weights = elephant.weights if k is None else reduce_to(elephant.weights, k)
    bound, err_p, err_n = check_against_numpy(mesh, weights, handles, poses, layout=layout)
    assert err_p < POSITION_TOL and err_n < NORMAL_TOL, (err_p, err_n)
    assert bound.normals_mode == "blended-matrix" and bound.last_seconds > 0
    assert bound.k4 == -(-bound.packed.k // 4)


@pytest.mark.parametrize("k,layout", [(None, "auto"), (4, "fixed"), (4, "compact")])
def test_cage_matches_numpy(cage, k, layout):
    mesh, handles, W, poses = cage
    weights = W if k is None else reduce_to(W, k)
    bound, err_p, err_n = check_against_numpy(mesh, weights, handles, poses, layout=layout)
    assert err_p < POSITION_TOL and err_n < NORMAL_TOL, (err_p, err_n)
    assert bound.normals_mode == "approximate-affine" and bound.fit_double


def test_single_precision_fit_error_is_reported(cage):
    """float32 fit: the error grows with cond(P); measured, and bounded loosely."""
    mesh, handles, W, poses = cage
    _, err_p, err_n = check_against_numpy(mesh, reduce_to(W, 4), handles, poses, fit_precision="single")
    print(f"\nGLSL approximate-affine normals, float32 fit, k=4 IDW cage: max {err_n:.2e} rad from numpy")
    assert err_p < POSITION_TOL and err_n < 1e-3


def test_csr_layout_is_refused_and_context_is_reported(elephant, gl_context):
    with pytest.raises(StepError, match="vertex attributes"):
        OpenGLDeformer().bind(elephant.mesh, elephant.weights, OpenGLDeformer.Params(layout="csr"))
    assert gl_context.renderer and gl_context.version
    print(f"\nOpenGL deformer ran on: {gl_context.renderer}, {gl_context.version} ({gl_context.platform} display)")


def test_buffers_are_reused_and_close_releases(elephant, skeleton):
    mesh, handles, poses = skeleton
    bound = OpenGLDeformer().bind(mesh, reduce_to(elephant.weights, 4), OpenGLDeformer.Params(), handles=handles)
    names = (bound._vao, tuple(bound._buffers), bound._tbo, tuple(bound._feedback))
    a = bound(poses[0]).copy()
    b = bound(poses[1]).copy()
    bound.deform(poses[1], normals=True)
    assert (bound._vao, tuple(bound._buffers), bound._tbo, tuple(bound._feedback)) == names
    assert np.abs(a - b).max() > 1e-3 and np.array_equal(bound(poses[0]), a)
    bound.close()
    assert bound._vao is None


def test_normal_estimators_on_the_opengl_backend(elephant, skeleton, cage):
    from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
    from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals

    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 8)
    for est, (est_mesh, est_handles, weights, est_poses) in ((BlendedMatrixNormals(), (mesh, handles, reduced, poses)),
                                                 (ApproximateAffineNormals(), cage)):
        for T in est_poses:
            ref = est.estimate(est_mesh, weights, est_handles, T, None, est.Params())
            dev = est.estimate(est_mesh, weights, est_handles, T, None, est.Params(backend="opengl"))
            assert angles(dev, ref).max() < NORMAL_TOL


def test_yaml_deform_opengl(write_pipeline, tmp_path, capsys):
    from test_deformers_opencl import PIPELINE

    from rigslim.commands.cli import main

    results = {}
    for label, extra in (("numpy", ""), ("opengl", "  - deform: opengl\n  - normals: blended-matrix\n"
                                                   "    backend: opengl")):
        path = write_pipeline(PIPELINE.format(extra=extra), name=f"gl-{label}.yaml")
        out = tmp_path / f"gl-{label}.json"
        assert main(["run", "-q", str(path), "--metrics", str(out)]) == 0
        results[label] = json.loads(out.read_text())["evaluations"][0]["metrics"]
    capsys.readouterr()
    a, b = results["numpy"], results["opengl"]
    assert a["position_rms_pct"]["mean"] == pytest.approx(b["position_rms_pct"]["mean"], abs=1e-5)
    # recomputed (numpy run) against blended-matrix (opengl run) normals: same order, different estimators
    assert 0 < b["normal_rms_rad"]["mean"] < 3 * a["normal_rms_rad"]["mean"] + 0.05
