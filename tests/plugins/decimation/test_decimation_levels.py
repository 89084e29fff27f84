"""rigslim.plugins.decimation.levels: face targets, the error bound, strictly decreasing levels."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.errors import StepError
from rigslim.plugin.contract import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.levels import SOURCE, choose_levels, collapse_distances, parse_max_error
from tests.plugins.decimation.test_decimation_collapse import decimate, tube


class FakeHierarchy:
    """Just what choose_levels reads: faces after each collapse, the source faces."""

    def __init__(self, n_faces, F_count):
        self.n_faces = np.asarray(n_faces)
        self.n_collapses = len(n_faces)
        self.F = np.zeros((F_count, 3))

    def faces_after(self, t):
        return int(self.n_faces[t - 1]) if t else len(self.F)


def test_parse_max_error_units_and_bad_values():
    assert parse_max_error(1) == (1.0, "%") and parse_max_error("0.5%") == (0.5, "%")
    assert parse_max_error("0.02m") == (0.02, "m") and parse_max_error(" 2e-1 ") == (0.2, "%")
    assert parse_max_error(None) is None and parse_max_error("none") is None and parse_max_error("off") is None
    for bad in ("1cm", "-1", "0", "abc"):
        with pytest.raises(StepError, match="max_error"):
            parse_max_error(bad)


def test_unreachable_targets_share_one_level_and_are_named_by_their_faces():
    h = FakeHierarchy([98, 96, 94, 92, 90], 100)
    d = np.zeros(5)
    out = choose_levels(h, [0.95, 0.5, 0.25], [95, 50, 25], d, None, "quartic")
    assert [c.label for c in out] == ["quartic-95pct", "quartic-50pct-90f", "quartic-25pct-90f"]
    assert [c.faces for c in out] == [94, 90, 90]
    assert out[1].stopped == "no collapse" and out[1].same_as is None
    assert out[2].same_as == "quartic-50pct-90f"          # no level of its own: faces strictly decrease
    levels = [c for c in out if c.same_as is None]
    assert all(a.faces > b.faces for a, b in zip(levels, levels[1:], strict=False))


def test_a_target_that_ends_before_the_first_collapse_is_no_level():
    """The bound below the first collapse (minetest at 1 %), or nothing to collapse: the targets end at the
    source itself, which is no level (once a level with the source's faces was written)."""
    h = FakeHierarchy([98, 96], 100)
    out = choose_levels(h, [0.5, 0.25], [50, 25], np.array([0.5, 0.6]), 0.1, "quartic")
    assert [c.same_as for c in out] == [SOURCE, SOURCE] and [c.faces for c in out] == [100, 100]
    assert [c.collapses for c in out] == [0, 0] and out[0].stopped == "max_error"
    none = choose_levels(FakeHierarchy([], 100), [0.5], [50], np.zeros(0), None, "quartic")
    assert none[0].same_as == SOURCE and none[0].stopped == "no collapse"
    met = choose_levels(h, [0.995, 0.5], [100, 50], np.array([0.5, 0.6]), None, "quartic")   # 0.995 rounds to 100
    assert met[0].same_as == SOURCE and met[0].stopped is None and met[0].collapses == 0
    assert met[1].same_as is None and met[1].faces == 96


def test_the_bound_stops_a_level_before_its_target():
    h = FakeHierarchy([98, 96, 94, 92, 90, 88], 100)
    d = np.array([0.1, 0.3, 0.2, 0.6, 0.5, 0.9])         # running max 0.1 0.3 0.3 0.6 0.6 0.9
    out = choose_levels(h, [96, 88], [96, 88], d, 0.55, "quartic")
    assert out[0].faces == 96 and out[0].stopped is None and out[0].error == pytest.approx(0.3)
    assert out[1].faces == 94 and out[1].stopped == "max_error" and out[1].error <= 0.55
    assert out[1].label == "quartic-88f-94f"


def test_collapse_distances_are_zero_on_a_plane_and_bounded_by_the_bound():
    asset = tube(n_around=12, n_along=12)
    hier, levels = decimate(asset, "quartic", targets=[0.5, 0.1], max_error="none")
    from rigslim.plugins.decimation.quadrics import per_pose_quadrics

    Q, _ = per_pose_quadrics(asset.mesh.V, asset.mesh.F, asset.weights, asset.example_poses().T)
    d = collapse_distances(hier, Q)
    assert d.shape == (hier.n_collapses,) and (d >= 0).all() and d[-1] > 0
    diag = asset.mesh.bbox_diagonal
    bound_pct = 100 * float(np.median(d)) / diag
    h2, lv2 = decimate(asset, "quartic", targets=[0.5, 0.1], max_error=bound_pct)
    assert lv2[-1].n_faces > levels[-1].n_faces                      # stopped before 10 %
    k = int(np.flatnonzero(h2.n_faces == lv2[-1].n_faces)[0]) + 1
    assert np.maximum.accumulate(d)[k - 1] <= bound_pct / 100 * diag * 1.05   # the test pose's diagonal differs


def test_seams_from_arrays_lock_and_collapse_along():
    """``asset.extras["seams"] = (locked, charts)``: seam locks for any input (e.g. Blender's arrays)."""
    asset = tube(n_around=12, n_along=12)
    V, F = asset.mesh.V, asset.mesh.F
    charts = (V[F].mean(axis=1)[:, 0] > 0).astype(np.int64)       # two charts split by the x = 0 plane
    counts = np.zeros((len(V), 2), int)
    np.add.at(counts, (F.ravel(), np.repeat(charts, 3)), 1)
    locked = (counts > 0).all(axis=1)
    asset.extras["seams"] = (locked, charts)
    plugin = get_host().get("articulated-decimation", "quartic")
    ctx = StepContext()
    plugin.apply(asset, plugin.parse_params({"targets": [0.25], "seams": "lock"}), ctx)
    assert ctx.report["locked_seam_vertices"] == int(locked.sum())
    assert ctx.report["seam_vertices_collapsing_along"] > 0
    asset.extras["seams"] = (locked[:-1], charts)
    with pytest.raises(StepError, match="seams"):
        plugin.apply(asset, plugin.parse_params({"targets": [0.25], "seams": "lock"}), StepContext())


def test_part_sizes_counts_parts_and_those_at_four_faces():
    from rigslim.plugins.decimation.articulated import part_sizes

    tetra = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 2], [2, 3, 0]])
    strip = np.array([[0, 1, 2], [1, 3, 2], [2, 3, 4], [3, 5, 4], [4, 5, 6]])       # 5 faces: not minimal
    F = np.concatenate([tetra + 10, strip + 20, tetra + 40, [[60, 61, 62]]])   # vertex ids with gaps
    assert part_sizes(F) == (4, 3)
    assert part_sizes(np.zeros((0, 3), int)) == (0, 0)
