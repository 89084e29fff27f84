"""rigslim.numerics.surface_distance: what pymeshlab is given (the hostile cases are in tests/hostile)."""

from __future__ import annotations

import numpy as np

from rigslim.numerics.surface_distance import metro_distance, referenced


def _box():
    V = np.array([[x, y, z] for x in (0.0, 1.0) for y in (0.0, 1.0) for z in (0.0, 1.0)])
    F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                  [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    return V, F


def test_a_vertex_only_repeated_corner_faces_use_is_no_surface():
    """A CSM conversion's (0, 0, 0) faces left a lone point 1378 m away: 44 % of the diagonal between a file and
    its own copy. Faces with a repeated corner and the vertices only they use are not measured."""
    V, F = _box()
    far = np.vstack([V, [[50.0, 0.0, 0.0]]])
    with_point = np.vstack([F, [[8, 8, 8], [8, 8, 0]]])
    Vr, Fr = referenced(far, with_point)
    assert len(Vr) == 8 and np.array_equal(Fr, F)
    d = metro_distance(far, with_point, V, F, samples=2000)
    assert d["max"] < 1e-9, d
    assert metro_distance(V + [0.0, 0.0, 0.1], F, V, F, samples=2000)["max"] > 0.09   # a real offset still counts


def _grid(n: int):
    x, y = np.meshgrid(np.linspace(0, 1, n), np.linspace(0, 1, n))
    V = np.c_[x.ravel(), y.ravel(), np.zeros(n * n)]
    F = [[i * n + j, i * n + j + 1, (i + 1) * n + j + 1] for i in range(n - 1) for j in range(n - 1)]
    F += [[i * n + j, (i + 1) * n + j + 1, (i + 1) * n + j] for i in range(n - 1) for j in range(n - 1)]
    return V, np.array(F)


def test_every_vertex_is_measured_when_the_mesh_has_more_vertices_than_samples():
    """pymeshlab's Hausdorff filter draws ``samplenum`` of a larger mesh's vertices at random; a spike at one
    of 2,500 vertices was then missed in most draws. Every vertex is measured: the spike's height, every run."""
    V, F = _grid(50)
    spiked = V.copy()
    spiked[1275, 2] = 0.3                                  # one vertex near the middle, 0.3 up
    found = [metro_distance(spiked, F, V, F, samples=100)["max"] for _ in range(5)]
    assert min(found) > 0.29, found
    d = metro_distance(spiked, F, V, F, samples=100)
    assert d["n_samples"] == 2 * (2500 + 100)              # both meshes' vertices, and 100 points per side
