"""The animated error of levels (framework/numerics/level_error.py)."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.level_error import bounding_radius, level_errors, sampled_distance, surface_distance


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
    d = sampled_distance(V, F, V + [0, 0, 0.05], F, samples=3000)
    assert d["max"] == pytest.approx(0.05, rel=1e-9) and d["rms"] == pytest.approx(0.05, rel=1e-9)


def test_sampled_and_metro_agree_on_a_bump():
    pytest.importorskip("pymeshlab")
    V, F = _grid(20)
    W = V.copy()
    W[:, 2] = 0.1 * np.exp(-((V[:, 0] - 0.5) ** 2 + (V[:, 1] - 0.5) ** 2) / 0.02)
    a, b = sampled_distance(W, F, V, F, 20000), surface_distance(W, F, V, F, 20000)
    assert a["max"] == pytest.approx(b["max"], rel=0.05)
    assert a["rms"] == pytest.approx(b["rms"], rel=0.05)


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
