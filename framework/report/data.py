"""What the report's renders need, re-read from a run's inputs: mesh, input weights, poses, reduced weights."""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from rigslim.errors import InputError


@dataclass
class RenderData:
    """Mesh, input weights, poses and the reduced weights of each evaluation of one run."""

    asset: Any
    reduced: dict  # evaluation step index -> ReducedWeights
    notes: list = field(default_factory=list)
    #: evaluation step index -> (normal estimator name, its parameters); default ("recomputed", {})
    normals: dict = field(default_factory=dict)


def _pipeline_path(document: dict, json_path: Path | None) -> Path | None:
    resolved = document.get("pipeline_file")
    if resolved and Path(resolved).is_file():
        return Path(resolved)
    p = document.get("pipeline")
    if not p:
        return None
    p = Path(p)
    cands = [p] if p.is_absolute() else [Path.cwd() / p] + ([json_path.parent / p] if json_path else [])
    return next((c for c in cands if c.is_file()), None)


def load_render_data(document: dict, json_path=None) -> RenderData:
    """Re-read what a run used, to render it after the fact.

    Inputs come from the run's pipeline file when it is found (relative to
    the working folder or the JSON's folder), so that reader options apply,
    else from the absolute paths under ``inputs``. The test split is the
    document's ``frames``. Reduced weights come from ``.npz`` (or ``.glb``/``.gltf``) files written by
    ``write:`` steps between an evaluation's ``solve`` and the next one.

    Raises
    ------
    InputError
        For runs that generated their weights (``generate`` steps): those
        are not among the inputs; a ``report:`` step renders such runs.
    """
    from types import SimpleNamespace

    from rigslim.io import read_reduced_npz
    from rigslim.model.poses import FrameSplit
    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs

    json_path = Path(json_path) if json_path else None
    notes = []
    if any(s.get("stage") == "generate" for s in document.get("steps") or []):
        raise InputError("the run generated its weights (a 'generate' step), so they cannot be re-read",
                         source=json_path, field="steps",
                         fix="render it with a 'report: out/report.html' step at the end of the pipeline")
    pipeline = _pipeline_path(document, json_path)
    host = get_host()
    pipeline_steps = []
    if pipeline is not None:
        doc, pipeline_steps = load_pipeline(pipeline, host=host)
        spec = SimpleNamespace(inputs=doc.inputs, poses=None)
        base = pipeline.parent.resolve()
    else:
        inputs = document.get("inputs") or {}
        if not inputs:
            raise InputError("the document records no inputs", source=json_path, field="inputs",
                             fix="use a metrics JSON written by 'rigslim run'")
        spec = SimpleNamespace(inputs=dict(inputs), poses=None)
        base = json_path.parent if json_path else Path.cwd()
        notes.append("pipeline file not found: inputs read with default reader options")
    asset = read_inputs(spec, base, host, StepContext(base_dir=base), json_path or "metrics document")
    frames = document.get("frames") or {}
    if asset.poses is not None and frames.get("test"):
        asset.split = FrameSplit(list(frames.get("examples") or []), list(frames["test"]),
                                 list(frames.get("dropped_from_test") or []))
    reduced, normals = {}, {}
    steps = document.get("steps") or []
    for ev in document["evaluations"]:
        at = ev.get("step")
        if not isinstance(at, int):
            continue
        # the normal estimator the evaluation measured with: the last 'normals' step before it (its name
        # as run, from the document; its parameters from the pipeline file when that step still names it)
        est = [i for i in range(1, min(at, len(steps))) if steps[i].get("stage") == "normals"]
        if est:
            i = est[-1]
            name = steps[i].get("plugin")
            same = [s for s in pipeline_steps if s.index == i and s.key == "normals" and s.plugin == name]
            normals[at] = (name, dict(same[0].params) if same else {})
        solve_at = max((i for i in range(1, min(at, len(steps))) if steps[i].get("stage") == "solve"), default=None)
        if solve_at is None:
            continue
        for s in steps[solve_at + 1:]:
            if s.get("stage") in ("select", "solve"):
                break
            if s.get("stage") == "write" and str(s.get("path", "")).lower().endswith((".npz", ".glb", ".gltf")):
                path = Path(s["path"])
                if not path.is_absolute() and pipeline is not None:
                    path = pipeline.parent / path
                if path.is_file():
                    gltf = path.suffix.lower() != ".npz"     # the written glTF's own weights (rigslim.report.gltf)
                    if gltf:
                        from rigslim.report.gltf import reduced_from_gltf
                    R = reduced_from_gltf(path, asset) if gltf else read_reduced_npz(path)
                    problem = _mismatch(asset, R, ev, steps[solve_at], tolerance=0.05 if gltf else 1e-3)
                    if problem is None:
                        reduced[at] = R
                        break
                    notes.append(f"{document.get('name', 'run')} / {ev.get('name')}: {path} {problem}; "
                                 "not rendered (write each run's weights to its own file)")
        if at not in reduced:
            notes.append(f"{document.get('name', 'run')} / {ev.get('name')}: no reduced weights found "
                         "(add a 'write: out/NAME.npz' or .glb step after the solve to render them)")
    return RenderData(asset, reduced, notes, normals)


def _mismatch(asset, R, evaluation: dict, solve_step: dict, tolerance: float = 1e-3) -> str | None:
    """Why the reduced weights ``R`` are not the ones an evaluation measured, or None.

    Checks the shape, k, and recomputes the position error of the first test
    frame (``100 sqrt(mean_v |v(alpha) - vhat|^2) / diagonal``), which must
    equal the recorded ``position_rms_pct`` (to 1e-3 relative: float32
    deformers), so that an ``.npz`` overwritten by a later run is not
    rendered under the wrong name.
    """
    from rigslim.numerics.blend import linear_blend

    if asset.mesh is None or R.n_vertices != asset.mesh.n_vertices:
        return "has another vertex count than the mesh"
    if solve_step.get("k") is not None and R.k != solve_step["k"]:
        return f"holds k={R.k}, the run solved k={solve_step['k']}"
    per = (evaluation.get("metrics") or {}).get("position_rms_pct", {})
    if isinstance(per, dict) and per.get("per_frame") and asset.poses is not None and asset.split is not None:
        f = asset.split.test[0]
        T = asset.poses.T[f]
        d = linear_blend(asset.mesh.V, R, T) - linear_blend(asset.mesh.V, asset.weights, T)
        from rigslim.numerics.units import diagonal

        rms = float(np.sqrt(np.mean(np.sum(d * d, axis=1))))
        want = float(per["per_frame"][0])
        # schema 3: % of the world-space diagonal of the first test frame; 1 and 2: of the rest mesh's
        world = diagonal(linear_blend(asset.mesh.V, asset.weights, T))
        err = min((100.0 * rms / x for x in (world, asset.mesh.bbox_diagonal) if x > 0),
                  key=lambda e: abs(e - want), default=0.0)
        if abs(err - want) > tolerance * max(abs(want), 1e-6) + 1e-9:   # glTF: quantised weights, 5 %
            return f"gives {err:.6g}% on frame {f}, the run measured {want:.6g}% (overwritten by another run?)"
    return None
