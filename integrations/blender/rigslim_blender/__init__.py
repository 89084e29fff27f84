"""rigslim for Blender: Limit Influences fitted to the animation, and Generate Skinned LODs.

Object Data properties of a skinned mesh > rigslim. rigslim itself runs out of process, in the
Python installation named in the add-on's preferences (docs/blender.md).
"""

from __future__ import annotations

import bpy

from . import operators, ui

_classes = ui.classes + operators.classes


def menu_func(self, context):
    self.layout.separator()
    self.layout.operator(operators.RIGSLIM_OT_limit_influences.bl_idname)
    self.layout.operator(operators.RIGSLIM_OT_generate_lods.bl_idname)


def register():
    for cls in _classes:
        bpy.utils.register_class(cls)
    ui.register_properties()
    bpy.types.VIEW3D_MT_object.append(menu_func)


def unregister():
    bpy.types.VIEW3D_MT_object.remove(menu_func)
    ui.unregister_properties()
    for cls in reversed(_classes):
        bpy.utils.unregister_class(cls)
