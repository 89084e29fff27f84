"""A skinned test character built with bpy: a tube on a chain of bones, dense weights, two actions.

Run inside Blender's Python (the ``bpy`` module): the tube has ``rings x segments`` vertices on a
UV-mapped cylinder with a seam, two materials (lower and upper half), and weights that fall off as
``exp(-((z - c_b) / sigma)^2)`` over every bone, so each vertex has up to ``n_bones`` influences.
"Bend" bends the chain about X, "Twist" twists it about its axis while bending about Y.
"""

from __future__ import annotations

import math

import bpy
import numpy as np


def tube_mesh(name: str, rings: int, segments: int, length: float, radius: float) -> bpy.types.Mesh:
    verts, faces, uvs = [], [], []
    for r in range(rings):
        z = length * r / (rings - 1)
        for s in range(segments):
            a = 2 * math.pi * s / segments
            verts.append((radius * math.cos(a), radius * math.sin(a), z))
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            faces.append((a, b, b + segments, a + segments))
            u0, u1 = s / segments, (s + 1) / segments          # the last column wraps to u = 1: a UV seam
            v0, v1 = r / (rings - 1), (r + 1) / (rings - 1)
            uvs += [(u0, v0), (u1, v0), (u1, v1), (u0, v1)]
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata(verts, [], faces)
    uv = mesh.uv_layers.new(name="UVMap")
    uv.data.foreach_set("uv", np.asarray(uvs, np.float32).ravel())
    for poly in mesh.polygons:
        poly.use_smooth = True
        poly.material_index = 0 if poly.center.z < length / 2 else 1
    mesh.update()
    return mesh


def build(n_bones: int = 6, rings: int = 25, segments: int = 16, length: float = 4.0, sigma: float = 0.55,
          frames: int = 40) -> tuple[bpy.types.Object, bpy.types.Object]:
    """A fresh scene with the tube ``Tube`` on the armature ``Rig`` and actions ``Bend`` and ``Twist``."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    arm_data = bpy.data.armatures.new("Rig")
    rig = bpy.data.objects.new("Rig", arm_data)
    scene.collection.objects.link(rig)
    bpy.context.view_layer.objects.active = rig
    bpy.ops.object.mode_set(mode="EDIT")
    step = length / n_bones
    parent = None
    for i in range(n_bones):
        eb = arm_data.edit_bones.new(f"Bone{i}")
        eb.head, eb.tail = (0, 0, i * step), (0, 0, (i + 1) * step)
        if parent is not None:
            eb.parent, eb.use_connect = parent, True
        parent = eb
    bpy.ops.object.mode_set(mode="OBJECT")
    mesh = tube_mesh("Tube", rings, segments, length, 0.4)
    for name, colour in (("Lower", (0.8, 0.3, 0.2, 1)), ("Upper", (0.2, 0.4, 0.8, 1))):
        mat = bpy.data.materials.new(name)
        mat.diffuse_color = colour
        mesh.materials.append(mat)
    tube = bpy.data.objects.new("Tube", mesh)
    scene.collection.objects.link(tube)
    tube.parent = rig
    mod = tube.modifiers.new("Armature", "ARMATURE")
    mod.object = rig
    centres = (np.arange(n_bones) + 0.5) * step
    groups = [tube.vertex_groups.new(name=f"Bone{i}") for i in range(n_bones)]
    for v in mesh.vertices:
        w = np.exp(-((v.co.z - centres) / sigma) ** 2)
        w /= w.sum()
        for g, x in zip(groups, w, strict=True):
            if x > 1e-3:
                g.add([v.index], float(x), "REPLACE")
    rig.animation_data_create()
    for name, axes in (("Bend", ((1.0, 0.0, 0.0), None)), ("Twist", ((0.0, 0.6, 0.0), (0.0, 1.0, 0.0)))):
        action = bpy.data.actions.new(name)
        action.use_fake_user = True
        rig.animation_data.action = action
        for f in range(1, frames + 1):
            t = (f - 1) / (frames - 1)
            for i, pb in enumerate(rig.pose.bones):
                pb.rotation_mode = "XYZ"
                bend = math.sin(2 * math.pi * t + i * 0.7) * 0.5
                twist = math.sin(2 * math.pi * t * 1.5 + i) * 0.8 if axes[1] else 0.0
                pb.rotation_euler = (axes[0][0] * bend, twist, axes[0][1] * bend)
                pb.keyframe_insert("rotation_euler", frame=f)
    rig.animation_data.action = bpy.data.actions["Bend"]
    scene.frame_start, scene.frame_end = 1, frames
    scene.frame_set(1)
    return tube, rig
