"""``rigslim lod``'s stderr line for a level that removed parts whole before the hierarchy's end."""

from __future__ import annotations

from rigslim.commands.lod import _say_where_it_stopped


def record(early: bool) -> dict:
    return {"target": 0.5, "target_faces": 220, "faces": 220, "label": "quartic-50pct", "stopped": None,
            "same_as": None, "parts_removed": 110, "removal_distance": 0.0285, "faces_collapsed": 440,
            "removed_early": early}


def test_an_early_removal_says_it_cost_less_than_collapsing_on(capsys):
    _say_where_it_stopped(record(True), "1%", None)
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["rigslim lod: level quartic-50pct: 110 parts were removed whole at 440 faces, where that costs "
                   "less error than collapsing on, the smallest and nearest to the rest first (the farthest "
                   "0.0285 m away; --keep-parts keeps them)"]


def test_a_removal_after_the_last_collapse_says_no_collapse_was_left(capsys):
    _say_where_it_stopped(record(False), "1%", None)
    err = capsys.readouterr().err
    assert "no collapse was left at 440 faces, so 110 parts were removed whole" in err


def test_a_level_the_bound_stopped_after_early_removals_names_both_limits(capsys):
    """The bound stopped the level short of its target after removing parts early: the next collapse and the
    next removal both pass it (not "no collapse was left": collapses were left)."""
    t = {**record(True), "target": 0.25, "target_faces": 110, "faces": 170, "label": "quartic-25pct-170f",
         "stopped": "max_error", "parts_removed": 125}
    _say_where_it_stopped(t, "1%", None)
    err = capsys.readouterr().err.strip().splitlines()
    assert err[-1] == ("rigslim lod: level quartic-25pct-170f stopped at 170 faces, target 0.25 (110 faces): the "
                       "next collapse and removing its next part whole exceed --max-error 1% (125 removed; "
                       "--max-error none goes on)")
    t["removed_early"] = False
    _say_where_it_stopped(t, "1%", None)
    assert "no collapse was left and removing its next part whole exceeds --max-error 1%" in capsys.readouterr().err
