"""Running a pipeline: the steps in order, the outputs committed together, the metrics document written."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

import rigslim
from rigslim.errors import PipelineError, RigslimError
from rigslim.io.atomic import atomic_path, check_output, output_transaction, refuse_input_as_output
from rigslim.model.asset import Asset
from rigslim.model.weights import influence_counts
from rigslim.plugin.contract import StepContext, returned
from rigslim.plugin.evaluation import Evaluation
from rigslim.plugin.host import PluginHost, get_host
from rigslim.runtime.document import Step, check_params, load_pipeline
from rigslim.runtime.inputs import read_inputs
from rigslim.runtime.metrics_document import SCHEMA_VERSION, UNITS, merge_levels


@dataclass
class RunResult:
    """What :func:`run_pipeline` returns: the final asset and the metrics document."""

    asset: Asset
    document: dict
    evaluations: list = field(default_factory=list)


def run_pipeline(path, *, overrides: Sequence[str] = (), metrics_path=None, host: PluginHost | None = None,
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
    from rigslim.runtime.progress import Reporter

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
    _refuse_inputs_as_outputs(path, base, steps, metrics_path, asset, read_file=raw is None)
    document = {
        "schema_version": SCHEMA_VERSION,
        "units": dict(UNITS),
        "rigslim_version": rigslim.__version__,
        "pipeline": str(path),
        "pipeline_file": str(path.resolve()) if raw is None or path.is_file() else None,
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
        with reporter.status(f"step {step.index}: {step.key} {step.label if step.key != 'evaluate' else ''}"):
            try:
                entry = _run_step(step, asset, host, ctx, base, path, document)
            except RigslimError as e:
                if not e.source:  # a field naming the step (a plugin's failure) needs only the file
                    e.source = str(path) if (e.field or "").startswith(f"steps[{step.index}]") else \
                        f"{path} steps[{step.index}] ({step.key})"
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


def referenced_files(doc) -> list[Path]:
    """The files a glTF document's buffers and images name by URI (``data:`` URIs and other schemes aside),
    resolved against the document's folder as its reader resolves them."""
    from urllib.parse import unquote

    out = []
    for kind in ("buffers", "images"):
        for item in doc.json.get(kind, []) or []:
            uri = item.get("uri") if isinstance(item, dict) else None
            if isinstance(uri, str) and uri and not uri.startswith("data:") and ":" not in uri.split("/")[0]:
                out.append(Path(doc.path).parent / unquote(uri))
    return out


def _split_files(step: Step, steps: list[Step], out: Path) -> dict[str, Path]:
    """The files a ``split: true`` write step will write, as far as the pipeline says before it runs: one per
    face target of the decimate step before it (:func:`rigslim.io.gltf.sidecar.split_names`; the writer
    checks the levels it names otherwise itself) and the sidecar."""
    from rigslim.io.gltf.sidecar import sidecar_path, split_names

    decimate = [s for s in steps if s.key == "decimate" and s.index < step.index]
    targets = (decimate[-1].params.get("targets") if decimate else None) or []
    targets = [t for t in targets if isinstance(t, int | float) and not isinstance(t, bool) and t > 0] \
        if isinstance(targets, list) else []
    label = f"steps[{step.index}].{step.key}"
    files = {f"{label} (split, target {t:g})": p for t, p in zip(targets, split_names(out, targets), strict=True)}
    return files | {f"{label} (split sidecar)": sidecar_path(out)}


def _refuse_inputs_as_outputs(path: Path, base: Path, steps: list[Step], metrics_path, asset: Asset,
                              read_file: bool) -> None:
    """One line, before any step runs, if a ``write:``/``report:`` step or the metrics names a file the run
    read: an input, a file a glTF input references, or the pipeline document itself."""
    inputs: list = [path] if read_file or path.is_file() else []
    inputs += list((asset.provenance.get("inputs") or {}).values())
    document = getattr(asset.extras.get("gltf"), "document", None)
    if document is not None:
        inputs += referenced_files(document)
    asset.extras["read_files"] = [Path(p) for p in inputs if p is not None]   # a writer's later outputs: split
    outputs = {}
    for step in steps:
        if step.key in ("write", "report"):
            out = Path(str(step.output))
            out = out if out.is_absolute() else base / out
            files = _split_files(step, steps, out) if step.params.get("split") is True else \
                {f"steps[{step.index}].{step.key}": out}
            for label, file in files.items():
                outputs[label] = file
                if file.suffix.lower() == ".gltf" and not step.params.get("embed"):   # the glTF writer's OUT.bin
                    outputs[f"{label} (its buffer)"] = file.with_suffix(".bin")
    if metrics_path is not None:
        outputs["--metrics"] = metrics_path
    try:
        refuse_input_as_output(outputs, inputs, distinct=False)
    except RigslimError as e:
        if e.field and e.field.startswith("steps["):
            e.source = str(path)
            e.args = (e.one_line(),)
        raise


def _run_step(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
              document: dict) -> dict:
    """Run one step; return its entry of the metrics document.

    ``evaluate`` (several metrics) and ``write``/``report`` (a writer chosen by the output path) have runners
    of their own; every other step runs its plugin's :meth:`rigslim.plugin.Plugin.apply`, which stores the
    stage's result in the asset.
    """
    entry = {"stage": step.key, "plugin": step.label if step.key != "evaluate" else "metrics",
             "name": step.name}
    runner = _STEP_RUNNERS.get(step.key)
    if runner is not None:
        return runner(step, asset, host, ctx, base, source, document, entry)
    assert step.plugin is not None  # a plugin step (evaluate, write and report have runners of their own)
    plugin = host.get(step.stage, step.plugin)
    params = plugin.parse_params(step.params)
    with host.calling(step.stage, step.plugin, f"steps[{step.index}].{step.key}"):
        entry.update(plugin.apply(asset, params, ctx))
    return entry


def _run_evaluate(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
                  document: dict, entry: dict) -> dict:
    evaluation = Evaluation(asset, host, ctx)
    metrics: dict = {}
    levels: list[dict] = []
    for name, p in step.metrics:
        metric = host.metric(name)
        params = metric.parse_params(p)
        with host.calling("metric", name, f"steps[{step.index}].evaluate.{name}"), \
                np.errstate(over="ignore", invalid="ignore"):  # non-finite results: null + note in the JSON
            result = metric.compute(evaluation, params, ctx)
        returned(metric, "compute", result, dict, "a dict of metric values")
        values = dict(result)
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
    entry["plugin"] = step.label
    return entry


def _run_write(step: Step, asset: Asset, host: PluginHost, ctx: StepContext, base: Path, source: Path,
               document: dict, entry: dict) -> dict:
    out = Path(str(step.output))
    out = out if out.is_absolute() else base / out
    params = dict(step.params)
    name = params.pop("writer", "report" if step.key == "report" else None)
    ctx.document = document
    writers = host.writers()
    if name is None:
        fitting = host.by_suffix("writer", out.suffix)  # two writers taking the suffix: DuplicatePluginError
        if not fitting:
            sufs = sorted({s for w in writers.values() for s in w.suffixes})
            raise PipelineError(f"no writer for '{out.suffix}' files", source=source,
                                field=f"steps[{step.index}].write", fix="use one of " + ", ".join(sufs))
        writer = fitting[0]
    else:
        writer = host.writer(name)
    checked = check_params(writer, params, source, f"steps[{step.index}]")
    with host.calling("writer", writer.name, f"steps[{step.index}].{step.key}"):
        writer.write(out, asset, checked, ctx)
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
    """Write the metrics JSON atomically, strict JSON (non-finite values as null, noted: rigslim.io.jsonsafe)."""
    from rigslim.io.jsonsafe import dumps_strict

    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_strict(document, indent=2) + "\n")
