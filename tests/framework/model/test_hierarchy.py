"""ProgressiveHierarchy and SimplifiedLevel (rigslim.model.hierarchy) on a hand-made merge tree."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.io.hierarchy import read_hierarchy, write_hierarchy
from rigslim.model.hierarchy import ProgressiveHierarchy
from rigslim.model.weights import ReducedWeights


@pytest.fixture
def fan():
    """A hexagon fan around vertex 0 (6 faces); two collapses: (0, 1) -> 7, then (7, 2) -> 8."""
    ang = np.linspace(0, 2 * np.pi, 6, endpoint=False)
    V = np.vstack([[0, 0, 0], np.c_[np.cos(ang), np.sin(ang), np.zeros(6)]])
    F = np.array([[0, i, i % 6 + 1] for i in range(1, 7)])
    V_all = np.vstack([V, [0.5, 0, 0], [0.6, 0.4, 0]])
    idx = np.array([[0, 1]] * 9)
    vals = np.array([[1.0, 0.0]] * 7 + [[0.5, 0.5], [0.25, 0.75]])
    w = ReducedWeights(idx, vals, 2)
    return ProgressiveHierarchy(V_all, w, F, [[0, 1], [7, 2]], [0.1, 0.3], [4, 3], method="test",
                                params={"max_bones": 2})


def test_prefix_replays_the_collapses(fan):
    lv0, lv1, lv2 = fan.prefix(0), fan.prefix(1), fan.prefix(2)
    assert (lv0.n_faces, lv1.n_faces, lv2.n_faces) == (6, 4, 3)
    assert set(lv1.vertex_ids) == {2, 3, 4, 5, 6, 7}
    assert np.allclose(lv1.mesh.V[list(lv1.vertex_ids).index(7)], [0.5, 0, 0])
    assert set(lv2.vertex_ids) == {3, 4, 5, 6, 8}
    row = list(lv2.vertex_ids).index(8)
    assert np.allclose(lv2.weights.values[row], [0.25, 0.75])
    assert lv2.error == pytest.approx(0.3) and lv0.error == 0.0


def test_prefix_keeps_the_sources_double_sided_faces(fan):
    """A face the source has twice (a double-sided card, both orientations) stays twice in every prefix: a
    level has the faces the loop counted (the suite's wolf lost 40 of 174 faces, its cards, before)."""
    F = np.vstack([fan.F, fan.F[[3, 4], ::-1]])
    h = ProgressiveHierarchy(fan.V, fan.weights, F, fan.collapses, fan.errors, [6, 5], method="test",
                             params={"max_bones": 2})
    for t, faces in [(0, 8), (1, 6), (2, 5)]:
        lv = h.prefix(t)
        assert lv.n_faces == faces == (len(F) if t == 0 else h.n_faces[t - 1])


def test_extraction_by_faces_and_error(fan):
    assert fan.at_faces(6).n_faces == 6
    assert fan.at_faces(5).n_faces == 4
    assert fan.at_faces(1).n_faces == 3           # the coarsest there is
    assert fan.at_error(0.05).n_faces == 6
    assert fan.at_error(0.2).n_faces == 4
    assert fan.at_error(1.0).n_faces == 3


def test_adaptive_needs_both_children_and_the_budget(fan):
    b = np.full(7, 1.0)
    assert fan.adaptive(b).n_faces == 3
    b[2] = 0.2                                    # vertex 2 only tolerates 0.2: second collapse refused
    assert fan.adaptive(b).n_faces == 4
    b[1] = 0.0                                    # first collapse refused, so the second cannot happen
    assert fan.adaptive(b).n_faces == 6
    with pytest.raises(InputError):
        fan.adaptive(np.ones(3))


def test_save_load_round_trip(fan, tmp_path):
    write_hierarchy(tmp_path / "h.npz", fan)
    back = read_hierarchy(tmp_path / "h.npz")
    assert back.params == {"max_bones": 2} and back.method == "test"
    for t in range(3):
        a, b = fan.prefix(t), back.prefix(t)
        assert np.array_equal(a.mesh.F, b.mesh.F) and np.array_equal(a.mesh.V, b.mesh.V)
        assert np.array_equal(a.weights.values, b.weights.values)


def test_load_rejects_other_files(tmp_path):
    np.savez(tmp_path / "x.npz", a=np.zeros(3))
    with pytest.raises(InputError, match="not a rigslim progressive hierarchy"):
        read_hierarchy(tmp_path / "x.npz")
    (tmp_path / "y.npz").write_text("junk")
    with pytest.raises(InputError):
        read_hierarchy(tmp_path / "y.npz")


def test_inconsistent_sizes_are_rejected(fan):
    with pytest.raises(ValueError):
        ProgressiveHierarchy(fan.V[:-1], fan.weights, fan.F, fan.collapses, fan.errors, fan.n_faces)
