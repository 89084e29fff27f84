"""``rigslim reduce IN.glb -o OUT.glb``: k influences per vertex in one command."""

from __future__ import annotations

import sys
from pathlib import Path

from rigslim.commands.compare import compare
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
    input_section,
    is_usd,
    write_step,
)
from rigslim.errors import InputError


def reduce_pipeline(src: Path, out: Path, *, k: int, select: str, solve: str, clip, fps: float, frames: int,
                    quantize: str, skin: int | None = None) -> dict:
    """The pipeline ``rigslim reduce`` runs (without animation: k-largest, no evaluation; select None: rewrite only)."""
    steps = []
    animated = frames >= 2
    if select is not None:
        steps += [{"select": select, "k": k}, {"solve": solve if animated else "k-largest"}]
        if animated:
            steps.append({"evaluate": ["position-rms", "normal-deviation", "max-influences"]})
    steps.append(write_step(out, quantize=quantize, clamp_negative=True, keep_input_weights=False))
    return {"name": f"reduce-{src.stem}", "inputs": input_section(src, _gltf_input(src, clip, fps, frames, skin)),
            "poses": _poses(frames), "steps": steps}


def cmd_reduce(args) -> int:
    from rigslim.io.atomic import scratch_folder, staged_view

    src, out = _check_input(args.input), _check_output(args.output)
    if not 1 <= args.k <= (64 if is_usd(out) else 8):      # UsdSkel's elementSize has no limit of its own
        raise InputError(f"-k {args.k}: glTF holds 1 to 8 influences per vertex" if not is_usd(out) else
                         f"-k {args.k} is not 1..64", field="-k", fix="give -k 1..8 (glTF) or 1..64 (USD)")
    _check_fps(args.fps)
    with command_session(args, [src], {"-o": out}) as (source,):
        frames, clip, duration = clip_frames(src, args.clip, args.fps, source)
        console = _console(args)
        select, solve = args.select, args.solve
        joints = _joint_count(src, source)
        if args.k >= joints:
            print(f"rigslim reduce: the skin has {joints} joints, so every vertex already has at most k = {args.k}: "
                  f"writing the weights normalised", file=sys.stderr)
            select = solve = None
        elif frames < 2:
            print(f"rigslim reduce: {src.name} has no animation: falling back to k-largest weights", file=sys.stderr)
            select, solve = "k-largest", "k-largest"
        with scratch_folder("rigslim-reduce-") as tmp:
            runs = _chain(src, out, lambda i, o, s: reduce_pipeline(
                i, o, k=args.k, select=select, solve=solve, clip=args.clip, fps=args.fps, frames=frames,
                quantize=args.quantize, skin=s), args, console, tmp, source)
        pipeline, result, _ = runs[-1]
        seconds = sum(r[2] for r in runs)
        metrics = result.evaluations[-1]["metrics"] if result.evaluations else {}
        world = {}
        if frames >= 2:     # the test frames again, in world units, from the file about to be committed
            with staged_view(out) as written:
                world = compare(src, written, clip=args.clip, frames=_poses(frames)["test"], fps=args.fps,
                                hausdorff=False)
            world = {k: world[k] for k in ("position_rms_m", "position_max_m", "position_rms_pct",
                                           "normal_rms_rad", "reference_diagonal_m") if k in world}
        doc = _header("reduce") | {"input": str(src), "output": str(out), "clip": clip, "clip_seconds": duration,
                                    "frames": frames, "k": args.k, "select": select, "solve": solve,
                                    "fallback_k_largest": frames < 2, "seconds": seconds, "metrics": metrics,
                                    "world": world, "pipeline": pipeline, "run": result.document}
        if len(runs) > 1:
            doc["per_skin"] = [{"skin": p["inputs"]["gltf"].get("skin"), "pipeline": p, "seconds": t,
                                "metrics": r.evaluations[-1]["metrics"] if r.evaluations else {}}
                               for p, r, t in runs]
        _emit_report(args, doc)
    line = f"wrote {out} (k = {args.k}, {select or 'no'}/{solve or 'no'} reduction, {seconds:.2f} s)"
    if "position_rms_m" in world:
        line += (f"; test-pose position RMS {world['position_rms_pct']:.4g} % of the world-space diagonal "
                 f"({world['position_rms_m']:.4g} m of {world['reference_diagonal_m']:.4g} m)")
    print(line)
    return 0
