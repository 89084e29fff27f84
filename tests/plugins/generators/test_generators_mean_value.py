"""Mean value coordinates: partition of unity, linear precision, affine reproduction,
numpy vs OpenCL, and the special cases on or near cage faces, edges and vertices."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.plugins.generators.mean_value import mean_value_coordinates, mean_value_coordinates_opencl


def octahedron_cage():
    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]]) * [1.0, 1.3, 0.8]
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    return V, F


def star_cage():
    """A non-convex closed cage: an octahedron with one vertex pushed in (a dent)."""
    V, F = octahedron_cage()
    import igl

    # subdivide once (loop-free midpoint subdivision) and dent the top
    V2, F2 = igl.upsample(V, F, 1)
    V2 = V2 / np.linalg.norm(V2, axis=1, keepdims=True) * [1.0, 1.3, 0.8]
    top = np.argmax(V2[:, 2])
    V2[top, 2] *= 0.3
    return V2, F2


def inside_points(V, F, count, rng):
    import igl

    lo, hi = V.min(0), V.max(0)
    P = rng.uniform(lo, hi, (4 * count, 3))
    w = igl.winding_number(V, F, P)
    return P[w > 0.5][:count]


def face_points(V, F, rng, count):
    f = rng.integers(0, len(F), count)
    b = rng.dirichlet([1, 1, 1], count)
    X = np.einsum("pi,pij->pj", b, V[F[f]])
    N = np.cross(V[F[f, 1]] - V[F[f, 0]], V[F[f, 2]] - V[F[f, 0]])
    return X, N / np.linalg.norm(N, axis=1, keepdims=True)


@pytest.mark.parametrize("cage", [octahedron_cage, star_cage])
def test_partition_of_unity_and_linear_precision_inside(cage, rng):
    V, F = cage()
    P = inside_points(V, F, 500, rng)
    W = mean_value_coordinates(P, V, F)
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-10
    assert np.abs(W @ V - P).max() < 1e-10


def test_positive_inside_a_convex_cage(rng):
    V, F = octahedron_cage()
    W = mean_value_coordinates(inside_points(V, F, 300, rng), V, F)
    assert W.min() > 0


def test_affine_motion_of_the_cage_is_reproduced(rng):
    V, F = star_cage()
    P = inside_points(V, F, 300, rng)
    W = mean_value_coordinates(P, V, F)
    A = rng.normal(size=(3, 3)) + 3 * np.eye(3)
    t = rng.normal(size=3)
    assert np.abs(W @ (V @ A.T + t) - (P @ A.T + t)).max() < 1e-10


def test_outside_points_keep_linear_precision(rng):
    V, F = star_cage()
    Q = rng.uniform(-3, 3, (300, 3))
    W = mean_value_coordinates(Q, V, F)
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-10
    assert np.abs(W @ V - Q).max() < 1e-8


@pytest.mark.parametrize("dist", [0.0, 1e-13, 1e-11, 1e-9, 1e-7])
@pytest.mark.parametrize("side", [1.0, -1.0])
def test_stable_on_and_near_faces(dist, side, rng):
    V, F = star_cage()
    X, N = face_points(V, F, rng, 200)
    Y = X + side * dist * N
    W = mean_value_coordinates(Y, V, F)
    assert np.isfinite(W).all()
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-12
    # linear precision to round-off; points closer than ~1e-12 snap onto the face (error = their distance)
    bound = 1e-12 + (dist if dist < 1e-11 else 0.0)
    assert np.abs(W @ V - Y).max() < bound


def test_on_vertices_and_edges():
    V, F = octahedron_cage()
    assert np.abs(mean_value_coordinates(V, V, F) - np.eye(len(V))).max() < 1e-15
    E = 0.3 * V[F[:, 0]] + 0.7 * V[F[:, 1]]
    W = mean_value_coordinates(E, V, F)
    assert np.abs(W @ V - E).max() < 1e-14
    # only the two edge endpoints carry weight
    assert ((np.abs(W) > 1e-14).sum(axis=1) == 2).all()
    # and 1e-9 off an edge, outward, still reproduces the point
    Y = E * (1 + 1e-9)
    assert np.abs(mean_value_coordinates(Y, V, F) @ V - Y).max() < 1e-10


def test_smooth_across_a_face():
    V, F = star_cage()
    X, N = face_points(V, F, np.random.default_rng(3), 20)
    inside = mean_value_coordinates(X - 1e-6 * N, V, F)
    on = mean_value_coordinates(X, V, F)
    assert np.abs(inside - on).max() < 1e-4


@pytest.mark.opencl
def test_numpy_and_opencl_agree(rng):
    pytest.importorskip("pyopencl")
    from rigslim.device.opencl import OpenCLUnavailable

    V, F = star_cage()
    X, N = face_points(V, F, rng, 50)
    P = np.concatenate([inside_points(V, F, 300, rng), rng.uniform(-2, 2, (100, 3)), V,
                        0.5 * (V[F[:, 0]] + V[F[:, 1]]), X, X + 1e-9 * N])
    try:
        Wcl = mean_value_coordinates_opencl(P, V, F, device="cpu")
    except OpenCLUnavailable as e:
        pytest.skip(f"no OpenCL CPU device: {e}")
    Wnp = mean_value_coordinates(P, V, F)
    assert np.abs(Wcl - Wnp).max() < 1e-10


ELEPHANT_INPUTS = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:40"}
"""


def test_elephant_cage_pipeline_from_skeleton_motion(write_pipeline, tmp_path):
    """mesh + skeleton weights + animation -> automatic cage -> MVC -> reduce -> evaluate."""
    from rigslim.io import read_mesh
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline(ELEPHANT_INPUTS + """
steps:
  - generate: mean-value
    cage: auto
    cage_vertices: 60
    cage_resolution: 40
    save_cage: cage.obj
  - select: k-largest
    k: 8
  - solve: k-largest
  - evaluate: [position-rms, max-influences]
""")
    result = run_pipeline(path)
    asset = result.asset
    assert asset.handles.is_cage and asset.handles.n == asset.poses.n_handles == asset.weights.shape[1]
    report = result.document["steps"][1]["report"]
    assert report["cage"]["vertices_outside"] == 0 and report["cage"]["min_winding_number"] > 0.99
    assert report["cage_poses"]["poses"] == 457
    assert read_mesh(tmp_path / "cage.obj").n_vertices == asset.handles.n
    # frame 0 is the elephant's rest pose: the skinned cage is the rest cage and MVC reproduces the mesh
    assert np.allclose(asset.poses.T[0, :, :, 3], asset.handles.cage.V)
    from rigslim.numerics.blend import linear_blend

    # (the pipeline drops input weights below 1e-8 as round-off, hence not 1e-10)
    err = np.abs(linear_blend(asset.mesh.V, asset.weights, asset.poses.T[0]) - asset.mesh.V).max()
    assert err < 1e-8 * asset.mesh.bbox_diagonal
    m = result.document["evaluations"][0]["metrics"]
    assert m["max_influences"] == 8 and m["input_max_influences"] == asset.handles.n


@pytest.mark.opencl
def test_user_cage_file_and_opencl_backend(write_pipeline, tmp_path):
    pytest.importorskip("pyopencl")
    from rigslim.device.opencl import OpenCLUnavailable, get_runtime
    from rigslim.io import read_mesh
    from rigslim.plugins.generators.cage import build_cage
    from rigslim.runtime.run import run_pipeline

    try:
        get_runtime("cpu")
    except OpenCLUnavailable as e:
        pytest.skip(f"no OpenCL CPU device: {e}")
    import igl

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  cage: cage.obj
steps:
  - generate: mean-value
    backend: opencl
    device: cpu
""")
    mesh = read_mesh(path.parent / "data" / "elephant.obj")
    cage = build_cage(mesh, 40, resolution=32)
    igl.write_triangle_mesh(str(tmp_path / "cage.obj"), np.asarray(cage.V), np.asarray(cage.F))
    asset = run_pipeline(path).asset
    W = asset.weights.toarray()
    assert np.abs(W @ asset.handles.cage.V - mesh.V).max() < 1e-8 * mesh.bbox_diagonal


def test_mean_value_without_a_cage_is_a_step_error(write_pipeline):
    from rigslim.errors import StepError
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline(ELEPHANT_INPUTS + """
steps:
  - generate: mean-value
""")
    with pytest.raises(StepError, match="cage: auto"):
        run_pipeline(path)
