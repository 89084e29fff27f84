# mypy: disable-error-code="valid-type"
# (bpy properties are declared as annotations that call bpy.props: Blender's idiom)
"""The two operators: Limit Influences (fit to animation) and Generate Skinned LODs.

Each operator's work is one generator of steps (:meth:`StepOperator.steps`) that yields
``(fraction, message, waiting)``. ``execute`` (scripts, the redo panel, background mode) runs it to
the end; ``invoke`` from the UI runs it from a modal timer so that the status bar shows the progress
and Esc cancels (before anything was written: nothing changes; after: the objects already done stay
done and the rest are skipped). Both are undoable (one undo step).
"""

from __future__ import annotations

import json
import time
import traceback
from collections.abc import Generator, Iterator
from typing import Any

import bpy
import numpy as np
from bpy.props import BoolProperty, FloatProperty, IntProperty, StringProperty

from . import measure, runner
from . import scene as sc
from . import weights as wt

Step = tuple[float, str, bool]
#: A step generator whose ``yield from`` gives a value (a worker result, sampled poses).
Steps = Generator[Step, None, Any]

_CHECKED: dict[str, dict] = {}

#: Below this RMS (% of the diagonal) Blender's float32 vertex positions cannot tell two results apart.
ROUND_OFF_PCT = 1e-4


class Cancelled(Exception):
    """Esc before anything was written: the operator ends with nothing changed."""


class Stop(Exception):
    """Esc after some objects were written: skip the rest, keep what is done (one undo step)."""


def addon_prefs(context) -> object | None:
    addon = context.preferences.addons.get(__package__)
    return addon.preferences if addon else None


def rigslim_python(context) -> tuple[str, dict]:
    """The configured rigslim Python and its ``worker.py version`` answer (cached per path)."""
    prefs = addon_prefs(context)
    python, _ = runner.find_python(getattr(prefs, "rigslim_python", "") if prefs else "")
    if python not in _CHECKED:
        _CHECKED[python] = runner.check(python)
    return python, _CHECKED[python]


def skinned_selection(context) -> list[bpy.types.Object]:
    objs = [o for o in context.selected_objects if sc.is_skinned(o)]
    if not objs and sc.is_skinned(context.active_object):
        objs = [context.active_object]
    return objs


def _status(context, text: str | None) -> None:
    ws = getattr(context, "workspace", None)
    if ws is not None:
        ws.status_text_set(text)


class StepOperator:
    """Runs :meth:`steps` to completion (``execute``) or one step per timer tick (``invoke``/``modal``)."""

    bl_options = {"REGISTER", "UNDO"}
    report: Any                      # bpy.types.Operator.report (the operator classes mix this in first)
    _timer = None
    _gen: Iterator[Step] | None = None
    cancel_requested = False
    written = 0

    def steps(self, context) -> Iterator[Step]:
        raise NotImplementedError

    def checkpoint(self) -> bool:
        """Called between steps: raise :class:`Cancelled` before any write, else tell the caller to stop."""
        if not self.cancel_requested:
            return False
        if not self.written:
            raise Cancelled()
        return True

    def _fail(self, exc: Exception) -> set[str]:
        self.report({"ERROR"}, f"rigslim: {exc}")
        return {"CANCELLED"}

    def _bug(self, exc: Exception) -> set[str]:
        traceback.print_exc()
        done = f" ({self.written} object(s) were already changed)" if self.written else " (nothing was changed)"
        self.report({"ERROR"}, f"rigslim: internal error {type(exc).__name__}: {exc}{done}; the traceback is on "
                               "the system console, please report it")
        return {"CANCELLED"}

    def execute(self, context):
        self.cancel_requested, self.written = False, 0
        last = ""
        try:
            for fraction, message, waiting in self.steps(context):
                if bpy.app.background and message != last:
                    print(f"rigslim: {fraction * 100:3.0f}% {message}", flush=True)
                    last = message
                if waiting:
                    time.sleep(0.05)
        except (runner.RunnerError, sc.SkinError) as exc:
            return self._fail(exc)
        except Exception as exc:  # a bug: one line in Blender, the traceback on the console
            return self._bug(exc)
        return {"FINISHED"}

    def invoke(self, context, event):
        if bpy.app.background or context.window is None:
            return self.execute(context)
        self.cancel_requested, self.written = False, 0
        # bpy.context, not the invoke's context: that one is only valid during this call
        self._gen = self.steps(bpy.context)
        wm = context.window_manager
        self._timer = wm.event_timer_add(0.05, window=context.window)
        wm.progress_begin(0, 100)
        wm.modal_handler_add(self)
        return {"RUNNING_MODAL"}

    def _end(self, context) -> None:
        wm = context.window_manager
        if self._timer is not None:
            wm.event_timer_remove(self._timer)
            self._timer = None
        wm.progress_end()
        _status(context, None)

    def modal(self, context, event):
        if event.type == "ESC" and event.value == "PRESS":
            self.cancel_requested = True
        if event.type != "TIMER" and not self.cancel_requested:
            return {"RUNNING_MODAL"}
        deadline = time.monotonic() + 0.04
        try:
            while True:
                fraction, message, waiting = next(self._gen)
                if waiting or time.monotonic() > deadline:
                    break
        except StopIteration:
            self._end(context)
            return {"FINISHED"}
        except Cancelled:
            self._end(context)
            self.report({"WARNING"}, "rigslim: cancelled, nothing changed")
            return {"CANCELLED"}
        except (runner.RunnerError, sc.SkinError) as exc:
            self._end(context)
            return self._fail(exc)
        except Exception as exc:
            self._end(context)
            return self._bug(exc)
        context.window_manager.progress_update(int(100 * fraction))
        _status(context, f"rigslim: {message}  ({int(100 * fraction)} %, Esc to cancel)")
        return {"RUNNING_MODAL"}

    def cancel(self, context):
        if self._gen is not None:
            self._gen.close()
        self._end(context)

    def run_job(self, python: str, command: str, request: dict, lo: float, hi: float) -> Steps:
        """Run the worker, yielding its progress mapped onto [lo, hi]; returns its result (``yield from``)."""
        job = runner.Job(python, command, request).start()
        try:
            while not job.poll():
                if self.cancel_requested:
                    job.cancel()
                    raise Cancelled() if not self.written else Stop()
                yield lo + (hi - lo) * job.fraction, f"{job.message} ({job.elapsed():.0f} s)", True
        except GeneratorExit:
            job.cancel()
            raise
        return job.result()


def sample_poses(op: StepOperator, context, skin: sc.Skin, frames, lo: float, hi: float,
                 label: str) -> Steps:
    """Bone transforms of ``frames`` (``(action, frame)`` pairs) through the depsgraph; returns (p, n', 3, 4)."""
    scene = context.scene
    out = []
    for i, (action, frame) in enumerate(frames):
        if op.checkpoint():
            raise Stop()
        sc.go_to(scene, skin.armature, action, frame)
        out.append(sc.bone_transforms(skin, context.evaluated_depsgraph_get()))
        yield lo + (hi - lo) * (i + 1) / len(frames), f"{label}: {action.name} frame {frame}", False
    return wt.rest_handle_poses(skin, np.stack(out))


def action_frames(op, skin: sc.Skin, holdout: int):
    if not sc.parse_actions(op.actions):
        raise sc.SkinError(f"{skin.obj.name}: no action poses the bones of {skin.armature.name}; "
                           "animate it or name the actions to fit (actions: Walk, Run:1-40)")
    examples, test = sc.split_frames(op.actions, getattr(op, "test_actions", ""), op.frame_step, holdout)
    if not examples:
        raise sc.SkinError(f"{skin.obj.name}: the actions' frame ranges give no frame to fit (with the held-out "
                           "actions taken out); widen them or fit more actions")
    return examples, test


class RIGSLIM_OT_limit_influences(StepOperator, bpy.types.Operator):
    """Reduce the selected skinned meshes to k bone influences per vertex, with weights fitted to the
    animation by rigslim (instead of dropping the smallest like Limit Total)"""

    bl_idname = "rigslim.limit_influences"
    bl_label = "Limit Influences (Fit to Animation)"
    bl_options = {"REGISTER", "UNDO"}

    k: IntProperty(name="Influences", description="Bone influences per vertex", default=4, min=1, max=32)
    actions: StringProperty(name="Actions", default="",
                            description="Actions to fit, comma separated, each optionally NAME:START-END; "
                                        "empty: every action that poses bones")
    frame_step: IntProperty(name="Frame Step", default=1, min=1, max=100,
                            description="Sample every n-th frame of each action")
    test_actions: StringProperty(name="Held-Out Actions", default="",
                                 description="Actions only measured, never fitted (e.g. Run while fitting Walk); "
                                             "empty: hold out every n-th sampled frame instead")
    holdout: IntProperty(name="Hold Out Every", default=4, min=0, max=100,
                         description="Every n-th sampled frame is not fitted but used to measure the error "
                                     "against Limit Total (0 or 1: fit every frame, measure none)")
    measure: BoolProperty(name="Compare with Limit Total", default=True,
                          description="Measure rigslim's and Blender's Limit Total error on the held-out frames")
    keep_better: BoolProperty(name="Keep Limit Total If Better", default=True,
                              description="If Limit Total's result has the lower error on the held-out frames, "
                                          "write it instead of rigslim's fit (and say so)")
    select: StringProperty(name="Selection", default="",
                           description="rigslim influence selection plugin (empty: the library's default)")
    solve: StringProperty(name="Solver", default="",
                          description="rigslim weight solver plugin (empty: the library's default)")

    @classmethod
    def poll(cls, context):
        return bool(skinned_selection(context)) and context.mode == "OBJECT"

    def steps(self, context) -> Iterator[Step]:
        python, info = rigslim_python(context)
        objs = skinned_selection(context)
        for j, obj in enumerate(objs):
            if self.checkpoint():
                break
            lo, hi = j / len(objs), (j + 1) / len(objs)
            try:
                yield from self.limit_one(context, obj, python, info, lo, hi)
            except Stop:
                break
        if self.cancel_requested:
            self.report({"WARNING"}, f"rigslim: cancelled after {self.written} of {len(objs)} objects")

    def limit_one(self, context, obj, python, info, lo, hi) -> Steps:
        span = hi - lo
        skin = sc.read_skin(obj)
        for w in skin.warnings:
            self.report({"WARNING"}, f"rigslim: {obj.name}: {w}")
        examples, test = action_frames(self, skin, self.holdout)
        with sc.preserved_animation(context.scene, skin.armature):
            T = yield from sample_poses(self, context, skin, examples, lo, lo + 0.2 * span, "sampling poses")
            request = {"V": skin.V, "F": skin.F, "k": np.int64(self.k), "poses": T, "select": np.str_(self.select),
                       "solve": np.str_(self.solve), **wt.request_weights(skin)}
            res = yield from self.run_job(python, "reduce", request, lo + 0.2 * span, lo + 0.8 * span)
            idx, val = wt.blender_rows(skin, res["indices"], res["values"])
            held = measure.HeldOut(skin, self.k) if (self.measure and test) else None
            try:
                wt.write_groups(obj, skin, idx, val)
                self.written += 1
                for i, (action, frame) in enumerate(test if held else []):
                    if self.checkpoint():
                        break
                    sc.go_to(context.scene, skin.armature, action, frame)
                    assert held is not None
                    held.measure_frame(context.evaluated_depsgraph_get())
                    yield lo + span * (0.8 + 0.2 * (i + 1) / len(test)), f"measuring: {action.name} {frame}", False
                kept = "rigslim"
                if held is not None and self.keep_better and held.rms["rigslim"] \
                        and held.errors("rigslim").rms_pct > held.errors("limit_total").rms_pct:
                    wt.write_groups(obj, skin, *wt.fixed_rows(sc.read_skin(held.limited), self.k))
                    kept = "limit_total"
            finally:
                if held is not None:
                    held.remove()
        self.report_result(obj, skin, res, examples, test, held, kept)

    def report_result(self, obj, skin, res, examples, test, held, kept: str) -> None:
        method = f"{res['select']} + {res['solve']}"
        line = (f"rigslim: {obj.name}: {self.k} influences per vertex ({method}, {len(examples)} frames fitted, "
                f"{float(res['seconds']):.1f} s)")
        record = {"k": self.k, "select": str(res["select"]), "solve": str(res["solve"]),
                  "fitted_frames": len(examples), "held_out_frames": len(test), "seconds": float(res["seconds"]),
                  "input_max_influences": skin.max_influences(), "kept": kept}
        if held is not None and held.rms["rigslim"]:
            ours, theirs = held.errors("rigslim"), held.errors("limit_total")
            ratio = theirs.rms_pct / ours.rms_pct if ours.rms_pct > 0 else float("inf")
            verdict = ("both at float32 round-off, k loses nothing here"
                       if max(ours.rms_pct, theirs.rms_pct) <= ROUND_OFF_PCT
                       else f"{ratio:.2f}x lower" if ratio >= 1 else f"{1 / ratio:.2f}x higher")
            line += (f"; held-out error {ours} vs Limit Total {theirs}: {verdict}"
                     f" over {len(held.rms['rigslim'])} frames")
            if kept == "limit_total":
                line += "; the fit was worse on those frames, so Limit Total's weights were kept"
            record.update({"rms_pct": ours.rms_pct, "max_pct": ours.max_pct, "limit_total_rms_pct": theirs.rms_pct,
                           "limit_total_max_pct": theirs.max_pct, "measured_frames": len(held.rms["rigslim"])})
        obj["rigslim_limit"] = json.dumps(record)
        self.report({"INFO"}, line)


def _ratios(text: str) -> list[float]:
    try:
        vals = [float(s) for s in text.replace(";", ",").split(",") if s.strip()]
    except ValueError:
        raise sc.SkinError(f"ratios: '{text}' is not a list of numbers; write e.g. 0.5, 0.25, 0.125") from None
    if not vals or any(not (0 < v < 1) for v in vals):
        raise sc.SkinError(f"ratios: '{text}': give fractions of the faces between 0 and 1, e.g. 0.5, 0.25")
    return sorted(set(vals), reverse=True)


def lod_request(skin: sc.Skin, T: np.ndarray, op, extra: dict) -> dict:
    """Mesh, weights, poses, per-loop UVs and per-corner chart keys for the worker's ``lod`` command."""
    mesh = skin.obj.data
    n_loops = len(mesh.loops)
    layers = []
    for uv in mesh.uv_layers:
        a = np.empty(n_loops * 2, np.float64)
        uv.data.foreach_get("uv", a)
        layers.append(a.reshape(n_loops, 2))
    X = np.hstack(layers) if layers else np.zeros((n_loops, 0))
    mat = np.empty(len(mesh.polygons), np.int64)
    mesh.polygons.foreach_get("material_index", mat)
    corner = np.concatenate([X[skin.L].reshape(3 * len(skin.L), X.shape[1]),
                             np.repeat(mat[skin.tri_poly], 3)[:, None].astype(float)], axis=1)
    _, keys = np.unique(corner, axis=0, return_inverse=True)
    return {"V": skin.V, "F": skin.F, "L": skin.L, "n_loops": np.int64(n_loops), "loop_values": X,
            "corner_keys": keys.reshape(-1, 3).astype(np.int64), "poses": T, "ratios": np.array(_ratios(op.ratios)),
            "max_bones": np.int64(op.max_bones), "extra_params": np.str_(json.dumps(extra)), **wt.request_weights(skin)}


def remove_old_lods(obj, names: set[str]) -> None:
    for child in list(obj.children):
        if child.name in names or child.name.startswith(f"{obj.name}_LOD"):
            mesh = child.data if child.type == "MESH" else None
            bpy.data.objects.remove(child, do_unlink=True)
            if mesh is not None and mesh.users == 0:
                bpy.data.meshes.remove(mesh)


def build_lod(skin: sc.Skin, res: dict, i: int, name: str) -> bpy.types.Object:
    """One LOD child object: triangles, UV layers, materials, smooth flags, deform groups, Armature modifier."""
    src = skin.obj
    V, faces, source = res[f"l{i}_V"], res[f"l{i}_faces"], res[f"l{i}_source"]
    values = res[f"l{i}_values"]
    me = bpy.data.meshes.new(name)
    me.from_pydata(V.tolist(), [], faces.tolist())
    poly = skin.tri_poly[source]
    src_mat = np.empty(len(src.data.polygons), np.int64)
    src.data.polygons.foreach_get("material_index", src_mat)
    src_smooth = np.empty(len(src.data.polygons), bool)
    src.data.polygons.foreach_get("use_smooth", src_smooth)
    me.polygons.foreach_set("material_index", src_mat[poly])
    me.polygons.foreach_set("use_smooth", src_smooth[poly])
    for j, layer in enumerate(src.data.uv_layers):
        uv = me.uv_layers.new(name=layer.name)
        uv.data.foreach_set("uv", values[:, :, 2 * j:2 * j + 2].reshape(-1))
    if src.data.uv_layers.active is not None:
        me.uv_layers.active_index = src.data.uv_layers.active_index
    for mat in src.data.materials:
        me.materials.append(mat)
    me.validate()
    me.update()
    ob = bpy.data.objects.new(name, me)
    for coll in src.users_collection:
        coll.objects.link(ob)
    ob.parent = src
    ob.matrix_parent_inverse.identity()
    ob.matrix_basis.identity()
    for slot_src, slot in zip(src.material_slots, ob.material_slots, strict=False):
        slot.link = slot_src.link
        if slot_src.link == "OBJECT":
            slot.material = slot_src.material
    groups = [ob.vertex_groups.new(name=b) for b in skin.bones]
    idx, val = wt.blender_rows(skin, res[f"l{i}_indices"], res[f"l{i}_weights"])
    for v, (ii, ww) in enumerate(zip(idx.tolist(), val.tolist(), strict=True)):
        for h, w in zip(ii, ww, strict=True):
            if h >= 0 and w > 0:
                groups[h].add([v], w, "REPLACE")
    mod_src = sc.armature_modifier(src)
    mod = ob.modifiers.new("Armature", "ARMATURE")
    mod.object = skin.armature
    mod.use_deform_preserve_volume = bool(getattr(mod_src, "use_deform_preserve_volume", False))
    return ob


class RIGSLIM_OT_generate_lods(StepOperator, bpy.types.Operator):
    """Make child objects NAME_LOD1..N of the selected skinned meshes, simplified by rigslim with the
    animation (vertex groups, UVs and materials kept)"""

    bl_idname = "rigslim.generate_lods"
    bl_label = "Generate Skinned LODs"
    bl_options = {"REGISTER", "UNDO"}

    ratios: StringProperty(name="Ratios", default="0.5, 0.25, 0.125",
                           description="Fraction of the faces kept by each level, comma separated")
    max_bones: IntProperty(name="Bone Limit", default=4, min=0, max=32,
                           description="At most this many bones per vertex at every level (0: no limit)")
    actions: StringProperty(name="Actions", default="",
                            description="Actions whose poses the levels are fitted to, comma separated, each "
                                        "optionally NAME:START-END; empty: every action that poses bones")
    frame_step: IntProperty(name="Frame Step", default=2, min=1, max=100,
                            description="Sample every n-th frame of each action")
    more_parameters: StringProperty(name="More Parameters", default="",
                                    description="More parameters of rigslim's decimator, as JSON "
                                                "(e.g. {\"min_normal_cos\": 0.2}); see docs/blender.md")
    max_error: FloatProperty(name="Max Error %", default=0.0, min=0.0, max=100.0,
                             description="Stop every level before a collapse would move the surface farther than "
                                         "this, in % of the mesh's diagonal, over every fitted pose (rigslim's "
                                         "max_error; a level can then keep more faces than its ratio; 0: off)")

    @classmethod
    def poll(cls, context):
        return bool(skinned_selection(context)) and context.mode == "OBJECT"

    def steps(self, context) -> Iterator[Step]:
        python, info = rigslim_python(context)
        known = set(info.get("decimator_parameters", []))
        try:
            extra = json.loads(self.more_parameters) if self.more_parameters.strip() else {}
        except ValueError as exc:
            raise sc.SkinError(f"more parameters: not JSON ({exc}); write e.g. {{\"min_normal_cos\": 0.2}}") from None
        if self.max_error > 0:
            extra["max_error"] = float(self.max_error)
        unknown = sorted(set(extra) - known) if known else []
        if unknown:
            raise sc.SkinError(f"more parameters: {', '.join(unknown)} unknown to rigslim {info.get('version')}'s "
                               f"decimator; it takes {', '.join(sorted(known))}")
        objs = skinned_selection(context)
        for j, obj in enumerate(objs):
            if self.checkpoint():
                break
            try:
                yield from self.lods_one(context, obj, python, extra, j / len(objs), (j + 1) / len(objs))
            except Stop:
                break

    def lods_one(self, context, obj, python, extra, lo, hi) -> Steps:
        span = hi - lo
        skin = sc.read_skin(obj)
        examples, _ = action_frames(self, skin, 0)
        with sc.preserved_animation(context.scene, skin.armature):
            T = yield from sample_poses(self, context, skin, examples, lo, lo + 0.2 * span, "sampling poses")
        request = lod_request(skin, T, self, extra)
        res = yield from self.run_job(python, "lod", request, lo + 0.2 * span, lo + 0.9 * span)
        n = int(res["n_levels"])
        names = [f"{obj.name}_LOD{i + 1}" for i in range(n)]
        remove_old_lods(obj, set(names))
        summary = []
        for i, name in enumerate(names):
            ob = build_lod(skin, res, i, name)
            summary.append(f"{name} {len(ob.data.polygons)} faces")
            yield lo + span * (0.9 + 0.1 * (i + 1) / n), f"building {name}", False
        self.written += 1
        obj["rigslim_lods"] = json.dumps({"levels": [{"name": nm, "faces": int(len(res[f"l{i}_faces"])),
                                                      "vertices": int(len(res[f"l{i}_V"])),
                                                      "label": str(res[f"l{i}_label"]),
                                                      "error": float(res[f"l{i}_error"])}
                                                     for i, nm in enumerate(names)],
                                          "method": str(res["method"]), "seconds": float(res["seconds"]),
                                          "fitted_frames": len(examples), "max_bones": self.max_bones})
        self.report({"INFO"}, f"rigslim: {obj.name}: {', '.join(summary)} ({res['method']}, "
                              f"bone limit {self.max_bones or 'none'}, {len(examples)} frames, "
                              f"{float(res['seconds']):.1f} s)")


class RIGSLIM_OT_check_installation(bpy.types.Operator):
    """Find the rigslim installation and report its version"""

    bl_idname = "rigslim.check_installation"
    bl_label = "Check rigslim"

    def execute(self, context):
        _CHECKED.clear()
        try:
            python, info = rigslim_python(context)
        except runner.RunnerError as exc:
            self.report({"ERROR"}, f"rigslim: {exc}")
            return {"CANCELLED"}
        d = info.get("reduce_defaults", {})
        self.report({"INFO"}, f"rigslim {info['version']} at {python} (reduction: {d.get('select')} + "
                              f"{d.get('solve')}; LODs: {info.get('simplify_method')})")
        return {"FINISHED"}


classes = (RIGSLIM_OT_limit_influences, RIGSLIM_OT_generate_lods, RIGSLIM_OT_check_installation)
