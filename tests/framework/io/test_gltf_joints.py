"""Joints a glTF file needs at every level (framework/io/gltf/joints.py): attached nodes, other skins, names."""

from __future__ import annotations

import copy
import json
from pathlib import Path

import pytest

from rigslim.errors import InputError
from rigslim.io.gltf.document import load_gltf
from rigslim.io.gltf.joints import compile_keep_pattern, joints_the_file_needs, named_joints, other_skin_joints
from rigslim.io.gltf.skin import read_gltf_skin
from rigslim.io.gltf.write import write_pruned

ROOT = Path(__file__).resolve().parents[3]
DRONE = ROOT / "examples" / "data" / "gltf" / "suite" / "re_drone.glb"
WUSON = ROOT / "examples" / "data" / "gltf" / "suite" / "wuson.glb"


def test_a_joint_with_an_attached_node_is_needed():
    """re_drone's Weapon node hangs from Hand.Left: the hand must keep skinning the vertices around it."""
    skin = read_gltf_skin(DRONE, weld=True)
    need = joints_the_file_needs(skin)
    names = skin.handles.names
    hand = names.index("Hand.Left")
    assert hand in need and "Weapon" in need[hand]
    assert all(why.startswith("attached") for why in need.values())    # one skin, no pattern: attachments only
    assert names.index("Head") not in need


def test_keep_joints_pattern_finds_names_anywhere():
    skin = read_gltf_skin(WUSON, weld=True)
    need = joints_the_file_needs(skin, "^Tail0[12]$|Ear")
    got = sorted(skin.handles.names[h] for h in need)
    assert got == sorted(n for n in skin.handles.names if n in ("Tail01", "Tail02") or "Ear" in n)
    assert all(why == "named" for why in need.values())
    assert named_joints(["a", "b"], None) == {}


def test_a_bad_pattern_is_one_line():
    with pytest.raises(InputError, match="regular expression") as e:
        compile_keep_pattern("Hand(", "--keep-joints")
    assert e.value.field == "--keep-joints"


def test_joints_another_skin_weights_are_needed(tmp_path):
    """A second skin (the same joints, in reverse order) on a second node of the scene: every joint its
    mesh weights is needed by the first skin's levels, found through the second skin's own joint list."""
    doc = load_gltf(WUSON)
    js = copy.deepcopy(doc.json)
    sk = copy.deepcopy(js["skins"][0])
    node = next(n for n in js["nodes"] if "skin" in n)
    js["skins"].append(sk)
    js["nodes"].append({"name": "twin", "mesh": node["mesh"], "skin": 1})
    js["scenes"][js.get("scene", 0)]["nodes"].append(len(js["nodes"]) - 1)
    out = tmp_path / "two_skins.glb"
    write_pruned(out, doc, js)
    skin = read_gltf_skin(out, skin=0, weld=True)
    other = other_skin_joints(skin)
    used = set(skin.weights.nonzero()[1].tolist())
    assert set(other) == used and all(why == "used by skin 1" for why in other.values())
    # a skin whose mesh nodes are not in the scene (a writer's level nodes) counts for nothing
    js2 = json.loads(json.dumps(js))
    js2["scenes"][js2.get("scene", 0)]["nodes"].remove(len(js2["nodes"]) - 1)
    out2 = tmp_path / "hidden.glb"
    write_pruned(out2, doc, js2)
    assert other_skin_joints(read_gltf_skin(out2, skin=0, weld=True)) == {}
