"""Levels as files of their own: the names of the split files and the ``OUT.lod.json`` sidecar beside them.

An engine without ``MSFT_lod`` loads one file per level (:func:`rigslim.io.gltf.write.split_levels` cuts
them out of a file written with ``lod: true``) and needs to know when to show which. The sidecar says so:
for level 0 (the input) and each level, its file (relative to the sidecar's folder), faces, vertices,
joints, influences, test-pose error and the screen-coverage range in which it shows
(:mod:`rigslim.io.gltf.switch`, :mod:`rigslim.numerics.screen_coverage`).

Both front ends write them: ``rigslim lod --split`` and the glTF writer's ``split: true`` in a pipeline
(the pipeline that ``rigslim lod --split --save-pipeline`` saves). The rows come from a run's step
reports (``steps``: the metrics document's ``steps`` entries), so both write the same sidecar.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

__all__ = ["SIDECAR_SCHEMA", "SIDECAR_VERSION", "kept_level_targets", "level_rows", "sidecar_path", "split_names",
           "split_outputs", "switch_camera", "write_sidecar"]

#: Schema name of ``OUT.lod.json``.
SIDECAR_SCHEMA = "rigslim-lod-sidecar"
SIDECAR_VERSION = 1


def sidecar_path(out: Path) -> Path:
    """``OUT.lod.json`` beside ``OUT.glb``."""
    out = Path(out)
    return out.with_name(f"{out.stem}.lod.json")


def split_names(out: Path, targets) -> list[Path]:
    """``OUT-50.glb``, ``OUT-25.glb``: one file per level, named after its face target (a fraction of the
    input's faces as a percentage; a face count as ``OUT-500f.glb``)."""
    out = Path(out)
    return [out.with_name(f"{out.stem}-{t * 100:g}{out.suffix}" if t < 1 else f"{out.stem}-{int(t)}f{out.suffix}")
            for t in targets]


def _steps(steps: list[dict], stage: str) -> list[dict]:
    return [s for s in steps if s.get("stage") == stage]


def kept_level_targets(steps: list[dict]) -> dict[str, float]:
    """Level label -> the face target it was made for, from the last decimation's report (``targets``
    entries with ``same_as`` None: the targets that have a level of their own)."""
    report = (_steps(steps, "decimate") or [{}])[-1].get("report") or {}
    return {t["label"]: t["target"] for t in report.get("targets") or []
            if t.get("same_as") is None and t.get("label") is not None}


def split_outputs(out: Path, labels: list[str], steps: list[dict]) -> list[Path]:
    """The split file of each level (``labels``, finest first): named after its face target
    (:func:`split_names`), or, for a level made otherwise (an error or adaptive target), after its label."""
    out = Path(out)
    targets = kept_level_targets(steps)
    return [split_names(out, [targets[x]])[0] if x in targets else out.with_name(f"{out.stem}-{x}{out.suffix}")
            for x in labels]


def level_rows(asset, steps: list[dict]) -> list[dict]:
    """Per level of ``asset.levels``: faces, vertices, joints (and the skin of each level mesh),
    influences (vertices x influences, the most per vertex), the joint budget, error and coverage, from the
    run's decimate and write step reports."""
    decimate = (_steps(steps, "decimate") or [{}])[-1].get("report", {})
    write = (_steps(steps, "write") or [{}])[-1].get("report", {})
    budget = {r["label"]: r for r in (decimate.get("joint_budget") or {}).get("levels", [])}
    switch = {r["label"]: r for r in (write.get("switch") or {}).get("levels", [])}
    prims = {r["label"]: r for r in write.get("level_primitives", [])}
    rows = []
    for lv in asset.levels:
        counts = lv.weights.influence_counts()
        used = np.unique(lv.weights.indices[lv.weights.values != 0])
        row = {"label": lv.label, "faces": lv.n_faces, "vertices": lv.n_vertices, "joints": int(len(used)),
               "influences": int(counts.sum()), "max_bones": int(counts.max(initial=0)),
               "joint_matrices_per_draw": list((prims.get(lv.label) or {}).get("skin_joints", {}).values()) or None}
        if (prims.get(lv.label) or {}).get("joints") is not None:     # as written (a weight may round to 0)
            row["joints"] = int(prims[lv.label]["joints"])
        if lv.label in budget:
            b = budget[lv.label]
            row["joint_budget"] = {k: b.get(k) for k in ("budget", "joints_before", "dropped", "met", "strategy",
                                                         "example_rms", "error", "max_error", "stopped",
                                                         "next_error")}
        if lv.label in switch:
            s = switch[lv.label]
            row |= {k: s[k] for k in ("error_max_m", "error_rms_m", "screen_coverage", "switch_distance_m")}
        rows.append(row)
    return rows


def switch_camera(steps: list[dict]) -> dict | None:
    """The write step's coverage camera and ``MSFT_screencoverage`` (None when unmeasured)."""
    sw = ((_steps(steps, "write") or [{}])[-1].get("report") or {}).get("switch")
    if not sw:
        return None
    return {k: sw.get(k) for k in ("pixel_error", "fov_deg", "resolution", "aspect", "error", "bounding_radius_m",
                                   "test_frames", "coverage")}


def _relative(path: Path, folder: Path) -> str:
    try:
        return os.path.relpath(Path(path).resolve(), Path(folder).resolve())
    except ValueError:            # another drive
        return str(Path(path).resolve())


def sp_indices(W) -> np.ndarray:
    """Column indices of a sparse matrix's stored non-zeros."""
    import scipy.sparse as sp

    A = sp.csr_matrix(W)
    return A.indices[A.data != 0]


def write_sidecar(path: Path, *, source: Path, outputs: list[Path], rows: list[dict], asset, header: dict,
                  camera: dict | None, combined: dict | None = None, radius: float | None = None) -> dict:
    """``OUT.lod.json``: each level's file, faces, joints, error and the coverage range it shows in.

    Level 0 is the input (``asset``: the character as read). Level ``i`` shows while
    ``min_coverage <= coverage < max_coverage`` (Babylon's screen coverage of the bounding sphere,
    :mod:`rigslim.numerics.screen_coverage`), i.e. from ``switch_distance_m`` on; file paths are relative
    to the sidecar's folder. ``camera``: :func:`switch_camera` (None: no coverage measured). ``combined``
    and ``radius``: the level-0 figures and coverage of a file whose skins were simplified apart, and the
    character's bounding radius (``rows`` then combine the skins' levels too).
    """
    from rigslim.io.atomic import atomic_path
    from rigslim.io.jsonsafe import dumps_strict

    cam = camera or {}
    cov = (combined or cam).get("coverage") or []
    full_joints = int(len(np.unique(sp_indices(asset.weights)))) if asset.weights is not None else None
    levels = [{"level": 0, "file": _relative(source, path.parent), "label": "input",
               "faces": combined["faces"] if combined else asset.mesh.n_faces if asset.mesh is not None else None,
               "joints": combined["joints"] if combined else full_joints,
               "error_max_m": 0.0, "error_rms_m": 0.0, "max_coverage": 1.0,
               "min_coverage": cov[0] if cov else None, "switch_distance_m": 0.0}]
    for i, (row, file) in enumerate(zip(rows, outputs, strict=False), 1):
        levels.append({"level": i, "file": _relative(file, path.parent), "label": row["label"], "faces": row["faces"],
                       "vertices": row["vertices"], "joints": row["joints"], "influences": row["influences"],
                       "max_bones": row["max_bones"], "error_max_m": row.get("error_max_m"),
                       "error_rms_m": row.get("error_rms_m"),
                       "max_coverage": cov[i - 1] if len(cov) > i - 1 else None,
                       "min_coverage": cov[i] if len(cov) > i else None,
                       "switch_distance_m": row.get("switch_distance_m")} | ({"skins": row["skins"]} if "skins" in row
                                                                             else {}))
    doc = header | {"sidecar_schema": SIDECAR_SCHEMA, "sidecar_version": SIDECAR_VERSION, "camera": {
        k: cam.get(k) for k in ("pixel_error", "fov_deg", "resolution", "aspect", "error")},
        "bounding_radius_m": radius if radius is not None else cam.get("bounding_radius_m"),
        "test_frames": cam.get("test_frames"),
        "coverage": "pi r^2 / (4 aspect d^2 tan^2(fov / 2)): the bounding sphere's share of the screen area "
                    "(Babylon.js's MSFT_screencoverage); show level i while min_coverage <= coverage < max_coverage",
        "levels": levels}
    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_strict(doc, indent=2) + "\n")
    return doc
