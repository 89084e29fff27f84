"""Drive the rigslim Blender extension headless; run with the Python of .venv-blender (the bpy module).

    python blender_driver.py --zip dist/rigslim-0.1.0.zip --rigslim-python .venv/bin/python --out result.json

Builds the test scene (tests/support/blender_scene.py) or imports a glTF character with Blender's own
importer (``--gltf``), installs the zip as a user extension (``BLENDER_USER_RESOURCES`` should point at
a temporary folder), runs both operators and writes what the tests assert on as JSON:

- ``limit``: the operator's record, and the same comparison measured here independently: a copy of the
  mesh keeps the input weights, another gets Blender's Limit Total + Normalize All (run here), and all
  three are posed by Blender's depsgraph at the held-out frames;
- ``groups``: deform groups per vertex and weight sums after the operator;
- ``lods``: for each child NAME_LODi, its faces, vertex groups, materials, UV range, bones per vertex,
  and how far its posed vertices lie from the posed full mesh;
- ``errors``: the one-line messages of a missing rigslim and of a bad action name.
"""

from __future__ import annotations

import argparse
import json
import os
import sys

import bpy
import mathutils.kdtree
import numpy as np

sys.path.insert(0, os.path.dirname(os.path.abspath(__file__)))


def install(zip_path: str):
    bpy.ops.extensions.package_install_files(filepath=zip_path, repo="user_default", enable_on_install=True)
    module = "bl_ext.user_default.rigslim"
    if module not in bpy.context.preferences.addons:
        raise SystemExit(f"the extension {zip_path} did not install as {module}")
    return module


def select_only(obj) -> None:
    for o in bpy.context.view_layer.objects:
        o.select_set(o is obj)
    bpy.context.view_layer.objects.active = obj


def gltf_character(path: str):
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=path)
    meshes = [o for o in bpy.context.scene.objects if o.type == "MESH"
              and any(m.type == "ARMATURE" for m in o.modifiers)]
    if not meshes:
        raise SystemExit(f"{path}: no skinned mesh after import")
    # the mesh with the most vertices blended by two or more bones (where limiting can change something)
    obj = max(meshes, key=lambda o: (sum(len(v.groups) > 1 for v in o.data.vertices), len(o.data.vertices)))
    arm = next(m.object for m in obj.modifiers if m.type == "ARMATURE")
    for a in bpy.data.actions:
        a.use_fake_user = True
    return obj, arm


def measure_independently(ext, obj, ref, lt, test) -> dict:
    sc = ext.scene
    D = float(np.linalg.norm(np.ptp(sc.read_skin(ref).V, axis=0)))
    out: dict[str, list[float]] = {"rigslim": [], "limit_total": [], "rigslim_max": [], "limit_total_max": []}
    skin = sc.read_skin(ref)
    with sc.preserved_animation(bpy.context.scene, skin.armature):
        for action, frame in test:
            sc.go_to(bpy.context.scene, skin.armature, action, frame)
            dg = bpy.context.evaluated_depsgraph_get()
            X = sc.evaluated_positions(ref, dg)
            for key, ob in (("rigslim", obj), ("limit_total", lt)):
                d = np.linalg.norm(sc.evaluated_positions(ob, dg) - X, axis=1)
                out[key].append(float(np.sqrt(np.mean(d * d)) * 100 / D))
                out[key + "_max"].append(float(d.max() * 100 / D))
    return {"rms_pct": float(np.mean(out["rigslim"])), "limit_total_rms_pct": float(np.mean(out["limit_total"])),
            "max_pct": float(np.max(out["rigslim_max"])), "limit_total_max_pct": float(np.max(out["limit_total_max"])),
            "frames": len(test)}


def group_stats(ext, obj) -> dict:
    count, total = ext.weights.deform_counts(obj)
    weighted = count > 0
    return {"max_groups": int(count.max()), "weighted": int(weighted.sum()), "vertices": len(count),
            "max_sum_error": float(np.abs(total[weighted] - 1).max(initial=0.0))}


def lod_stats(ext, obj, arm, frame_spec) -> list[dict]:
    sc = ext.scene
    out = []
    bones = {b.name for b in arm.data.bones if b.use_deform}
    for child in sorted(obj.children, key=lambda c: c.name):
        me = child.data
        count, total = ext.weights.deform_counts(child)
        uv = np.empty(len(me.loops) * 2)
        if me.uv_layers:
            me.uv_layers[0].data.foreach_get("uv", uv)
        mats = np.empty(len(me.polygons), np.int64)
        me.polygons.foreach_get("material_index", mats)
        action, frame = frame_spec
        with sc.preserved_animation(bpy.context.scene, arm):
            sc.go_to(bpy.context.scene, arm, action, frame)
            dg = bpy.context.evaluated_depsgraph_get()
            full = sc.evaluated_positions(obj, dg)
            lod = sc.evaluated_positions(child, dg)
        rest = np.empty(len(me.vertices) * 3)
        me.vertices.foreach_get("co", rest)
        D = float(np.linalg.norm(np.ptp(full, axis=0)))
        tree = mathutils.kdtree.KDTree(len(full))
        for i, p in enumerate(full):
            tree.insert(p, i)
        tree.balance()
        near = np.array([tree.find(p)[2] for p in lod])
        out.append({
            "name": child.name, "parent": child.parent.name, "faces": len(me.polygons), "vertices": len(me.vertices),
            "groups": sorted(vg.name for vg in child.vertex_groups), "groups_are_bones": all(
                vg.name in bones for vg in child.vertex_groups),
            "max_groups": int(count.max()), "max_sum_error": float(np.abs(total - 1).max()),
            "materials": [m.name for m in me.materials], "material_indices": sorted(set(mats.tolist())),
            "uv_layers": [u.name for u in me.uv_layers], "uv_finite": bool(np.isfinite(uv).all()),
            "uv_min": float(uv.min()), "uv_max": float(uv.max()),
            "armature": next((m.object.name for m in child.modifiers if m.type == "ARMATURE"), None),
            "posed_moved": float(np.abs(lod - rest.reshape(-1, 3)).max()),
            "posed_distance_pct": float(np.max(near) * 100 / D),
            "valid": not me.validate(verbose=False)})
    return out


def expect_error(fn) -> str:
    try:
        fn()
    except RuntimeError as exc:
        return str(exc).strip()
    return ""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--zip", required=True)
    ap.add_argument("--rigslim-python", required=True)
    ap.add_argument("--out", required=True)
    ap.add_argument("--gltf", default=None)
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--ratios", default="0.5, 0.25")
    ap.add_argument("--max-bones", type=int, default=2)
    ap.add_argument("--actions", default="")
    ap.add_argument("--frame-step", type=int, default=1)
    ap.add_argument("--max-error", type=float, default=0.05, help="for the bounded LOD run, % of the diagonal")
    ap.add_argument("--select", default="")
    ap.add_argument("--solve", default="")
    ap.add_argument("--skip-lods", action="store_true")
    ap.add_argument("--test-actions", default="", help="held-out actions (empty: every 4th frame)")
    ap.add_argument("--no-keep-better", action="store_true", help="measure the raw fit (never keep Limit Total)")
    ap.add_argument("--blend", default=None, help="also save the scene there")
    args = ap.parse_args(sys.argv[sys.argv.index("--") + 1:] if "--" in sys.argv else sys.argv[1:])
    if args.gltf:
        obj, arm = gltf_character(args.gltf)
    else:
        import blender_scene

        obj, arm = blender_scene.build()
    module = install(args.zip)
    import importlib

    ext = importlib.import_module(module)
    prefs = bpy.context.preferences.addons[module].preferences
    result: dict = {"blender": bpy.app.version_string, "object": obj.name, "errors": {}}

    prefs.rigslim_python = "/nonexistent/python"
    select_only(obj)
    result["errors"]["missing_rigslim"] = expect_error(lambda: bpy.ops.rigslim.limit_influences(k=args.k))
    prefs.rigslim_python = args.rigslim_python
    result["errors"]["bad_action"] = expect_error(lambda: bpy.ops.rigslim.limit_influences(k=args.k,
                                                                                           actions="NoSuchAction"))
    result["input_groups"] = group_stats(ext, obj)
    result["source_triangles"] = sum(len(p.vertices) - 2 for p in obj.data.polygons)
    ref = ext.measure.temporary_copy(obj, "Reference")
    lt = ext.measure.temporary_copy(obj, "LimitTotal")
    select_only(lt)
    bpy.ops.object.vertex_group_limit_total(group_select_mode="BONE_DEFORM", limit=args.k)
    bpy.ops.object.vertex_group_normalize_all(group_select_mode="BONE_DEFORM", lock_active=False)
    result["limit_total_groups"] = group_stats(ext, lt)
    select_only(obj)
    op = bpy.ops.rigslim.limit_influences(k=args.k, actions=args.actions, frame_step=args.frame_step, holdout=4,
                                          select=args.select, solve=args.solve, keep_better=not args.no_keep_better,
                                          test_actions=args.test_actions)
    result["limit_status"] = sorted(op)
    result["limit"] = json.loads(obj["rigslim_limit"])
    result["groups"] = group_stats(ext, obj)
    _, test = ext.scene.split_frames(args.actions, args.test_actions, args.frame_step, 4)
    result["independent"] = measure_independently(ext, obj, ref, lt, test)
    result["temporary_objects_left"] = sorted(o.name for o in bpy.data.objects if "rigslim-" in o.name)
    ext.measure.remove_copy(ref)
    ext.measure.remove_copy(lt)
    if args.skip_lods:
        with open(args.out, "w") as fh:
            json.dump(result, fh, indent=1)
        return 0
    select_only(obj)
    bpy.ops.rigslim.generate_lods(ratios=args.ratios, max_bones=args.max_bones, actions=args.actions,
                                  frame_step=max(args.frame_step, 2), max_error=args.max_error)
    result["lod_bounded"] = json.loads(obj["rigslim_lods"])
    result["lod_bounded_children"] = sorted(c.name for c in obj.children)
    op = bpy.ops.rigslim.generate_lods(ratios=args.ratios, max_bones=args.max_bones, actions=args.actions,
                                       frame_step=max(args.frame_step, 2))
    result["lod_status"] = sorted(op)
    result["lod_record"] = json.loads(obj["rigslim_lods"])
    result["lods"] = lod_stats(ext, obj, arm, test[len(test) // 2])
    result["source_materials"] = [m.name for m in obj.data.materials]
    result["source_faces"] = len(obj.data.polygons)
    result["undo_flag"] = "UNDO" in ext.operators.RIGSLIM_OT_limit_influences.bl_options
    if args.blend:
        bpy.ops.wm.save_as_mainfile(filepath=os.path.abspath(args.blend))
    with open(args.out, "w") as fh:
        json.dump(result, fh, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())
