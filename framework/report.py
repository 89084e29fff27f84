"""HTML reports of one or more pipeline runs: table, plots and renders in one file.

A report reads metrics documents (the JSON of ``rigslim run --metrics``, see
docs/pipelines.md), one row per evaluation, and writes a single
self-contained HTML page (every image a ``data:`` URI):

- a summary table: method, k, reduction time, position and normal RMS
  (mean / max over test frames), Metro error when measured, influence counts;
- matplotlib figures (:mod:`rigslim.report_plots`): per-frame error curves,
  error against k when runs with several k are given, and weight-count
  histograms before and after reduction;
- renders of chosen test frames (:mod:`rigslim.render`, OpenGL through EGL):
  the deformation with the full input weights, with each run's reduced
  weights, and the reduced deformation coloured by normal deviation.

To render, the report needs the mesh, the input weights, the poses and the
reduced weights: a ``report:`` pipeline step hands them over in memory;
``rigslim report`` re-reads the inputs recorded in the document (through the
pipeline file when it can be found, so reader options apply) and the
``.npz`` a ``write:`` step saved after the evaluated solve.

Example
-------
::

    rigslim run examples/elephant-k4.yaml --metrics out/k4.json
    rigslim run examples/elephant-k4.yaml --set select.k=6 --metrics out/k6.json
    rigslim report out/k4.json out/k6.json -o out/report.html --png-dir out/renders
"""

from __future__ import annotations

import base64
import datetime as _dt
import html
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from rigslim.errors import InputError, RigslimError
from rigslim.io.atomic import atomic_path, output_transaction

#: Colour map of the normal-deviation renders (pale yellow: none, dark red: the scale's maximum).
HEAT_CMAP = "YlOrRd"
#: Colours of the full and reduced deformation renders.
FULL_COLOR = (0.72, 0.76, 0.86)
REDUCED_COLOR = (0.88, 0.76, 0.60)
LEVEL_COLOR = (0.70, 0.84, 0.70)
#: Reduction stages whose seconds count as the evaluation's reduction time.
TIMED_STAGES = ("generate", "select", "solve", "decimate")


@dataclass
class EvaluationRow:
    """One evaluation of one metrics document, flattened for the table and the plots.

    Attributes
    ----------
    label : str
        Unique name in the report (the evaluation's name, prefixed by the run's
        name when two runs share evaluation names).
    method : str
        The solve step's plugin, else the decimate step's (``"input"`` when there is neither).
    selection : str or None
        The select step's plugin.
    k : int or None
    seconds : float
        Seconds of the generate/select/solve/decimate steps since the previous evaluation.
    frames : list of int
        Test frames of the run.
    position_per_frame, normal_per_frame : ndarray or None
        ``position_rms_pct`` and ``normal_rms_rad`` per test frame.
    metro : dict
        Metric keys that mention Metro or Hausdorff, with their mean (or value).
    metro_per_frame : ndarray or None
        ``hausdorff_rms_pct`` per test frame (Metro RMS distance, % of the diagonal).
    levels : dict
        Per simplified level (``key@level`` metrics of a decimation): ``{level: {key: value}}``.
    histogram_input, histogram_reduced : list of int or None
        Vertices per number of non-zero weights.
    """

    label: str
    run: str
    evaluation: str
    source: str
    document: dict = field(repr=False)
    step: int | None
    method: str
    selection: str | None
    k: int | None
    seconds: float
    frames: list
    position_per_frame: np.ndarray | None
    normal_per_frame: np.ndarray | None
    metrics: dict = field(repr=False)
    metro: dict = field(default_factory=dict)
    metro_per_frame: np.ndarray | None = None
    levels: dict = field(default_factory=dict)
    histogram_input: list | None = None
    histogram_reduced: list | None = None

    def _stat(self, key, which):
        v = self.metrics.get(key)
        return float(v[which]) if isinstance(v, dict) and v.get(which) is not None else None

    @property
    def position_mean(self):
        return self._stat("position_rms_pct", "mean")

    @property
    def position_max(self):
        return self._stat("position_rms_pct", "max")

    @property
    def normal_mean(self):
        return self._stat("normal_rms_rad", "mean")

    @property
    def normal_max(self):
        return self._stat("normal_rms_rad", "max")

    def worst_frame(self) -> int | None:
        """The test frame with the largest position error (else normal, else Metro error)."""
        per = next((p for p in (self.position_per_frame, self.normal_per_frame, self.metro_per_frame)
                    if p is not None), None)
        if per is None or len(per) != len(self.frames) or not len(per):
            return self.frames[0] if self.frames else None
        return int(self.frames[int(np.argmax(per))])


def load_document(path) -> dict:
    """Read and check a metrics JSON document.

    Raises
    ------
    InputError
        When the file is missing, not JSON, has no ``evaluations`` list, or
        a part the report uses has the wrong type (:mod:`rigslim.report_input`).
    """
    from rigslim.report_input import read_metrics_document

    return read_metrics_document(path)  # UTF-8, bounded, typed (file + JSON path in every message)


def _per_frame(metrics, key):
    v = metrics.get(key)
    if isinstance(v, dict) and isinstance(v.get("per_frame"), list):  # null (not finite when written) -> NaN
        return np.asarray([np.nan if x is None else x for x in v["per_frame"]], dtype=np.float64)
    return None


def summarize(document: dict, source: str = "") -> list[EvaluationRow]:
    """One :class:`EvaluationRow` per evaluation of a metrics document.

    The method and k come from the last ``solve`` (and ``select``) step before
    the evaluation (``steps[i]`` is step i; ``steps[0]`` is reading the
    inputs); the time is the sum of the reduction steps' seconds since the
    previous evaluation.
    """
    steps = document.get("steps") or []
    frames = list((document.get("frames") or {}).get("test") or [])
    rows = []
    for ev in document["evaluations"]:
        at = ev.get("step")
        before = steps[1:at] if isinstance(at, int) and 0 < at <= len(steps) else steps[1:]
        solve = next((s for s in reversed(before) if s.get("stage") == "solve"), None)
        select = next((s for s in reversed(before) if s.get("stage") == "select"), None)
        decimate = next((s for s in reversed(before) if s.get("stage") == "decimate"), None)
        seconds = 0.0
        for s in reversed(before):
            if s.get("stage") == "evaluate":
                break
            if s.get("stage") in TIMED_STAGES:
                seconds += float(s.get("seconds", 0.0))
        k = (solve or {}).get("k", (select or {}).get("k"))
        metrics = ev.get("metrics") or {}
        metro, levels = {}, {}
        for key, value in metrics.items():
            name, sep, level = key.partition("@")
            if sep:  # per-level values of a simplification: "hausdorff_rms_pct@10%", "faces@10%"
                levels.setdefault(level, {})[name] = value
            elif "metro" in key.lower() or "hausdorff" in key.lower():
                metro[key] = (None if value["mean"] is None else float(value["mean"])) \
                    if isinstance(value, dict) and "mean" in value else value
        hist = ev.get("influence_histogram") or {}
        rows.append(EvaluationRow(
            label=str(ev.get("name", "evaluation")), run=str(document.get("name", "run")),
            evaluation=str(ev.get("name", "evaluation")), source=str(source), document=document, step=at,
            method=(solve or decimate or {}).get("plugin", "input"), selection=(select or {}).get("plugin"),
            k=int(k) if k is not None else None, seconds=seconds, frames=frames,
            position_per_frame=_per_frame(metrics, "position_rms_pct"),
            normal_per_frame=_per_frame(metrics, "normal_rms_rad"), metrics=metrics, metro=metro, levels=levels,
            metro_per_frame=_per_frame(metrics, "hausdorff_rms_pct"),
            histogram_input=hist.get("input"), histogram_reduced=hist.get("reduced")))
    return rows


def _unique_labels(rows: list[EvaluationRow]) -> None:
    seen: dict[str, int] = {}
    for r in rows:
        seen[r.label] = seen.get(r.label, 0) + 1
    for r in rows:
        if seen[r.label] > 1:
            r.label = f"{r.run} / {r.evaluation}"
    seen = {}
    for r in rows:
        if r.label in seen:
            seen[r.label] += 1
            r.label = f"{r.label} ({seen[r.label]})"
        else:
            seen[r.label] = 1


# ----------------------------------------------------------------------------------------------
# The data renders need


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

    from rigslim.host import get_host
    from rigslim.io import read_reduced_npz
    from rigslim.pipeline import load_pipeline, read_inputs
    from rigslim.plugin import StepContext
    from rigslim.poses import FrameSplit

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
                    gltf = path.suffix.lower() != ".npz"     # the written glTF's own weights (rigslim.report_gltf)
                    if gltf:
                        from rigslim.report_gltf import reduced_from_gltf
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
    from rigslim.blend import linear_blend

    if asset.mesh is None or R.n_vertices != asset.mesh.n_vertices:
        return "has another vertex count than the mesh"
    if solve_step.get("k") is not None and R.k != solve_step["k"]:
        return f"holds k={R.k}, the run solved k={solve_step['k']}"
    per = (evaluation.get("metrics") or {}).get("position_rms_pct", {})
    if isinstance(per, dict) and per.get("per_frame") and asset.poses is not None and asset.split is not None:
        f = asset.split.test[0]
        T = asset.poses.T[f]
        d = linear_blend(asset.mesh.V, R, T) - linear_blend(asset.mesh.V, asset.weights, T)
        err = 100.0 * float(np.sqrt(np.mean(np.sum(d * d, axis=1)))) / asset.mesh.bbox_diagonal
        want = float(per["per_frame"][0])
        if abs(err - want) > tolerance * max(abs(want), 1e-6) + 1e-9:   # glTF: quantised weights, 5 %
            return f"gives {err:.6g}% on frame {f}, the run measured {want:.6g}% (overwritten by another run?)"
    return None


# ----------------------------------------------------------------------------------------------
# Renders


def normal_deviation_degrees(full_normals: np.ndarray, reduced_normals: np.ndarray) -> np.ndarray:
    """Per-vertex angle in degrees between two normal fields.

    Notes
    -----
    ``theta_v = atan2(|n_v x nhat_v|, n_v . nhat_v)``, accurate for small
    angles (the per-vertex term of the ``normal_rms_rad`` metric).
    """
    cross = np.linalg.norm(np.cross(full_normals, reduced_normals), axis=1)
    dot = np.einsum("ij,ij->i", full_normals, reduced_normals)
    return np.degrees(np.arctan2(cross, dot))


def heat_colors(values: np.ndarray, vmax: float, cmap: str = HEAT_CMAP) -> np.ndarray:
    """(m, 3) RGB in [0, 1] of ``values / vmax`` (clipped) through a matplotlib colour map."""
    from matplotlib import colormaps

    t = np.clip(np.asarray(values, dtype=np.float64) / max(vmax, 1e-12), 0.0, 1.0)
    return colormaps[cmap](t)[:, :3]


@dataclass
class RenderedFrame:
    """The images of one test frame of runs that share their inputs."""

    run: str  # the runs' names
    frame: int
    full: np.ndarray
    #: [(row label, image, heat image, max deviation in degrees, RMS deviation in radians)]
    reduced: list
    levels: list = field(default_factory=list)  # [(level label, faces, image)] of a simplification


@dataclass
class RenderSet:
    frames: list = field(default_factory=list)
    heat_max: float = 0.0
    backend: str = ""
    notes: list = field(default_factory=list)


def render_rows(rows: list[EvaluationRow], data: dict, *, frames=None, width: int = 320, height: int = 270,
                backend: str = "auto", projection: str = "perspective", azimuth: float = 30.0,
                elevation: float = 15.0, up_axis: int = 1, heat_max: float | None = None,
                progress: Callable = lambda it, total=None, description="": it) -> RenderSet:
    """Render chosen test frames of every run: full, each reduced, each normal-deviation heat map.

    Parameters
    ----------
    rows : evaluation rows (all runs)
    data : dict
        ``id(document) -> RenderData``; runs without an entry are skipped.
    frames : list of int, optional
        Animation frames to render; default the worst test frame (largest
        position error) of the first evaluation of each group of runs that
        share inputs and test frames (one full render serves the group).
    heat_max : float, optional
        Top of the colour scale in degrees; default the largest 99th
        percentile of the per-vertex deviation over all renders, so that one
        outlying vertex does not wash out the scale.

    Notes
    -----
    Full: ``v^j = sum_i w_{v,i} T_i^j [v; 1]`` with the input weights;
    reduced: the same with the reduced weights; simplified levels
    (``asset.extras["levels"]`` of a ``decimate`` step, in-pipeline reports
    only): each level's rest mesh blended with its own weights. The full
    deformation is shaded with its area-weighted normals (the reference of
    the ``normal_rms_rad`` metric), the reduced one with the normals of the
    normal estimator its evaluation used (``recomputed`` unless a
    ``normals:`` step chose another); the heat map colours the reduced
    deformation by ``theta_v`` (:func:`normal_deviation_degrees`) between
    the two, the per-vertex term of ``normal_rms_rad``.
    All images of one frame share one camera fitted to the full deformation.
    """
    from rigslim.blend import linear_blend, per_vertex_normals
    from rigslim.render import Camera, render_mesh

    out = RenderSet()
    jobs = []
    # runs of the same inputs and test frames share one full render per frame
    groups: dict = {}
    for r in rows:
        if id(r.document) not in data:
            continue
        inputs = r.document.get("inputs")
        key = (json.dumps(inputs, sort_keys=True), tuple(r.frames)) if inputs else id(r.document)
        groups.setdefault(key, []).append(r)
    for group in groups.values():
        asset = data[id(group[0].document)].asset
        runs = list(dict.fromkeys(r.run for r in group))
        name = ", ".join(runs)
        if asset.mesh is None or asset.weights is None or asset.poses is None:
            out.notes.append(f"{name}: no mesh, weights or poses to render")
            continue
        wanted = list(frames) if frames else [group[0].worst_frame()]
        for f in dict.fromkeys(wanted):
            if f is None:
                continue
            if not 0 <= int(f) < len(asset.poses):
                raise InputError(f"frame {f} is outside the animation (0..{len(asset.poses) - 1})",
                                 source=group[0].source or group[0].run, field="frames",
                                 fix="choose test frames of the run")
            if group[0].frames and int(f) not in group[0].frames:
                out.notes.append(f"{name}: frame {f} is not a test frame")
            jobs.append((group, name, asset, int(f)))
    heat_jobs = []  # (reduced entry, positions, normals, per-vertex deviation, camera, faces)
    for group, name, asset, f in progress(jobs, total=len(jobs), description="rendering frames"):
        F = asset.mesh.F
        T = asset.poses.T[f]
        X = linear_blend(asset.mesh.V, asset.weights, T)
        N = per_vertex_normals(X, F)
        cam = Camera.fit(X, width, height, projection=projection, azimuth=azimuth, elevation=elevation,
                         up_axis=up_axis, tight=True)
        full, used = render_mesh(X, F, FULL_COLOR, cam, normals=N, backend=backend)
        out.backend = used
        rf = RenderedFrame(name, f, full, [])
        for r in group:
            R = data[id(r.document)].reduced.get(r.step)
            if R is None:
                continue
            Xr = linear_blend(asset.mesh.V, R, T)
            Nr = _estimated_normals(asset, R, T, Xr, data[id(r.document)].normals.get(r.step))
            img, _ = render_mesh(Xr, F, REDUCED_COLOR, cam, normals=Nr, backend=backend)
            dev = normal_deviation_degrees(N, Nr)
            entry = [r.label, img, None, float(dev.max()), float(np.sqrt(np.mean(np.radians(dev) ** 2)))]
            rf.reduced.append(entry)
            heat_jobs.append((entry, Xr, Nr, dev, cam, F))
        for level in data[id(group[0].document)].asset.extras.get("levels") or []:
            Xl = linear_blend(level.mesh.V, level.weights, T)
            img, _ = render_mesh(Xl, level.mesh.F, LEVEL_COLOR, cam, backend=backend)
            rf.levels.append((str(level.label), int(level.mesh.n_faces), img))
        out.frames.append(rf)
    # heat maps last: their colour scale is shared by every render of the report
    tops = [float(np.percentile(dev, 99)) for _, _, _, dev, _, _ in heat_jobs]
    out.heat_max = float(heat_max) if heat_max else max(tops + [1e-3])
    for entry, Xr, Nr, dev, cam, F in heat_jobs:
        entry[2], _ = render_mesh(Xr, F, heat_colors(dev, out.heat_max), cam, normals=Nr, backend=backend)
    return out


def _estimated_normals(asset, R, T, Xr, estimator) -> np.ndarray:
    """Unit normals of a reduced deformation from the named normal estimator (default recomputed)."""
    from rigslim.blend import per_vertex_normals

    name, params = estimator or ("recomputed", {})
    if name == "recomputed" and not params:
        return per_vertex_normals(Xr, asset.mesh.F)
    from rigslim.host import get_host

    plugin = get_host().get("normal-estimator", name)
    N = np.asarray(plugin.estimate(asset.mesh, R, asset.handles, T, Xr, plugin.parse_params(params)),
                   dtype=np.float64)
    length = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, length, out=np.zeros_like(N), where=length > 0)


# ----------------------------------------------------------------------------------------------
# HTML


def _data_uri(png: bytes) -> str:
    return "data:image/png;base64," + base64.b64encode(png).decode("ascii")


def _fmt(x, digits=4) -> str:
    if x is None:
        return "&ndash;"
    if isinstance(x, float):
        if x == 0 or (1e-3 <= abs(x) < 1e5):
            return f"{x:.{digits}g}"
        return f"{x:.3e}"
    return html.escape(str(x))


_CSS = """
body{font-family:system-ui,-apple-system,'DejaVu Sans',sans-serif;margin:24px auto;max-width:1180px;color:#222;
background:#fff;line-height:1.4;padding:0 16px}
h1{font-size:1.6em;margin-bottom:4px}h2{font-size:1.2em;margin-top:28px;border-bottom:1px solid #ddd;
padding-bottom:4px}.meta{color:#666;font-size:.85em}
table{border-collapse:collapse;font-size:.88em;margin:8px 0}th,td{border:1px solid #ddd;padding:4px 8px;
text-align:right}th{background:#f3f4f6}td.l,th.l{text-align:left}tr:nth-child(even) td{background:#fafafa}
figure{display:inline-block;margin:6px;text-align:center;vertical-align:top}figcaption{font-size:.8em;color:#444}
img{max-width:100%;border:1px solid #eee}.plots img{display:block;margin:8px 0}
.frame{margin:10px 0 18px}.pair{display:inline-block;vertical-align:top;margin-right:14px}
td{white-space:nowrap}.notes{color:#8a5a00;font-size:.85em}
#rigslim-check{color:#999;font-size:.75em;margin-top:30px}
"""

# Marks the page once loaded: how many images decoded, and errors caught (for the browser test).
_CHECK_JS = """
(function(){
  var errors = [];
  window.addEventListener('error', function(e){ errors.push(String(e.message || e)); });
  window.addEventListener('load', function(){
    var imgs = Array.prototype.slice.call(document.images);
    var ok = imgs.filter(function(i){ return i.complete && i.naturalWidth > 0; }).length;
    var el = document.getElementById('rigslim-check');
    el.setAttribute('data-images-ok', String(ok));
    el.setAttribute('data-images-total', String(imgs.length));
    el.setAttribute('data-errors', String(errors.length));
    el.textContent = 'page check: ' + ok + ' of ' + imgs.length + ' images decoded, ' +
                     errors.length + ' script errors';
  });
})();
"""


def _table(rows: list[EvaluationRow]) -> str:
    metro_keys = sorted({k for r in rows for k in r.metro})
    names = {"hausdorff_rms_pct": "Metro RMS % mean", "hausdorff_max_pct": "Metro max % mean"}
    head = ["run / evaluation", "method", "k", "reduction (s)", "position RMS % mean", "position RMS % max",
            "normal RMS rad mean", "normal RMS rad max", "normal median rad", "normal p95 rad", "normal p99 rad",
            "normals &gt; 90&deg; (max)", "normal area RMS rad"] + [names.get(k, k) for k in metro_keys] + \
        ["max influences (input &rarr; reduced)", "mean influences"]
    out = ["<table><thead><tr>" + "".join(f'<th class="{"l" if i < 2 else ""}">{h}</th>'
                                           for i, h in enumerate(head)) + "</tr></thead><tbody>"]
    for r in rows:
        m = r.metrics
        method = html.escape(r.method) + (f' <span class="meta">({html.escape(r.selection)} selection)</span>'
                                          if r.selection and r.selection != r.method else "")
        infl = f"{_fmt(m.get('input_max_influences'))} &rarr; {_fmt(m.get('max_influences'))}" \
            if "max_influences" in m else "&ndash;"
        cells = [f'<td class="l">{html.escape(r.label)}</td>', f'<td class="l">{method}</td>',
                 f"<td>{_fmt(r.k)}</td>", f"<td>{r.seconds:.3f}</td>", f"<td>{_fmt(r.position_mean)}</td>",
                 f"<td>{_fmt(r.position_max)}</td>", f"<td>{_fmt(r.normal_mean)}</td>",
                 f"<td>{_fmt(r.normal_max)}</td>"]
        cells += [f"<td>{_fmt(r._stat(k, 'mean'))}</td>" for k in ("normal_median_rad", "normal_p95_rad",
                                                                  "normal_p99_rad")]
        cells += [f"<td>{_fmt(r._stat('normal_flipped', 'max'))}</td>",
                  f"<td>{_fmt(r._stat('normal_area_rms_rad', 'mean'))}</td>"]
        cells += [f"<td>{_fmt(r.metro.get(k))}</td>" for k in metro_keys]
        cells += [f"<td>{infl}</td>", f"<td>{_fmt(m.get('mean_influences'))}</td>"]
        out.append("<tr>" + "".join(cells) + "</tr>")
    out.append("</tbody></table>")
    if any(r.levels for r in rows):
        out.append("<h3>Simplified levels</h3><table><thead><tr><th class=\"l\">run / evaluation</th>"
                   "<th class=\"l\">level</th><th>faces</th><th>Metro RMS % mean</th><th>Metro RMS % max</th>"
                   "<th>Metro max % mean</th><th>Metro max % max</th></tr></thead><tbody>")
        for r in rows:
            for level, vals in r.levels.items():
                rms, mx = vals.get("hausdorff_rms_pct") or {}, vals.get("hausdorff_max_pct") or {}
                out.append(f'<tr><td class="l">{html.escape(r.label)}</td><td class="l">{html.escape(level)}</td>'
                           f"<td>{_fmt(vals.get('faces'))}</td><td>{_fmt(rms.get('mean'))}</td>"
                           f"<td>{_fmt(rms.get('max'))}</td><td>{_fmt(mx.get('mean'))}</td>"
                           f"<td>{_fmt(mx.get('max'))}</td></tr>")
        out.append("</tbody></table>")
    return "\n".join(out)


@dataclass
class Report:
    """A built report: the HTML text and the PNG renders (name -> bytes)."""

    html: str
    renders: dict
    rows: list
    notes: list


def build_report(documents: list[tuple[dict, str]], *, data: dict | None = None, frames=None,
                 width: int = 320, height: int = 270, backend: str = "auto", projection: str = "perspective",
                 azimuth: float = 30.0, elevation: float = 15.0, up_axis: int = 1, title: str | None = None,
                 render: bool = True, progress: Callable = lambda it, total=None, description="": it) -> Report:
    """Build the HTML report of some metrics documents.

    Parameters
    ----------
    documents : list of (document, source)
        Metrics documents and where they came from (shown in the report).
    data : dict, optional
        ``id(document) -> RenderData`` for documents whose data is in memory;
        the others are loaded with :func:`load_render_data`.
    frames : list of int, optional
        Animation frames to render (default: each run's worst test frame).
    width, height : int
        Size of each render in pixels.
    backend : {"auto", "opengl", "numpy"}
        Renderer (``auto``: OpenGL through EGL when available).
    render : bool
        False leaves the renders out (table and plots only).
    """
    from rigslim import __version__
    from rigslim import report_plots as plots
    from rigslim.report_input import check_render_size

    check_render_size(width, height)

    rows: list[EvaluationRow] = []
    for doc, source in documents:
        rows += summarize(doc, source)
    _unique_labels(rows)
    notes: list[str] = []
    data = dict(data or {})
    renders: dict[str, bytes] = {}
    rset = None
    if render:
        for doc, source in documents:
            if id(doc) in data:
                continue
            try:
                data[id(doc)] = load_render_data(doc, source if source and Path(source).is_file() else None)
            except RigslimError as e:  # moved or edited inputs: report without its renders
                notes.append(f"{doc.get('name', source)}: cannot re-read the inputs ({e.one_line()})")
                continue
        for doc, _ in documents:
            rd = data.get(id(doc))
            if rd is not None:
                notes += rd.notes
        rset = render_rows(rows, data, frames=frames, width=width, height=height, backend=backend,
                           projection=projection, azimuth=azimuth, elevation=elevation, up_axis=up_axis,
                           progress=progress)
        notes += rset.notes
    # HTML
    title = title or ("rigslim report: " + ", ".join(dict.fromkeys(r.run for r in rows)))
    when = _dt.datetime.now(_dt.timezone.utc).strftime("%Y-%m-%d %H:%M UTC")
    parts = [f"<!DOCTYPE html><html lang=\"en\"><head><meta charset=\"utf-8\"><title>{html.escape(title)}</title>",
             "<meta name=\"viewport\" content=\"width=device-width,initial-scale=1\">",
             f"<style>{_CSS}</style></head><body>",
             f"<h1>{html.escape(title)}</h1>",
             f"<div class=\"meta\">rigslim {html.escape(__version__)} &middot; {when}"
             + (f" &middot; renders: {html.escape(rset.backend)}" if rset and rset.backend else "") + "</div>",
             "<div class=\"meta\">sources: " + ", ".join(html.escape(str(s) or "pipeline") for _, s in documents)
             + "</div>"]
    mesh = documents[0][0].get("mesh") or {}
    if mesh:
        n_test = len(rows[0].frames) if rows else 0
        parts.append(f"<div class=\"meta\">mesh: {mesh.get('vertices')} vertices, {mesh.get('faces')} faces; "
                     f"{n_test} test frames (never used for fitting)</div>")
    parts += ["<h2>Summary</h2>", _table(rows),
              "<div class=\"meta\">Position RMS: RMS vertex distance between reduced and full deformation, "
              "% of the rest bounding-box diagonal; normal RMS: RMS angle between their normals (radians). "
              "Mean and max over test frames. Reduction time: generate, select, solve and decimate steps "
              "since the previous evaluation.</div>",
              "<h2>Plots</h2><div class=\"plots\">",
              f"<img alt=\"error per test frame\" src=\"{_data_uri(plots.error_curves(rows))}\">"]
    ks = {}
    for r in rows:
        if r.k is not None:
            ks.setdefault(r.method, set()).add(r.k)
    if any(len(v) > 1 for v in ks.values()):
        parts.append(f"<img alt=\"error against k\" src=\"{_data_uri(plots.error_vs_k(rows))}\">")
    elif ks:
        notes.append("error against k: give runs of one method with several k to see it")
    if any(r.histogram_input is not None or r.histogram_reduced is not None for r in rows):
        parts.append(f"<img alt=\"weight-count histograms\" src=\"{_data_uri(plots.influence_histograms(rows))}\">")
    elif ks:
        notes.append("weight-count histograms: the documents have no 'influence_histogram'")
    parts.append("</div>")
    if rset is not None and rset.frames:
        parts.append("<h2>Renders</h2><div class=\"meta\">First: the full input weights. Then per evaluation: "
                     "the reduced weights, and the reduced deformation coloured by the angle between its "
                     "normals and the full deformation's; or each simplified level with its own weights.</div>")
        if any(rf.reduced for rf in rset.frames):
            parts.append(f"<img alt=\"normal deviation scale\" "
                         f"src=\"{_data_uri(plots.colorbar(rset.heat_max, HEAT_CMAP))}\">")
        for rf in rset.frames:
            base = _slug(f"{rf.run.split(',')[0]}-frame{rf.frame}")
            png = _png_of(rf.full)
            renders[f"{base}-full.png"] = png
            figs = [f"<div class=\"pair\"><figure><img alt=\"full frame {rf.frame}\" src=\"{_data_uri(png)}\">"
                    f"<figcaption>full weights</figcaption></figure></div>"]
            for label, img, heat, dmax, _ in rf.reduced:
                p1, p2 = _png_of(img), _png_of(heat)
                renders[f"{base}-{_slug(label)}-reduced.png"] = p1
                renders[f"{base}-{_slug(label)}-normals.png"] = p2
                figs.append(f"<div class=\"pair\"><figure><img alt=\"{html.escape(label)} frame {rf.frame}\" "
                            f"src=\"{_data_uri(p1)}\"><figcaption>{html.escape(label)}</figcaption></figure>"
                            f"<figure><img alt=\"{html.escape(label)} normal deviation\" src=\"{_data_uri(p2)}\">"
                            f"<figcaption>{html.escape(label)}: normal deviation (max {dmax:.2f}&deg;)"
                            f"</figcaption></figure></div>")
            for label, faces, img in rf.levels:
                p1 = _png_of(img)
                renders[f"{base}-{_slug(label)}-level.png"] = p1
                figs.append(f"<div class=\"pair\"><figure><img alt=\"{html.escape(label)} frame {rf.frame}\" "
                            f"src=\"{_data_uri(p1)}\"><figcaption>{html.escape(label)} ({faces} faces, "
                            f"own weights)</figcaption></figure></div>")
            parts.append(f"<div class=\"frame\"><h3>{html.escape(rf.run)}, frame {rf.frame}</h3>{''.join(figs)}</div>")
    from rigslim.report_gltf import lod_section, world_units_section

    parts.append(world_units_section(documents))
    parts.append(lod_section(documents))
    if notes:
        parts.append("<h2>Notes</h2><ul class=\"notes\">" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                     + "</ul>")
    parts.append(f"<div id=\"rigslim-check\">page check pending</div><script>{_CHECK_JS}</script></body></html>")
    return Report("\n".join(parts), renders, rows, notes)


def _png_of(image) -> bytes:
    from rigslim.render import png_bytes

    return png_bytes(image)


def _slug(text: str) -> str:
    keep = "".join(c if c.isalnum() or c in "-_." else "-" for c in text)
    return "-".join(p for p in keep.split("-") if p) or "run"


def _umask_mode() -> int:
    import os

    mask = os.umask(0)
    os.umask(mask)
    return 0o666 & ~mask


def write_report(path, report: Report, png_dir=None) -> list[Path]:
    """Write the HTML (and the renders as PNG files into ``png_dir``) atomically; return the PNG paths.

    The files get the usual permissions (``0o666`` less the umask), not the
    private mode of the temporary file they were written to, so that a web
    server or a colleague can read them.
    """
    path = Path(path)
    mode = _umask_mode()
    with output_transaction():  # the page and its PNG files are renamed into place together
        return _write_report_files(path, report, png_dir, mode)


def _write_report_files(path, report, png_dir, mode) -> list[Path]:
    import os

    with atomic_path(path) as tmp:
        Path(tmp).write_text(report.html, encoding="utf-8")
        os.chmod(tmp, mode)
    written = []
    if png_dir is not None:
        png_dir = Path(png_dir)
        for name, data in report.renders.items():
            with atomic_path(png_dir / name) as tmp:
                Path(tmp).write_bytes(data)
                os.chmod(tmp, mode)
            written.append(png_dir / name)
    return written
