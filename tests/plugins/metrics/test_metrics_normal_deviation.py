"""normal-deviation: RMS, percentiles, count above 90 degrees and area-weighted RMS on a hand-made mesh."""

import numpy as np
import pytest

from rigslim.model.mesh import Mesh
from rigslim.numerics.blend import per_vertex_normals
from rigslim.numerics.normal_error import normal_angles, normal_statistics
from rigslim.plugins.metrics.normal_deviation import NormalDeviation


def grid(n=10):
    """An n x n grid of unit squares in the z = 0 plane, two triangles each."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return Mesh(V, F)


class FlippedEvaluation:
    """Two frames of the flat grid; in the 'reduced' deformation vertex ``flip`` has its normal reversed."""

    def __init__(self, mesh, flip):
        self.mesh = mesh
        self.full = per_vertex_normals(mesh.V, mesh.F)
        self.red = self.full.copy()
        self.red[flip] *= -1.0

    def __len__(self):
        return 2

    def full_normals(self, j):
        return self.full

    def reduced_normals(self, j):
        return self.red


def test_one_flipped_vertex():
    mesh = grid(10)   # 100 vertices
    ev = FlippedEvaluation(mesh, flip=55)
    theta = normal_angles(ev.reduced_normals(0), ev.full_normals(0))
    assert theta[55] == pytest.approx(np.pi) and np.abs(np.delete(theta, 55)).max() < 1e-12
    m = NormalDeviation().compute(ev, None)
    assert m["normal_rms_rad"]["mean"] == pytest.approx(np.pi / 10)          # sqrt(pi^2 / 100)
    assert m["normal_median_rad"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert m["normal_p95_rad"]["mean"] == pytest.approx(0.0, abs=1e-12)
    # 99th percentile of 99 zeros and one pi: position 0.99 * 99 = 98.01 between 0 and pi
    assert m["normal_p99_rad"]["mean"] == pytest.approx(0.01 * np.pi)
    assert m["normal_flipped"]["per_frame"] == [1.0, 1.0]
    # area-weighted: the interior vertex 55 has area 1 of the grid's total 81
    areas = mesh.massmatrix.diagonal()
    assert areas[55] == pytest.approx(1.0) and areas.sum() == pytest.approx(81.0)
    assert m["normal_area_rms_rad"]["mean"] == pytest.approx(np.pi / 9)      # sqrt(pi^2 * 1 / 81)


def test_statistics_of_spread_error():
    theta = np.linspace(0.0, 0.2, 101)
    s = normal_statistics(theta)
    assert s["normal_median_rad"] == pytest.approx(0.1)
    assert s["normal_p95_rad"] == pytest.approx(0.19)
    assert s["normal_flipped"] == 0 and "normal_area_rms_rad" not in s


def test_just_above_and_below_90_degrees():
    z = np.array([[0.0, 0.0, 1.0]] * 2)
    tilt = np.array([[np.sin(np.pi / 2 + 1e-6), 0.0, np.cos(np.pi / 2 + 1e-6)],
                     [np.sin(np.pi / 2 - 1e-6), 0.0, np.cos(np.pi / 2 - 1e-6)]])
    assert normal_statistics(normal_angles(tilt, z))["normal_flipped"] == 1
