"""``rigslim lod IN.glb -o OUT.glb``: a skinned LOD chain in one command."""

from __future__ import annotations

import sys
from pathlib import Path

from rigslim.commands.gltf_common import (
    _chain,
    _check_fps,
    _check_input,
    _check_output,
    _console,
    _emit_report,
    _gltf_input,
    _header,
    _joint_count,
    _poses,
    clip_frames,
    command_session,
    every_clip_poses,
    input_section,
    is_usd,
    no_motion,
    skin_meshes,
    unnormalised_note,
    write_step,
)
from rigslim.commands.lod_levels import (
    decimate_params,
    level_rows,
    print_levels,
    say_joint_budget_stops,
    sidecar_path,
    skin_split_rows,
    switch_camera,
    write_params,
    write_sidecar,
)
from rigslim.errors import InputError
from rigslim.io.gltf.sidecar import split_names
from rigslim.runtime.metrics_document import flat_metrics


def parse_ratios(text: str) -> list[float]:
    try:
        ratios = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        ratios = []
    if not ratios or any(not 0 < r < 1 for r in ratios) or sorted(ratios, reverse=True) != ratios:
        raise InputError(f"--ratios '{text}' is not a decreasing list of fractions in (0, 1)", field="--ratios",
                         fix="write e.g. --ratios 0.5,0.25")
    return ratios


#: ``--max-error`` default: 1 % of the first test pose's world diagonal (gltfpack's ``-se`` default is 1 %).
DEFAULT_MAX_ERROR = "1%"


def parse_max_error_option(text: str) -> str | None:
    """``--max-error``: ``E`` or ``E%`` (% of the world diagonal), ``Em`` (metres), ``none``."""
    from rigslim.errors import StepError
    from rigslim.model.units import parse_length_bound

    try:
        parsed = parse_length_bound(text, "--max-error")
    except StepError:
        raise InputError(f"--max-error '{text}' is not an error bound", field="--max-error",
                         fix="give a percentage of the world diagonal (1 or 1%), metres (0.02m), or none") from None
    return None if parsed is None else f"{parsed[0]:g}{parsed[1]}"


def bounded(method: str) -> bool:
    """Whether the decimation ``method`` takes ``max_error`` (static QSlim, pymeshlab's, does not); an unknown
    name counts as bounded, so that the pipeline names it with the valid ones."""
    from rigslim.errors import PluginNotFoundError
    from rigslim.plugin.host import get_host

    try:
        return "max_error" in get_host().get("articulated-decimation", method).Params.model_fields
    except PluginNotFoundError:
        return True


#: Test frames ``lod --measure`` measures with ``metro`` at most (evenly spread over every clip's).
MEASURED_FRAMES = 24


def lod_pipeline(src: Path, out: Path, *, ratios, max_bones: int, clip, fps: float, frames: int, quantize: str,
                 method: str = "quartic", measure: bool = False, skin: int | None = None,
                 max_error: str | None = DEFAULT_MAX_ERROR, joints: dict | None = None,
                 coverage: dict | None = None, keep_parts: bool = False) -> dict:
    """The pipeline ``rigslim lod`` runs: a decimation step with a bone limit (and ``joints``: the joint budget,
    :func:`rigslim.commands.lod_levels.decimate_params`; ``keep_parts``: ``prune_parts: false``), then the LOD
    writer (``coverage``: its switch camera).

    Animated: the example poses come from every clip (``clip``: that one) and the levels are measured on
    held-out frames of each, as ``rigslim reduce`` does (:func:`rigslim.commands.gltf_common.every_clip_poses`):
    a limb that only the third clip moves is seen by the collapses."""
    steps = [{"decimate": method, "targets": list(ratios), "max_bones": max_bones,
              **({"max_error": "none" if max_error is None else max_error} if bounded(method) else {}),
              **({"prune_parts": False} if keep_parts else {}), **(joints or {})}]
    if measure:       # metro on at most MEASURED_FRAMES test frames of all the clips' (a pymeshlab run each)
        steps.append({"evaluate": {"metro": {"frames": MEASURED_FRAMES}, "max-influences": {}}})
    write = write_step(out, quantize=quantize, lod=True, clamp_negative=True)
    if not is_usd(out):
        write.update(coverage or {})
    steps.append(write)
    return {"name": f"lod-{src.stem}", "inputs": input_section(src, _gltf_input(src, clip, fps, frames, skin)),
            "poses": every_clip_poses(src, clip) if frames >= 2 else _poses(frames), "steps": steps}


def cmd_lod(args) -> int:
    from rigslim.io.atomic import scratch_folder
    from rigslim.io.gltf.write import split_levels

    src, out = _check_input(args.input), _check_output(args.output)
    ratios = parse_ratios(args.ratios)
    if args.split and is_usd(out):
        raise InputError("--split writes one glTF file per level", field="--split",
                         fix="leave --split out: a USD output holds every level in its LOD variant set")
    if not 1 <= args.max_bones <= (64 if is_usd(out) else 8):
        raise InputError(f"--max-bones {args.max_bones}: glTF holds 1 to 8 influences per vertex",
                         field="--max-bones", fix="give 1..8 (4 for three.js and most engines)")
    _check_fps(args.fps)
    max_error = parse_max_error_option(args.max_error)
    if not bounded(args.method):
        if max_error is not None and args.max_error != DEFAULT_MAX_ERROR:
            raise InputError(f"--method {args.method} has no error bound", field="--max-error",
                             fix="leave --max-error out (or give none), or use --method quartic")
        max_error = None
    joints, coverage = decimate_params(args, len(ratios)), write_params(args)
    named = {"-o": out} if not args.split else \
        {f"--split (level {r:g})": p for r, p in zip(ratios, split_names(out, ratios), strict=True)} | \
        {"--split (sidecar)": sidecar_path(out)}
    with command_session(args, [src], named) as (source,), scratch_folder("rigslim-lod-") as tmp:
        frames, clip, duration = clip_frames(src, args.clip, args.fps, source, moving=True)
        unnormalised = unnormalised_note("lod", src.name, source)
        if frames < 2:
            _joint_count(src, source)              # a file without a skin is refused before the note
            why = no_motion(src.name, clip, duration, source, args.clip is None)
            print(f"rigslim lod: {why}: simplifying for the rest pose only", file=sys.stderr)
        console = _console(args)
        target = tmp / f"lod{out.suffix}" if args.split else out
        runs = _chain(src, target, lambda i, o, s: lod_pipeline(
            i, o, ratios=ratios, max_bones=args.max_bones, clip=args.clip, fps=args.fps, frames=frames,
            quantize=args.quantize, method=args.method, measure=args.measure, skin=s, max_error=max_error,
            joints=joints, coverage=coverage, keep_parts=args.keep_parts), args, console, tmp, source,
            saved=_split_in_writer(out) if args.split else None)
        pipeline, result, _ = runs[0]
        seconds = sum(r[2] for r in runs)
        step = _decimate_step(result)
        targets = step.get("report", {}).get("targets") or [{"target": r, "same_as": None} for r in ratios]
        kept = [t for t in targets if t["same_as"] is None]
        outputs = [out]
        reached = kept_targets(runs, ratios)    # a file each with --split (a skin short of one shows its coarsest)
        if args.split:
            outputs = split_names(out, reached)
            split_levels(target, outputs)
        doc, rows = _lod_document(args, src, outputs, runs, result, targets, kept, step, clip, duration, frames,
                                  ratios, max_error, seconds)
        if args.split and not is_usd(out):
            doc["sidecar"] = str(sidecar_path(out))
            if len(runs) == 1:
                write_sidecar(sidecar_path(out), source=src, outputs=outputs, rows=rows, result=result,
                              header=_header("lod"))
            else:                 # the files show every skin: their rows combine the skins' levels
                radius, camera = character_radius(runs), skins_camera(runs, coverage)
                merged, combined = skin_split_rows(doc["per_skin"], reached, radius, camera)
                write_sidecar(sidecar_path(out), source=src, outputs=outputs, rows=merged, result=result,
                              header=_header("lod"), combined=combined, radius=radius, camera=camera)
        _emit_report(args, doc)
    if len(runs) == 1:
        wrote = ", ".join(str(p) for p in outputs) if rows or not args.split else doc.get("sidecar")
        print(f"wrote {wrote}: {_levels_line(rows, doc['input_faces'])}"
              + (f", at most {args.max_bones} bones per vertex" if rows else "") + f", {seconds:.2f} s")
        _say_levels(rows, targets, max_error, doc["locked_seam_vertices"], "rigslim lod: ")
    else:                     # one decimation per skin: each skin's levels and stops, named by its meshes
        wrote = ", ".join(str(p) for p in outputs) if outputs else doc.get("sidecar")
        print(f"wrote {wrote}: {len(runs)} skins, each simplified on its own, at most {args.max_bones} bones per "
              f"vertex, {seconds:.2f} s")
        for entry in doc["per_skin"]:
            name = f"skin {entry['skin']} ({', '.join(entry['meshes'])})"
            print(f"{name}: {_levels_line(entry['rows'], entry['input_faces'])}")
            _say_levels(entry["rows"], entry["targets"], max_error, entry["locked_seam_vertices"],
                        f"rigslim lod: {name}: ")
    if unnormalised:
        print(unnormalised, file=sys.stderr)
    return 0


def _split_in_writer(out: Path):
    """``--split --save-pipeline``: the saved pipeline's write step names ``-o`` and splits there itself
    (the glTF writer's ``split: true``), where the command splits a scratch file."""
    def saved(pipeline: dict) -> dict:
        write = pipeline["steps"][-1]
        write["write"], write["split"] = str(out.absolute()), True
        return pipeline
    return saved


def _lod_document(args, src, outputs, runs, result, targets, kept, step, clip, duration, frames, ratios,
                  max_error, seconds) -> tuple[dict, list[dict]]:
    """The ``--report`` document of ``rigslim lod`` and its level rows."""
    write = result.document["steps"][-1].get("report", {})
    rows = []
    for t, row in zip(kept, level_rows(result), strict=False):
        rows.append({"ratio": t["target"]} | row | {"target_faces": t.get("target_faces"), "error": t.get("error"),
                                                    "max_error": t.get("max_error"), "stopped": t.get("stopped")})
    per_prim = {x["label"]: x["primitive_faces"] for x in write.get("level_primitives", [])}
    for row in rows:
        row["primitive_faces"] = per_prim.get(row["label"])
        if (row.get("joint_budget") or {}).get("error") is not None:     # the faces' error plus the joints'
            row["error"] = row["joint_budget"]["error"]
    doc = _header("lod") | {"input": str(src), "outputs": [str(p) for p in outputs], "clip": clip,
                             "clip_seconds": duration, "frames": frames, "ratios": ratios,
                             "max_bones": args.max_bones, "method": args.method, "split": args.split,
                             "max_error": max_error, "targets": targets,
                             "input_faces": step.get("report", {}).get("input_faces"),
                             "locked_seam_vertices": step.get("report", {}).get("locked_seam_vertices"),
                             "levels": rows, "seconds": seconds,
                             # the command report keeps KEY@LEVEL names (rigslim-gltf-command v1)
                             "metrics": flat_metrics(result.evaluations[-1]) if result.evaluations else {},
                             "pipeline": runs[0][0], "run": result.document}
    if len(runs) > 1:          # one decimation per skin; the top-level levels are the first skin's
        from rigslim.io.gltf.document import load_gltf

        doc["per_skin"] = []
        js = load_gltf(src).json
        for p, r, t in runs:
            st = _decimate_step(r).get("report", {})
            skin = p["inputs"]["gltf"].get("skin")
            reached = [x for x in st.get("targets", []) if x["same_as"] is None]
            skin_rows = [{"ratio": x["target"]} | row for x, row in zip(reached, level_rows(r), strict=False)]
            doc["per_skin"].append({"skin": skin, "meshes": skin_meshes(js, skin), "seconds": t, "pipeline": p,
                                    "input_faces": st.get("input_faces"), "input_joints": _joints_used(r),
                                    "targets": st.get("targets", []),
                                    "locked_seam_vertices": st.get("locked_seam_vertices"),
                                    "levels": [lv["faces"] for lv in st.get("levels", [])], "rows": skin_rows,
                                    "metrics": flat_metrics(r.evaluations[-1]) if r.evaluations else {}})
    split = result.asset.split if result.asset is not None else None
    if split is not None and split.clips and isinstance(split.clips.get("test"), list):
        # per clip, the frames (its own numbers, at --fps) the collapses fitted and the levels were measured on
        doc["clips"] = {side: split.clips.get(side, []) for side in ("examples", "test")}
    doc["switch"] = switch_camera(result)
    return doc, rows


def _levels_line(rows: list[dict], input_faces) -> str:
    """``2 levels (348, 174 faces of 696)``, or why there is none."""
    if not rows:
        return f"no level (every target ends at the source's {input_faces} faces)"
    faces = ", ".join(f"{r['faces']}" for r in rows)
    return f"{len(rows)} level{'' if len(rows) == 1 else 's'} ({faces} faces of {input_faces})"


def _say_levels(rows: list[dict], targets: list[dict], max_error: str | None, seam_vertices, prefix: str) -> None:
    """The level lines (stdout), then where each target stopped and each joint budget (stderr)."""
    print_levels(rows)
    for t in targets:
        _say_where_it_stopped(t, max_error, seam_vertices, prefix)
    say_joint_budget_stops(rows, max_error)


def _decimate_step(result) -> dict:
    return next(s for s in result.document["steps"] if s["stage"] == "decimate")


def _joints_used(result) -> int | None:
    """How many joints the run's input skin weighs (its asset's weights)."""
    import numpy as np

    from rigslim.io.gltf.sidecar import sp_indices

    W = result.asset.weights if result.asset is not None else None
    return None if W is None else int(len(np.unique(sp_indices(W))))


def character_radius(runs) -> float:
    """Half the diagonal of the bounding box of every skin's mesh in the first test pose (several skins: the
    whole character's bounding sphere, as the ``--split`` sidecar's coverage needs)."""
    import numpy as np

    from rigslim.numerics.blend import linear_blend

    boxes = []
    for _, result, _ in runs:
        a = result.asset
        X = linear_blend(a.mesh.V, a.weights, a.test_poses().T[0])
        boxes += [X.min(axis=0), X.max(axis=0)]
    B = np.array(boxes)
    return 0.5 * float(np.linalg.norm(B.max(axis=0) - B.min(axis=0)))


def skins_camera(runs, coverage: dict) -> dict:
    """The switch camera of the first skin's run that measured levels (a skin may have none), else the one
    ``coverage`` (the writer's parameters) describes."""
    from rigslim.numerics.screen_coverage import DEFAULT_ASPECT

    for _, result, _ in runs:
        camera = switch_camera(result)
        if camera and camera.get("pixel_error") is not None:
            return camera
    return {"pixel_error": coverage["pixel_error"], "fov_deg": coverage["fov"], "resolution": coverage["resolution"],
            "aspect": DEFAULT_ASPECT, "error": coverage.get("switch_error", "max")}


def kept_targets(runs, ratios) -> list[float]:
    """The face targets (in ``ratios`` order) that have a level in at least one skin's run: one ``--split`` file
    each. A skin whose levels end before a target shows its coarsest level in that file (``level_document``)."""
    kept: set[float] = set()
    for _, result, _ in runs:
        kept |= {t["target"] for t in _decimate_step(result).get("report", {}).get("targets") or []
                 if t["same_as"] is None}
    return [r for r in ratios if r in kept]


def _say_where_it_stopped(t: dict, max_error: str | None, seam_vertices, prefix: str = "rigslim lod: ") -> None:
    """One stderr line for a target the level did not reach: the bound, no collapse left, or a finer level
    (``prefix``: ``rigslim lod: `` and, with several skins, which one)."""
    if "faces" not in t:
        return
    where = f"target {t['target']:g} ({t['target_faces']} faces)"
    if t.get("parts_removed") and t["same_as"] is None and t.get("removed_early"):
        print(f"{prefix}level {t['label']}: {t['parts_removed']} parts were removed whole at "
              f"{t['faces_collapsed']} faces, where that costs less error than collapsing on, the smallest and "
              f"nearest to the rest first (the farthest {t['removal_distance']:.3g} m away; --keep-parts keeps "
              f"them)", file=sys.stderr)
    elif t.get("parts_removed") and t["same_as"] is None:
        print(f"{prefix}level {t['label']}: no collapse was left at {t['faces_collapsed']} faces, so "
              f"{t['parts_removed']} parts were removed whole, the smallest and nearest to the rest "
              f"first (the farthest {t['removal_distance']:.3g} m away; --keep-parts keeps them)", file=sys.stderr)
    if t["same_as"] == "source":          # the decimation's levels.SOURCE: ended before the first collapse
        if t["stopped"] is None or t["faces"] <= 1.03 * t["target_faces"]:
            print(f"{prefix}{where}: the source's own {t['faces']} faces meet it, so it has no level",
                  file=sys.stderr)
            return
        why = (f"the first collapse already exceeds --max-error {max_error} (--max-error none goes on)"
               if t["stopped"] == "max_error" else "no collapse was valid")
        print(f"{prefix}{where} not reached: {why}; the source's {t['faces']} faces are no level",
              file=sys.stderr)
    elif t["faces"] <= 1.03 * t["target_faces"]:
        return
    elif t["same_as"] is not None:
        print(f"{prefix}{where} not reached: it ends at the {t['faces']} faces of level {t['same_as']}, "
              f"so it has no level of its own", file=sys.stderr)
    elif t["stopped"] == "max_error" and t.get("parts_removed"):
        limits = ("the next collapse and removing its next part whole exceed" if t.get("removed_early") else
                  "no collapse was left and removing its next part whole exceeds")
        print(f"{prefix}level {t['label']} stopped at {t['faces']} faces, {where}: {limits} --max-error "
              f"{max_error} ({t['parts_removed']} removed; --max-error none goes on)", file=sys.stderr)
    elif t["stopped"] == "max_error":
        print(f"{prefix}level {t['label']} stopped at {t['faces']} faces, {where}: the next collapse exceeds "
              f"--max-error {max_error} (--max-error none goes on)", file=sys.stderr)
    elif t.get("parts_removed"):
        print(f"{prefix}level {t['label']} stopped at {t['faces']} faces, {where}: no collapse was left and "
              f"one part is left", file=sys.stderr)
    else:
        held = []
        if t.get("parts"):
            held.append(f"{t['minimal_parts']} of its {t['parts']} parts are at 4 faces or fewer and stay whole")
        if seam_vertices:
            held.append(f"{seam_vertices} locked seam vertices stay")
        why = "; ".join(held) or "every remaining collapse would break a guard (docs/simplification.md)"
        print(f"{prefix}level {t['label']} stopped at {t['faces']} faces, {where}: no valid collapse was left "
              f"({why})", file=sys.stderr)
