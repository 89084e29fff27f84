"""One-command glTF front ends: ``rigslim reduce``, ``rigslim lod``, ``rigslim compare``, ``rigslim inspect``.

``reduce`` and ``lod`` build a pipeline document (the same YAML a user could
write: :func:`reduce_pipeline`, :func:`lod_pipeline`) and run it with
:func:`rigslim.pipeline.run_pipeline`; ``--save-pipeline FILE.yaml`` writes
that document. ``compare`` poses two files with their own skins at the same
clip times and measures the two-sided Hausdorff (Metro) distance;
``inspect`` describes a file. ``--report FILE.json`` writes a document
with ``schema: "rigslim-gltf-command"`` and ``schema_version``
(:data:`REPORT_SCHEMA_VERSION`); docs/gltf.md describes its keys.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import yaml

from rigslim.errors import InputError
from rigslim.metrics_document import flat_metrics

#: Version of the ``--report`` / ``--json`` documents of these commands.
REPORT_SCHEMA = "rigslim-gltf-command"
REPORT_SCHEMA_VERSION = 1
DEFAULT_FPS = 30.0


# --------------------------------------------------------------------------- helpers


def _check_input(path, what: str = "input") -> Path:
    p = Path(path)
    if p.suffix.lower() not in (".glb", ".gltf"):
        raise InputError(f"'{p.suffix or p.name}' is not a glTF file", source=p, field=what,
                         fix="give a .glb or .gltf file")
    if not p.is_file():
        raise InputError("file not found", source=p, field=what, fix="check the path")
    return p.resolve()


def _check_output(path) -> Path:
    p = Path(path)
    if p.suffix.lower() not in (".glb", ".gltf"):
        raise InputError(f"output '{p.name}' is not a .glb or .gltf", source=p, field="-o",
                         fix="write to OUT.glb or OUT.gltf")
    return p.resolve()


def clip_frames(path: Path, clip, fps: float) -> tuple[int, str | None, float]:
    """Frame count of a clip sampled at ``fps`` (1 without animation), its name and its duration."""
    from rigslim.io.gltf import animation_duration, find_animation, load_gltf

    doc = _json_only(path)
    light = doc is not None
    if not light:
        doc = load_gltf(path)
    anim = find_animation(doc, clip)
    if anim is None:
        return 1, None, 0.0
    if light:           # the largest key time, from the accessors' max (the reader checks the keys themselves)
        acc = doc.json["accessors"]
        duration = max([float(acc[smp["input"]]["max"][0]) for smp in doc.json["animations"][anim]["samplers"]],
                       default=0.0)
    else:
        duration = animation_duration(doc, anim)
    name = doc.json["animations"][anim].get("name", str(anim))
    return int(np.floor(duration * fps + 1e-3)) + 1, name, duration


def _json_only(path: Path):
    """The document's JSON without its buffers or pygltflib's typed parse (0.5 s on a 12k-face file), when
    every animation sampler's input accessor has its ``max``; else None (the caller loads it fully; the
    pipeline's reader checks the whole file anyway)."""
    from rigslim.io.gltf import GltfDocument, _parse_glb

    try:
        data = path.read_bytes()
        js = _parse_glb(data, path)[0] if data[:4] == b"glTF" else json.loads(data)
        for anim in js.get("animations", []):
            for smp in anim.get("samplers", []):
                if "max" not in js["accessors"][smp["input"]]:
                    return None
        return GltfDocument(path, js, [])
    except Exception:        # anything odd: the full reader gives the proper one-line error
        return None


def skins_used(js: dict) -> list[int]:
    """Skins that mesh nodes of the default scene use, in depth-first order of first use."""
    nodes = js.get("nodes", [])
    scenes = js.get("scenes", [])
    if scenes:
        scene = scenes[js.get("scene", 0)] if isinstance(js.get("scene", 0), int) else scenes[0]
        order, stack = [], list(reversed(scene.get("nodes", [])))
        while stack:
            i = stack.pop()
            order.append(i)
            stack.extend(reversed(nodes[i].get("children", [])))
    else:
        order = range(len(nodes))
    out = []
    for i in order:
        n = nodes[i]
        if "skin" in n and "mesh" in n and n["skin"] not in out:
            out.append(n["skin"])
    return out


def _gltf_input(path: Path, clip, fps: float, frames: int, skin: int | None = None) -> dict:
    spec = {"path": str(path), "fps": fps}
    if skin is not None:
        spec["skin"] = skin
    if clip is not None:
        spec["animation"] = clip
    if frames < 2:
        spec["times"] = [0.0, 0.0]      # rest pose only: one example and one (identical) test frame
    return spec


#: Most example poses the commands fit to (long clips are subsampled evenly).
MAX_EXAMPLE_POSES = 24


def _poses(frames: int) -> dict:
    """Example frames ``0, s, 2s, ...`` (at most :data:`MAX_EXAMPLE_POSES`) and test frames halfway between."""
    if frames < 2:
        return {"examples": "0", "test": "1"}
    step = max(2, -(-frames // MAX_EXAMPLE_POSES))
    return {"examples": f"0:{frames}:{step}", "test": f"{max(1, step // 2)}:{frames}:{step}"}


def _run(pipeline: dict, args, console) -> tuple[object, float]:
    """Write the pipeline as YAML (temporary, or --save-pipeline) and run it."""
    from rigslim.pipeline import run_pipeline

    text = yaml.safe_dump(pipeline, sort_keys=False)
    if getattr(args, "save_pipeline", None):
        Path(args.save_pipeline).write_text(text)
    with tempfile.TemporaryDirectory(prefix="rigslim-cmd-") as tmp:
        yml = Path(tmp) / f"{pipeline['name']}.yaml"
        yml.write_text(text)
        t0 = time.perf_counter()
        result = run_pipeline(yml, console=console)
        return result, time.perf_counter() - t0


def _chain(src: Path, out: Path, make, args, console, tmp: Path):
    """Run ``make(input, output, skin)`` pipelines once per skin, each reading the previous one's output.

    One skin: one run, ``skin`` None (the reader's default). Returns ``[(pipeline, result, seconds), ...]``.
    """
    from rigslim.io.gltf import load_gltf

    skins = skins_used(load_gltf(src).json)
    if len(skins) <= 1:
        pipeline = make(src, out, None)
        return [(pipeline, *_run(pipeline, args, console))]
    runs, inp = [], src
    for i, s in enumerate(skins):
        dst = out if i == len(skins) - 1 else tmp / f"skin{s}{out.suffix}"
        pipeline = make(inp, dst, s)
        runs.append((pipeline, *_run(pipeline, args, console)))
        inp = dst
    return runs


def _console(args):
    from rich.console import Console

    return Console(stderr=True, quiet=not args.verbose)


def _emit_report(args, doc: dict) -> None:
    if getattr(args, "report", None):
        from rigslim.io.atomic import atomic_path

        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(json.dumps(doc, indent=2, default=_jsonable) + "\n")


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def _header(command: str) -> dict:
    import rigslim

    return {"schema": REPORT_SCHEMA, "schema_version": REPORT_SCHEMA_VERSION, "command": command,
            "rigslim_version": rigslim.__version__}


# --------------------------------------------------------------------------- reduce


def reduce_pipeline(src: Path, out: Path, *, k: int, select: str, solve: str, clip, fps: float, frames: int,
                    quantize: str, skin: int | None = None) -> dict:
    """The pipeline ``rigslim reduce`` runs (without animation: k-largest, no evaluation; select None: rewrite only)."""
    steps = []
    animated = frames >= 2
    if select is not None:
        steps += [{"select": select, "k": k}, {"solve": solve if animated else "k-largest"}]
        if animated:
            steps.append({"evaluate": ["position-rms", "normal-deviation", "max-influences"]})
    steps.append({"write": str(out), "quantize": quantize, "clamp_negative": True, "keep_input_weights": False})
    return {"name": f"reduce-{src.stem}", "inputs": {"gltf": _gltf_input(src, clip, fps, frames, skin)},
            "poses": _poses(frames), "steps": steps}


def cmd_reduce(args) -> int:
    src, out = _check_input(args.input), _check_output(args.output)
    if not 1 <= args.k <= 8:
        raise InputError(f"-k {args.k}: glTF holds 1 to 8 influences per vertex", field="-k", fix="give -k 1..8")
    frames, clip, duration = clip_frames(src, args.clip, args.fps)
    console = _console(args)
    select, solve = args.select, args.solve
    joints = _joint_count(src)
    if args.k >= joints:
        print(f"rigslim reduce: the skin has {joints} joints, so every vertex already has at most k = {args.k}: "
              f"writing the weights normalised", file=sys.stderr)
        select = solve = None
    elif frames < 2:
        print(f"rigslim reduce: {src.name} has no animation: falling back to k-largest weights", file=sys.stderr)
        select, solve = "k-largest", "k-largest"
    with tempfile.TemporaryDirectory(prefix="rigslim-reduce-") as tmp:
        runs = _chain(src, out, lambda i, o, s: reduce_pipeline(
            i, o, k=args.k, select=select, solve=solve, clip=args.clip, fps=args.fps, frames=frames,
            quantize=args.quantize, skin=s), args, console, Path(tmp))
    pipeline, result, _ = runs[-1]
    seconds = sum(r[2] for r in runs)
    metrics = result.evaluations[-1]["metrics"] if result.evaluations else {}
    world = {}
    if frames >= 2:     # the test frames again, in world units, from the written file
        world = compare(src, out, clip=args.clip, frames=_poses(frames)["test"], fps=args.fps, hausdorff=False)
        world = {k: world[k] for k in ("position_rms_m", "position_max_m", "position_rms_pct", "normal_rms_rad",
                                       "reference_diagonal_m") if k in world}
    doc = _header("reduce") | {"input": str(src), "output": str(out), "clip": clip, "clip_seconds": duration,
                                "frames": frames, "k": args.k, "select": select, "solve": solve,
                                "fallback_k_largest": frames < 2, "seconds": seconds, "metrics": metrics,
                                "world": world, "pipeline": pipeline, "run": result.document}
    if len(runs) > 1:
        doc["per_skin"] = [{"skin": p["inputs"]["gltf"].get("skin"), "pipeline": p, "seconds": t,
                            "metrics": r.evaluations[-1]["metrics"] if r.evaluations else {}} for p, r, t in runs]
    _emit_report(args, doc)
    line = f"wrote {out} (k = {args.k}, {select or 'no'}/{solve or 'no'} reduction, {seconds:.2f} s)"
    if "position_rms_m" in world:
        line += (f"; test-pose position RMS {world['position_rms_pct']:.4g} % of the world-space diagonal "
                 f"({world['position_rms_m']:.4g} m of {world['reference_diagonal_m']:.4g} m)")
    print(line)
    return 0


def _joint_count(path: Path) -> int:
    from rigslim.io.gltf import load_gltf

    skins = load_gltf(path).json.get("skins", [])
    if not skins:
        raise InputError("the file has no skin", source=path, field="skins", fix="give a skinned glTF")
    return max(len(s.get("joints", [])) for s in skins)


# --------------------------------------------------------------------------- lod


def parse_ratios(text: str) -> list[float]:
    try:
        ratios = [float(x) for x in text.split(",") if x.strip()]
    except ValueError:
        ratios = []
    if not ratios or any(not 0 < r < 1 for r in ratios) or sorted(ratios, reverse=True) != ratios:
        raise InputError(f"--ratios '{text}' is not a decreasing list of fractions in (0, 1)", field="--ratios",
                         fix="write e.g. --ratios 0.5,0.25")
    return ratios


def split_names(out: Path, ratios) -> list[Path]:
    """``OUT-50.glb``, ``OUT-25.glb``: one file per level, named after the percentage of faces."""
    return [out.with_name(f"{out.stem}-{r * 100:g}{out.suffix}") for r in ratios]


def lod_pipeline(src: Path, out: Path, *, ratios, max_bones: int, clip, fps: float, frames: int, quantize: str,
                 method: str = "quartic", measure: bool = False, skin: int | None = None) -> dict:
    """The pipeline ``rigslim lod`` runs: a decimation step with a bone limit, then the LOD writer."""
    steps = [{"decimate": method, "targets": list(ratios), "max_bones": max_bones}]
    if measure:
        steps.append({"evaluate": ["metro", "max-influences"]})
    steps.append({"write": str(out), "quantize": quantize, "lod": True, "clamp_negative": True})
    return {"name": f"lod-{src.stem}", "inputs": {"gltf": _gltf_input(src, clip, fps, frames, skin)},
            "poses": _poses(frames), "steps": steps}


def cmd_lod(args) -> int:
    from rigslim.io.gltf_lod import split_levels

    src, out = _check_input(args.input), _check_output(args.output)
    ratios = parse_ratios(args.ratios)
    if not 1 <= args.max_bones <= 8:
        raise InputError(f"--max-bones {args.max_bones}: glTF holds 1 to 8 influences per vertex",
                         field="--max-bones", fix="give 1..8 (4 for three.js and most engines)")
    frames, clip, duration = clip_frames(src, args.clip, args.fps)
    if frames < 2:
        print(f"rigslim lod: {src.name} has no animation: simplifying for the rest pose only", file=sys.stderr)
    console = _console(args)
    with tempfile.TemporaryDirectory(prefix="rigslim-lod-", dir=out.parent if out.parent.exists() else None) as tmp:
        target = Path(tmp) / f"lod{out.suffix}" if args.split else out
        runs = _chain(src, target, lambda i, o, s: lod_pipeline(
            i, o, ratios=ratios, max_bones=args.max_bones, clip=args.clip, fps=args.fps, frames=frames,
            quantize=args.quantize, method=args.method, measure=args.measure, skin=s), args, console, Path(tmp))
        pipeline, result, _ = runs[0]
        seconds = sum(r[2] for r in runs)
        outputs = [out]
        if args.split:
            outputs = split_names(out, ratios)
            split_levels(target, outputs)
    levels = result.asset.levels
    step = next(s for s in result.document["steps"] if s["stage"] == "decimate")
    write = result.document["steps"][-1].get("report", {})
    rows = []
    for r, lv in zip(ratios, levels, strict=False):
        rows.append({"ratio": r, "label": lv.label, "faces": lv.n_faces, "vertices": lv.n_vertices,
                     "max_bones": int(lv.weights.influence_counts().max())})
    per_prim = {x["label"]: x["primitive_faces"] for x in write.get("level_primitives", [])}
    for row in rows:
        row["primitive_faces"] = per_prim.get(row["label"])
    doc = _header("lod") | {"input": str(src), "outputs": [str(p) for p in outputs], "clip": clip,
                             "clip_seconds": duration, "frames": frames, "ratios": ratios,
                             "max_bones": args.max_bones, "method": args.method, "split": args.split,
                             "input_faces": step.get("report", {}).get("input_faces"),
                             "locked_seam_vertices": step.get("report", {}).get("locked_seam_vertices"),
                             "levels": rows, "seconds": seconds,
                             # the command report keeps KEY@LEVEL names (rigslim-gltf-command v1)
                             "metrics": flat_metrics(result.evaluations[-1]) if result.evaluations else {},
                             "pipeline": pipeline, "run": result.document}
    if len(runs) > 1:          # one decimation per skin; the top-level levels are the first skin's
        doc["per_skin"] = []
        for p, r, t in runs:
            st = next(x for x in r.document["steps"] if x["stage"] == "decimate").get("report", {})
            doc["per_skin"].append({"skin": p["inputs"]["gltf"].get("skin"), "seconds": t, "pipeline": p,
                                    "input_faces": st.get("input_faces"),
                                    "levels": [lv["faces"] for lv in st.get("levels", [])]})
    _emit_report(args, doc)
    faces = ", ".join(f"{r['faces']}" for r in rows)
    print(f"wrote {', '.join(str(p) for p in outputs)}: {len(rows)} levels ({faces} faces of "
          f"{doc['input_faces']}), at most {args.max_bones} bones per vertex, {seconds:.2f} s")
    for r in rows:
        if r["faces"] > 1.05 * r["ratio"] * (doc["input_faces"] or 0):
            print(f"rigslim lod: level {r['label']} stopped at {r['faces']} faces: no valid collapse was left "
                  f"(seam corners and mesh boundaries stay fixed; {doc['locked_seam_vertices']} seam vertices)",
                  file=sys.stderr)
    return 0


# --------------------------------------------------------------------------- compare


def parse_frames_spec(spec: str | None, count: int) -> list[int]:
    """``a:b:c`` (Python range), or a comma list; default every frame."""
    if spec is None:
        return list(range(count))
    try:
        if ":" in spec:
            parts = [int(x) if x else None for x in spec.split(":")]
            frames = list(range(count))[slice(*parts)]
        else:
            frames = [int(x) for x in spec.split(",") if x.strip()]
    except ValueError:
        frames = []
    if not frames or min(frames) < 0:
        raise InputError(f"--frames '{spec}' gives no frames of the clip's {count}", field="--frames",
                         fix="write e.g. --frames 1:30:2 or --frames 3,7")
    return frames


def posed_surfaces(path: Path, *, clip, times, level: int = 0):
    """World-space positions of a file's skinned primitives (unwelded, every skin) at ``times``, faces, skins.

    Each file poses with its own skin: ``v' = sum_i w_i G(joint_i) IBM_i v``, which
    is in world units (metres) whatever scale the joints carry.
    """
    from rigslim.blend import linear_blend
    from rigslim.io.gltf import _read_gltf_skin, load_gltf
    from rigslim.io.gltf_lod import level_document

    doc = level_document(load_gltf(path), level)
    Ps, Fs, skins, start = [], [], [], 0
    for s in skins_used(doc.json) or [None]:          # every skin's meshes, as one surface
        skin = _read_gltf_skin(doc, clip, DEFAULT_FPS, None, s, True, False, list(times))
        Ps.append(np.stack([linear_blend(skin.mesh.V, skin.weights, skin.poses.T[j]) for j in range(len(times))]))
        Fs.append(np.asarray(skin.mesh.F) + start)
        start += skin.mesh.n_vertices
        skins.append(skin)
    return np.concatenate(Ps, axis=1), np.concatenate(Fs), skins


def compare(ref: Path, cand: Path, *, clip=None, frames: str | None = None, level: int = 0, fps: float = DEFAULT_FPS,
            samples: int = 20000, hausdorff: bool = True) -> dict:
    """Distances between two skinned files posed by their own skins at the same clip times.

    Returns
    -------
    dict
        ``hausdorff_rms_pct``, ``hausdorff_max_pct`` (% of the reference's
        world-space bounding-box diagonal in the first compared frame),
        ``hausdorff_rms_m``, ``hausdorff_max_m`` (world units: metres for
        glTF), ``faces``; when both have the same vertices and faces also
        ``position_rms_m``/``position_max_m``/``position_rms_pct`` (vertex to
        vertex) and ``normal_rms_rad``.

    Notes
    -----
    Per frame j, :func:`rigslim.numerics.surface_distance.metro_distance` gives
    the two-sided sampled RMS ``r_j`` and max ``h_j``; the results are
    ``mean_j r_j`` and ``max_j h_j``.
    """
    from rigslim.blend import per_vertex_normals
    from rigslim.numerics.surface_distance import metro_distance

    if hausdorff:
        try:
            import pymeshlab  # noqa: F401
        except ImportError:
            from rigslim.errors import StepError

            raise StepError("rigslim compare measures Hausdorff distances with pymeshlab, which is not installed",
                            field="compare", fix="pip install 'rigslim[metro]'") from None
    count, clip_name, _ = clip_frames(ref, clip, fps)
    chosen = parse_frames_spec(frames, count)
    if max(chosen) >= count:
        raise InputError(f"--frames reaches frame {max(chosen)} but the clip has {count} at {fps:g} fps",
                         field="--frames", fix=f"use frames 0..{count - 1}")
    times = [f / fps for f in chosen]
    Pr, Fr, sr = posed_surfaces(ref, clip=clip, times=times)
    Pc, Fc, sc = posed_surfaces(cand, clip=clip if clip is not None else None, times=times, level=level)
    lo, hi = Pr[0].min(axis=0), Pr[0].max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if diag <= 0:
        raise InputError("the reference has zero extent", source=ref, field="POSITION", fix="give a real mesh")
    out = _header("compare") | {
        "reference": str(ref), "candidate": str(cand), "level": level, "clip": clip_name, "fps": fps,
        "frames": chosen, "reference_diagonal_m": diag, "faces": int(len(Fc)), "reference_faces": int(len(Fr))}
    if hausdorff:
        rms, mx = [], []
        for j in range(len(times)):
            d = metro_distance(Pc[j], Fc, Pr[j], Fr, samples)
            rms.append(d["rms"])
            mx.append(d["max"])
        rms, mx = np.asarray(rms), np.asarray(mx)
        out |= {"hausdorff_rms_pct": float(100 * rms.mean() / diag), "hausdorff_max_pct": float(100 * mx.max() / diag),
                "hausdorff_rms_m": float(rms.mean()), "hausdorff_max_m": float(mx.max()),
                "hausdorff_max_pct_mean": float(100 * mx.mean() / diag),
                "per_frame_rms_m": rms.tolist(), "per_frame_max_m": mx.tolist(), "samples": samples}
    if Pr.shape == Pc.shape and np.array_equal(Fr, Fc):
        dist = np.linalg.norm(Pc - Pr, axis=-1)
        out |= {"position_rms_m": float(np.sqrt((dist ** 2).mean())), "position_max_m": float(dist.max()),
                "position_rms_pct": float(100 * np.sqrt((dist ** 2).mean()) / diag)}
        ang = []
        for j in range(len(times)):
            nr, nc = per_vertex_normals(Pr[j], Fr), per_vertex_normals(Pc[j], Fc)
            ok = np.isfinite(nr).all(axis=1) & np.isfinite(nc).all(axis=1)
            ang.append(np.arccos(np.clip((nr[ok] * nc[ok]).sum(axis=1), -1, 1)))
        a = np.concatenate(ang)
        out["normal_rms_rad"] = float(np.sqrt((a * a).mean())) if a.size else 0.0
    return out


def cmd_compare(args) -> int:
    ref, cand = _check_input(args.reference, "REFERENCE"), _check_input(args.candidate, "CANDIDATE")
    res = compare(ref, cand, clip=args.clip, frames=args.frames, level=args.level, fps=args.fps,
                  samples=args.samples)
    _emit_report(args, res)
    if args.json:
        print(json.dumps({k: v for k, v in res.items() if not k.startswith("per_frame")}, default=_jsonable))
        return 0
    print(f"{cand.name} (level {args.level}, {res['faces']} faces) vs {ref.name} ({res['reference_faces']} faces), "
          f"{len(res['frames'])} frames of {res['clip'] or 'the rest pose'}:")
    if "position_rms_m" in res:
        print(f"  vertex position RMS {res['position_rms_pct']:.4g} % ({res['position_rms_m']:.4g} m), "
              f"max {res['position_max_m']:.4g} m (same topology)")
    print(f"  Hausdorff RMS {res['hausdorff_rms_pct']:.4f} % of the diagonal ({res['hausdorff_rms_m']:.4g} m), "
          f"max {res['hausdorff_max_pct']:.4f} % ({res['hausdorff_max_m']:.4g} m); "
          f"diagonal {res['reference_diagonal_m']:.4g} m")
    if "normal_rms_rad" in res:
        print(f"  normal RMS {res['normal_rms_rad']:.4g} rad (same topology)")
    return 0


# --------------------------------------------------------------------------- inspect


def inspect(path: Path) -> dict:
    """Skins, joints, clips, meshes, primitives, attributes, influences and weight-sum defects of a file."""
    from rigslim.io.gltf import animation_duration, load_gltf, read_accessor, skinning_sets
    from rigslim.io.gltf_lod import lod_nodes

    doc = load_gltf(path)
    js = doc.json
    out = _header("inspect") | {"path": str(path), "generator": js.get("asset", {}).get("generator"),
                                 "extensions_used": js.get("extensionsUsed", [])}
    out["skins"] = [{"index": i, "name": s.get("name"), "joints": len(s.get("joints", [])),
                     "joint_names": [js["nodes"][j].get("name") for j in s.get("joints", [])]}
                    for i, s in enumerate(js.get("skins", []))]
    out["animations"] = [{"index": i, "name": a.get("name"), "channels": len(a.get("channels", [])),
                          "seconds": animation_duration(doc, i)} for i, a in enumerate(js.get("animations", []))]
    meshes = []
    for mi, mesh in enumerate(js.get("meshes", [])):
        prims = []
        for pi, prim in enumerate(mesh.get("primitives", [])):
            attrs = prim.get("attributes", {})
            info = {"index": pi, "mode": prim.get("mode", 4), "material": prim.get("material"),
                    "attributes": {k: {"count": js["accessors"][a]["count"], "type": js["accessors"][a]["type"],
                                       "componentType": js["accessors"][a]["componentType"],
                                       "normalized": js["accessors"][a].get("normalized", False)}
                                   for k, a in sorted(attrs.items())},
                    "targets": len(prim.get("targets", []))}
            if "indices" in prim:
                info["triangles"] = js["accessors"][prim["indices"]]["count"] // 3
            sets = skinning_sets(attrs)
            if sets and "POSITION" in attrs:
                count = js["accessors"][attrs["POSITION"]]["count"]
                total, nz = np.zeros(count), np.zeros(count, np.int64)
                for s in sets:
                    W = np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"]), float).reshape(count, -1)
                    total += W.sum(axis=1)
                    nz += (W != 0).sum(axis=1)
                dev = np.abs(total - 1.0)
                info["influences_histogram"] = np.bincount(nz).tolist()
                info["weight_sums"] = {"min": float(total.min(initial=1.0)), "max": float(total.max(initial=1.0)),
                                       "off_by_more_than_1e-3": int((dev > 1e-3).sum())}
            prims.append(info)
        meshes.append({"index": mi, "name": mesh.get("name"), "primitives": prims})
    out["meshes"] = meshes
    out["nodes_with_skin"] = [{"node": i, "name": n.get("name"), "mesh": n.get("mesh"), "skin": n["skin"]}
                              for i, n in enumerate(js.get("nodes", [])) if "skin" in n and "mesh" in n]
    out["lod"] = {str(i): ids for i, ids in lod_nodes(js).items()}
    out["materials"] = [m.get("name") for m in js.get("materials", [])]
    return out


def cmd_inspect(args) -> int:
    info = inspect(_check_input(args.input))
    _emit_report(args, info)
    if args.json:
        print(json.dumps(info, indent=2, default=_jsonable))
        return 0
    print(f"{info['path']} (generator: {info['generator']})")
    for s in info["skins"]:
        print(f"skin {s['index']} '{s['name']}': {s['joints']} joints")
    for a in info["animations"]:
        print(f"clip {a['index']} '{a['name']}': {a['seconds']:.3f} s, {a['channels']} channels")
    if not info["animations"]:
        print("no animations")
    for m in info["meshes"]:
        print(f"mesh {m['index']} '{m['name']}': {len(m['primitives'])} primitive(s)")
        for p in m["primitives"]:
            print(f"  primitive {p['index']}: material {p['material']}, {p.get('triangles', '?')} triangles, "
                  f"attributes {', '.join(p['attributes'])}" + (f", {p['targets']} morph targets" if p["targets"]
                                                                 else ""))
            if "influences_histogram" in p:
                h = p["influences_histogram"]
                ws = p["weight_sums"]
                print("    influences per vertex: " + ", ".join(f"{i}: {c}" for i, c in enumerate(h) if c)
                      + f"; weight sums {ws['min']:.4g}..{ws['max']:.4g}, "
                        f"{ws['off_by_more_than_1e-3']} vertices off by more than 1e-3")
    for node, ids in info["lod"].items():
        print(f"node {node}: MSFT_lod levels {ids}")
    return 0


# --------------------------------------------------------------------------- argparse


def _common(p: argparse.ArgumentParser, clip: bool = True) -> None:
    if clip:
        p.add_argument("--clip", metavar="NAME", help="animation clip (name or index; default the first)")
        p.add_argument("--fps", type=float, default=DEFAULT_FPS, help="frame rate the clip is sampled at (30)")
    p.add_argument("-v", "--verbose", action="store_true", help="step details on stderr")
    p.add_argument("--report", metavar="FILE.json", help=f"write the {REPORT_SCHEMA} document here")


def add_commands(sub) -> None:
    """Register ``reduce``, ``lod``, ``compare`` and ``inspect`` on the ``rigslim`` subparsers."""
    p = sub.add_parser("reduce", help="reduce a skinned glTF's influences to k per vertex (one command)")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("-o", "--output", required=True, metavar="OUT.glb")
    p.add_argument("-k", type=int, default=4, help="influences per vertex (1..8; default 4)")
    p.add_argument("--select", default="k-largest", help="influence selection plugin (k-largest, best-fit, ...)")
    p.add_argument("--solve", default="geometric", help="weight solver (geometric, poisson, smooth, k-largest)")
    p.add_argument("--quantize", choices=["ubyte", "ushort", "float"], default="ubyte")
    p.add_argument("--save-pipeline", metavar="FILE.yaml", help="also write the pipeline this command runs")
    _common(p)
    p.set_defaults(func=cmd_reduce)

    p = sub.add_parser("lod", help="skinned LOD chain (MSFT_lod, or one file per level) in one command")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("-o", "--output", required=True, metavar="OUT.glb")
    p.add_argument("--ratios", default="0.5,0.25", help="fractions of the faces, decreasing (default 0.5,0.25)")
    p.add_argument("--max-bones", type=int, default=4, help="influences per vertex at every level (default 4)")
    p.add_argument("--method", default="quartic", help="decimator (quartic, mohr-gleicher, decoro-rusinkiewicz)")
    p.add_argument("--quantize", choices=["ubyte", "ushort", "float"], default="ubyte")
    p.add_argument("--split", action="store_true", help="one file per level: OUT-50.glb, OUT-25.glb")
    p.add_argument("--measure", action="store_true", help="also measure each level (metro) on the test frames")
    p.add_argument("--save-pipeline", metavar="FILE.yaml", help="also write the pipeline this command runs")
    _common(p)
    p.set_defaults(func=cmd_lod)

    p = sub.add_parser("compare", help="test-pose Hausdorff distance of a skinned glTF to a reference")
    p.add_argument("reference", metavar="REF.glb")
    p.add_argument("candidate", metavar="CANDIDATE.glb")
    p.add_argument("--frames", metavar="a:b:c", help="frames of the clip at --fps (default: every frame)")
    p.add_argument("--level", type=int, default=0, help="MSFT_lod level of the candidate (0: full meshes)")
    p.add_argument("--samples", type=int, default=20000, help="surface samples per direction and frame")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _common(p)
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("inspect", help="skins, joints, clips, primitives, attributes and influences of a glTF")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _common(p, clip=False)
    p.set_defaults(func=cmd_inspect)
