"""Reading a skinned mesh from Blender: rest mesh, deform weights, and bone transforms per frame.

Blender's Armature modifier (linear blend, "Preserve Volume" off) moves a vertex v of the mesh
object as

    v' = v + sum_b w_b (T_b v - v) / sum_b w_b,      T_b = S^-1 P_b B_b^-1 S,   S = A^-1 M

with ``P_b`` the evaluated pose matrix of bone b and ``B_b`` its rest matrix (both in armature
space), A and M the armature's and mesh's world matrices, and the sum over the vertex groups of
deforming bones (weights are normalised at run time; a vertex with none does not move). So the
handle transforms rigslim fits to are the 3 x 4 rows of ``T_b`` in the mesh object's local space,
read for every sampled frame from the depsgraph (constraints, drivers and IK included), and the
weights are the groups' weights divided by their sum.
"""

from __future__ import annotations

import contextlib
import re
from dataclasses import dataclass, field

import bpy
import numpy as np


class SkinError(Exception):
    """A one-line problem with the selected object (shown in Blender)."""


@dataclass
class Skin:
    """The linear blend skin of one mesh object, as rigslim reads it.

    Attributes
    ----------
    obj, armature : the mesh object and the armature object its Armature modifier uses
    bones : names of the n handles (deforming bones that have a vertex group here), in group order
    groups : (n,) vertex group index of each handle
    V : (m, 3) rest positions (mesh local space); F, L : (f, 3) triangles by vertex and by loop
    tri_poly : (f,) polygon of each triangle
    rows, cols, values : the (m, n) weights as triplets, every weighted row summing to one
    unweighted : (m,) bool, vertices with no deform weight (Blender leaves them at rest)
    warnings : things the fit cannot model exactly (preserve volume, modifiers before the armature)
    """

    obj: bpy.types.Object
    armature: bpy.types.Object
    bones: list[str]
    groups: np.ndarray
    V: np.ndarray
    F: np.ndarray
    L: np.ndarray
    tri_poly: np.ndarray
    rows: np.ndarray
    cols: np.ndarray
    values: np.ndarray
    unweighted: np.ndarray
    warnings: list[str] = field(default_factory=list)

    @property
    def n_vertices(self) -> int:
        return len(self.V)

    @property
    def bbox_diagonal(self) -> float:
        return float(np.linalg.norm(self.V.max(axis=0) - self.V.min(axis=0))) if len(self.V) else 0.0

    def max_influences(self) -> int:
        return int(np.bincount(self.rows, minlength=self.n_vertices).max(initial=0))


def armature_modifier(obj: bpy.types.Object) -> bpy.types.ArmatureModifier | None:
    """The first enabled Armature modifier with an armature object, or None."""
    for mod in obj.modifiers:
        if mod.type == "ARMATURE" and mod.object is not None and mod.show_viewport:
            return mod
    return None


def is_skinned(obj: bpy.types.Object | None) -> bool:
    return obj is not None and obj.type == "MESH" and armature_modifier(obj) is not None


def _check_modifier(obj: bpy.types.Object, mod) -> list[str]:
    if not mod.use_vertex_groups:
        raise SkinError(f"{obj.name}: its Armature modifier '{mod.name}' does not use vertex groups; "
                        "enable Bind To > Vertex Groups")
    if mod.use_bone_envelopes:
        raise SkinError(f"{obj.name}: its Armature modifier '{mod.name}' binds to bone envelopes, which rigslim "
                        "cannot fit; turn Bind To > Bone Envelopes off (weights only)")
    warnings = []
    if mod.use_deform_preserve_volume:
        warnings.append("Preserve Volume (dual quaternions) is on; rigslim fits linear blend skinning")
    if mod.vertex_group:
        warnings.append(f"the modifier's mask group '{mod.vertex_group}' is ignored by the fit")
    before = [m.name for m in obj.modifiers[:list(obj.modifiers).index(mod)] if m.show_viewport]
    if before:
        warnings.append("modifiers before the Armature modifier (" + ", ".join(before)
                        + ") are not part of the rest mesh rigslim fits")
    return warnings


def read_skin(obj: bpy.types.Object) -> Skin:
    """The rest mesh, triangles and normalised deform weights of a skinned mesh object.

    Raises
    ------
    SkinError
        Not a mesh with an Armature modifier, or no vertex group of a deforming bone.
    """
    if obj.type != "MESH":
        raise SkinError(f"{obj.name} is a {obj.type.lower()}, not a mesh; select skinned meshes")
    mod = armature_modifier(obj)
    if mod is None:
        raise SkinError(f"{obj.name} has no Armature modifier with an armature; add one (Ctrl+P > With Automatic "
                        "Weights) before limiting influences")
    warnings = _check_modifier(obj, mod)
    arm = mod.object
    deform = {b.name for b in arm.data.bones if b.use_deform}
    handles = [(vg.index, vg.name) for vg in obj.vertex_groups if vg.name in deform]
    if not handles:
        raise SkinError(f"{obj.name} has no vertex group named after a deforming bone of {arm.name}; "
                        "weight paint it or parent it With Automatic Weights")
    mesh = obj.data
    m = len(mesh.vertices)
    flat = np.empty(m * 3, np.float64)
    mesh.vertices.foreach_get("co", flat)
    V = flat.reshape(m, 3)
    mesh.calc_loop_triangles()
    nt = len(mesh.loop_triangles)
    F = np.empty(nt * 3, np.int64)
    L = np.empty(nt * 3, np.int64)
    P = np.empty(nt, np.int64)
    mesh.loop_triangles.foreach_get("vertices", F)
    mesh.loop_triangles.foreach_get("loops", L)
    mesh.loop_triangles.foreach_get("polygon_index", P)
    if nt == 0:
        raise SkinError(f"{obj.name} has no faces")
    column = {gi: c for c, (gi, _) in enumerate(handles)}
    rows, cols, vals = [], [], []
    for v in mesh.vertices:
        for g in v.groups:
            c = column.get(g.group)
            if c is not None and g.weight > 0.0:
                rows.append(v.index)
                cols.append(c)
                vals.append(g.weight)
    rows_a, cols_a = np.asarray(rows, np.int64), np.asarray(cols, np.int64)
    vals_a = np.asarray(vals, np.float64)
    total = np.bincount(rows_a, weights=vals_a, minlength=m)
    unweighted = total <= 1e-4                       # Blender's armature deform skips these (contrib <= 1e-4)
    keep = ~unweighted[rows_a]
    rows_a, cols_a, vals_a = rows_a[keep], cols_a[keep], vals_a[keep] / total[rows_a[keep]]
    if unweighted.all():
        raise SkinError(f"{obj.name}: no vertex has a weight in a deforming bone's group")
    return Skin(obj, arm, [name for _, name in handles], np.array([gi for gi, _ in handles], np.int64), V,
                F.reshape(nt, 3), L.reshape(nt, 3), P, rows_a, cols_a, vals_a, unweighted, warnings)


# --------------------------------------------------------------------------- actions and frames


def action_fcurves(action: bpy.types.Action):
    """Every F-curve of an action, legacy (Blender 4.2-4.3) or slotted/layered (4.4 and later)."""
    legacy = getattr(action, "fcurves", None)
    if legacy is not None and len(legacy):
        return list(legacy)
    out = []
    for layer in getattr(action, "layers", []):
        for strip in layer.strips:
            for bag in getattr(strip, "channelbags", []):
                out.extend(bag.fcurves)
    return out


def animates_pose(action: bpy.types.Action) -> bool:
    """Whether an action has an F-curve on a pose bone."""
    return any(fc.data_path.startswith("pose.bones[") for fc in action_fcurves(action))


def pose_actions() -> list[bpy.types.Action]:
    return [a for a in bpy.data.actions if animates_pose(a)]


_RANGE = re.compile(r"^(?P<name>.*?)(?::(?P<start>-?\d+)-(?P<end>-?\d+))?$")


def parse_actions(spec: str) -> list[tuple[bpy.types.Action, int | None, int | None]]:
    """``"Walk, Run:10-40"`` -> actions with optional frame ranges ("" -> every action that poses bones).

    Raises
    ------
    SkinError
        An unknown action name, or a range whose end is before its start.
    """
    out = []
    if not spec.strip():
        return [(a, None, None) for a in pose_actions()]
    for item in (s.strip() for s in spec.split(",")):
        if not item:
            continue
        mt = _RANGE.match(item)
        assert mt is not None
        name = mt["name"].strip()
        action = bpy.data.actions.get(name)
        if action is None:
            have = ", ".join(a.name for a in pose_actions()) or "none"
            raise SkinError(f"actions: no action named '{name}' (actions that pose bones: {have})")
        start = int(mt["start"]) if mt["start"] is not None else None
        end = int(mt["end"]) if mt["end"] is not None else None
        if start is not None and end is not None and end < start:
            raise SkinError(f"actions: '{item}' ends before it starts; write NAME:START-END with START <= END")
        out.append((action, start, end))
    return out


def sample_frames(actions, step: int, holdout: int) -> tuple[list, list]:
    """Example and held-out ``(action, frame)`` pairs: every ``step``-th frame, every ``holdout``-th held out.

    Held-out samples interleave the examples (sample ``i`` is held out when ``i % holdout == holdout // 2``),
    so no frame is used for both fitting and measuring.
    """
    examples: list = []
    test: list = []
    i = 0
    for action, start, end in actions:
        a0, a1 = action.frame_range
        first = int(round(a0)) if start is None else start
        last = int(round(a1)) if end is None else end
        for f in range(first, last + 1, max(1, step)):
            (test if holdout > 1 and i % holdout == holdout // 2 else examples).append((action, f))
            i += 1
    return examples, test


@contextlib.contextmanager
def preserved_animation(scene: bpy.types.Scene, armature: bpy.types.Object):
    """Restore the scene frame and the armature's action (and slot) whatever happens inside."""
    frame, sub = scene.frame_current, scene.frame_subframe
    ad = armature.animation_data
    action = ad.action if ad else None
    slot = getattr(ad, "action_slot", None) if ad else None
    try:
        yield
    finally:
        if armature.animation_data is not None:
            armature.animation_data.action = action
            if slot is not None and hasattr(armature.animation_data, "action_slot"):
                with contextlib.suppress(Exception):
                    armature.animation_data.action_slot = slot
        scene.frame_set(frame, subframe=sub)


def set_action(armature: bpy.types.Object, action: bpy.types.Action) -> None:
    """Make ``action`` the armature's active action (choosing an object slot on Blender 4.4+)."""
    ad = armature.animation_data or armature.animation_data_create()
    if ad.action is not action:
        ad.action = action
    if hasattr(ad, "action_slot") and ad.action_slot is None:
        slots = [s for s in getattr(action, "slots", []) if getattr(s, "target_id_type", "OBJECT") == "OBJECT"]
        if slots:
            ad.action_slot = slots[0]


def go_to(scene: bpy.types.Scene, armature: bpy.types.Object, action, frame: int) -> None:
    set_action(armature, action)
    scene.frame_set(frame)


def _matrix(m) -> np.ndarray:
    return np.array([list(row) for row in m], np.float64)


def bone_transforms(skin: Skin, depsgraph) -> np.ndarray:
    """(n, 3, 4) handle transforms ``T_b`` of the current frame, in the mesh's local space (module notes)."""
    arm = skin.armature.evaluated_get(depsgraph)
    obj = skin.obj.evaluated_get(depsgraph)
    S = np.linalg.inv(_matrix(arm.matrix_world)) @ _matrix(obj.matrix_world)
    Si = np.linalg.inv(S)
    out = np.empty((len(skin.bones), 3, 4))
    rest = skin.armature.data.bones
    for i, name in enumerate(skin.bones):
        P = _matrix(arm.pose.bones[name].matrix)
        B = _matrix(rest[name].matrix_local)
        out[i] = (Si @ P @ np.linalg.inv(B) @ S)[:3]
    return out


def evaluated_positions(obj: bpy.types.Object, depsgraph) -> np.ndarray:
    """(m, 3) vertex positions of the evaluated (deformed) mesh, local space."""
    ev = obj.evaluated_get(depsgraph)
    mesh = ev.to_mesh()
    try:
        X = np.empty(len(mesh.vertices) * 3, np.float64)
        mesh.vertices.foreach_get("co", X)
    finally:
        ev.to_mesh_clear()
    return X.reshape(-1, 3)


def split_frames(actions: str, test_actions: str, step: int, holdout: int) -> tuple[list, list]:
    """Example and held-out ``(action, frame)`` pairs from the operators' action properties.

    With ``test_actions`` empty, :func:`sample_frames` over ``actions`` (every ``holdout``-th sample held out).
    Otherwise the test actions' frames are the held-out set and every sample of the other chosen actions is
    fitted (no action is in both: one fitted on a clip, measured on another, as rigslim's clip splits do).
    """
    if not test_actions.strip():
        return sample_frames(parse_actions(actions), step, holdout)
    test = parse_actions(test_actions)
    held = {a.name for a, _, _ in test}
    fit = [item for item in parse_actions(actions) if item[0].name not in held]
    return sample_frames(fit, step, 0)[0], sample_frames(test, step, 0)[0]
