"""Parts removed early (plugins/decimation/prune.py, ``early_removals``): a level takes a shorter collapse prefix
and removes whole parts when that costs less error than collapsing on, and only then."""

from __future__ import annotations

import numpy as np

from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.prune import face_parts

#: A cuboid's 12 triangles (outward), corners indexed by their (x, y, z) bits.
BOX = np.array([[0, 2, 3], [0, 3, 1], [4, 5, 7], [4, 7, 6], [0, 1, 5], [0, 5, 4],
                [2, 6, 7], [2, 7, 3], [0, 4, 6], [0, 6, 2], [1, 3, 7], [1, 7, 5]], np.int64)


def box(lo, hi):
    lo, hi = np.asarray(lo, float), np.asarray(hi, float)
    return np.array([[(hi if i & 4 else lo)[0], (hi if i & 2 else lo)[1], (hi if i & 1 else lo)[2]]
                     for i in range(8)])


def plated_boxes(gap: float):
    """Four 2 x 2 x 2 blocks in a row (a blocky character's boxes: no collapse of one is free), each with a
    separate plate (a two-triangle quad, an armour layer) ``gap`` in front of its +z face."""
    V, F = [], []
    for i in range(4):
        x = 3.0 * i
        F.append(BOX + len(V) * 0 + sum(len(v) for v in V))
        V.append(box([x, 0, 0], [x + 2, 2, 2]))
        q = np.array([[x + 0.1, 0.1, 2 + gap], [x + 1.9, 0.1, 2 + gap], [x + 1.9, 1.9, 2 + gap],
                      [x + 0.1, 1.9, 2 + gap]])
        F.append(np.array([[0, 1, 2], [0, 2, 3]]) + sum(len(v) for v in V))
        V.append(q)
    return np.concatenate(V), np.concatenate(F)


def decimated(V, F, target, **params):
    from test_decimation_source_error import rigid_asset

    asset = rigid_asset(V, F)
    plugin = get_host().get("articulated-decimation", "quartic")
    said: list[str] = []
    ctx = StepContext(log=said.append)
    plugin.apply(asset, plugin.parse_params({"targets": [target], "max_error": "none", **params}), ctx)
    return asset, ctx.report["targets"][0], said


def test_plates_on_the_blocks_go_before_any_block_is_cut():
    """56 faces to 48: removing the four plates (0.01 in front of their blocks) costs far less than the collapses
    that would turn blocks into wedges, so the level keeps every block whole and loses only the plates."""
    V, F = plated_boxes(0.01)
    asset, t, said = decimated(V, F, 48 / 56)
    lv = asset.levels[0]
    assert t["stopped"] is None and t["faces"] == lv.n_faces == 48
    assert t["parts_removed"] == 4 and t["removed_early"] and t["faces_collapsed"] == 56
    assert t["removal_distance"] < 0.02 and t["error"] < 0.02
    n, _ = face_parts(np.asarray(lv.mesh.F))
    assert n == 4 and np.isclose(lv.mesh.V[:, 2].max(), 2.0)            # four whole blocks, no plate
    assert any("parts removed whole after 0 collapses, for less error" in line for line in said)
    # without parts removed the same target is met by cutting blocks, at a far larger error
    _, kept, _ = decimated(V, F, 48 / 56, prune_parts=False)
    assert kept["parts_removed"] == 0 and kept["faces"] <= 48 and kept["error"] > 10 * t["error"]


def test_plates_that_stand_off_are_collapsed_as_before():
    """The same plates 3 units in front of the blocks: removing one moves its surface 3 units (its peak), more
    than the collapses cost, so the level is the collapse prefix it was."""
    V, F = plated_boxes(3.0)
    asset, t, _ = decimated(V, F, 48 / 56)
    _, off, _ = decimated(V, F, 48 / 56, prune_parts=False)
    assert t["parts_removed"] == 0 and "removed_early" not in t
    assert (t["faces"], t["error"]) == (off["faces"], off["error"])



def plated_tetrahedra(gap: float = 0.01):
    """A 2 x 2 x 2 block and three tetrahedra (4 faces each: no collapse may shrink one), each with a quad plate
    ``gap`` under its base: the collapses can only fold the block (at a cost) and end at 24 of the 32 faces."""
    V, F = [box([0, 0, 0], [2, 2, 2])], [BOX]
    for i in range(4):
        x = 3.0 * i
        if i:
            F.append(np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]]) + sum(len(v) for v in V))
            V.append(np.array([[x, 0, 0], [x + 2, 0, 0], [x, 2, 0], [x, 0, 2]], float))
        F.append(np.array([[0, 2, 1], [0, 3, 2]]) + sum(len(v) for v in V))
        V.append(np.array([[x + 0.1, 0.1, -gap], [x + 1.5, 0.1, -gap], [x + 0.8, 0.8, -gap], [x + 0.1, 1.5, -gap]]))
    return np.concatenate(V), np.concatenate(F)


def test_a_target_that_ended_at_a_finer_level_gets_its_own_by_early_removal():
    """Targets 24 and 22 of 32 faces: the collapses fold the block and end at 24, so the second target ended at
    the first's level (``same_as``) and both were then reached from there by removing parts. Now the first
    removes the four plates and keeps the block whole, and the second gets a level of its own: two folds of the
    block (28 faces) and three plates removed, error 0.972. (With the face-side error at the new faces'
    centroids only, it was one fold and the four plates, error 0.986.)"""
    from test_decimation_source_error import rigid_asset

    V, F = plated_tetrahedra()
    asset = rigid_asset(V, F)
    plugin = get_host().get("articulated-decimation", "quartic")
    ctx = StepContext()
    plugin.apply(asset, plugin.parse_params({"targets": [24 / 32, 22 / 32], "max_error": "none"}), ctx)
    first, second = ctx.report["targets"]
    assert list(asset.hierarchy.n_faces) == [30, 28, 26, 24]
    assert [lv.n_faces for lv in asset.levels] == [first["faces"], second["faces"]]
    assert first["same_as"] is None and second["same_as"] is None
    assert first["removed_early"] and first["faces_collapsed"] == 32 and first["parts_removed"] == 4
    assert second["faces"] == 22 and second["removed_early"] and second["faces_collapsed"] == 28
    assert second["parts_removed"] == 3 and second["error"] < 0.98
    assert second["error"] < first["error"] + 1.0 and first["error"] < 0.02
    whole = asset.levels[0]
    assert face_parts(np.asarray(whole.mesh.F))[0] == 4 and whole.mesh.V[:, 2].min() == 0.0   # block kept whole


def test_a_target_the_bound_stopped_at_the_source_is_reached_by_removing_plates():
    """With a 1 % bound the first collapse (a block folded) is already too far, so the level used to end at the
    source's 56 faces and was no level; the plates lie within the bound and their removal is the level."""
    V, F = plated_boxes(0.01)
    _, off, _ = decimated(V, F, 48 / 56, max_error="1%", prune_parts=False)
    assert off["same_as"] == "source" and off["stopped"] == "max_error"
    asset, t, _ = decimated(V, F, 48 / 56, max_error="1%")
    assert t["same_as"] is None and t["stopped"] is None and t["faces"] == 48 and t["removed_early"]
    assert t["removal_distance"] <= t["max_error"] and len(asset.levels) == 1


def test_a_target_the_plates_cannot_reach_within_the_bound_stops_at_the_fewest_faces_within_it():
    """Target 24 of 56 faces with a 1 % bound: every collapse (a block folded) passes the bound and removing the
    four plates leaves 48 faces, short of 24. The level used to be none at all ("the source's 56 faces are no
    level"); the fewest faces within the bound are the plates removed, so that is the level, stopped by the
    bound, and said so."""
    V, F = plated_boxes(0.01)
    asset, t, _ = decimated(V, F, 24 / 56, max_error="1%")
    assert t["same_as"] is None and t["stopped"] == "max_error" and t["faces"] == 48
    assert t["parts_removed"] == 4 and t["removed_early"] and t["faces_collapsed"] == 56
    assert t["error"] <= t["max_error"] and t["removal_distance"] <= t["max_error"]
    assert [lv.n_faces for lv in asset.levels] == [48]
    lv = asset.levels[0]
    assert face_parts(np.asarray(lv.mesh.F))[0] == 4 and np.isclose(lv.mesh.V[:, 2].max(), 2.0)  # blocks whole


def test_a_coarser_target_the_bound_stops_ends_at_the_finer_level_the_plates_made():
    """Targets 48 and 24 of 56 faces, 1 % bound: the first is reached by removing the plates; the second can get
    no fewer faces within the bound, so it ends at the first's level (``same_as``), not at the source."""
    V, F = plated_boxes(0.01)
    from test_decimation_source_error import rigid_asset

    asset = rigid_asset(V, F)
    plugin = get_host().get("articulated-decimation", "quartic")
    ctx = StepContext()
    plugin.apply(asset, plugin.parse_params({"targets": [48 / 56, 24 / 56], "max_error": "1%"}), ctx)
    first, second = ctx.report["targets"]
    assert first["same_as"] is None and first["faces"] == 48 and first["stopped"] is None
    assert second["same_as"] == first["label"] and second["faces"] == 48 and second["stopped"] == "max_error"
    assert [lv.n_faces for lv in asset.levels] == [48]


def test_targets_that_ended_at_a_replaced_level_take_its_faces():
    """A level replaced by removals (218 -> 214 faces on the sweep's boar) takes the coarser targets that ended
    at it along: their ``same_as``, faces, prefix and error are the new level's (they said "ends at the 218
    faces of level quartic-50pct-214f")."""
    from rigslim.plugins.decimation.levels import LevelChoice
    from rigslim.plugins.decimation.prune import _redirected

    old = LevelChoice(0.5, 181, 180, 218, 0.02, "max_error", "quartic-50pct-218f")
    new = LevelChoice(0.5, 181, 178, 214, 0.021, "max_error", "quartic-50pct-214f", parts_removed=1)
    coarser = LevelChoice(0.25, 90, 180, 218, 0.02, "max_error", "quartic-25pct-218f", same_as=old.label)
    other = LevelChoice(0.1, 36, 0, 362, 0.0, "max_error", "quartic-10pct", same_as="source")
    out = _redirected([new, coarser, other], old.label, new)
    assert out[0] is new and out[2] is other
    assert (out[1].same_as, out[1].faces, out[1].collapses, out[1].error) == (new.label, 214, 178, 0.021)
