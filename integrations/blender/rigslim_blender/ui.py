# mypy: disable-error-code="valid-type"
# (bpy properties are declared as annotations that call bpy.props: Blender's idiom)
"""The add-on preferences (where rigslim is) and the panel in Properties > Object Data."""

from __future__ import annotations

import json

import bpy
from bpy.props import BoolProperty, FloatProperty, IntProperty, PointerProperty, StringProperty

from . import scene as sc


class RigslimPreferences(bpy.types.AddonPreferences):
    bl_idname = __package__

    rigslim_python: StringProperty(
        name="rigslim Python", subtype="FILE_PATH", default="",
        description="The python of an environment where rigslim is installed (e.g. ~/rigslim/.venv/bin/python), "
                    "its folder, or its rigslim command; empty: $RIGSLIM_PYTHON, then a rigslim command on PATH")

    def draw(self, context):
        col = self.layout.column()
        col.prop(self, "rigslim_python")
        col.operator("rigslim.check_installation", icon="CHECKMARK")


class RigslimSettings(bpy.types.PropertyGroup):
    """What the panel's buttons pass to the operators (stored on the mesh object)."""

    k: IntProperty(name="Influences", default=4, min=1, max=32, description="Bone influences per vertex")
    actions: StringProperty(name="Actions", default="",
                            description="Actions to fit, comma separated, each optionally NAME:START-END; "
                                        "empty: every action that poses bones")
    frame_step: IntProperty(name="Frame Step", default=1, min=1, max=100,
                            description="Sample every n-th frame of each action")
    test_actions: StringProperty(name="Held-Out Actions", default="",
                                 description="Actions only measured, never fitted; empty: every n-th frame")
    holdout: IntProperty(name="Hold Out Every", default=4, min=0, max=100,
                         description="Every n-th sampled frame is only used to measure the error")
    measure: BoolProperty(name="Compare with Limit Total", default=True)
    keep_better: BoolProperty(name="Keep Limit Total If Better", default=True,
                              description="Write Limit Total's result when it has the lower held-out error")
    ratios: StringProperty(name="Ratios", default="0.5, 0.25, 0.125",
                           description="Fraction of the faces kept by each LOD level")
    max_bones: IntProperty(name="Bone Limit", default=4, min=0, max=32,
                           description="At most this many bones per vertex in every LOD (0: no limit)")
    max_error: FloatProperty(name="Max Error %", default=0.0, min=0.0, max=100.0,
                             description="Stop each level before the surface moves farther than this, % of the "
                                         "diagonal (0: off)")


def _last(obj, key: str) -> dict | None:
    try:
        return json.loads(obj[key]) if key in obj else None
    except (TypeError, ValueError):
        return None


class DATA_PT_rigslim(bpy.types.Panel):
    bl_label = "rigslim"
    bl_space_type = "PROPERTIES"
    bl_region_type = "WINDOW"
    bl_context = "data"

    @classmethod
    def poll(cls, context):
        return sc.is_skinned(context.object)

    def draw(self, context):
        obj = context.object
        s = obj.rigslim
        layout = self.layout
        layout.use_property_split = True
        layout.use_property_decorate = False
        mod = sc.armature_modifier(obj)
        names = [a.name for a in sc.pose_actions()]
        col = layout.column(align=True)
        col.prop(s, "actions")
        col.label(text=("Fits: " + ", ".join(names)) if not s.actions.strip() and names
                  else ("No action poses bones" if not names else ""), icon="ACTION")
        col.prop(s, "frame_step")
        box = layout.box()
        box.label(text="Limit Influences", icon="GROUP_BONE")
        col = box.column()
        col.prop(s, "k")
        col.prop(s, "test_actions")
        col.prop(s, "holdout")
        col.prop(s, "measure")
        col.prop(s, "keep_better")
        op = col.operator("rigslim.limit_influences", text="Limit Influences (Fit to Animation)",
                          icon="MOD_VERTEX_WEIGHT")
        op.k, op.actions, op.frame_step, op.holdout, op.measure = s.k, s.actions, s.frame_step, s.holdout, s.measure
        op.keep_better, op.test_actions = s.keep_better, s.test_actions
        last = _last(obj, "rigslim_limit")
        if last and "rms_pct" in last:
            col.label(text=f"Last: {last['rms_pct']:.3g} % RMS vs Limit Total {last['limit_total_rms_pct']:.3g} %",
                      icon="INFO")
        box = layout.box()
        box.label(text="Skinned LODs", icon="MOD_DECIM")
        col = box.column()
        col.prop(s, "ratios")
        col.prop(s, "max_bones")
        col.prop(s, "max_error")
        op = col.operator("rigslim.generate_lods", text="Generate Skinned LODs", icon="MOD_DECIM")
        op.ratios, op.max_bones, op.actions, op.max_error = s.ratios, s.max_bones, s.actions, s.max_error
        op.frame_step = max(s.frame_step, 1)
        lods = _last(obj, "rigslim_lods")
        if lods:
            col.label(text=", ".join(f"{lv['name'].rsplit('_', 1)[-1]}: {lv['faces']}" for lv in lods["levels"]),
                      icon="INFO")
        if mod is not None and mod.use_deform_preserve_volume:
            layout.label(text="Preserve Volume is on: rigslim fits linear blend skinning", icon="ERROR")


classes = (RigslimPreferences, RigslimSettings, DATA_PT_rigslim)


def register_properties():
    bpy.types.Object.rigslim = PointerProperty(type=RigslimSettings)


def unregister_properties():
    del bpy.types.Object.rigslim
