"""What ``rigslim lod`` adds per level: joint budgets, switch hints, the report rows and the ``--split`` sidecar.

- ``--max-joints 40,24,12`` (one per level, or one for all; a number below 1 is a fraction of the skin's
  joints), ``--keep-joints REGEX`` and ``--joint-choice`` become the decimation step's ``joint_budget``,
  ``keep_joints`` and ``joint_choice`` (:mod:`rigslim.plugins.decimation.joint_budget`);
- ``--pixel-error P``, ``--fov DEG``, ``--resolution H`` become the glTF writer's coverage parameters
  (:mod:`rigslim.io.gltf.switch`);
- :func:`level_rows` gives each level's faces, joints, influences, error and coverage for ``--report``;
- :func:`write_sidecar` writes ``OUT.lod.json`` beside ``--split`` outputs, for engines without ``MSFT_lod``.
"""

from __future__ import annotations

import sys
from pathlib import Path

from rigslim.errors import InputError
from rigslim.io.gltf import sidecar
from rigslim.io.gltf.sidecar import SIDECAR_SCHEMA, sidecar_path

__all__ = ["SIDECAR_SCHEMA", "add_level_arguments", "decimate_params", "level_rows", "parse_max_joints",
           "print_levels", "say_joint_budget_stops", "sidecar_path", "skin_split_rows", "switch_camera", "write_params",
           "write_sidecar"]

def add_level_arguments(p) -> None:
    """The per-level options of ``rigslim lod``."""
    p.add_argument("--max-joints", metavar="J", help="joints each level's skin may list: one per level "
                   "(40,24,12) or one for all; below 1 a fraction of the skin's joints (0.5)")
    p.add_argument("--keep-joints", metavar="REGEX", help="with --max-joints: never drop joints whose name "
                   "this regular expression finds (joints with attached nodes and other skins' joints stay anyway)")
    p.add_argument("--joint-choice", choices=["leaf-first", "global", "best"], default=None,
                   help="with --max-joints: drop leaf joints only, any joint, or the better of both (default global)")
    p.add_argument("--pixel-error", type=float, default=1.0, metavar="P",
                   help="switch coverage: where a level's test-pose error projects to P pixels (default 1)")
    p.add_argument("--switch-error", choices=["max", "rms"], default="max",
                   help="switch coverage from each level's largest test-pose error (default) or its RMS")
    p.add_argument("--fov", type=float, default=60.0, metavar="DEG", help="... for this vertical field of view "
                   "(default 60)")
    p.add_argument("--resolution", type=int, default=1080, metavar="H", help="... and a viewport H pixels high "
                   "(default 1080)")


def parse_max_joints(text: str | None, n_levels: int) -> float | list[float] | None:
    """``--max-joints``: one number for every level, or one per level (``40,24,12``)."""
    if text is None:
        return None
    try:
        values = [float(x) for x in str(text).split(",") if x.strip()]
    except ValueError:
        values = []
    bad = not values or any(not v > 0 or (v >= 1 and v != int(v)) for v in values)
    if bad or len(values) not in (1, n_levels):
        raise InputError(f"--max-joints '{text}' is not one joint count (or fraction) per level of {n_levels}",
                         field="--max-joints", fix="give one count for all levels (24)"
                         + (f" or {n_levels} counts (e.g. {','.join(str(40 >> i) for i in range(n_levels))})"
                            if n_levels > 1 else "") + ", or fractions of the skin's joints (0.5)")
    values = [int(v) if v >= 1 else v for v in values]
    return values[0] if len(values) == 1 else values


def decimate_params(args, n_levels: int) -> dict:
    """The decimation step's joint parameters from the command line (empty without ``--max-joints``)."""
    budget = parse_max_joints(getattr(args, "max_joints", None), n_levels)
    if budget is None:
        for flag in ("keep_joints", "joint_choice"):
            if getattr(args, flag, None) is not None:
                raise InputError(f"--{flag.replace('_', '-')} needs --max-joints", field=f"--{flag.replace('_', '-')}",
                                 fix="add --max-joints J (joints per level), or leave it out")
        return {}
    out: dict = {"joint_budget": budget}
    if getattr(args, "keep_joints", None):
        from rigslim.io.gltf.joints import compile_keep_pattern

        compile_keep_pattern(args.keep_joints, "--keep-joints")
        out["keep_joints"] = args.keep_joints
    if getattr(args, "joint_choice", None):
        out["joint_choice"] = args.joint_choice
    return out


def write_params(args) -> dict:
    """The glTF writer's coverage parameters from the command line."""
    if not args.pixel_error > 0:
        raise InputError(f"--pixel-error {args.pixel_error} is not positive", field="--pixel-error",
                         fix="give a number of pixels, e.g. 1")
    if not 0 < args.fov < 180:
        raise InputError(f"--fov {args.fov} is not an angle in (0, 180) degrees", field="--fov", fix="e.g. --fov 60")
    if args.resolution < 1:
        raise InputError(f"--resolution {args.resolution} is not a pixel count", field="--resolution",
                         fix="give the viewport height in pixels, e.g. 1080")
    return {"pixel_error": float(args.pixel_error), "fov": float(args.fov), "resolution": int(args.resolution),
            "switch_error": getattr(args, "switch_error", "max")}


def level_rows(result) -> list[dict]:
    """Per level of a ``rigslim lod`` run: faces, vertices, joints (and the skin of each level mesh),
    influences (vertices x influences, the most per vertex), the joint budget, error and coverage
    (:func:`rigslim.io.gltf.sidecar.level_rows`)."""
    return sidecar.level_rows(result.asset, result.document["steps"])


def print_levels(rows: list[dict]) -> None:
    """One stdout line per level: faces, joints, influences, error and where it switches in; a level that is
    never shown (the next, coarser level switches in at the same coverage, its maximum error being no larger)
    says so."""
    for i, r in enumerate(rows):
        line = f"  {r['label']}: {r['faces']} faces, {r['joints']} joints, {r['influences']} influences"
        if r.get("error_max_m") is not None:
            line += (f", test-pose error max {r['error_max_m']:.3g} m (RMS {r['error_rms_m']:.3g} m), from "
                     f"{r['switch_distance_m']:.3g} m / coverage {r['screen_coverage']:.3g}")
            nxt = rows[i + 1] if i + 1 < len(rows) else None
            if nxt is not None and nxt.get("screen_coverage") is not None and \
                    nxt["screen_coverage"] >= r["screen_coverage"]:
                line += (f"; never shown: {nxt['label']}'s max error ({nxt['error_max_m']:.3g} m) is no larger, "
                         "so it switches in at the same distance")
        b = r.get("joint_budget")
        if b and b.get("stopped") == "max_error":
            line += f" (joint budget {b['budget']} not met within --max-error)"
        elif b and not b.get("met", True):
            line += f" (joint budget {b['budget']} not met: the rest are joints the file needs)"
        print(line)


def say_joint_budget_stops(rows: list[dict], max_error: str | None) -> None:
    """One stderr line per level whose joint budget the error bound stopped: the joints kept, the error the
    next merge would reach against the bound, and the fix."""
    for r in rows:
        b = r.get("joint_budget") or {}
        if b.get("stopped") != "max_error":
            continue
        print(f"rigslim lod: level {r['label']} keeps {r['joints']} joints, above --max-joints {b['budget']}: "
              f"merging one more would reach error {b['next_error']:.4g} m, above --max-error {max_error} "
              f"({b['max_error']:.4g} m; the level is at {b['error']:.4g} m); raise --max-joints or --max-error",
              file=sys.stderr)


def switch_camera(result) -> dict | None:
    """The write step's coverage camera and ``MSFT_screencoverage`` (None when unmeasured)."""
    return sidecar.switch_camera(result.document["steps"])


def skin_split_rows(per_skin: list[dict], targets: list[float], radius: float, camera: dict) -> tuple[list[dict], dict]:
    """The ``--split`` files' rows when each skin was simplified on its own (``rigslim lod`` on a file with
    several skins): file i shows, for every skin, its level for ``targets[i]`` or, where its levels end before
    that target, its coarsest level (none: its full mesh), as ``level_document`` does.

    A file's faces, vertices and influences are its skins' sums; ``joints`` and ``max_bones`` the most of any
    skin (each skin is drawn with its own joint palette); ``error_max_m`` and ``error_rms_m`` the largest of its
    skins'; ``skins`` lists what each skin shows. Its coverage is that of the whole character's bounding sphere
    (``radius``) where the file's error, the largest of any skin's (and of any finer file's), projects to the
    camera's pixel error (:func:`rigslim.numerics.screen_coverage.coverage_series`). Returns the rows and the
    level-0 row's ``faces`` and ``joints`` (``per_skin``'s ``input_faces`` and ``input_joints``), with ``coverage``
    (one value per file and the input's).
    """
    from rigslim.numerics.screen_coverage import coverage_series

    rows = []
    for target in targets:
        shown = []
        for entry in per_skin:
            reached = [r for r in entry["rows"] if r["ratio"] >= target]
            row = reached[-1] if reached else None
            shown.append({"skin": entry["skin"], "label": row["label"] if row else "input",
                          "faces": row["faces"] if row else entry["input_faces"], "row": row})
        levels = [x["row"] for x in shown if x["row"] is not None]
        rows.append({"label": " + ".join(dict.fromkeys(x["label"] for x in shown)),
                     "faces": sum(x["faces"] for x in shown),
                     "vertices": sum(r["vertices"] for r in levels),
                     "joints": max((r["joints"] for r in levels), default=0),
                     "influences": sum(r["influences"] for r in levels),
                     "max_bones": max((r["max_bones"] for r in levels), default=0),
                     "error_max_m": max((r.get("error_max_m") or 0.0 for r in levels), default=0.0),
                     "error_rms_m": max((r.get("error_rms_m") or 0.0 for r in levels), default=0.0),
                     "skins": [{k: x[k] for k in ("skin", "label", "faces")} for x in shown]})
    series = coverage_series([r["error_max_m"] if camera.get("error") != "rms" else r["error_rms_m"] for r in rows],
                             radius, pixel_error=camera["pixel_error"], fov=camera["fov_deg"],
                             resolution=camera["resolution"], aspect=camera["aspect"])
    for row, d in zip(rows, series["switch_distance_m"], strict=True):
        row["switch_distance_m"] = d
    return rows, {"faces": sum(e["input_faces"] for e in per_skin), "coverage": series["coverage"],
                  "joints": max((e["input_joints"] for e in per_skin), default=None)}


def write_sidecar(path: Path, *, source: Path, outputs: list[Path], rows: list[dict], result, header: dict,
                  combined: dict | None = None, radius: float | None = None, camera: dict | None = None) -> dict:
    """``OUT.lod.json`` of a ``rigslim lod --split`` run (:func:`rigslim.io.gltf.sidecar.write_sidecar`;
    ``camera``: the switch camera, by default the run's write step's)."""
    return sidecar.write_sidecar(path, source=source, outputs=outputs, rows=rows, asset=result.asset, header=header,
                                 camera=camera or switch_camera(result), combined=combined, radius=radius)
