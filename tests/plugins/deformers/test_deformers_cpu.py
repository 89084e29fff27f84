"""The cpu deformer (numba, positions and normals fused) against the numpy reference.

Positions within 1e-5 of the bounding-box diagonal and normals within 1e-4 rad
(float32 arithmetic; the approximate-affine fit in float64), for skeletons
and cages, fixed (int32/float32) and compact (uint16/float16) layouts, k that
does not divide the SIMD width, and vertex counts that are not a multiple of
the kernel's block size.
"""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.device.opencl import OpenCLUnavailable
from rigslim.errors import StepError
from rigslim.model.handles import Handles, cage_transforms
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.largest_entries import k_largest
from rigslim.plugins.deformers.cpu_deformer import CPUDeformer
from rigslim.plugins.deformers.cpu_kernels import BLOCK, LANES, SUB, half_tables
from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
from rigslim.plugins.solvers.renormalised import renormalised_weights

POSITION_TOL = 1e-5      # fraction of the bounding-box diagonal
NORMAL_TOL = 1e-4        # radians


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


def check_against_numpy(mesh, weights, handles, poses, layout):
    bound = CPUDeformer().bind(mesh, weights, CPUDeformer.Params(layout=layout), handles=handles)
    ref = NumpyDeformer().bind(mesh, bound.effective, NumpyDeformer.Params(), handles=handles)
    diag = mesh.bbox_diagonal
    worst_p, worst_n = 0.0, 0.0
    for T in poses:
        P, N = bound.deform(T, normals=True)
        P0, N0 = ref.deform(T, normals=True)
        assert P.shape == (mesh.n_vertices, 3) and N.shape == (mesh.n_vertices, 3) and P.dtype == np.float64
        worst_p = max(worst_p, np.linalg.norm(P - P0, axis=1).max() / diag)
        worst_n = max(worst_n, angles(N, N0).max())
        np.testing.assert_array_equal(bound(T), P)                    # positions-only kernel agrees exactly
    assert worst_p < POSITION_TOL, f"{layout}: position error {worst_p:.2e} of the diagonal"
    assert worst_n < NORMAL_TOL, f"{layout}: normal error {worst_n:.2e} rad"
    assert bound.last_seconds > 0
    return bound


def test_elephant_is_not_a_multiple_of_the_block(elephant):
    assert elephant.mesh.n_vertices % BLOCK != 0 and elephant.mesh.n_vertices > 2 * BLOCK


@pytest.mark.parametrize("k,layout", [(None, "fixed"), (3, "fixed"), (4, "compact"), (5, "compact"), (7, "fixed"),
                                      (8, "fixed"), (8, "compact")])
def test_skeleton_matches_numpy(elephant, skeleton, k, layout):
    mesh, handles, poses = skeleton
    weights = elephant.weights if k is None else reduce_to(elephant.weights, k)
    bound = check_against_numpy(mesh, weights, handles, poses, layout)
    assert bound.layout == layout and bound.normals_mode == "blended-matrix"


@pytest.mark.parametrize("k,layout", [(None, "auto"), (3, "fixed"), (4, "compact"), (5, "fixed")])
def test_cage_matches_numpy(cage, k, layout):
    mesh, handles, W, poses = cage
    weights = W if k is None else reduce_to(W, k)
    bound = check_against_numpy(mesh, weights, handles, poses, layout)
    assert bound.normals_mode == "approximate-affine"


def test_small_mesh_below_one_block_and_random_transforms(rng):
    """Fewer vertices than one block, 13 handles, k = 5, general (non-rigid) transforms and a reflection."""
    random_mesh_against_numpy(rng, 37)


@pytest.mark.parametrize("m", [SUB - 3, 3 * SUB + 5, BLOCK + 2 * SUB + LANES + 1])
def test_vector_normal_pass_partial_sub_blocks(rng, m):
    """The skeleton normal pass runs on sub-blocks of SUB vertices, LANES at a time: partial last sub-blocks."""
    assert m % SUB and m % LANES
    random_mesh_against_numpy(rng, m)


def random_mesh_against_numpy(rng, m):
    n, k = 13, 5
    V = rng.standard_normal((m, 3))
    F = np.array([[i, i + 1, i + 2] for i in range(m - 2)])
    idx = np.stack([rng.choice(n, k, replace=False) for _ in range(m)]).astype(np.int32)
    val = rng.uniform(0.1, 1.0, (m, k))
    weights = ReducedWeights(idx, val / val.sum(axis=1, keepdims=True), n)
    T = np.concatenate([np.eye(3)[None, None].repeat(n, 1).repeat(2, 0) + 0.2 * rng.standard_normal((2, n, 3, 3)),
                        rng.standard_normal((2, n, 3, 1))], axis=3)
    T[0, :, 0, :3] *= -1                                # det < 0: normals keep their orientation
    mesh = Mesh(V, F)
    check_against_numpy(mesh, weights, None, T, "fixed")  # two frames: the second reuses the normal scratch


def test_half_tables_decode_every_finite_float16():
    bits = np.arange(65536, dtype=np.uint16)
    half = bits.view(np.float16)
    finite = np.isfinite(half)
    offset, scale = half_tables()
    top = bits.astype(np.int64) >> 10
    decoded = ((bits & 1023).astype(np.float32) + offset[top]) * scale[top]
    np.testing.assert_array_equal(decoded[finite], half[finite].astype(np.float32))


def test_compact_layout_error_bound(elephant, skeleton):
    """float16 weights (relative rounding <= 2^-11 each): |dv| <= 2^-11 sum_l |w_l| |T_l [v;1]| per vertex."""
    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 4)
    bound = CPUDeformer().bind(mesh, reduced, CPUDeformer.Params(layout="compact", normals="none"))
    ref = NumpyDeformer().bind(mesh, reduced, NumpyDeformer.Params(normals="none"))
    worst = 0.0
    for T in poses:
        exact = ref(T)
        B = np.einsum("vkij,vj->vki", T[reduced.indices][..., :3], mesh.V) + T[reduced.indices][..., 3]
        spread = np.abs(reduced.values)[:, :, None] * np.abs(B)
        bound_v = 2.0 ** -11 * spread.sum(axis=1).max(axis=1) * np.sqrt(3) + 1e-5 * mesh.bbox_diagonal
        err = np.linalg.norm(bound(T) - exact, axis=1)
        assert (err <= bound_v).all()
        worst = max(worst, err.max() / mesh.bbox_diagonal)
    print(f"\ncpu compact layout vs float64 weights: max position error {worst:.2e} of the diagonal")
    assert worst < 1e-3


def test_outputs_are_preallocated_and_reused(elephant, skeleton):
    mesh, handles, poses = skeleton
    bound = CPUDeformer().bind(mesh, reduce_to(elephant.weights, 4), CPUDeformer.Params(), handles=handles)
    P, N = bound.positions, bound.normals
    bound.launch(poses[0], normals=True)
    first = P.copy()
    bound.launch(poses[1], normals=False)
    assert bound.positions is P and bound.normals is N
    assert np.abs(first - P).max() > 1e-3
    bound.launch(poses[0], normals=True)
    np.testing.assert_array_equal(first, P)
    assert P.dtype == np.float32 and N.dtype == np.float32


def test_layout_and_normal_errors(elephant, skeleton):
    mesh, handles, poses = skeleton
    with pytest.raises(StepError, match="layout"):
        CPUDeformer().bind(mesh, elephant.weights, CPUDeformer.Params.model_construct(layout="csr", engine="numba",
                                                                                   normals="auto"))
    bound = CPUDeformer().bind(mesh, reduce_to(elephant.weights, 4), CPUDeformer.Params(normals="none"))
    with pytest.raises(StepError, match="without normals"):
        bound.deform(poses[0], normals=True)


def test_engine_numba_by_default_and_opencl_on_the_cpu_device(elephant, skeleton):
    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 4)
    numba = CPUDeformer().bind(mesh, reduced, CPUDeformer.Params(), handles=handles)
    assert numba.engine == "numba" and numba.backend == "cpu"
    try:
        bound = CPUDeformer().bind(mesh, reduced, CPUDeformer.Params(engine="opencl"), handles=handles)
    except OpenCLUnavailable as e:
        pytest.skip(f"no CPU OpenCL device: {e}")
    import pyopencl as cl

    assert bound.engine == "opencl" and not bound.runtime.device.type & cl.device_type.GPU
    P, N = bound.deform(poses[0], normals=True)
    P0, N0 = numba.deform(poses[0], normals=True)
    assert np.linalg.norm(P - P0, axis=1).max() < POSITION_TOL * mesh.bbox_diagonal
    assert angles(N, N0).max() < NORMAL_TOL
    bound.close()


def test_normal_estimators_on_the_cpu_backend(elephant, skeleton, cage):
    from rigslim.plugins.normals.approximate_affine import ApproximateAffineNormals
    from rigslim.plugins.normals.blended_matrix import BlendedMatrixNormals

    mesh, handles, poses = skeleton
    reduced = reduce_to(elephant.weights, 8)
    for est, (est_mesh, est_handles, weights, est_poses) in ((BlendedMatrixNormals(), (mesh, handles, reduced, poses)),
                                                 (ApproximateAffineNormals(), cage)):
        for T in est_poses:
            ref = est.estimate(est_mesh, weights, est_handles, T, None, est.Params())
            dev = est.estimate(est_mesh, weights, est_handles, T, None, est.Params(backend="cpu"))
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


def test_yaml_deform_and_normals_steps_use_cpu(write_pipeline, tmp_path, capsys):
    from rigslim.commands.cli import main

    results = {}
    for label, extra in (("numpy", "  - normals: blended-matrix"),
                         ("cpu", "  - deform: cpu\n    layout: compact\n"
                                 "  - normals: blended-matrix\n    backend: cpu")):
        path = write_pipeline(PIPELINE.format(extra=extra), name=f"{label}.yaml")
        out = tmp_path / f"{label}.json"
        assert main(["run", "-q", str(path), "--metrics", str(out)]) == 0
        doc = json.loads(out.read_text())
        results[label] = doc["evaluations"][0]["metrics"]
        plugins = [s["plugin"] for s in doc["steps"]]
        assert ("cpu" in plugins) == (label == "cpu")
    capsys.readouterr()
    a, b = results["numpy"], results["cpu"]
    assert a["position_rms_pct"]["mean"] == pytest.approx(b["position_rms_pct"]["mean"], abs=5e-3)
    assert a["normal_rms_rad"]["mean"] == pytest.approx(b["normal_rms_rad"]["mean"], abs=1e-3)
