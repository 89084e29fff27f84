"""``rigslim reduce IN.glb -o OUT.glb``: k influences per vertex in one command."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

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
    every_clip_poses,
    input_section,
    is_usd,
    no_motion,
    unnormalised_note,
    write_step,
)
from rigslim.errors import InputError

#: ``rigslim reduce``'s selection: best-fit by error (``--select NAME[:BY]``, ``--by``; k-largest is the baseline).
DEFAULT_SELECT = "best-fit:error"


def resolved_select(select: str | None, by: str | None) -> str:
    """``--select NAME[:BY]`` with ``--by BY`` as one ``NAME[:BY]``: best-fit without a criterion is best-fit by
    error (the command's default, not the plugin's); a ``--by`` that contradicts ``:BY`` is an error."""
    name, _, by_in_name = (select or DEFAULT_SELECT.partition(":")[0]).partition(":")
    if by and by_in_name and by != by_in_name:
        raise InputError(f"--select {select} and --by {by} name two criteria", field="--by",
                         fix=f"give one: --select {name}:{by}, or --by {by} alone")
    chosen = by or by_in_name or ("error" if name == "best-fit" else "")
    return f"{name}:{chosen}" if chosen else name


def select_step(select: str, k: int) -> dict:
    """The ``select`` step of a :func:`resolved_select` ``NAME[:BY]`` (``by`` of best-fit)."""
    name, _, by = select.partition(":")
    return {"select": name, "k": k} | ({"by": by} if by else {})


def reduce_pipeline(src: Path, out: Path, *, k: int, select: str | None, solve: str | None, clip, fps: float,
                    frames: int, quantize: str, skin: int | None = None) -> dict:
    """The pipeline ``rigslim reduce`` runs (without animation: k-largest, no evaluation; select None: rewrite only).

    Animated: example poses from every clip (``--clip``: that one), held-out frames of each for the
    solver's guard and for the test (``poses: {examples: {clips: ...}}``, :mod:`rigslim.runtime.clips`).
    """
    steps = []
    animated = frames >= 2
    if select is not None:
        steps += [select_step(select, k), {"solve": solve if animated else "k-largest"}]
        if animated:
            steps.append({"evaluate": ["position-rms", "normal-deviation", "max-influences"]})
    steps.append(write_step(out, quantize=quantize, clamp_negative=True, keep_input_weights=False))
    poses = every_clip_poses(src, clip) if animated else _poses(frames)
    return {"name": f"reduce-{src.stem}", "inputs": input_section(src, _gltf_input(src, clip, fps, frames, skin)),
            "poses": poses, "steps": steps}


def _world(src: Path, written: Path, split, clip, fps: float) -> dict:
    """Position and normal errors of the written file on the test frames of every clip, in world units
    (pooled over the clips' frames; % of the first clip's world-space diagonal). A USD side: the clip of
    ``--clip`` (default the first, its bound clip) only, as :func:`rigslim.commands.compare.candidate_clip`
    matches no clip names across the two formats: its test frames, or every frame where it has none (a
    first clip of one pose)."""
    per_clip = (split.clips or {}).get("test") if split is not None else None
    if not isinstance(per_clip, list) or is_usd(src) or is_usd(written):
        compared = clip_frames(src, clip, fps)[1]         # the clip compare poses: --clip, else the first
        part = next((p for p in per_clip or [] if p["clip"] in (compared, "input animation")), None)
        frames = ",".join(map(str, part["frames"])) if part else None
        return compare(src, written, clip=clip, frames=frames, fps=fps, hausdorff=False)
    sq = nsq = count = 0.0
    out: dict = {}
    for part in per_clip:
        label = part["clip"]
        name = clip if label == "input animation" else (int(label[1:]) if label.startswith("#") else label)
        res = compare(src, written, clip=name, frames=",".join(map(str, part["frames"])), fps=fps, hausdorff=False)
        if "position_rms_m" not in res:
            return res
        n = len(part["frames"])
        sq += n * res["position_rms_m"] ** 2
        nsq += n * res.get("normal_rms_rad", 0.0) ** 2
        count += n
        out.setdefault("reference_diagonal_m", res["reference_diagonal_m"])
        out["position_max_m"] = max(out.get("position_max_m", 0.0), res["position_max_m"])
    out["position_rms_m"] = float(np.sqrt(sq / count))
    out["position_rms_pct"] = 100.0 * out["position_rms_m"] / out["reference_diagonal_m"]
    out["normal_rms_rad"] = float(np.sqrt(nsq / count))
    out["clips"] = len(per_clip)
    return out


def _solver_reports(result) -> list[dict]:
    """The ``solve`` steps' solver reports of a pipeline run."""
    return [s.get("solver", {}) for s in result.document["steps"] if s.get("stage") == "solve"]


def _passes_through(result) -> bool:
    """Whether the solve kept every vertex's input weights exactly (each has at most k influences)."""
    solved = _solver_reports(result)
    m = len(result.asset.mesh.V) if result.asset is not None and result.asset.mesh is not None else -1
    return bool(solved) and all(int(r.get("passed_through", -1)) == m for r in solved)


def cmd_reduce(args) -> int:
    from rigslim.io.atomic import scratch_folder, staged_view

    src, out = _check_input(args.input), _check_output(args.output)
    if not 1 <= args.k <= (64 if is_usd(out) else 8):      # UsdSkel's elementSize has no limit of its own
        raise InputError(f"-k {args.k}: glTF holds 1 to 8 influences per vertex" if not is_usd(out) else
                         f"-k {args.k} is not 1..64", field="-k", fix="give -k 1..8 (glTF) or 1..64 (USD)")
    _check_fps(args.fps)
    with command_session(args, [src], {"-o": out}) as (source,):
        frames, clip, duration = clip_frames(src, args.clip, args.fps, source, moving=True)
        unnormalised = unnormalised_note("reduce", src.name, source)
        console = _console(args)
        select: str | None = resolved_select(args.select, args.by)
        solve = args.solve
        joints = _joint_count(src, source)
        if args.k >= joints:
            print(f"rigslim reduce: the skin has {joints} joints, so every vertex already has at most k = {args.k}: "
                  f"writing the weights normalised", file=sys.stderr)
            select = solve = None
        elif frames < 2:
            why = no_motion(src.name, clip, duration, source, args.clip is None)
            print(f"rigslim reduce: {why}: falling back to k-largest weights", file=sys.stderr)
            select, solve = "k-largest", "k-largest"
        with scratch_folder("rigslim-reduce-") as tmp:
            runs = _chain(src, out, lambda i, o, s: reduce_pipeline(
                i, o, k=args.k, select=select, solve=solve, clip=clip if args.clip is not None else None,
                fps=args.fps, frames=frames, quantize=args.quantize, skin=s),
                args, console, tmp, source)
        pipeline, result, _ = runs[-1]
        seconds = sum(r[2] for r in runs)
        metrics = result.evaluations[-1]["metrics"] if result.evaluations else {}
        world = {}
        if frames >= 2:     # the test frames again, in world units, from the file about to be committed
            with staged_view(out) as written:
                world = _world(src, written, result.asset.split, args.clip, args.fps)
            world = {k: world[k] for k in ("position_rms_m", "position_max_m", "position_rms_pct",
                                           "normal_rms_rad", "reference_diagonal_m", "clips") if k in world}
        fallback = sum(int(r.get("fallback_vertices", 0)) for r in _solver_reports(result))
        reweighted = max([int(r.get("reweight_rounds", 0)) for r in _solver_reports(result)] or [0])
        untouched = select is not None and all(_passes_through(r[1]) for r in runs)
        doc = _header("reduce") | {"input": str(src), "output": str(out), "clip": clip, "clip_seconds": duration,
                                    "frames": frames, "k": args.k, "select": select, "solve": solve,
                                    "fallback_k_largest": frames < 2, "guard_fallback_vertices": fallback,
                                    "reweight_rounds": reweighted,
                                    "passed_through": untouched,
                                    "seconds": seconds, "metrics": metrics,
                                    "world": world, "pipeline": pipeline, "run": result.document}
        if len(runs) > 1:
            doc["per_skin"] = [{"skin": p["inputs"]["gltf"].get("skin"), "pipeline": p, "seconds": t,
                                "metrics": r.evaluations[-1]["metrics"] if r.evaluations else {}}
                               for p, r, t in runs]
        _emit_report(args, doc)
    line = f"wrote {out} (k = {args.k}, {select or 'no'}/{solve or 'no'} reduction, {seconds:.2f} s)"
    if "position_rms_m" in world:
        over = f" over {world['clips']} clips" if world.get("clips", 1) > 1 else ""
        line += (f"; test-pose position RMS{over} {world['position_rms_pct']:.4g} % of the world-space diagonal "
                 f"({world['position_rms_m']:.4g} m of {world['reference_diagonal_m']:.4g} m)")
    if untouched:
        line += f"; every vertex has at most {args.k} influences, so the weights pass through unchanged"
    elif frames >= 2 and select is not None and solve not in ("k-largest", None):
        line += f"; {fallback} vertices fell back to k-largest on held-out frames"
        if reweighted:
            line += f" (after {reweighted} re-solve{'s' if reweighted > 1 else ''} weighting the failing clips more)"
    print(line)
    if unnormalised:
        print(unnormalised, file=sys.stderr)
    return 0
