"""Blender-side half of benchmarks/blender_extension.py: render the extension's results with Workbench.

Run with the Python of .venv-blender (the bpy module), after ``--`` or directly:

    python benchmarks/blender_render.py --zip Z --rigslim-python P --out DIR [--gltf FILE] [--k 2]

Writes into DIR, for one character at the held-out frame where Blender's Limit Total errs most:
``input.png``, ``limit_total.png``, ``rigslim.png`` and ``rigslim_best_fit.png`` coloured by each
vertex's distance to the input-weight pose (one scale, 0 to Limit Total's largest distance), then
``lod0.png`` .. ``lodN.png`` (the full mesh and each NAME_LODi posed at that frame, wireframe on
top), and ``figures.json`` (the frame, the colour scale, the faces of each level).
"""

from __future__ import annotations

import argparse
import json
import math
import os
import sys

import bpy
import mathutils
import numpy as np

sys.path.insert(0, os.path.join(os.path.dirname(os.path.abspath(__file__)), "..", "tests", "support"))
import blender_driver  # noqa: E402


def heat(t: np.ndarray) -> np.ndarray:
    """(m, 4) colours from 0 (dark blue) through green and yellow to 1 (red)."""
    stops = np.array([[0.05, 0.1, 0.45], [0.1, 0.6, 0.35], [0.95, 0.85, 0.1], [0.85, 0.1, 0.05]])
    x = np.clip(t, 0, 1) * (len(stops) - 1)
    i = np.minimum(x.astype(int), len(stops) - 2)
    f = (x - i)[:, None]
    rgb = stops[i] * (1 - f) + stops[i + 1] * f
    return np.c_[rgb, np.ones(len(t))]


def paint(obj, values: np.ndarray) -> None:
    mesh = obj.data
    attr = mesh.color_attributes.get("rigslim_error") or mesh.color_attributes.new("rigslim_error", "FLOAT_COLOR",
                                                                                    "POINT")
    attr.data.foreach_set("color", values.astype(np.float32).ravel())
    mesh.color_attributes.active_color = attr


def setup_render(scene, objs, res=(520, 520)) -> None:
    scene.render.engine = "BLENDER_WORKBENCH"
    scene.render.resolution_x, scene.render.resolution_y = res
    scene.render.film_transparent = False
    scene.display.shading.light = "STUDIO"
    scene.world = scene.world or bpy.data.worlds.new("World")
    scene.world.color = (1, 1, 1)
    dg = bpy.context.evaluated_depsgraph_get()
    pts = []
    for ob in objs:
        ev = ob.evaluated_get(dg)
        me = ev.to_mesh()
        pts += [ev.matrix_world @ v.co for v in me.vertices]
        ev.to_mesh_clear()
    P = np.array([tuple(p) for p in pts])
    lo, hi = P.min(axis=0), P.max(axis=0)
    centre = mathutils.Vector(((lo + hi) / 2).tolist())
    size = float(np.linalg.norm(hi - lo))
    cam = scene.camera
    if cam is None:
        cam = bpy.data.objects.new("DocCamera", bpy.data.cameras.new("DocCamera"))
        scene.collection.objects.link(cam)
        scene.camera = cam
    cam.data.lens = 50
    cam.data.clip_start, cam.data.clip_end = size * 1e-3, size * 10
    direction = mathutils.Vector((1.0, -1.3, 0.45)).normalized()
    cam.location = centre + direction * size * 1.55
    cam.rotation_euler = (centre - cam.location).to_track_quat("-Z", "Y").to_euler()


def render(scene, path: str, show: list) -> None:
    for ob in scene.objects:
        if ob.type == "MESH":
            ob.hide_render = ob not in show
    scene.render.filepath = path
    bpy.ops.render.render(write_still=True)


def wire_copy(obj):
    """A copy drawn as black edges on top (Wireframe modifier after the armature)."""
    w = obj.copy()
    w.data = obj.data.copy()
    bpy.context.scene.collection.objects.link(w)
    mod = w.modifiers.new("Wire", "WIREFRAME")
    diag = float(np.linalg.norm(np.ptp(np.array([v.co[:] for v in obj.data.vertices]), axis=0)))
    mod.thickness = diag * 0.002
    mod.use_replace = True
    mat = bpy.data.materials.get("DocWire") or bpy.data.materials.new("DocWire")
    mat.diffuse_color = (0.05, 0.05, 0.05, 1)
    w.data.materials.clear()
    w.data.materials.append(mat)
    return w


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zip", required=True)
    ap.add_argument("--rigslim-python", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--gltf", default=None)
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--ratios", default="0.5, 0.25")
    ap.add_argument("--max-bones", type=int, default=4)
    args = ap.parse_args(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
    os.makedirs(args.out, exist_ok=True)
    if args.gltf:
        obj, arm = blender_driver.gltf_character(args.gltf)
    else:
        import blender_scene

        obj, arm = blender_scene.build()
    module = blender_driver.install(args.zip)
    import importlib

    ext = importlib.import_module(module)
    bpy.context.preferences.addons[module].preferences.rigslim_python = args.rigslim_python
    scene = bpy.context.scene
    meas = ext.measure
    ref = meas.temporary_copy(obj, "Input")
    lt = meas.temporary_copy(obj, "LimitTotal")
    meas.limit_total(lt, args.k)
    best = meas.temporary_copy(obj, "BestFit")
    blender_driver.select_only(best)
    bpy.ops.rigslim.limit_influences(k=args.k, holdout=4, measure=False, select="best-fit")
    blender_driver.select_only(obj)
    bpy.ops.rigslim.limit_influences(k=args.k, holdout=4, measure=False)
    _, test = ext.scene.sample_frames(ext.scene.parse_actions(""), 1, 4)
    skin = ext.scene.read_skin(ref)
    D = skin.bbox_diagonal
    worst, worst_err = test[0], -1.0
    with ext.scene.preserved_animation(scene, arm):
        for action, frame in test:
            ext.scene.go_to(scene, arm, action, frame)
            dg = bpy.context.evaluated_depsgraph_get()
            e = np.linalg.norm(ext.scene.evaluated_positions(lt, dg) - ext.scene.evaluated_positions(ref, dg), axis=1)
            if e.max() > worst_err:
                worst, worst_err = (action, frame), float(e.max())
    ext.scene.go_to(scene, arm, *worst)
    dg = bpy.context.evaluated_depsgraph_get()
    X = ext.scene.evaluated_positions(ref, dg)
    errors = {}
    for name, ob in (("input", ref), ("limit_total", lt), ("rigslim", obj), ("rigslim_best_fit", best)):
        d = np.linalg.norm(ext.scene.evaluated_positions(ob, dg) - X, axis=1)
        errors[name] = {"rms_pct": float(np.sqrt(np.mean(d * d)) * 100 / D), "max_pct": float(d.max() * 100 / D)}
        paint(ob, heat(d / worst_err if worst_err > 0 else d))
    scene.display.shading.color_type = "VERTEX"
    setup_render(scene, [ref])
    for name, ob in (("input", ref), ("limit_total", lt), ("rigslim", obj), ("rigslim_best_fit", best)):
        render(scene, os.path.join(args.out, f"{name}.png"), [ob])
    for ob in (ref, lt, best):
        meas.remove_copy(ob)
    blender_driver.select_only(obj)
    bpy.ops.rigslim.generate_lods(ratios=args.ratios, max_bones=args.max_bones)
    ext.scene.go_to(scene, arm, *worst)
    scene.display.shading.color_type = "MATERIAL"
    levels = [obj] + sorted(obj.children, key=lambda c: c.name)
    faces = []
    for i, ob in enumerate(levels):
        w = wire_copy(ob)
        render(scene, os.path.join(args.out, f"lod{i}.png"), [ob, w])
        meas.remove_copy(w)
        faces.append({"name": ob.name, "faces": len(ob.data.polygons),
                      "triangles": sum(len(p.vertices) - 2 for p in ob.data.polygons)})
    with open(os.path.join(args.out, "figures.json"), "w") as fh:
        json.dump({"object": obj.name, "action": worst[0].name, "frame": worst[1], "k": args.k,
                   "colour_scale_pct": worst_err * 100 / D, "errors_at_frame": errors, "levels": faces,
                   "max_bones": args.max_bones, "blender": bpy.app.version_string,
                   "diagonal": D, "camera_fov_deg": math.degrees(scene.camera.data.angle)}, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
