"""``rigslim compare REF.glb CANDIDATE.glb``: test-pose Hausdorff (Metro) distance."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.commands.gltf_common import (
    DEFAULT_FPS,
    _check_fps,
    _check_input,
    _emit_report,
    _header,
    _jsonable,
    clip_frames,
    command_session,
    is_usd,
    skins_used,
)
from rigslim.errors import InputError
from rigslim.io.jsonsafe import dumps_strict


def parse_frames_spec(spec: str | None, count: int) -> list[int]:
    """``--frames``: ``a:b:c`` (Python slice), ``a,b,c`` or one frame (:func:`rigslim.model.poses.parse_frames`,
    the one frame-spec parser); default every frame of the clip's ``count``."""
    from rigslim.model.poses import parse_frames

    if spec is None:
        return list(range(count))
    return parse_frames(spec, count, field_name="--frames")


def posed_surfaces(path: Path, *, clip, times, level: int = 0):
    """World-space positions of a file's skinned primitives (unwelded, every skin) at ``times``, faces, skins.

    Each file poses with its own skin: ``v' = sum_i w_i G(joint_i) IBM_i v``, which
    is in world units (metres) whatever scale the joints carry.
    """
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.lod import level_document
    from rigslim.io.gltf.skin import skin_from_document
    from rigslim.numerics.blend import linear_blend

    if is_usd(path):
        return _posed_usd(path, clip=clip, times=times, level=level)
    doc = level_document(load_gltf(path), level)
    Ps, Fs, skins, start = [], [], [], 0
    used: list[int | None] = list(skins_used(doc.json)) or [None]
    for s in used:          # every skin's meshes, as one surface
        skin = skin_from_document(doc, animation=clip, fps=DEFAULT_FPS, skin=s, times=list(times))
        Ps.append(np.stack([linear_blend(skin.mesh.V, skin.weights, skin.poses.T[j]) for j in range(len(times))]))
        Fs.append(np.asarray(skin.mesh.F) + start)
        start += skin.mesh.n_vertices
        skins.append(skin)
    return np.concatenate(Ps, axis=1), np.concatenate(Fs), skins


def _posed_usd(path: Path, *, clip, times, level: int = 0):
    """:func:`posed_surfaces` of a USD file: its meshes bound to one skeleton, posed by rigslim's linear blend
    (UsdSkel's own skinning agrees to float32, docs/usd.md), in world metres with Y up
    (:func:`rigslim.io.usd.summary.world_points`); ``level`` reads variant ``LOD<level>``."""
    from rigslim.io.usd.read import read_usd_skin
    from rigslim.io.usd.summary import world_points

    skin = read_usd_skin(path, animation=clip, times=list(times), lod=level if level else None)
    return world_points(skin), np.asarray(skin.mesh.F), [skin]


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
    from rigslim.numerics.blend import per_vertex_normals
    from rigslim.numerics.surface_distance import metro_distance

    if hausdorff:
        try:
            import pymeshlab  # noqa: F401
        except ImportError:
            from rigslim.errors import StepError

            raise StepError("rigslim compare measures Hausdorff distances with pymeshlab, which is not installed",
                            field="compare", fix="pip install 'rigslim[metro]'") from None
    from rigslim.io.gltf.document import load_gltf, read_once

    with read_once():           # each file parsed once (the command's own session, if any, shares it)
        count, clip_name, _ = clip_frames(ref, clip, fps, None if is_usd(ref) else load_gltf(ref))
        chosen = parse_frames_spec(frames, count)
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
        per_frame = [metro_distance(Pc[j], Fc, Pr[j], Fr, samples) for j in range(len(times))]
        rms = np.asarray([d["rms"] for d in per_frame])
        mx = np.asarray([d["max"] for d in per_frame])
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
    _check_fps(args.fps)
    with command_session(args, [ref, cand], {}):
        res = compare(ref, cand, clip=args.clip, frames=args.frames, level=args.level, fps=args.fps,
                      samples=args.samples)
        _emit_report(args, res)
    if args.json:
        print(dumps_strict({k: v for k, v in res.items() if not k.startswith("per_frame")}, default=_jsonable))
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
