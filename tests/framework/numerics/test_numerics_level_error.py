"""The animated error of levels (framework/numerics/level_error.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.level_error import bounding_radius, level_errors
from rigslim.numerics.surface_distance import exact_sampled_distance, metro_distance


def _grid(n=12, z=0.0):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.c_[x.ravel(), y.ravel(), np.full(n * n, z)]
    F = []
    for i in range(n - 1):
        for j in range(n - 1):
            a = i * n + j
            F += [[a, a + 1, a + n + 1], [a, a + n + 1, a + n]]
    return V, np.array(F)


def test_parallel_planes_are_their_offset_apart():
    V, F = _grid()
    for backend in ("bvh", "libigl", "meshlab"):
        d = exact_sampled_distance(V, F, V + [0, 0, 0.05], F, samples=3000, backend=backend)
        assert d["max"] == pytest.approx(0.05, rel=1e-6) and d["rms"] == pytest.approx(0.05, rel=1e-6)


def _bump():
    V, F = _grid(20)
    W = V.copy()
    W[:, 2] = 0.1 * np.exp(-((V[:, 0] - 0.5) ** 2 + (V[:, 1] - 0.5) ** 2) / 0.02)
    return W, V, F


def test_exact_sampled_distance_agrees_with_metro_on_a_bump():
    pytest.importorskip("pymeshlab")
    W, V, F = _bump()
    a, b = exact_sampled_distance(W, F, V, F, 20000), metro_distance(W, F, V, F, 20000)
    assert a["max"] == pytest.approx(b["max"], rel=0.05)
    assert a["rms"] == pytest.approx(b["rms"], rel=0.05)


def test_meshlab_libigl_and_the_hierarchy_give_the_same_exact_distances():
    """The same samples, each distance exact every way: the hierarchy and libigl agree to double round-off,
    MeshLab to float32's."""
    pytest.importorskip("pymeshlab")
    W, V, F = _bump()
    a = exact_sampled_distance(W, F, V, F, 5000, backend="meshlab")
    b = exact_sampled_distance(W, F, V, F, 5000, backend="libigl")
    c = exact_sampled_distance(W, F, V, F, 5000, backend="bvh")
    assert a["n_samples"] == b["n_samples"] == c["n_samples"]
    assert a["max"] == pytest.approx(b["max"], rel=1e-5) and a["rms"] == pytest.approx(b["rms"], rel=1e-5)
    assert c["max"] == pytest.approx(b["max"], rel=1e-12) and c["rms"] == pytest.approx(b["rms"], rel=1e-12)


def test_level_errors_pose_each_level_with_its_own_weights():
    V, F = _grid(8)
    mesh = Mesh(V, F)
    one = ReducedWeights(np.zeros((len(V), 1), int), np.ones((len(V), 1)), 2)
    other = ReducedWeights(np.ones((len(V), 1), int), np.ones((len(V), 1)), 2)
    T = np.zeros((3, 2, 3, 4))
    T[..., :3] = np.eye(3)
    T[:, 1, 2, 3] = [0.0, 0.02, 0.04]                       # joint 1 lifts by 0, 2, 4 cm
    levels = [SimplifiedLevel(mesh, one, "same"), SimplifiedLevel(mesh, other, "lifted")]
    out = level_errors(mesh, one.to_sparse(), T, levels, samples=2000)
    assert out[0]["error_max"] == pytest.approx(0.0, abs=1e-7)    # pymeshlab samples in float32: ~1e-8 noise
    assert out[1]["error_max"] == pytest.approx(0.04, rel=1e-6)
    assert out[1]["error_rms"] == pytest.approx(0.02, rel=1e-6)       # mean over the frames of 0, 2, 4 cm
    assert bounding_radius(V, one, T[0]) == pytest.approx(0.5 * np.sqrt(2))


def test_level_errors_are_repeatable_and_agree_with_one_backend():
    """Two level-frame pairs at once (libigl here, MeshLab on its thread) give the same figures in every run,
    and within float32 round-off of libigl alone."""
    from rigslim.numerics.surface_distance import surface_samples

    W, V, F = _bump()
    mesh = Mesh(V, F)
    one = ReducedWeights(np.zeros((len(V), 1), int), np.ones((len(V), 1)), 2)
    half = ReducedWeights(np.zeros((200, 1), int), np.ones((200, 1)), 2)
    T = np.zeros((6, 2, 3, 4))
    T[..., :3] = np.eye(3)
    T[:, 0, 2, 3] = np.linspace(0.0, 0.05, 6)
    levels = [SimplifiedLevel(Mesh(W, F), one, "bump"), SimplifiedLevel(Mesh(V[:200], F[(F < 200).all(1)]), half,
                                                                         "part")]
    other = ReducedWeights(np.ones((len(V), 1), int), np.ones((len(V), 1)), 2).to_sparse()   # the full mesh
    a = level_errors(mesh, other, T, levels, samples=3000)
    assert a == level_errors(mesh, other, T, levels, samples=3000)
    for i, level in enumerate(levels):
        for j in range(len(T)):
            X = level.mesh.V + T[j, 0, :, 3]
            ref = exact_sampled_distance(X, level.mesh.F, V, F, 3000, None, surface_samples(V, F, 3000, seed=1),
                                         backend="libigl")
            assert a[i]["per_frame_max"][j] == pytest.approx(ref["max"], rel=1e-5, abs=1e-9)
            assert a[i]["per_frame_rms"][j] == pytest.approx(ref["rms"], rel=1e-5, abs=1e-9)
    assert a[0]["per_frame_max"][-1] > a[0]["per_frame_max"][0] > 0
