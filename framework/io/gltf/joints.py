"""Which joints of a skin a glTF file needs at every level of detail (joint budgets, docs/gltf.md).

A joint budget (``joint_budget:`` of a ``decimate:`` step, ``rigslim lod --max-joints``) re-fits the
vertices of some joints onto others, so that a level's skin lists fewer joints. The node hierarchy and
the animation are never changed; but some joints must keep skinning their vertices, or the file would
look wrong:

- **attached**: the joint node carries a mesh, camera or light itself, or has a child node that is
  not a joint of the skin and holds no joint of it below (a socket, a prop, a rigid mesh: ``Weapon``
  under ``Hand.Left``). The attachment follows the joint; the skin around it must too.
- **other skins**: a joint that another skin of the scene gives weight to (two skinned parts of one
  character meet where both follow the same joints).
- **named**: a joint whose node name matches the user's ``keep_joints`` pattern (``re.search``).
"""

from __future__ import annotations

import re

import numpy as np

from rigslim.errors import InputError
from rigslim.io.gltf.document import read_accessor
from rigslim.io.gltf.skin import GltfSkin, skinning_sets

__all__ = ["compile_keep_pattern", "joints_the_file_needs", "named_joints", "scene_nodes"]


def compile_keep_pattern(pattern: str | None, field: str = "keep_joints") -> re.Pattern | None:
    """The compiled ``keep_joints`` regular expression (None: none); a bad one is a one-line error."""
    if pattern is None or pattern == "":
        return None
    try:
        return re.compile(pattern)
    except re.error as e:
        raise InputError(f"'{pattern}' is not a regular expression ({e})", field=field,
                         fix="give a Python regular expression, e.g. 'Head|Hand' (matched anywhere in the name)"
                         ) from None


def named_joints(names: list[str], pattern: str | None, field: str = "keep_joints") -> dict[int, str]:
    """Handle index -> ``"named"`` for every joint name the pattern finds (``re.search``)."""
    rx = compile_keep_pattern(pattern, field)
    if rx is None:
        return {}
    return {i: "named" for i, name in enumerate(names) if rx.search(str(name))}


def scene_nodes(js: dict) -> list[int]:
    """Nodes of the default scene, depth first (every node when the file has no scene)."""
    nodes = js.get("nodes", [])
    scenes = js.get("scenes", [])
    if not scenes:
        return list(range(len(nodes)))
    scene = scenes[js.get("scene", 0)] if isinstance(js.get("scene", 0), int) else scenes[0]
    order, stack, seen = [], list(reversed(scene.get("nodes", []))), set()
    while stack:
        i = stack.pop()
        if i in seen:
            continue
        seen.add(i)
        order.append(i)
        stack.extend(reversed(nodes[i].get("children", [])))
    return order


def _subtree_has(js: dict, root: int, wanted: set[int]) -> bool:
    nodes = js["nodes"]
    stack = [root]
    seen = set()
    while stack:
        i = stack.pop()
        if i in seen:
            continue
        seen.add(i)
        if i in wanted:
            return True
        stack.extend(nodes[i].get("children", []))
    return False


def attached_joints(skin: GltfSkin) -> dict[int, str]:
    """Handle index -> reason for joints with a mesh, camera or light, or an attached child (module docstring).

    Nodes that instantiate a mesh with *this* skin are not attachments (a skinned mesh ignores its node's
    transform), nor are the level nodes a writer added (not in the default scene).
    """
    js = skin.document.json
    nodes = js.get("nodes", [])
    joint_set = set(skin.joints)
    shown = set(scene_nodes(js))
    out: dict[int, str] = {}
    for h, j in enumerate(skin.joints):
        node = nodes[j]
        if "mesh" in node and node.get("skin") != skin.skin:
            out[h] = "attached: the joint node holds a mesh"
            continue
        if "camera" in node or "KHR_lights_punctual" in node.get("extensions", {}):
            out[h] = "attached: the joint node holds a camera or light"
            continue
        for c in node.get("children", []):
            child = nodes[c]
            if c in joint_set or c not in shown:
                continue
            if "mesh" in child and child.get("skin") == skin.skin:
                continue
            if not _subtree_has(js, c, joint_set):
                out[h] = f"attached: node '{child.get('name', c)}' hangs from it"
                break
    return out


def other_skin_joints(skin: GltfSkin) -> dict[int, str]:
    """Handle index -> reason for joints that another skin of the default scene gives non-zero weight to."""
    doc, js = skin.document, skin.document.json
    nodes = js.get("nodes", [])
    joint_of = {node: h for h, node in enumerate(skin.joints)}
    out: dict[int, str] = {}
    done = set()
    for i in scene_nodes(js):
        node = nodes[i]
        s = node.get("skin")
        if s is None or "mesh" not in node or s == skin.skin or (s, node["mesh"]) in done:
            continue
        done.add((s, node["mesh"]))
        joints = js["skins"][s]["joints"]
        for prim in js["meshes"][node["mesh"]].get("primitives", []):
            attrs = prim.get("attributes", {})
            for n in skinning_sets(attrs):
                J = np.asarray(read_accessor(doc, attrs[f"JOINTS_{n}"]), np.int64).reshape(-1)
                W = np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{n}"]), float).reshape(-1)
                for local in np.unique(J[(W != 0) & (J >= 0) & (J < len(joints))]):
                    h = joint_of.get(int(joints[int(local)]))
                    if h is not None:
                        out.setdefault(h, f"used by skin {s}")
    return out


def joints_the_file_needs(skin: GltfSkin, keep_joints: str | None = None) -> dict[int, str]:
    """Handle index -> why the joint must keep its vertices at every level (module docstring).

    Parameters
    ----------
    skin : GltfSkin
        The skin read (:func:`rigslim.io.gltf.skin.read_gltf_skin`).
    keep_joints : str, optional
        A regular expression; joints whose node name it finds are kept too.
    """
    out = named_joints(list(skin.handles.names), keep_joints)
    for h, why in {**other_skin_joints(skin), **attached_joints(skin)}.items():
        out.setdefault(h, why)
    return dict(sorted(out.items()))
