"""normal-deviation: RMS, percentiles, flips and area-weighted RMS on hand-made meshes; degenerate normals
(cancelling faces) left out and counted; unchanged weights give no flips on real characters."""

from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import per_vertex_normals
from rigslim.numerics.normal_error import (
    DEGENERATE_RATIO,
    degenerate_normals,
    normal_angles,
    normal_conditioning,
    normal_statistics,
)
from rigslim.plugin.evaluation import Evaluation
from rigslim.plugin.host import get_host
from rigslim.plugins.metrics.normal_deviation import NormalDeviation

SUITE = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "suite"


def grid(n=10):
    """An n x n grid of unit squares in the z = 0 plane, two triangles each (vertex i n + j at (i, j, 0))."""
    x, y = np.meshgrid(np.arange(n, dtype=float), np.arange(n, dtype=float), indexing="ij")
    V = np.stack([x.ravel(), y.ravel(), np.zeros(n * n)], axis=1)
    idx = np.arange(n * n).reshape(n, n)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel(), idx[:-1, 1:].ravel()
    F = np.concatenate([np.stack([a, b, c], 1), np.stack([a, c, d], 1)])
    return V, F


def finned_grid():
    """The 10 x 10 grid with a fin: vertex 100 above the edge 44-54 in the two triangles (44, 54, 100) and
    (54, 44, 100), one each way, as a zero-thickness wall has. Their area vectors cancel: vertex 100's
    normal sum is zero (degenerate), and at 44 and 54 they cancel each other, leaving the grid's normal."""
    V, F = grid(10)
    V = np.vstack([V, [[4.5, 4.0, 1.0]]])
    F = np.vstack([F, [[44, 54, 100], [54, 44, 100]]])
    return Mesh(V, F)


class StubEvaluation:
    """Frames of one mesh: full and reduced positions given, normals recomputed from them, the reduced
    normals of the vertices in ``turn`` replaced (a perturbation confined to those vertices), and zero
    normals (vertices whose faces cancel exactly) of both given the direction (0, 1, 0): the direction of
    a cancelling sum is whatever round-off makes it."""

    def __init__(self, mesh, full, reduced=None, turn=None):
        self.mesh = mesh
        self.full = [np.asarray(p, dtype=float) for p in full]
        self.red = [p.copy() for p in self.full] if reduced is None else [np.asarray(p, float) for p in reduced]
        self.turn = turn or {}

    @staticmethod
    def _directed(n):
        n[np.linalg.norm(n, axis=1) == 0] = [0.0, 1.0, 0.0]
        return n

    def __len__(self):
        return len(self.full)

    def full_positions(self, j):
        return self.full[j]

    def reduced_positions(self, j):
        return self.red[j]

    def full_normals(self, j):
        return self._directed(per_vertex_normals(self.full[j], self.mesh.F))

    def reduced_normals(self, j):
        n = self._directed(per_vertex_normals(self.red[j], self.mesh.F))
        for v, new in self.turn.items():
            n[v] = new
        return n


def test_one_flipped_vertex():
    V, F = grid(10)   # 100 vertices
    mesh = Mesh(V, F)
    ev = StubEvaluation(mesh, [V, V], turn={55: [0.0, 0.0, -1.0]})
    theta = normal_angles(ev.reduced_normals(0), ev.full_normals(0))
    assert theta[55] == pytest.approx(np.pi) and np.abs(np.delete(theta, 55)).max() < 1e-12
    m = NormalDeviation().compute(ev, None)
    assert m["normal_rms_rad"]["mean"] == pytest.approx(np.pi / 10)          # sqrt(pi^2 / 100)
    assert m["normal_median_rad"]["mean"] == pytest.approx(0.0, abs=1e-12)
    assert m["normal_p95_rad"]["mean"] == pytest.approx(0.0, abs=1e-12)
    # 99th percentile of 99 zeros and one pi: position 0.99 * 99 = 98.01 between 0 and pi
    assert m["normal_p99_rad"]["mean"] == pytest.approx(0.01 * np.pi)
    assert m["normal_flipped"]["per_frame"] == [1.0, 1.0]
    assert m["degenerate_normals"] == 0 and m["normal_degenerate_posed"]["max"] == 0
    # area-weighted: the interior vertex 55 has area 1 of the grid's total 81
    areas = mesh.massmatrix.diagonal()
    assert areas[55] == pytest.approx(1.0) and areas.sum() == pytest.approx(81.0)
    assert m["normal_area_rms_rad"]["mean"] == pytest.approx(np.pi / 9)      # sqrt(pi^2 * 1 / 81)


def test_cancelling_vertex_is_left_out_and_counted():
    """The fin's tip has a degenerate rest normal: turning its reduced normal changes no statistic."""
    mesh = finned_grid()
    c = normal_conditioning(mesh.V, mesh.F)
    assert c[100] == 0.0 and np.delete(c, 100).min() > 0.5    # at 44 and 54 the fin's faces add to sum |n_f|
    assert np.flatnonzero(degenerate_normals(mesh.V, mesh.F)).tolist() == [100]
    plain = NormalDeviation().compute(StubEvaluation(mesh, [mesh.V]), None)
    turned = StubEvaluation(mesh, [mesh.V], turn={100: [0.0, 0.0, -1.0]})
    assert normal_angles(turned.reduced_normals(0), turned.full_normals(0))[100] > 1.0   # a real perturbation
    m = NormalDeviation().compute(turned, None)
    assert m["degenerate_normals"] == plain["degenerate_normals"] == 1
    for key in ("normal_rms_rad", "normal_median_rad", "normal_p95_rad", "normal_p99_rad", "normal_flipped",
                "normal_area_rms_rad"):
        assert m[key]["per_frame"] == plain[key]["per_frame"], key
    assert m["normal_flipped"]["max"] == 0 and m["normal_rms_rad"]["max"] < 1e-12


def test_conditioning_of_a_nearly_cancelling_pair():
    """Two triangles folded back onto each other at angle phi from flat-and-opposite: c = sin(phi / 2)."""
    phi = 2e-4
    V = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [0.5, 1.0, 0.0],
                  [0.5, np.cos(phi), np.sin(phi)]])
    F = np.array([[0, 1, 2], [1, 0, 3]])
    c = normal_conditioning(V, F)
    assert c[0] == pytest.approx(np.sin(phi / 2), rel=1e-6) and c[0] < DEGENERATE_RATIO
    assert c[2] == pytest.approx(1.0)    # a vertex of one face only


def test_posed_degenerate_reference_and_flip_definition():
    """A frame that folds a 3 x 3 grid back onto itself makes the middle row's reference normals degenerate:
    they are left out of that frame and counted; a reduced normal that turns by > 90 degrees where the reduced
    deformation's own normal is degenerate is no flip, one where it is defined is."""
    V, F = grid(3)            # 9 vertices, the centre 4 inside
    mesh = Mesh(V, F)
    folded = V.copy()
    folded[[6, 7, 8], 0] = 0.0          # fold the last row back over the first two: faces around 3..5 cancel
    folded[[6, 7, 8], 2] = 1e-9
    c = normal_conditioning(folded, F)
    bad = np.flatnonzero(c < DEGENERATE_RATIO)
    assert bad.size and normal_conditioning(V, F).min() == pytest.approx(1.0)
    m = NormalDeviation().compute(StubEvaluation(mesh, [V, folded]), None)
    assert m["degenerate_normals"] == 0
    assert m["normal_degenerate_posed"]["per_frame"] == [0.0, float(bad.size)]
    # flips: vertex 4 turned in a reduced deformation that is fine (counts) or folded (does not)
    flip = {4: [0.0, 0.0, -1.0]}
    assert NormalDeviation().compute(StubEvaluation(mesh, [V], turn=flip), None)["normal_flipped"]["max"] == 1
    pinched = V.copy()
    pinched[[3, 5], :] = pinched[4]     # collapse the row through 4: its faces lose their area
    pinched[[0, 1, 2, 6, 7, 8], 0] = 1.0
    assert normal_conditioning(pinched, F)[4] < DEGENERATE_RATIO
    m = NormalDeviation().compute(StubEvaluation(mesh, [V], [pinched], turn=flip), None)
    assert m["normal_flipped"]["max"] == 0 and m["normal_rms_rad"]["max"] > 0.5


def test_statistics_of_spread_error():
    theta = np.linspace(0.0, 0.2, 101)
    s = normal_statistics(theta)
    assert s["normal_median_rad"] == pytest.approx(0.1)
    assert s["normal_p95_rad"] == pytest.approx(0.19)
    assert s["normal_flipped"] == 0 and "normal_area_rms_rad" not in s


def test_statistics_over_no_vertex():
    s = normal_statistics(np.array([3.0]), np.ones(1), valid=np.array([False]))
    assert s == {"normal_rms_rad": 0.0, "normal_median_rad": 0.0, "normal_p95_rad": 0.0, "normal_p99_rad": 0.0,
                 "normal_flipped": 0}


def test_just_above_and_below_90_degrees():
    z = np.array([[0.0, 0.0, 1.0]] * 2)
    tilt = np.array([[np.sin(np.pi / 2 + 1e-6), 0.0, np.cos(np.pi / 2 + 1e-6)],
                     [np.sin(np.pi / 2 - 1e-6), 0.0, np.cos(np.pi / 2 - 1e-6)]])
    assert normal_statistics(normal_angles(tilt, z))["normal_flipped"] == 1


def _as_reduced(W, scale=None) -> ReducedWeights:
    """The input weights W (sparse) in the reduced layout, each multiplied by ``scale`` (per non-zero)."""
    W = sp.csr_matrix(W)
    counts = np.diff(W.indptr)
    m, k = W.shape[0], int(counts.max())
    rows = np.repeat(np.arange(m), counts)
    slot = np.arange(W.nnz) - np.repeat(W.indptr[:-1], counts)
    idx = np.zeros((m, k), dtype=np.int32)
    val = np.zeros((m, k))
    idx[rows, slot] = W.indices
    val[rows, slot] = W.data * (1.0 if scale is None else scale)
    return ReducedWeights(idx, val, W.shape[1])


def _unchanged_weights_metrics(asset):
    """Metrics of the input weights as the reduction, exactly and with round-off (each weight times
    1 + 1e-15 z, z standard normal), plus the flips a plain 'angle > 90 degrees' count gives."""
    out = {}
    scale = 1.0 + 1e-15 * np.random.default_rng(0).standard_normal(asset.weights.nnz)
    for name, reduced in (("exact", _as_reduced(asset.weights)), ("round-off", _as_reduced(asset.weights, scale))):
        asset.reduced = reduced
        ev = Evaluation(asset, get_host())
        m = NormalDeviation().compute(ev, None)
        plain = sum(normal_statistics(normal_angles(ev.reduced_normals(j), ev.full_normals(j)))["normal_flipped"]
                    for j in range(len(ev)))
        out[name] = (m, plain)
    return out


def test_unchanged_weights_give_no_flips_on_a_suite_character():
    """wolf.glb (welded as pipelines read it) has 24 vertices whose faces cancel; round-off alone flips their
    plain normals hundreds of times over the clip, and the metric counts none."""
    from rigslim.io.gltf.skin import read_gltf_skin

    skin = read_gltf_skin(SUITE / "wolf.glb", weld=True)
    n = len(skin.poses)
    asset = Asset(mesh=skin.mesh, handles=skin.handles, weights=skin.weights, poses=skin.poses,
                  split=FrameSplit.from_specs([0], f"1:{n}:1", n))
    res = _unchanged_weights_metrics(asset)
    for name, (m, _plain) in res.items():
        assert sum(m["normal_flipped"]["per_frame"]) == 0, name
        assert m["normal_rms_rad"]["max"] < 1e-9 and m["normal_p99_rad"]["max"] < 1e-9, name
        assert m["degenerate_normals"] == 24, name
    assert res["round-off"][1] > 0       # without the definition round-off does flip normals here


def test_unchanged_weights_give_no_flips_on_the_elephant(elephant):
    res = _unchanged_weights_metrics(elephant)
    for name, (m, _plain) in res.items():
        assert sum(m["normal_flipped"]["per_frame"]) == 0, name
        assert m["normal_rms_rad"]["max"] < 1e-9, name
