"""What the report's renders need, re-read from a run's inputs: mesh, input weights, poses, reduced weights."""

from __future__ import annotations

import copy
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
    json_path = Path(json_path) if json_path else None
    notes: list[str] = []
    if any(s.get("stage") == "generate" for s in document.get("steps") or []):
        raise InputError("the run generated its weights (a 'generate' step), so they cannot be re-read",
                         source=json_path, field="steps",
                         fix="render it with a 'report: out/report.html' step at the end of the pipeline")
    asset, pipeline, pipeline_steps = _run_inputs(document, json_path, notes)
    reduced, normals = {}, {}
    steps = document.get("steps") or []
    for ev in document["evaluations"]:
        at = ev.get("step")
        if not isinstance(at, int):
            continue
        estimator = _evaluation_normals(at, steps, pipeline_steps)
        if estimator is not None:
            normals[at] = estimator
        solve_at = max((i for i in range(1, min(at, len(steps))) if steps[i].get("stage") == "solve"), default=None)
        if solve_at is None:
            continue
        R = _written_reduced(document, ev, steps, solve_at, pipeline, asset, notes)
        if R is not None:
            reduced[at] = R
        if at not in reduced:
            notes.append(f"{document.get('name', 'run')} / {ev.get('name')}: no reduced weights found "
                         "(add a 'write: out/NAME.npz' or .glb step after the solve to render them)")
    return RenderData(asset, reduced, notes, normals)


def _run_inputs(document: dict, json_path: Path | None, notes: list[str]):
    """The asset of the run's inputs (with the document's frame split), the pipeline file (or None) and its
    parsed steps; read with the pipeline's reader options (its file, else the pipeline a command report
    holds, ``pipeline_document``), else from the document's ``inputs``. Poses: :func:`_stacked_clips`."""
    from rigslim.model.poses import FrameSplit
    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import PipelineDoc, Step, load_pipeline
    from rigslim.runtime.inputs import read_inputs

    pipeline = _pipeline_path(document, json_path)
    host = get_host()
    pipeline_steps: list[Step] = []
    in_memory = document.get("pipeline_document")
    if pipeline is not None or isinstance(in_memory, dict):
        named = pipeline or Path(str(document.get("pipeline") or "pipeline"))
        doc, pipeline_steps = load_pipeline(named, host=host,
                                            raw=None if pipeline is not None else copy.deepcopy(in_memory))
        spec = doc.model_copy(update={"poses": None})  # the inputs alone: frames come from the document
        base = pipeline.parent.resolve() if pipeline is not None else (json_path.parent if json_path else Path.cwd())
    else:
        inputs = document.get("inputs") or {}
        if not inputs:
            raise InputError("the document records no inputs", source=json_path, field="inputs",
                             fix="use a metrics JSON written by 'rigslim run'")
        spec = PipelineDoc.model_construct(inputs=dict(inputs), poses=None, steps=[])  # read_inputs' part only
        base = json_path.parent if json_path else Path.cwd()
        notes.append("pipeline file not found: inputs read with default reader options")
    _check_command_input(document, json_path)
    asset = read_inputs(spec, base, host, StepContext(base_dir=base), json_path or "metrics document")
    frames = document.get("frames") or {}
    if asset.poses is not None and frames.get("test"):
        gltf = spec.inputs.get("gltf") if isinstance(spec.inputs, dict) else None
        segments = _stacked_clips(frames, asset, base, json_path or "metrics document",
                                  gltf if isinstance(gltf, dict) else None)
        asset.split = FrameSplit(list(frames.get("examples") or []), list(frames["test"]),
                                 list(frames.get("dropped_from_test") or []), clips=frames.get("clips"),
                                 segments=segments)
    return asset, pipeline, pipeline_steps


def _check_command_input(document: dict, json_path: Path | None) -> None:
    """Refuse, with the way that works, a command report of several skins whose run read a file that is gone
    (``rigslim reduce``'s last skin reads the output of the skin before it, an intermediate file)."""
    command = document.get("command_report") or {}
    skins = command.get("skins") or []
    gltf = (document.get("inputs") or {}).get("gltf")
    if len(skins) > 1 and gltf and not Path(gltf).is_file():
        raise InputError(f"'rigslim {command.get('command')}' ran one pipeline per skin ({len(skins)}); this run "
                         f"(skin {skins[-1]}) read an intermediate file, gone", source=json_path,
                         field="run.inputs.gltf",
                         fix=f"render a skin with 'rigslim run --metrics' on its pipeline (inputs: gltf: "
                             f"{{path: {Path(str(command.get('input'))).name}, skin: N}})")


def _clip_labels(clips) -> list[str]:
    """The clips of a document's ``frames.clips`` in the order the run stacked them: the example clips, then the
    test clips not among them (:func:`rigslim.runtime.clips.clip_split`)."""
    labels: list[str] = []
    for side in ("examples", "validation", "test"):
        parts = (clips or {}).get(side) or []
        for part in parts if isinstance(parts, list) else [parts]:
            label = part.get("clip") if isinstance(part, dict) else None
            if isinstance(label, str) and label not in labels:
                labels.append(label)
    return labels


def _stacked_clips(frames: dict, asset, base: Path, source, gltf_params: dict | None) -> list[dict] | None:
    """Stack the poses of the clips the run used, as it stacked them, so that the document's frame numbers
    (numbered over the stacked clips) name the same poses here; returns the segments
    (``[{"clip", "start", "frames"}]``, :attr:`FrameSplit.segments`), None for a run of one clip.

    ``asset.poses`` is the input animation (``input animation``); the other clips are read as the run read them
    (:func:`rigslim.runtime.clips.load_clip`: an animation of the glTF input by name, or a ``.dmat`` file).
    """
    import numpy as np

    from rigslim.model.poses import Poses
    from rigslim.runtime.clips import load_clip

    labels = _clip_labels(frames.get("clips"))
    if not labels or labels == ["input animation"]:
        return None
    parts, segments, at = [], [], 0
    for label in labels:
        poses = asset.poses if label == "input animation" else \
            load_clip(label, asset, base, source, "frames.clips", gltf_params)[1]
        parts.append(poses.T)
        segments.append({"clip": label, "start": at, "frames": len(poses)})
        at += len(poses)
    asset.poses = Poses(np.concatenate(parts, axis=0), source=" + ".join(labels))
    return segments


def _evaluation_normals(at: int, steps: list[dict], pipeline_steps: list) -> tuple[str | None, dict] | None:
    """The normal estimator the evaluation at step ``at`` measured with: the last 'normals' step before it
    (its name as run, from the document; its parameters from the pipeline file when that step still names
    it), or None."""
    est = [i for i in range(1, min(at, len(steps))) if steps[i].get("stage") == "normals"]
    if not est:
        return None
    i = est[-1]
    name = steps[i].get("plugin")
    same = [s for s in pipeline_steps if s.index == i and s.key == "normals" and s.plugin == name]
    return name, dict(same[0].params) if same else {}


def _written_reduced(document: dict, ev: dict, steps: list[dict], solve_at: int, pipeline: Path | None, asset,
                     notes: list[str]):
    """The reduced weights an evaluation measured, from the first ``.npz``/``.glb``/``.gltf`` written after
    its solve (before the next select or solve) that matches it; None when there is none (a file that
    does not match is noted)."""
    from rigslim.io import read_reduced_npz

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
                problem = _mismatch(asset, R, ev, steps[solve_at], tolerance=0.05 if gltf else 1e-3,
                                    floor=QUANTISATION_FLOOR_PCT if gltf else 1e-6)
                if problem is None:
                    return R
                notes.append(f"{document.get('name', 'run')} / {ev.get('name')}: {path} {problem}; "
                             "not rendered (write each run's weights to its own file)")
    return None


#: Below this position RMS (% of the diagonal) a glTF file's weight quantisation (ubyte: 1/255 steps) dominates
#: the comparison with the recorded error: a reduction that accurate is checked to this absolute tolerance
#: (a 2.5e-6 % reduction read back from ubyte weights measured 8.1e-5 %).
QUANTISATION_FLOOR_PCT = 1e-3


def _mismatch(asset, R, evaluation: dict, solve_step: dict, tolerance: float = 1e-3,
              floor: float = 1e-6) -> str | None:
    """Why the reduced weights ``R`` are not the ones an evaluation measured, or None.

    Checks the shape, that ``R`` holds at most the k solved (a glTF file is as wide as its widest
    row, which may be narrower), and recomputes the position error of the first test
    frame (``100 sqrt(mean_v |v(alpha) - vhat|^2) / diagonal``), which must
    equal the recorded ``position_rms_pct`` (to ``tolerance`` relative, 1e-3: float32
    deformers; and ``floor`` absolute, in %), so that an ``.npz`` overwritten by a later run is not
    rendered under the wrong name.
    """
    from rigslim.numerics.blend import linear_blend

    if asset.mesh is None or R.n_vertices != asset.mesh.n_vertices:
        return "has another vertex count than the mesh"
    if solve_step.get("k") is not None and R.k > solve_step["k"]:
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
        if abs(err - want) > tolerance * abs(want) + floor:   # glTF: quantised weights, 5 % and the floor
            return f"gives {err:.6g}% on frame {f}, the run measured {want:.6g}% (overwritten by another run?)"
    return None
