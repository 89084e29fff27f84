"""Split-file names and the sidecar's rows (framework/io/gltf/sidecar.py)."""

from __future__ import annotations

from pathlib import Path

from rigslim.io.gltf.sidecar import kept_level_targets, sidecar_path, split_names, split_outputs


def test_split_names_follow_the_face_targets():
    out = Path("/d/char.glb")
    assert split_names(out, [0.5, 0.25, 0.125]) == [Path("/d/char-50.glb"), Path("/d/char-25.glb"),
                                                    Path("/d/char-12.5.glb")]
    assert split_names(Path("c.gltf"), [500, 120.0]) == [Path("c-500f.gltf"), Path("c-120f.gltf")]
    assert sidecar_path(Path("/d/char.glb")) == Path("/d/char.lod.json")


def test_split_outputs_name_levels_by_their_own_target_or_label():
    """Only targets with a level of their own (``same_as`` None) name files; a level made for an error
    target is named after its label."""
    steps = [{"stage": "read"},
             {"stage": "decimate", "report": {"targets": [
                 {"target": 0.5, "label": "quartic-50pct", "same_as": None},
                 {"target": 0.25, "label": "quartic-25pct-40f", "same_as": None},
                 {"target": 0.1, "label": "quartic-25pct-40f", "same_as": 0.25}]}}]
    assert kept_level_targets(steps) == {"quartic-50pct": 0.5, "quartic-25pct-40f": 0.25}
    names = split_outputs(Path("x.glb"), ["quartic-50pct", "quartic-25pct-40f", "quartic-err0.01"], steps)
    assert names == [Path("x-50.glb"), Path("x-25.glb"), Path("x-quartic-err0.01.glb")]
    assert split_outputs(Path("x.glb"), [], steps) == []
    assert split_outputs(Path("x.glb"), ["static-qslim-10pct"], [{"stage": "read"}]) == \
        [Path("x-static-qslim-10pct.glb")]
