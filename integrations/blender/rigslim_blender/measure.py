"""Held-out error measured by Blender itself: rigslim's weights and Blender's Limit Total, posed alike.

Before the new weights are written, two temporary copies of the mesh object are made (same
modifiers, same armature): one keeps the input weights (the reference), the other gets Blender's
own **Limit Total** (``object.vertex_group_limit_total``, deform bones, limit k) and **Normalize
All**. At every held-out frame the depsgraph deforms the three meshes and the error of each is

    e_f = 100 / D * sqrt( mean_i |x_i - x*_i|^2 )         (% of the rest bounding-box diagonal D)

as rigslim's ``position-rms`` metric defines it; the mean over frames and the largest vertex
distance are reported. The copies are removed afterwards.
"""

from __future__ import annotations

from dataclasses import dataclass

import bpy
import numpy as np

from . import scene as sc


@dataclass
class Errors:
    """Mean over held-out frames of the per-frame RMS (% of the diagonal), and the largest vertex distance (%)."""

    rms_pct: float
    max_pct: float

    def __str__(self) -> str:
        return f"{self.rms_pct:.3g} % RMS (max {self.max_pct:.3g} %)"


def temporary_copy(obj: bpy.types.Object, name: str) -> bpy.types.Object:
    """A linked-into-the-scene copy of ``obj`` with its own mesh data (removed by :func:`remove_copy`)."""
    copy = obj.copy()
    copy.data = obj.data.copy()
    copy.name = name
    bpy.context.scene.collection.objects.link(copy)
    return copy


def remove_copy(copy: bpy.types.Object) -> None:
    mesh = copy.data
    bpy.data.objects.remove(copy, do_unlink=True)
    if mesh is not None and mesh.users == 0:
        bpy.data.meshes.remove(mesh)


def limit_total(obj: bpy.types.Object, k: int) -> None:
    """Blender's own Limit Total (deform-bone groups, limit k), then Normalize All, on ``obj``.

    Blender 5.0's vertex group operators act on the view layer's selected objects whatever the
    context override says, so ``obj`` is made the only selected (and active) object meanwhile.
    """
    layer = bpy.context.view_layer
    selected = [o for o in layer.objects if o.select_get()]
    active = layer.objects.active
    try:
        for o in selected:
            o.select_set(False)
        obj.select_set(True)
        layer.objects.active = obj
        ctx = {"object": obj, "active_object": obj, "selected_objects": [obj], "selected_editable_objects": [obj]}
        with bpy.context.temp_override(**ctx):
            bpy.ops.object.vertex_group_limit_total(group_select_mode="BONE_DEFORM", limit=k)
            bpy.ops.object.vertex_group_normalize_all(group_select_mode="BONE_DEFORM", lock_active=False)
    finally:
        obj.select_set(False)
        for o in selected:
            o.select_set(True)
        layer.objects.active = active


def frame_errors(X: np.ndarray, ref: np.ndarray, diagonal: float) -> tuple[float, float]:
    """(RMS, max) vertex distance of one frame, % of ``diagonal``."""
    d = np.linalg.norm(X - ref, axis=1)
    scale = 100.0 / diagonal if diagonal > 0 else 0.0
    return float(np.sqrt(np.mean(d * d)) * scale), float(d.max(initial=0.0) * scale)


class HeldOut:
    """The reference and Limit Total copies of one object, and the errors measured over held-out frames."""

    def __init__(self, skin: sc.Skin, k: int):
        self.skin = skin
        self.reference = temporary_copy(skin.obj, f"{skin.obj.name}.rigslim-reference")
        self.limited = temporary_copy(skin.obj, f"{skin.obj.name}.rigslim-limit-total")
        limit_total(self.limited, k)
        self.rms: dict[str, list[float]] = {"rigslim": [], "limit_total": []}
        self.max: dict[str, list[float]] = {"rigslim": [], "limit_total": []}

    def measure_frame(self, depsgraph) -> None:
        """Add the current frame's errors (the scene must already be at that frame)."""
        ref = sc.evaluated_positions(self.reference, depsgraph)
        for key, ob in (("rigslim", self.skin.obj), ("limit_total", self.limited)):
            rms, mx = frame_errors(sc.evaluated_positions(ob, depsgraph), ref, self.skin.bbox_diagonal)
            self.rms[key].append(rms)
            self.max[key].append(mx)

    def errors(self, key: str) -> Errors:
        if not self.rms[key]:
            return Errors(float("nan"), float("nan"))
        return Errors(float(np.mean(self.rms[key])), float(np.max(self.max[key])))

    def remove(self) -> None:
        for ob in (self.reference, self.limited):
            try:
                remove_copy(ob)
            except ReferenceError:
                pass
