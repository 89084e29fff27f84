"""``rigslim compare REF.glb CANDIDATE.glb``: test-pose Hausdorff (Metro) distance."""

from __future__ import annotations

import re
import sys
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
    if is_usd(path):
        return _posed_usd(path, clip=clip, times=times, level=level)
    doc = level_document(load_gltf(path), level)
    Ps, Fs, skins, start = [], [], [], 0
    used: list[int | None] = list(skins_used(doc.json)) or [None]
    for s in used:          # every skin's meshes, as one surface
        skin = skin_from_document(doc, animation=clip, fps=DEFAULT_FPS, skin=s, times=list(times))
        Ps.append(blend_frames(skin.mesh.V, skin.weights, skin.poses.T[:len(times)]))
        Fs.append(np.asarray(skin.mesh.F) + start)
        start += skin.mesh.n_vertices
        skins.append(skin)
    return (Ps[0] if len(Ps) == 1 else np.concatenate(Ps, axis=1)), np.concatenate(Fs), skins


def blend_frames(V, weights, T) -> np.ndarray:
    """:func:`rigslim.numerics.blend.linear_blend` of every frame ``T[j]`` (``v'_j = X_v^j [v; 1]``,
    ``X_v^j = sum_i a_{v,i} T_i^j``), written into one preallocated ``(frames, m, 3)`` array: no list of
    frames and no stacked copy (1 GB per file and 31 frames at 1.3M vertices)."""
    from rigslim.numerics.blend import linear_blend

    out = np.empty((len(T), len(V), 3))
    for j in range(len(T)):
        out[j] = linear_blend(V, weights, T[j])
    return out


def _posed_usd(path: Path, *, clip, times, level: int = 0):
    """:func:`posed_surfaces` of a USD file: its meshes bound to one skeleton, posed by rigslim's linear blend
    (UsdSkel's own skinning agrees to float32, docs/usd.md), in world metres with Y up
    (:func:`rigslim.io.usd.summary.world_points`); ``level`` reads variant ``LOD<level>``."""
    from rigslim.io.usd.read import read_usd_skin
    from rigslim.io.usd.summary import world_points

    skin = read_usd_skin(path, animation=clip, times=list(times), lod=level if level else None)
    return world_points(skin), np.asarray(skin.mesh.F), [skin]


#: Above this many triangles (the larger of the two surfaces) ``compare`` measures the Hausdorff distance on at most
#: :data:`LARGE_HAUSDORFF_FRAMES` evenly spread frames unless ``hausdorff_frames`` says otherwise: pymeshlab
#: takes about 7 s of CPU per frame at 2.6M triangles (two meshes built, every vertex sampled both ways).
LARGE_MESH_FACES = 500_000
LARGE_HAUSDORFF_FRAMES = 3
#: Without ``--frames``, a clip of more frames than this is compared on this many evenly spread frames
#: (a 3,000 s clip at 30 fps is 90,001 frames: every one would take hours and (frames, vertices, 3) memory).
MAX_DEFAULT_FRAMES = 300


def hausdorff_frame_indices(n: int, cap: int) -> list[int]:
    """Indices (into ``n`` compared frames) of ``cap`` frames spread evenly: the ``n`` frames cut into ``cap``
    runs of consecutive frames, run ``i`` holding the frames ``k`` with ``i n / cap <= k < (i + 1) n / cap``, and
    the middle frame of each run taken (a looping clip's first and last frames, often the same pose, are not
    both taken); every frame when ``cap`` is 0 or ``>= n``."""
    if cap <= 0 or cap >= n:
        return list(range(n))
    out = []
    for i in range(cap):
        lo, hi = -(-i * n // cap), -(-(i + 1) * n // cap) - 1
        out.append((lo + hi) // 2)
    return out


def compared_frames(frames: str | None, count: int) -> list[int]:
    """``--frames`` of a clip of ``count`` frames; without it every frame, or :data:`MAX_DEFAULT_FRAMES`
    evenly spread ones (the first and the last among them) when the clip is longer."""
    if frames is None and count > MAX_DEFAULT_FRAMES:
        return sorted({int(round(x)) for x in np.linspace(0, count - 1, MAX_DEFAULT_FRAMES)})
    return parse_frames_spec(frames, count)


def compare(ref: Path, cand: Path, *, clip=None, frames: str | None = None, level: int = 0, fps: float = DEFAULT_FPS,
            samples: int = 20000, hausdorff: bool = True, hausdorff_frames: int | None = None,
            large_faces: int = LARGE_MESH_FACES) -> dict:
    """Distances between two skinned files posed by their own skins at the same clip times.

    Returns
    -------
    dict
        ``hausdorff_rms_pct``, ``hausdorff_max_pct`` (% of the reference's
        world-space bounding-box diagonal in the first compared frame),
        ``hausdorff_rms_m``, ``hausdorff_max_m`` (world units: metres for
        glTF), ``faces``, ``hausdorff_frames`` (the frame numbers measured),
        ``hausdorff_frame_cap`` (0: no cap), ``hausdorff_all_frames``; when
        both have the same faces, in the same order, also (vertices matched corner by corner,
        :func:`corner_map`, where one file splits or welds the other's vertices)
        ``position_rms_m``/``position_max_m``/``position_rms_pct`` (vertex to
        vertex, every frame), ``normal_rms_rad`` and ``hausdorff_max_bound_m``.

    Notes
    -----
    Per frame j, :func:`rigslim.numerics.surface_distance.metro_distance` gives
    the two-sided sampled RMS ``r_j`` and max ``h_j`` (every vertex of both
    surfaces plus ``samples`` area-weighted points per direction); the results
    are ``mean_j r_j`` and ``max_j h_j`` over the Hausdorff frames J:
    ``hausdorff_frames`` evenly spread ones (:func:`hausdorff_frame_indices`;
    0 = every compared frame). By default every frame, and
    :data:`LARGE_HAUSDORFF_FRAMES` when either surface has more than
    ``large_faces`` triangles. With equal topology the frame of the largest
    vertex-to-vertex distance joins J, and since the triangles correspond,
    ``max_j h_j <= max_{j, v} |v_c^j - v_r^j|`` over all frames (a point
    ``sum_i b_i c_i`` of a candidate triangle lies within ``max_i |c_i - r_i|``
    of ``sum_i b_i r_i``): ``hausdorff_max_bound_m``, the bound on every
    frame, the skipped ones too.
    """
    from rigslim.numerics.surface_distance import metro_distance, pymeshlab_available

    if hausdorff and not pymeshlab_available():   # found, not imported here (see surface_distance's docstring)
        from rigslim.errors import StepError

        raise StepError("rigslim compare measures Hausdorff distances with pymeshlab, which is not installed",
                        field="compare", fix="pip install 'rigslim[metro]'")
    from rigslim.io.gltf.document import load_gltf, read_once

    with read_once():           # each file parsed once (the command's own session, if any, shares it)
        count, clip_name, _ = clip_frames(ref, clip, fps, None if is_usd(ref) else load_gltf(ref))
        chosen = compared_frames(frames, count)
        times = [f / fps for f in chosen]
        cand_clip, cand_name, note = candidate_clip(ref, cand, clip, clip_name)
        Pr, Fr, sr = posed_surfaces(ref, clip=clip, times=times)
        Pc, Fc, sc = posed_surfaces(cand, clip=cand_clip, times=times, level=level)
    lo, hi = Pr[0].min(axis=0), Pr[0].max(axis=0)
    diag = float(np.linalg.norm(hi - lo))
    if diag <= 0:
        raise InputError("the reference has zero extent", source=ref, field="POSITION", fix="give a real mesh")
    out = _header("compare") | {
        "reference": str(ref), "candidate": str(cand), "level": level, "clip": clip_name,
        "candidate_clip": cand_name, **({"clip_note": note} if note else {}), "fps": fps,
        "frames": chosen, "clip_frames": count, "reference_diagonal_m": diag, "faces": int(len(Fc)),
        "reference_faces": int(len(Fr))}
    vertex, worst = matched_vertex_errors(Pr, Fr, Pc, Fc, diag)
    out |= vertex
    if hausdorff:
        large = max(len(Fr), len(Fc)) > large_faces
        cap = hausdorff_frames if hausdorff_frames is not None else (LARGE_HAUSDORFF_FRAMES if large else 0)
        idx = hausdorff_frame_indices(len(times), cap)
        if worst is not None and worst not in idx:
            idx = sorted([*idx, worst])
        per_frame = [metro_distance(Pc[j], Fc, Pr[j], Fr, samples) for j in idx]
        rms = np.asarray([d["rms"] for d in per_frame])
        mx = np.asarray([d["max"] for d in per_frame])
        out |= {"hausdorff_rms_pct": float(100 * rms.mean() / diag), "hausdorff_max_pct": float(100 * mx.max() / diag),
                "hausdorff_rms_m": float(rms.mean()), "hausdorff_max_m": float(mx.max()),
                "hausdorff_max_pct_mean": float(100 * mx.mean() / diag),
                "hausdorff_frames": [chosen[j] for j in idx], "hausdorff_frame_cap": int(cap),
                "hausdorff_all_frames": len(idx) == len(times),
                "per_frame_rms_m": rms.tolist(), "per_frame_max_m": mx.tolist(), "samples": samples}
        if "position_max_m" in out:
            out["hausdorff_max_bound_m"] = out["position_max_m"]
    return out


def _clip_names(path: Path) -> list[str | None]:
    """The names of a glTF file's animations (None for an unnamed one)."""
    from rigslim.io.gltf.document import load_gltf

    return [a.get("name") for a in load_gltf(path).json.get("animations", [])]


def candidate_clip(ref: Path, cand: Path, clip, clip_name: str | None) -> tuple[object, str | None, str | None]:
    """The candidate's clip to pose at the reference clip's times: ``(clip, its name, note)``.

    ``--clip`` (``clip`` not None) names one clip of both files (the candidate lacking it is an error naming
    ``--clip`` and its clips). Without it, the reference's first clip is compared with the candidate's clip of
    the same name, else with the candidate's first clip, and ``note`` (one line, printed to stderr by the
    command) says so. A USD side keeps the clip of ``--clip`` or its bound (first) clip: the USD export names
    its ``SkelAnimation`` prims after the glTF's clips, but USD prim names are identifiers (a glTF name with
    spaces or a leading digit is changed), so names are not matched across the two formats.
    """
    if is_usd(ref) or is_usd(cand):
        return clip, None, None
    names = _clip_names(cand)
    shown = ", ".join(repr(n) if n is not None else f"#{i}" for i, n in enumerate(names)) or "none"
    if clip is not None:
        if clip in names or (isinstance(clip, int) and not isinstance(clip, bool) and 0 <= clip < len(names)):
            return clip, clip if isinstance(clip, str) else names[clip], None
        if isinstance(clip, str) and clip.isdigit() and int(clip) < len(names):
            return clip, names[int(clip)], None
        if isinstance(clip, str) and re.fullmatch(r"#\d+", clip) and int(clip[1:]) < len(names) \
                and names[int(clip[1:])] is None:     # an unnamed clip, as it is listed (and labelled in reports)
            return int(clip[1:]), None, None
        raise InputError(f"the candidate has no clip {clip!r} (its clips: {shown})", source=cand, field="--clip",
                         fix="name a clip both files have, or rename the candidate's clip")
    named = clip_name is not None and clip_name in _clip_names(ref)       # an unnamed clip has no name to match
    if named and clip_name in names:
        return clip_name, clip_name, None
    if not names or clip_name is None or (not named and names[0] is None):    # two unnamed clips: nothing to match
        return None, names[0] if names else None, None
    first = repr(names[0]) if names[0] is not None else "#0 (unnamed)"
    mine = repr(clip_name) if named else "#0 (unnamed)"
    return None, names[0], (f"rigslim compare: {cand.name} has no clip {mine} (its clips: {shown}): comparing "
                            f"{ref.name}'s clip {mine} with its first clip {first} (--clip NAME compares a "
                            f"clip both files have)")


def matched_vertex_errors(Pr: np.ndarray, Fr: np.ndarray, Pc: np.ndarray, Fc: np.ndarray,
                          diag: float) -> tuple[dict, int | None]:
    """:func:`vertex_errors` of two posed files whose vertices correspond: the same vertices and faces, or the same
    faces in the same order with one file splitting the other's vertices (:func:`corner_map`, either way);
    ``({}, None)`` when they do not correspond."""
    if Pr.shape == Pc.shape and np.array_equal(Fr, Fc):
        return vertex_errors(Pr, Pc, Fr, diag)
    if (to_ref := corner_map(Fr, Fc, Pc.shape[1])) is not None:       # the candidate splits the reference's vertices
        return vertex_errors(Pr[:, to_ref], Pc, Fc, diag)
    if (to_cand := corner_map(Fc, Fr, Pr.shape[1])) is not None:      # the candidate welds them
        return vertex_errors(Pr, Pc[:, to_cand], Fr, diag)
    return {}, None


def corner_map(Fr: np.ndarray, Fc: np.ndarray, n_candidate: int) -> np.ndarray | None:
    """The ``Fr`` vertex of every ``Fc`` vertex when the two face lists are the same faces in the same order and
    ``Fc`` only splits vertices ``Fr`` shares (a glTF that splits a USD mesh's points at UV seams and materials):
    ``map[Fc] == Fr`` corner by corner, one ``Fr`` vertex per ``Fc`` vertex, every ``Fc`` vertex used
    (``n_candidate`` of them). None when there is no such map (other faces, another order, another mesh)."""
    if Fr.shape != Fc.shape or not len(Fc):
        return None
    out = np.full(n_candidate, -1, dtype=np.int64)
    out[Fc.ravel()] = Fr.ravel()
    if (out < 0).any() or not np.array_equal(out[Fc], Fr):
        return None
    return out


def vertex_errors(Pr: np.ndarray, Pc: np.ndarray, F: np.ndarray, diag: float) -> tuple[dict, int]:
    """Vertex-to-vertex errors of two posings of one mesh ``(frames, m, 3)`` on every frame, and the frame of the
    largest distance.

    ``position_rms_m = sqrt(mean_{j,v} |c_v^j - r_v^j|^2)``, ``position_max_m = max_{j,v} |c_v^j - r_v^j|``,
    ``position_rms_pct`` (of ``diag``) and ``normal_rms_rad``, the RMS angle between the area-weighted vertex
    normals (:func:`rigslim.numerics.blend.per_vertex_normals`) where both are defined (finite and of unit
    length: a vertex no face of non-zero area touches has a zero normal, left out); one frame at a time.
    """
    from rigslim.numerics.blend import per_vertex_normals

    n = len(Pr)
    sq, far = np.empty(n), np.empty(n)      # per frame: sum of squared vertex distances, and the largest distance
    ang = []
    for j in range(n):
        d = Pc[j] - Pr[j]
        d2 = np.einsum("vi,vi->v", d, d)
        sq[j], far[j] = d2.sum(), np.sqrt(d2.max())
        nr, nc = per_vertex_normals(Pr[j], F), per_vertex_normals(Pc[j], F)
        ok = _defined(nr) & _defined(nc)
        ang.append(np.arccos(np.clip((nr[ok] * nc[ok]).sum(axis=1), -1, 1)))
    a = np.concatenate(ang)
    rms = float(np.sqrt(sq.sum() / (n * Pr.shape[1])))
    return ({"position_rms_m": rms, "position_max_m": float(far.max()), "position_rms_pct": 100 * rms / diag,
             "normal_rms_rad": float(np.sqrt((a * a).mean())) if a.size else 0.0}, int(np.argmax(far)))


def _defined(N: np.ndarray) -> np.ndarray:
    """Rows of ``N`` that are unit normals: finite and not the zero vector of a vertex without area."""
    return np.isfinite(N).all(axis=1) & (np.einsum("vi,vi->v", N, N) > 0.25)


def cmd_compare(args) -> int:
    ref, cand = _check_input(args.reference, "REFERENCE"), _check_input(args.candidate, "CANDIDATE")
    _check_fps(args.fps)
    cap = getattr(args, "hausdorff_frames", None)
    if cap is not None and cap < 0:
        raise InputError(f"--hausdorff-frames {cap} is negative", field="--hausdorff-frames",
                         fix="give a frame count, or 0 for every frame")
    with command_session(args, [ref, cand], {}):
        res = compare(ref, cand, clip=args.clip, frames=args.frames, level=args.level, fps=args.fps,
                      samples=args.samples, hausdorff_frames=cap)
        _emit_report(args, res)
    if res.get("clip_note"):
        print(res["clip_note"], file=sys.stderr)
    if args.json:
        print(dumps_strict({k: v for k, v in res.items() if not k.startswith("per_frame")}, default=_jsonable))
        return 0
    print(f"{cand.name} (level {args.level}, {res['faces']} faces) vs {ref.name} ({res['reference_faces']} faces), "
          f"{len(res['frames'])} frames of {res['clip'] or 'the rest pose'}"
          + (f" (evenly spread over its {res['clip_frames']}; --frames chooses others)"
             if len(res['frames']) < res['clip_frames'] and args.frames is None else "") + ":")
    if "position_rms_m" in res:
        print(f"  vertex position RMS {res['position_rms_pct']:.4g} % ({res['position_rms_m']:.4g} m), "
              f"max {res['position_max_m']:.4g} m (same topology)")
    print(f"  Hausdorff RMS {res['hausdorff_rms_pct']:.4f} % of the diagonal ({res['hausdorff_rms_m']:.4g} m), "
          f"max {res['hausdorff_max_pct']:.4f} % ({res['hausdorff_max_m']:.4g} m); "
          f"diagonal {res['reference_diagonal_m']:.4g} m")
    if not res["hausdorff_all_frames"]:
        bound = (f"; every frame's max <= {res['hausdorff_max_bound_m']:.4g} m (vertex to vertex)"
                 if "hausdorff_max_bound_m" in res else "")
        print(f"  Hausdorff on {len(res['hausdorff_frames'])} of {len(res['frames'])} frames "
              f"({', '.join(map(str, res['hausdorff_frames']))}; --hausdorff-frames 0 for all){bound}")
    if "normal_rms_rad" in res:
        print(f"  normal RMS {res['normal_rms_rad']:.4g} rad (same topology)")
    return 0
