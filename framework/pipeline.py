"""YAML pipelines: validated documents, step by step execution, the metrics JSON.

A pipeline names inputs (paths relative to the YAML file), the example/test
frame split, and a list of steps. Each step is a mapping with exactly one
stage key (``generate``, ``select``, ``solve``, ``decimate``, ``deform``,
``normals``, ``evaluate``, ``write``, ``report``) whose value names the plugin; the other
keys are the plugin's parameters (plus an optional ``name``). See
docs/pipelines.md.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml
from pydantic import BaseModel, ConfigDict, ValidationError, field_validator

import rigslim
from rigslim.asset import Asset
from rigslim.clips import clip_split, uses_clips
from rigslim.errors import PipelineError, RigslimError, brief, closest
from rigslim.errors import PluginNotFoundError as PluginNotFound
from rigslim.evaluation import Evaluation
from rigslim.host import PluginHost, get_host
from rigslim.io.atomic import atomic_path, check_output, output_transaction
from rigslim.metrics_document import SCHEMA_VERSION, UNITS, merge_levels
from rigslim.plugin import STEP_STAGES, StepContext
from rigslim.poses import FrameSplit
from rigslim.weights import influence_counts
from rigslim.yamlio import load_yaml_file

#: Order in which input roles are read (others follow, in file order).
ROLE_ORDER = ["gltf", "mesh", "skeleton", "cage", "weights", "animation"]


class ClipFrames(BaseModel):
    """One side of a two-clip ``poses:`` (:mod:`rigslim.clips`)."""

    model_config = ConfigDict(extra="forbid")
    clip: str | int
    frames: str | int | list[str | int] | None = None


class PoseSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    examples: str | int | list[str | int] | ClipFrames
    test: str | int | list[str | int] | ClipFrames


class PipelineDoc(BaseModel):
    """The validated YAML document."""

    model_config = ConfigDict(extra="forbid")
    name: str | None = None
    description: str | None = None
    inputs: dict[str, Any] = {}
    poses: PoseSpec | None = None
    steps: list[dict[str, Any]]

    @field_validator("steps")
    @classmethod
    def _nonempty(cls, v):
        if not v:
            raise ValueError("a pipeline needs at least one step")
        return v


@dataclass
class Step:
    """One parsed step."""

    index: int           # 1-based
    key: str             # stage key in YAML ("solve")
    stage: str           # stage name ("weight-solver")
    plugin: Any          # plugin name, or for evaluate a list of (name, params)
    params: dict
    name: str


@dataclass
class RunResult:
    """What :func:`run_pipeline` returns: the final asset and the metrics document."""

    asset: Asset
    document: dict
    evaluations: list = field(default_factory=list)


def _format_validation(err: ValidationError) -> tuple[str, str]:
    e = err.errors()[0]
    loc = ".".join(str(x) for x in e["loc"])
    return loc, e["msg"]


def load_pipeline(path, overrides: list[str] = (), host: PluginHost | None = None, *,
                  raw: dict | None = None) -> tuple[PipelineDoc, list[Step]]:
    """Read, validate and parse a pipeline file.

    Parameters
    ----------
    path : path to the YAML file
    overrides : list of "STEP.PARAM=VALUE"
        STEP is a step's ``name``, its stage key, its plugin name or its
        1-based index; VALUE is parsed as YAML.
    raw : dict, optional
        The document itself (as YAML would load it); ``path`` then only names
        it in messages, and its folder is where relative paths resolve.
    """
    host = host or get_host()
    path = Path(path)
    if raw is None:
        raw = load_yaml_file(path)  # UTF-8, no repeated keys, bounded aliases and nesting
    if not isinstance(raw, dict):
        raise PipelineError("the document is not a mapping", source=path, field="top level",
                            fix="start with 'inputs:', 'poses:' and 'steps:'")
    odd = next((k for k in raw if not isinstance(k, str)), None)
    if odd is not None or any(not isinstance(k, str) for k in raw):
        raise PipelineError(f"top-level key {brief(odd)} is not a name", source=path, field="top level",
                            fix="the top-level keys are " + ", ".join(PipelineDoc.model_fields))
    try:
        doc = PipelineDoc.model_validate(raw)
    except ValidationError as err:
        loc, msg = _format_validation(err)
        top = loc.split(".")[0]
        fix = closest(top, PipelineDoc.model_fields) if "extra" in err.errors()[0]["type"] else \
            "see docs/pipelines.md"
        raise PipelineError(msg, source=path, field=loc, fix=fix) from None
    steps = [_parse_step(i, s, path, host) for i, s in enumerate(doc.steps, 1)]
    for item in overrides:
        _apply_override(item, steps, path, host)
    return doc, steps


def _parse_step(index: int, raw: dict, path: Path, host: PluginHost) -> Step:
    if not isinstance(raw, dict):
        raise PipelineError(f"step {index} is not a mapping", source=path, field=f"steps[{index}]",
                            fix="write each step as '- solve: poisson' with its parameters below")
    keys = [k for k in raw if k in STEP_STAGES]
    if len(keys) != 1:
        unknown = [k for k in raw if k not in STEP_STAGES and k != "name"]
        hint = closest(unknown[0], STEP_STAGES) if unknown and not keys else \
            "give exactly one of " + ", ".join(STEP_STAGES)
        what = f"unknown stage '{unknown[0]}'" if unknown and not keys else \
            f"step has {len(keys)} stage keys ({', '.join(keys) or 'none'})"
        raise PipelineError(what, source=path, field=f"steps[{index}]", fix=hint)
    key = keys[0]
    stage = STEP_STAGES[key]
    params = {k: v for k, v in raw.items() if k not in (key, "name")}
    value = raw[key]
    if key == "evaluate":
        plugin = _parse_metrics(value, index, path, host)
        name = raw.get("name") or f"evaluate{index}"
    elif key in ("write", "report"):
        if not isinstance(value, str):
            raise PipelineError(f"{key} needs an output path", source=path, field=f"steps[{index}].{key}",
                                fix="write e.g. 'write: out/weights.npz' or 'report: out/report.html'")
        plugin = value
        name = raw.get("name") or f"{key}{index}"
    else:
        if not isinstance(value, str):
            raise PipelineError(f"'{key}' needs a plugin name", source=path, field=f"steps[{index}].{key}",
                                fix=closest("", host.plugins(stage)))
        try:
            plugin_obj = host.get(stage, value)
        except PluginNotFound as e:
            raise PipelineError(e.problem, source=path, field=f"steps[{index}].{key}", fix=e.fix) from None
        _check_params(plugin_obj, params, path, f"steps[{index}]")
        plugin = value
        name = raw.get("name") or value
    return Step(index, key, stage, plugin, params, str(name))


def _parse_metrics(value, index, path, host) -> list[tuple[str, dict]]:
    if isinstance(value, str):
        items = [(value, {})]
    elif isinstance(value, list):
        items = []
        for v in value:
            if isinstance(v, str):
                items.append((v, {}))
            elif isinstance(v, dict) and len(v) == 1:
                (n, p), = v.items()
                items.append((n, p or {}))
            else:
                raise PipelineError(f"cannot read metric entry {brief(v)}", source=path,
                                    field=f"steps[{index}].evaluate", fix="list metric names")
    elif isinstance(value, dict):
        items = [(n, p or {}) for n, p in value.items()]
    else:
        raise PipelineError("evaluate needs metric names", source=path, field=f"steps[{index}].evaluate",
                            fix="write e.g. 'evaluate: [position-rms, normal-deviation]'")
    for n, p in items:
        if not isinstance(n, str) or not isinstance(p, dict):
            raise PipelineError(f"metric entry {brief(n)}: {brief(p)} is not 'name: {{parameters}}'", source=path,
                                field=f"steps[{index}].evaluate", fix="write e.g. 'evaluate: {position-rms: {}}' "
                                "or a list of metric names")
    for n, p in items:
        try:
            metric = host.get("metric", n)
        except PluginNotFound as e:
            raise PipelineError(e.problem, source=path, field=f"steps[{index}].evaluate", fix=e.fix) from None
        _check_params(metric, p, path, f"steps[{index}].evaluate.{n}")
    return items


def _check_params(plugin, params: dict, path, where: str):
    try:
        return plugin.parse_params(params)
    except ValidationError as err:
        # An unknown name usually explains a "missing" one too (a typo): report it first.
        e = sorted(err.errors(), key=lambda x: x["type"] != "extra_forbidden")[0]
        loc = ".".join(str(x) for x in e["loc"])
        if e["type"] == "extra_forbidden":
            fields = plugin.Params.model_fields
            fix = closest(loc, fields) if fields else f"'{plugin.name}' takes no parameters"
            raise PipelineError(f"unknown parameter '{loc}' for {plugin.stage} '{plugin.name}'", source=path,
                                field=f"{where}.{loc}", fix=fix) from None
        fields = ", ".join(plugin.Params.model_fields) or "none"
        raise PipelineError(f"{e['msg'].lower()} (got {brief(e.get('input'))})" if e["type"] != "missing"
                            else "required parameter is missing", source=path, field=f"{where}.{loc}",
                            fix=f"{plugin.stage} '{plugin.name}' takes: {fields}") from None


def _apply_override(item: str, steps: list[Step], path: Path, host: PluginHost) -> None:
    """One ``--set``: ``STEP.PARAM=VALUE`` sets a parameter; ``STEP=PLUGIN`` (or ``STEP.KEY=PLUGIN``,
    KEY the step's stage key) replaces the step's plugin, keeping the parameters the new plugin takes."""
    lhs = item.split("=", 1)[0]
    if "=" not in item or not lhs.strip():
        raise PipelineError(f"--set '{item}' is not STEP.PARAM=VALUE or STEP=PLUGIN", source=path, field="--set",
                            fix="write e.g. --set select.k=6 or --set solve=poisson")
    value = item.split("=", 1)[1]
    target, param = lhs.rsplit(".", 1) if "." in lhs else (lhs, None)
    matches = [s for s in steps if target in (s.name, s.key, str(s.index)) or
               (isinstance(s.plugin, str) and s.plugin == target)]
    if not matches:
        names = [s.name for s in steps] + [s.key for s in steps]
        raise PipelineError(f"--set names no step '{target}'", source=path, field="--set", fix=closest(target, names))
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError:
        parsed = value
    for step in matches:
        if step.key == "evaluate":
            raise PipelineError("--set cannot change evaluate steps", source=path, field="--set",
                                fix="edit the pipeline file")
        if param is None or param == step.key:
            if not isinstance(parsed, str) or not parsed.strip():
                what = "an output path" if step.key in ("write", "report") else "a plugin name"
                raise PipelineError(f"--set '{item}' gives {parsed!r}, not {what}", source=path, field="--set",
                                    fix=f"write e.g. --set {target}=NAME (rigslim plugins lists the names)"
                                    if what == "a plugin name" else f"write e.g. --set {target}=out/file")
            if step.key not in ("write", "report") and step.name == step.plugin:
                step.name = parsed  # a default name (the plugin's) follows the plugin
            step.plugin = parsed
            if step.key not in ("write", "report"):
                try:
                    plugin = host.get(step.stage, parsed)
                except PluginNotFound as e:
                    raise PipelineError(e.problem, source=path, field="--set", fix=e.fix) from None
                # Parameters of the old plugin that the new one does not take are dropped.
                step.params = {k: v for k, v in step.params.items() if k in plugin.Params.model_fields}
                _check_params(plugin, step.params, path, f"steps[{step.index}]")
            continue
        step.params[param] = parsed
        if step.key not in ("write", "report"):
            _check_params(host.get(step.stage, step.plugin), step.params, path, f"steps[{step.index}]")


def _gltf_inputs(inputs: dict) -> dict:
    """Beside ``gltf:``, ``animation:`` (a clip name or index, not a file) and ``fps:`` are the glTF reader's."""
    inputs = dict(inputs)
    spec = inputs["gltf"]
    spec = {"path": spec} if isinstance(spec, str) else dict(spec) if isinstance(spec, dict) else spec
    if isinstance(spec, dict):
        for key in ("animation", "fps"):
            value = inputs.get(key)
            if value is not None and not isinstance(value, dict) and not (
                    isinstance(value, str) and Path(value).suffix.lower() == ".dmat"):
                spec.setdefault(key, inputs.pop(key))
        inputs["gltf"] = spec
    return inputs


def read_inputs(doc: PipelineDoc, base: Path, host: PluginHost, ctx: StepContext, source) -> Asset:
    """Fill an :class:`Asset` from the ``inputs`` section, each role by its reader."""
    asset = Asset()
    inputs = dict(doc.inputs)
    normalize = inputs.pop("normalize", None)
    if "gltf" in inputs:
        inputs = _gltf_inputs(inputs)
    readers = host.plugins("reader")
    specs = {}
    for role, spec in inputs.items():
        if isinstance(spec, str):
            spec = {"path": spec}
        if not isinstance(spec, dict) or "path" not in spec:
            raise PipelineError(f"input '{role}' needs a path", source=source, field=f"inputs.{role}",
                                fix=f"write '{role}: path/to/file'")
        spec = dict(spec)
        if role == "weights" and normalize is not None:
            spec.setdefault("normalize", normalize)
        specs[role] = spec
    roles_known = sorted({r.role for r in readers.values()})
    order = sorted(specs, key=lambda r: ROLE_ORDER.index(r) if r in ROLE_ORDER else len(ROLE_ORDER))
    for role in order:
        spec = dict(specs[role])
        file = Path(spec.pop("path"))
        file = file if file.is_absolute() else base / file
        name = spec.pop("reader", None)
        if name is not None:
            try:
                reader = host.get("reader", name)
            except PluginNotFound as e:
                raise PipelineError(e.problem, source=source, field=f"inputs.{role}.reader", fix=e.fix) from None
        else:
            cands = [r for r in readers.values() if r.role == role]
            if not cands:
                raise PipelineError(f"unknown input '{role}'", source=source, field=f"inputs.{role}",
                                    fix=closest(role, roles_known))
            fitting = [r for r in cands if file.suffix.lower() in r.suffixes]
            if not fitting:
                sufs = sorted({s for r in cands for s in r.suffixes})
                raise PipelineError(f"no reader for '{file.suffix}' files as {role}", source=source,
                                    field=f"inputs.{role}", fix="use one of " + ", ".join(sufs))
            reader = fitting[0]
        if not file.exists():
            raise PipelineError("input file not found", source=file, field=f"inputs.{role}",
                                fix="check the path (relative paths are relative to the pipeline file)")
        params = _check_params(reader, spec, source, f"inputs.{role}")
        reader.read(file, asset, params, ctx)
        asset.provenance.setdefault("inputs", {})[role] = str(file)
    if asset.poses is None and asset.handles is not None:
        asset.provenance["poses"] = "rest pose only"
    if doc.poses is not None and uses_clips(doc.poses):
        gltf = _gltf_inputs(doc.inputs).get("gltf") if "gltf" in doc.inputs else None
        asset.poses, asset.split = clip_split(doc.poses, asset, base, source, gltf if isinstance(gltf, dict) else None)
    elif doc.poses is not None:
        if asset.poses is None:
            raise PipelineError("a 'poses' split is given but no animation", source=source,
                                field="inputs.animation", fix="add 'animation:' under inputs")
        asset.split = FrameSplit.from_specs(doc.poses.examples, doc.poses.test, len(asset.poses), source=source)
    return asset


def run_pipeline(path, *, overrides: list[str] = (), metrics_path=None, host: PluginHost | None = None,
                 console=None, on_evaluation: Callable | None = None, raw: dict | None = None) -> RunResult:
    """Run a pipeline file (or the document ``raw``, see :func:`load_pipeline`); return the asset and metrics.

    Outputs are committed together at the end: ``write``/``report`` steps and
    the metrics JSON (if asked for) stage temporary files, which are renamed
    into place only after the last step and the metrics succeeded; a failed or
    interrupted run leaves every output as it was (docs/pipelines.md, Guarantees).
    """
    with output_transaction():
        return _run_pipeline(path, overrides=overrides, metrics_path=metrics_path, host=host, console=console,
                             on_evaluation=on_evaluation, raw=raw)


def _run_pipeline(path, *, overrides, metrics_path, host, console, on_evaluation, raw=None) -> RunResult:
    from rigslim.progress import Reporter

    host = host or get_host()
    path = Path(path)
    doc, steps = load_pipeline(path, overrides, host, raw=raw)
    if metrics_path is not None:
        check_output(metrics_path)
    base = path.parent.resolve()
    reporter = Reporter(console)
    t0 = time.perf_counter()
    with reporter.status("reading inputs"):
        asset = read_inputs(doc, base, host, reporter.context(base), path)
    document = {
        "schema_version": SCHEMA_VERSION,
        "units": dict(UNITS),
        "rigslim_version": rigslim.__version__,
        "pipeline": str(path),
        "pipeline_file": str(path.resolve()),
        "name": doc.name or path.stem,
        "inputs": asset.provenance.get("inputs", {}),
        "mesh": ({"vertices": asset.mesh.n_vertices, "faces": asset.mesh.n_faces,
                  "bbox_diagonal": asset.mesh.bbox_diagonal} if asset.mesh is not None else None),
        "handles": ({"kind": asset.handles.kind, "count": asset.handles.n} if asset.handles else None),
        "frames": ({"examples": asset.split.examples, "test": asset.split.test,
                    "dropped_from_test": asset.split.dropped,
                    **({"clips": asset.split.clips} if asset.split.clips else {})} if asset.split else None),
        "steps": [{"stage": "read", "plugin": "inputs", "seconds": time.perf_counter() - t0}],
        "evaluations": [],
    }
    if asset.split and asset.split.dropped:
        reporter.note(f"test frames {asset.split.dropped} are also example frames: dropped from the test set")
    for step in steps:
        ctx = reporter.context(base)
        t = time.perf_counter()
        with reporter.status(f"step {step.index}: {step.key} {step.plugin if isinstance(step.plugin, str) else ''}"):
            try:
                entry = _run_step(step, asset, host, ctx, base, path, document)
            except RigslimError as e:
                if not e.source:
                    e.source = f"{path} steps[{step.index}] ({step.key})"
                    e.args = (e.one_line(),)
                raise
        entry.update({"seconds": time.perf_counter() - t})
        if ctx.report:
            entry.setdefault("report", ctx.report)
            if step.key == "solve":
                entry["solver"] = ctx.report
        document["steps"].append(entry)
        if step.key == "evaluate" and on_evaluation:
            on_evaluation(document["evaluations"][-1])
    if asset.handles is not None:  # a generate step may have replaced the skeleton by a cage
        document["handles"] = {"kind": asset.handles.kind, "count": asset.handles.n}
    document["seconds"] = time.perf_counter() - t0
    if metrics_path is not None:
        write_metrics(metrics_path, document)
    return RunResult(asset, document, document["evaluations"])


def _run_step(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
              document: dict) -> dict:
    """Run one step; return its entry of the metrics document.

    ``evaluate`` (several metrics) and ``write``/``report`` (a writer chosen by the output path) have runners
    of their own; every other step runs its plugin's :meth:`rigslim.plugin.Plugin.apply`, which stores the
    stage's result in the asset.
    """
    entry = {"stage": step.key, "plugin": step.plugin if isinstance(step.plugin, str) else "metrics",
             "name": step.name}
    runner = _STEP_RUNNERS.get(step.key)
    if runner is not None:
        return runner(step, asset, host, ctx, base, source, document, entry)
    plugin = host.get(step.stage, step.plugin)
    entry.update(plugin.apply(asset, plugin.parse_params(step.params), ctx))
    return entry


def _run_evaluate(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
                  document: dict, entry: dict) -> dict:
    evaluation = Evaluation(asset, host, ctx)
    metrics: dict = {}
    levels: list[dict] = []
    for name, p in step.plugin:
        metric = host.get("metric", name)
        with np.errstate(over="ignore", invalid="ignore"):  # non-finite results: null + note in the JSON
            values = dict(metric.compute(evaluation, metric.parse_params(p), ctx))
        merge_levels(levels, values.pop("levels", None) or [])
        metrics.update(values)
    label = step.name if step.name != f"evaluate{step.index}" else _default_label(document, asset)
    evaluation_entry = {"name": label, "step": step.index, "metrics": metrics}
    if levels:
        evaluation_entry["levels"] = levels
    if asset.weights is not None and asset.reduced is not None:
        # how many vertices have 0, 1, 2... non-zero weights before and after (report histograms)
        evaluation_entry["influence_histogram"] = {
            "input": np.bincount(influence_counts(asset.weights)).tolist(),
            "reduced": np.bincount(asset.reduced.influence_counts()).tolist()}
        # the weights this evaluation measured, for report steps that render several evaluations
        asset.extras.setdefault("evaluated_reduced", {})[step.index] = asset.reduced
        asset.extras.setdefault("evaluated_normals", {})[step.index] = (asset.normal_estimator,
                                                                        dict(asset.normal_params))
    document["evaluations"].append(evaluation_entry)
    entry["plugin"] = ",".join(n for n, _ in step.plugin)
    return entry


def _run_write(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
               document: dict, entry: dict) -> dict:
    out = Path(step.plugin)
    out = out if out.is_absolute() else base / out
    params = dict(step.params)
    name = params.pop("writer", "report" if step.key == "report" else None)
    ctx.document = document
    writers = host.plugins("writer")
    if name is None:
        fitting = [w for w in writers.values() if out.suffix.lower() in w.suffixes]
        if not fitting:
            sufs = sorted({s for w in writers.values() for s in w.suffixes})
            raise PipelineError(f"no writer for '{out.suffix}' files", source=source,
                                field=f"steps[{step.index}].write", fix="use one of " + ", ".join(sufs))
        writer = fitting[0]
    else:
        writer = host.get("writer", name)
    writer.write(out, asset, _check_params(writer, params, source, f"steps[{step.index}]"), ctx)
    entry.update({"plugin": writer.name, "path": str(out)})
    return entry


#: Steps whose value is not one plugin's name: evaluate (a list of metrics), write/report (an output path).
_STEP_RUNNERS: dict[str, Callable[..., dict]] = {"evaluate": _run_evaluate, "write": _run_write,
                                                  "report": _run_write}


def _default_label(document, asset) -> str:
    if asset.reduced is None and asset.levels:
        return f"{asset.provenance.get('decimator', 'decimate')}-levels"
    solver = asset.provenance.get("solver", "input")
    k = asset.reduced.k if asset.reduced is not None else None
    return f"{solver}-k{k}" if k else solver


def write_metrics(path, document: dict) -> None:
    """Write the metrics JSON atomically, strict JSON (non-finite values as null, noted: rigslim.jsonsafe)."""
    from rigslim.jsonsafe import dumps_strict

    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_strict(document, indent=2) + "\n")
