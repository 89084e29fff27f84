"""The batch view: ``rigslim report DIR/summary.csv -o batch.html``.

One self-contained HTML page (every image a ``data:`` URI) of a
``rigslim batch`` run (docs/batch.md):

- counts (ok / skipped / failed) and the failures with their one-line errors;
- histograms of each error metric over the assets (matplotlib);
- the worst assets by one error metric (default: the largest of
  ``hausdorff_max_pct_max``, ``position_rms_pct_max``, ``normal_rms_rad_max``
  present), each with two renders at its worst test frame: the deformation
  with the full input weights, and what the metric measured, coloured by
  each vertex's distance to the full deformation (% of that frame's
  world-space bounding-box diagonal): the reduced weights its outputs hold,
  or, when the metric measured a simplified level (``KEY@LEVEL`` columns,
  and the plain Hausdorff columns of a simplification, which are its first
  level's), that level posed with its own weights;
- every row in a table sorted by clicking a column header, inside a
  scroll box with the name column frozen.

All heat maps of one kind (reduced weights, levels) share one colour scale,
stated on a colour bar: 0 to the largest per-vertex distance over the page's
renders of that kind, at least :data:`HEAT_FLOOR_PCT`, so an asset with a
tiny error is drawn in the low colours whatever its neighbours' errors.

The renders re-read the asset's inputs through ``DIR/<name>/pipeline.yaml``
and the reduced weights from the first ``.npz`` (reduced weights) or
``.glb``/``.gltf`` output in ``DIR/<name>/`` whose mesh matches the input's;
a level from a ``.glb``/``.gltf`` output with ``MSFT_lod`` levels or a
``writer: levels`` folder (``levels.json``); an asset without such an output
is listed without renders, with the reason.
"""

from __future__ import annotations

import csv
import html
import json
import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from rigslim.errors import InputError

#: Ranking metrics, most telling first: the worst list uses the first one the summary has.
RANK_METRICS = ("hausdorff_max_pct_max", "position_rms_pct_max", "normal_rms_rad_max")
#: Smallest top of a batch page's heat-map colour scale (% of the diagonal): below it, errors are small.
HEAT_FLOOR_PCT = 0.1
#: Quantity and unit of the error metrics' summary columns (histogram axes).
QUANTITIES = {"position_rms_pct": ("position RMS", "% of diagonal"), "position_rms_m": ("position RMS", "world units"),
              "normal_rms_rad": ("normal RMS", "rad"), "normal_rms_deg": ("normal RMS", "degrees"),
              "hausdorff_rms_pct": ("Metro RMS distance", "% of diagonal"),
              "hausdorff_max_pct": ("Metro max distance", "% of diagonal"),
              "hausdorff_rms_m": ("Metro RMS distance", "world units"),
              "hausdorff_max_m": ("Metro max distance", "world units")}
NUMERIC_HINTS = ("seconds", "peak_memory_mb", "vertices", "faces", "joints", "input_influences",
                 "output_influences", "attempts", "threads")


@dataclass
class BatchReport:
    title: str
    source: str
    rows: list[dict]
    columns: list[str]
    rank_metric: str | None
    worst: list[dict]
    histograms: bytes | None
    renders: dict[str, list[tuple[str, bytes]]] = field(default_factory=dict)
    notes: dict[str, str] = field(default_factory=dict)
    #: per rendered asset: what its heat map shows (``kind`` "reduced" or "level", ``level``, ``faces``,
    #: ``source``, ``frame``, ``max_pct``)
    shown: dict[str, dict] = field(default_factory=dict)
    #: per kind of heat map: the top of its colour scale (% of the diagonal)
    scales: dict[str, float] = field(default_factory=dict)
    #: per histogram: (column, x-axis label, log bins, values left out of log bins (<= 0))
    histogram_axes: list[tuple[str, str, bool, int]] = field(default_factory=list)


def read_summary(path) -> tuple[list[dict], list[str]]:
    """Rows of a batch summary.csv (numbers parsed; empty cells are None) and its columns."""
    path = Path(path)
    try:
        with open(path, newline="", encoding="utf-8") as fh:
            reader = csv.DictReader(fh)
            columns = list(reader.fieldnames or [])
            raw = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise InputError(f"cannot read the summary ({getattr(e, 'strerror', None) or e})", source=path,
                         field="file", fix="give the summary.csv that 'rigslim batch' wrote") from None
    if not {"asset", "name", "status"} <= set(columns):
        raise InputError("not a batch summary (no asset, name and status columns)", source=path, field="header",
                         fix="give DIR/summary.csv of 'rigslim batch' (metrics JSON files make a run report)")
    rows = []
    for r in raw:
        row: dict[str, str | float | None] = {}
        for k, v in r.items():
            if v is None or v == "":
                row[k] = None
            elif k in ("asset", "name", "status", "error", "worker"):
                row[k] = v
            else:
                try:
                    row[k] = float(v)
                except ValueError:
                    row[k] = v
        rows.append(row)
    return rows, columns


def error_columns(columns: list[str]) -> list[str]:
    """Of a summary's column names, the error columns the report plots: ``*_mean`` / ``*_max`` of position,
    normal and Hausdorff errors (the values come from :func:`rigslim.batch.task.summary_metrics`)."""
    return [c for c in columns if c.endswith(("_mean", "_max")) and
            any(c.split(".")[-1].startswith(p) for p in ("position_rms", "normal_rms", "hausdorff"))]


def axis_label(column: str) -> str:
    """The quantity and unit a summary column holds, for an axis: ``hausdorff_max_pct@q-10pct_max`` gives
    ``Metro max distance, max over test frames, level q-10pct (% of diagonal)``."""
    name, step = column, ""
    if name.startswith("step") and "." in name:
        step, name = name.split(".", 1)
    stat = ""
    for suffix, words in (("_mean", "mean over test frames"), ("_max", "max over test frames")):
        if name.endswith(suffix):
            name, stat = name[:-len(suffix)], words
            break
    key, _, level = name.partition("@")
    quantity, unit = QUANTITIES.get(key) or (key, next((u for s, u in (("_pct", "%"), ("_rad", "rad"),
                                                                     ("_deg", "degrees"), ("_m", "world units"))
                                                       if key.endswith(s)), ""))
    parts = [quantity] + [w for w in (stat, f"level {level}" if level else "",
                                      f"evaluation at step {step[4:]}" if step else "") if w]
    return ", ".join(parts) + (f" ({unit})" if unit else "")


def _histograms(rows: list[dict], metrics: list[str]) -> tuple[bytes | None, list[tuple[str, str, bool, int]]]:
    """Histograms of up to six error columns over the assets, and each one's (column, x label, log bins,
    values left out of log bins); log bins where the values span more than two decades
    (:func:`rigslim.report.plots.histogram_bins`)."""
    from rigslim.report.plots import _figure, _png, color, histogram_bins

    metrics = [m for m in metrics if any(isinstance(r.get(m), float) for r in rows)][:6]
    if not metrics:
        return None, []
    cols = min(3, len(metrics))
    nrows = math.ceil(len(metrics) / cols)
    fig = _figure(3.6 * cols, 2.8 * nrows)
    axes = []
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(nrows, cols, i + 1)
        values = np.array([r[m] for r in rows if isinstance(r.get(m), float)])
        edges, log = histogram_bins(values, min(30, max(5, len(values) // 3)))
        left_out = int((values <= 0).sum()) if log else 0
        ax.hist(values[values > 0] if log else values, bins=edges, color=color(i))
        if log:
            ax.set_xscale("log")
        label = axis_label(m)
        ax.set_title(m + (f" ({left_out} at 0 not shown)" if left_out else ""), fontsize=8)
        ax.set_xlabel(label + (", log bins" if log else ""), fontsize=7)
        ax.set_ylabel("assets", fontsize=8)
        ax.tick_params(labelsize=7)
        axes.append((m, label, log, left_out))
    return _png(fig), axes


def _reduced_from_outputs(folder: Path, asset):
    """Reduced weights (sparse, m x n) from the asset's outputs, or (None, reason)."""
    import scipy.sparse as sp

    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import PipelineDoc
    from rigslim.runtime.inputs import read_inputs

    m, n = asset.mesh.n_vertices, asset.handles.n
    tried = []
    for p in sorted(folder.rglob("*")):
        if p.name.startswith(".") or not p.is_file():
            continue
        if p.suffix == ".npz":
            from rigslim.io import read_reduced_npz

            try:
                R = read_reduced_npz(p)
            except Exception:  # noqa: BLE001 - not reduced weights (a hierarchy .npz, ...)
                tried.append(p.name)
                continue
            if R.indices.shape[0] == m:
                rows = np.repeat(np.arange(m), R.k)
                return sp.csr_matrix((R.values.ravel(), (rows, R.indices.ravel())), shape=(m, n)), p.name
            tried.append(p.name)
        elif p.suffix in (".glb", ".gltf"):
            try:
                doc = PipelineDoc(inputs={"gltf": str(p)}, steps=[{"select": "k-largest"}])
                out = read_inputs(doc, folder, get_host(), StepContext(base_dir=folder), p)
            except Exception:  # noqa: BLE001 - an output we cannot read back is skipped, with the reason
                tried.append(p.name)
                continue
            if out.mesh is not None and out.mesh.n_vertices == m and out.weights is not None and \
                    out.weights.shape[1] == n and \
                    np.allclose(out.mesh.V, asset.mesh.V, atol=1e-4 * asset.mesh.bbox_diagonal):
                return sp.csr_matrix(out.weights), p.name
            tried.append(p.name)
    return None, ("no output holds reduced weights of this mesh" +
                  (f" (tried {', '.join(tried)})" if tried else " (write a .npz or .glb after the solve)"))


@dataclass
class AssetFrame:
    """One asset at one test frame, as the batch view draws it.

    Attributes
    ----------
    frame : int
        The animation frame (the worst test frame of the ranking metric).
    full, faces : ndarray
        The input mesh posed with the full input weights, and its triangles.
    shown, shown_faces : ndarray
        What the ranking metric measured, posed: the input mesh with the reduced weights, or a simplified
        level with its own weights; and its triangles.
    error_pct : ndarray
        Per vertex of ``shown``: its distance to the full deformation, % of the diagonal ``D`` of the full
        deformation's bounding box at this frame: ``100 |x_v - xhat_v| / D`` for reduced weights (same
        vertices), ``100 min_{y in full surface} |x_v - y| / D`` for a level (libigl's point-to-triangle
        distance; one side of the Metro distance).
    kind : {"reduced", "level"}
    source : str
        The output file (or levels folder) it was read from.
    level : str or None
        The level's name.
    """

    frame: int
    full: np.ndarray
    faces: np.ndarray
    shown: np.ndarray
    shown_faces: np.ndarray
    error_pct: np.ndarray
    kind: str
    source: str
    level: str | None = None


def _strip_column(column: str) -> tuple[str | None, str, str]:
    """A summary column as (``stepN`` prefix or None, metric key, level name or "")."""
    head, name = None, column
    if name.startswith("step") and "." in name:
        head, name = name.split(".", 1)
    for suffix in ("_mean", "_max"):
        if name.endswith(suffix):
            name = name[:-len(suffix)]
            break
    key, _, level = name.partition("@")
    return head, key, level


def measured_level(metrics: dict, column: str | None) -> tuple[dict | None, dict | None]:
    """The evaluation a summary column comes from, and the simplified level it measured (None: no level).

    A ``KEY@LEVEL`` column names its level. A plain column measured a level when the evaluation has
    levels and one of them holds the same values under that key: the Hausdorff metrics of a
    simplification report their first level's values as the evaluation's own
    (:mod:`rigslim.runtime.metrics_document`).
    """
    from rigslim.runtime.metrics_document import upgrade

    evaluations = upgrade(metrics).get("evaluations") or []
    if not evaluations or not column:
        return None, None
    head, key, level = _strip_column(column)
    ev = evaluations[-1]
    if head is not None:
        ev = next((e for e in evaluations if f"step{e.get('step')}" == head), ev)
    levels = [lv for lv in ev.get("levels") or [] if isinstance(lv, dict)]
    if level:
        return ev, next((lv for lv in levels if str(lv.get("name")) == level), {"name": level})
    value = (ev.get("metrics") or {}).get(key)
    if value is not None:
        for lv in levels:
            if lv.get(key) == value:
                return ev, lv
    return ev, None


def _worst_frame(test: list, ev: dict | None, record: dict | None, key: str) -> int:
    """The test frame where ``key`` (of the level record, else the evaluation, else position RMS) peaks."""
    for values in ((record or {}).get(key), ((ev or {}).get("metrics") or {}).get(key),
                   ((ev or {}).get("metrics") or {}).get("position_rms_pct")):
        per = values.get("per_frame") if isinstance(values, dict) else None
        if per and len(per) == len(test) and any(x is not None for x in per):
            return int(test[int(np.nanargmax(np.array([np.nan if x is None else x for x in per], float)))])
    return int(test[0])


def _level_from_outputs(folder: Path, asset, label: str, frame: int):
    """A simplified level of the asset's outputs posed at ``frame`` with its own weights: (positions, faces,
    source) or (None, None, reason). Read from a ``writer: levels`` folder (``levels.json``) or a glTF
    output whose ``MSFT_lod`` level node is named after the level."""
    from rigslim.io import read_mesh, read_reduced_npz
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.lod import level_document, lod_nodes
    from rigslim.io.gltf.skin import skin_from_document
    from rigslim.numerics.blend import linear_blend

    tried = []
    for p in sorted(folder.rglob("*")):
        if p.name.startswith(".") or not p.is_file():
            continue
        try:
            if p.name == "levels.json":
                entry = next((e for e in json.loads(p.read_text()).get("levels") or []
                              if isinstance(e, dict) and e.get("label") == label), None)
                if entry is None:
                    tried.append(str(p.relative_to(folder)))
                    continue
                mesh = read_mesh(p.parent / entry["mesh"])
                R = read_reduced_npz(p.parent / entry["reduced"])
                T = asset.poses.select([frame]).T[0]
                return linear_blend(mesh.V, R, T), np.asarray(mesh.F), str(p.parent.relative_to(folder))
            if p.suffix.lower() in (".glb", ".gltf"):
                doc = load_gltf(p)
                js = doc.json
                level = next((j for ids in lod_nodes(js).values() for j, n in enumerate(ids, 1)
                              if str(js["nodes"][n].get("name", "")) == label or
                              str(js["nodes"][n].get("name", "")).endswith("-" + label)), None)
                if level is None:
                    tried.append(p.name)
                    continue
                src = asset.extras.get("gltf")
                skin = skin_from_document(level_document(doc, level), animation=getattr(src, "animation", None),
                                          fps=getattr(src, "fps", 30.0), weld=True)
                if not 0 <= frame < len(skin.poses):
                    tried.append(p.name)
                    continue
                return linear_blend(skin.mesh.V, skin.weights, skin.poses.T[frame]), np.asarray(skin.mesh.F), p.name
        except Exception:  # noqa: BLE001 - an output we cannot read back is skipped, with the reason
            tried.append(p.name)
    return None, None, (f"no output holds level '{label}'" + (f" (tried {', '.join(tried)})" if tried else "")
                        + "; write a .glb with 'lod: true' or a 'writer: levels' folder")


def prepare_asset(folder: Path, metric: str | None = None) -> tuple[AssetFrame | None, str]:
    """What the batch view draws of an asset for the ranking column ``metric``: an :class:`AssetFrame`
    at the worst test frame, or None and the reason."""
    import igl

    from rigslim.numerics.blend import linear_blend
    from rigslim.numerics.units import diagonal
    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs

    try:
        metrics = json.loads((folder / "metrics.json").read_text())
        doc, _ = load_pipeline(folder / "pipeline.yaml")
        asset = read_inputs(doc, folder, get_host(), StepContext(base_dir=folder), folder / "pipeline.yaml")
    except Exception as e:  # noqa: BLE001 - the page still lists the asset, with the reason
        return None, f"inputs not re-readable ({' '.join(str(e).split())[:200]})"
    if asset.weights is None or asset.poses is None or asset.handles is None:
        return None, "the asset has no input weights or animation to render"
    assert asset.mesh is not None  # read_inputs() read it with the weights
    test = (metrics.get("frames") or {}).get("test") or list(range(len(asset.poses)))
    ev, record = measured_level(metrics, metric)
    frame = _worst_frame(test, ev, record, _strip_column(metric)[1] if metric else "position_rms_pct")
    T = asset.poses.select([frame]).T[0]
    full = linear_blend(asset.mesh.V, asset.weights, T)
    F = np.asarray(asset.mesh.F)
    D = max(diagonal(full), 1e-300)
    if record is not None:
        label = str(record.get("name"))
        X, FX, where = _level_from_outputs(folder, asset, label, frame)
        if X is None:
            return None, where
        d2 = igl.point_mesh_squared_distance(np.ascontiguousarray(X, float), np.ascontiguousarray(full, float),
                                             np.ascontiguousarray(F, np.int64))[0]
        err = 100.0 * np.sqrt(np.maximum(np.asarray(d2, float).reshape(-1), 0.0)) / D
        return AssetFrame(frame, full, F, X, FX, err, "level", where, label), ""
    R, where = _reduced_from_outputs(folder, asset)
    if R is None:
        return None, where
    reduced = linear_blend(asset.mesh.V, R, T)
    err = 100.0 * np.linalg.norm(full - reduced, axis=1) / D  # % of the world diagonal
    return AssetFrame(frame, full, F, reduced, F, err, "reduced", where), ""


def draw_asset(af: AssetFrame, vmax: float, width: int = 320, height: int = 270,
               backend: str = "auto") -> list[tuple[str, bytes]]:
    """Two renders of an :class:`AssetFrame` in one camera: the full deformation (grey), and what was
    measured coloured by ``error_pct`` on the scale 0 to ``vmax`` (% of the diagonal; larger values clip)."""
    from rigslim.report.render import Camera, png_bytes, render_mesh
    from rigslim.report.renders import HEAT_CMAP, heat_colors

    camera = Camera.fit(np.vstack([af.full, af.shown]), width, height)
    grey = np.array([0.75, 0.75, 0.78])
    img_full, _ = render_mesh(af.full, af.faces, grey, camera, backend=backend)
    img, _ = render_mesh(af.shown, af.shown_faces, heat_colors(af.error_pct, vmax, HEAT_CMAP), camera,
                         backend=backend)
    top = float(af.error_pct.max()) if len(af.error_pct) else 0.0
    what = (f"level {af.level} ({len(af.shown_faces)} faces, its own weights) from {af.source}; colour: each "
            "vertex's distance to the full deformation's surface" if af.kind == "level" else
            f"reduced weights from {af.source}; colour: each vertex's distance to the full deformation")
    scale = (f"clipped at {vmax:.3g}% (the colour bar's top); max {top:.3g}%" if top > vmax
             else f"max {top:.3g}%, colour bar 0 to {vmax:.3g}% of the diagonal")
    return [(f"frame {af.frame}, full weights ({len(af.faces)} faces)", png_bytes(img_full)),
            (f"{what}, {scale}", png_bytes(img))]


def render_asset(folder: Path, width: int = 320, height: int = 270, backend: str = "auto", *,
                 metric: str | None = None, vmax: float | None = None):
    """Two renders of an asset at its worst test frame: full weights, and what ``metric`` measured (reduced
    weights or a level) coloured by its distance to the full deformation.

    ``vmax`` is the top of the colour scale (% of the diagonal); default the asset's own largest distance,
    at least :data:`HEAT_FLOOR_PCT` (the batch page shares one scale over its assets instead).

    Returns
    -------
    (renders, note)
        ``renders`` is a list of (caption, PNG bytes); ``note`` says why there are none.
    """
    af, note = prepare_asset(folder, metric)
    if af is None:
        return [], note
    top = vmax if vmax else max(float(af.error_pct.max()), HEAT_FLOOR_PCT)
    return draw_asset(af, top, width, height, backend), ""


def build_batch_report(summary, *, worst: int = 10, metric: str | None = None, render: bool = True,
                       width: int = 320, height: int = 270, backend: str = "auto", title: str | None = None,
                       progress=lambda it, total=None, description="": it) -> BatchReport:
    """Read a batch summary.csv and build its report (see the module docstring).

    The asset folders are found beside the summary, whatever the working folder: a relative
    ``DIR/summary.csv`` (as docs/batch.md writes it) reads the same assets as its absolute path.
    """
    summary = Path(summary).resolve()
    rows, columns = read_summary(summary)
    metrics = error_columns(columns)
    if metric is not None and metric not in columns:
        raise InputError(f"the summary has no column '{metric}'", source=summary, field="--metric",
                         fix="one of: " + ", ".join(metrics or columns))
    rank = metric or next((m for m in RANK_METRICS if m in columns), metrics[0] if metrics else None)
    ranked = sorted((r for r in rows if r["status"] in ("ok", "skipped") and isinstance(r.get(rank), float)),
                    key=lambda r: -r[rank]) if rank else []
    png, axes = _histograms(rows, metrics)
    report = BatchReport(title or f"rigslim batch: {summary.parent.name}", str(summary), rows, columns, rank,
                         ranked[:worst], png, histogram_axes=axes)
    if render:
        frames: dict[str, AssetFrame] = {}
        for r in progress(report.worst, total=len(report.worst), description="reading the worst assets"):
            af, note = prepare_asset(summary.parent / r["name"], rank)
            if af is None:
                report.renders[r["name"]], report.notes[r["name"]] = [], note
            else:
                frames[r["name"]] = af
        # one colour scale per kind of heat map over the page: its largest distance, at least the floor
        for af in frames.values():
            report.scales[af.kind] = max(report.scales.get(af.kind, HEAT_FLOOR_PCT), float(af.error_pct.max()))
        for name, af in progress(list(frames.items()), total=len(frames), description="rendering the worst assets"):
            report.renders[name] = draw_asset(af, report.scales[af.kind], width, height, backend)
            report.shown[name] = {"kind": af.kind, "level": af.level, "faces": int(len(af.shown_faces)),
                                  "source": af.source, "frame": af.frame, "max_pct": float(af.error_pct.max())}
    return report


def _cell(value) -> str:
    if value is None:
        return ""
    if isinstance(value, float):
        if value == int(value) and abs(value) < 1e15:
            return str(int(value))
        return f"{value:.4g}"
    return html.escape(str(value))


def _uri(png: bytes) -> str:
    import base64

    return "data:image/png;base64," + base64.b64encode(png).decode()


_SORT_JS = """
document.querySelectorAll('table.sortable th').forEach(function (th, col) {
  th.addEventListener('click', function () {
    var table = th.closest('table'), body = table.tBodies[0];
    var asc = th.dataset.dir !== 'asc';
    table.querySelectorAll('th').forEach(function (h) { delete h.dataset.dir; });
    th.dataset.dir = asc ? 'asc' : 'desc';
    var rows = Array.prototype.slice.call(body.rows);
    rows.sort(function (a, b) {
      var x = a.cells[col].dataset.v !== undefined ? a.cells[col].dataset.v : a.cells[col].textContent;
      var y = b.cells[col].dataset.v !== undefined ? b.cells[col].dataset.v : b.cells[col].textContent;
      var nx = parseFloat(x), ny = parseFloat(y);
      var c = (!isNaN(nx) && !isNaN(ny)) ? nx - ny : (x === '' ? 1 : y === '' ? -1 : x.localeCompare(y));
      return asc ? c : -c;
    });
    rows.forEach(function (r) { body.appendChild(r); });
  });
});
"""

_CSS = """
body { font-family: system-ui, sans-serif; margin: 1.5em; color: #222; }
table { border-collapse: collapse; font-size: 12px; margin: 0.5em 0 1.5em; }
th, td { border: 1px solid #ccc; padding: 2px 6px; text-align: right; }
th { background: #f0f0f0; cursor: pointer; position: sticky; top: 0; }
th[data-dir=asc]::after { content: ' \\25B2'; } th[data-dir=desc]::after { content: ' \\25BC'; }
td.s { text-align: left; } tr.failed td { background: #fde8e8; } tr.skipped td { color: #557; }
.worst { display: flex; flex-wrap: wrap; gap: 1em; }
.card { border: 1px solid #ddd; padding: 0.5em; max-width: 680px; }
.card img { margin-right: 4px; } figcaption { font-size: 11px; color: #555; max-width: 320px; }
figure { display: inline-block; margin: 0 4px 0 0; vertical-align: top; }
p, code, td.s, figcaption { overflow-wrap: anywhere; }
.scroll { overflow: auto; max-width: 100%; max-height: 85vh; margin: 0.5em 0 1.5em; }
.scroll table { margin: 0; }
.scroll th:first-child, .scroll td:first-child { position: sticky; left: 0; z-index: 1; background: #fff;
  box-shadow: inset -1px 0 0 #bbb; }
.scroll th:first-child { z-index: 2; background: #f0f0f0; } .scroll tr.failed td:first-child { background: #fde8e8; }
.scroll td.s { overflow-wrap: normal; white-space: nowrap; } .scroll td.wrap { white-space: normal; min-width: 24em; }
.scales figure { margin-right: 1.5em; } .scales figcaption { max-width: 480px; }
"""


def render_html(report: BatchReport) -> str:
    """The page as one HTML string."""
    counts = {s: sum(r["status"] == s for r in report.rows) for s in ("ok", "skipped", "failed")}
    total_s = sum(r.get("seconds") or 0.0 for r in report.rows)
    e = html.escape
    out = [f"<!doctype html><html><head><meta charset='utf-8'><title>{e(report.title)}</title>"
           f"<style>{_CSS}</style></head><body>", f"<h1>{e(report.title)}</h1>",
           f"<p>{len(report.rows)} assets from <code>{e(report.source)}</code>: <b>{counts['ok']}</b> ok, "
           f"<b>{counts['skipped']}</b> skipped, <b>{counts['failed']}</b> failed; "
           f"{total_s:.1f} s of worker time.</p>"]
    failed = [r for r in report.rows if r["status"] == "failed"]
    out.append(f"<h2>Failures ({len(failed)})</h2>")
    if failed:
        out.append("<div class='scroll'><table><thead><tr><th>name</th><th>error</th><th>attempts</th><th>asset</th>"
                   "</tr></thead><tbody>")
        for r in failed:
            out.append(f"<tr class='failed'><td class='s'>{e(r['name'])}</td><td class='s wrap'>"
                       f"{e(r.get('error') or '')}</td><td>{_cell(r.get('attempts'))}</td><td class='s'>"
                       f"{e(r['asset'])}</td></tr>")
        out.append("</tbody></table></div>")
    else:
        out.append("<p>None.</p>")
    if report.histograms:
        out.append("<h2>Errors over the assets</h2>")
        axes = "; ".join(f"<b>{e(m)}</b>: {e(label)}" + (", log bins" if log else "") +
                         (f" ({n} at 0 not shown)" if n else "") for m, label, log, n in report.histogram_axes)
        out.append(f"<figure class='histograms'><img alt='histograms of the error metrics' "
                   f"src='{_uri(report.histograms)}'><figcaption style='max-width:none'>x axes: {axes}. "
                   "Log bins where the values span more than two decades.</figcaption></figure>")
    if report.rank_metric:
        out.append(f"<h2>The {len(report.worst)} worst by {e(report.rank_metric)}</h2>")
        if report.scales:
            out.append(_scales_html(report))
        out.append("<div class='worst'>")
        for r in report.worst:
            shown = report.shown.get(r["name"])
            attrs = "".join(f" data-{k.replace('_', '-')}='{e(str(v))}'" for k, v in (shown or {}).items()
                            if v is not None)
            if shown:
                attrs += f" data-scale-top='{report.scales[shown['kind']]!r}'"
            out.append(f"<div class='card'{attrs}><b>{e(r['name'])}</b>: {e(report.rank_metric)} = "
                       f"{_cell(r[report.rank_metric])}<br><small>{e(r['asset'])}</small><br>")
            for caption, png in report.renders.get(r["name"], []):
                out.append(f"<figure><img alt='{e(caption)}' src='{_uri(png)}'><figcaption>{e(caption)}"
                           "</figcaption></figure>")
            if r["name"] in report.notes:
                out.append(f"<p><small>not rendered: {e(report.notes[r['name']])}</small></p>")
            out.append("</div>")
        out.append("</div>")
    out.append("<h2>All assets</h2><p>Click a column header to sort; the table scrolls sideways, its name column "
               "stays.</p><div class='scroll'><table class='sortable'><thead><tr>")
    first = [c for c in ("name", "status") if c in report.columns]
    cols = first + [c for c in report.columns if c not in first and c != "error"] + ["error"]
    out += [f"<th>{e(c)}</th>" for c in cols]
    out.append("</tr></thead><tbody>")
    for r in report.rows:
        cells = []
        for c in cols:
            v = r.get(c)
            cls = " class='s'" if isinstance(v, str) or c in ("asset", "name", "status", "error", "worker") else ""
            data = f" data-v='{v!r}'" if isinstance(v, float) else ""
            cells.append(f"<td{cls}{data}>{_cell(v)}</td>")
        out.append(f"<tr class='{e(r['status'])}'>{''.join(cells)}</tr>")
    out.append(f"</tbody></table></div><script>{_SORT_JS}</script></body></html>")
    return "\n".join(out)


#: What each kind of heat map shows (colour-bar labels).
_KINDS = {"reduced": "reduced weights", "level": "simplified levels"}


def _scales_html(report: BatchReport) -> str:
    """One colour bar per kind of heat map on the page, 0 to its shared top (% of the diagonal)."""
    from rigslim.report.plots import colorbar
    from rigslim.report.renders import HEAT_CMAP

    figs = []
    for kind, top in report.scales.items():
        what = _KINDS.get(kind, kind)
        bar = colorbar(top, HEAT_CMAP, f"distance to the full deformation (% of the diagonal), 0 to {top:.3g}")
        figs.append(f"<figure class='scale' data-kind='{kind}' data-scale-top='{top!r}'><img alt='colour scale of "
                    f"the {what} renders, 0 to {top:.3g} % of the diagonal' src='{_uri(bar)}'><figcaption>one scale "
                    f"for every {what} render below: 0 to {top:.3g} % of the bounding-box diagonal of the full "
                    f"deformation (the largest distance on this page, at least {HEAT_FLOOR_PCT:g} %)</figcaption>"
                    "</figure>")
    return "<div class='scales'>" + "".join(figs) + "</div>"


def write_batch_report(path, report: BatchReport, png_dir=None) -> list[Path]:
    """Write the page (and the renders as PNG files into ``png_dir``), atomically; return the PNG paths."""
    from rigslim.io.atomic import atomic_path

    written = []
    if png_dir is not None:
        for name, imgs in report.renders.items():
            kind = (report.shown.get(name) or {}).get("kind", "reduced")
            for i, (_, png) in enumerate(imgs):
                p = Path(png_dir) / f"{name}-{'full' if i == 0 else kind}.png"
                with atomic_path(p) as tmp:
                    Path(tmp).write_bytes(png)
                written.append(p)
    with atomic_path(path) as tmp:
        Path(tmp).write_text(render_html(report), encoding="utf-8")
    return written


def cmd_report_batch(args) -> int:
    """``rigslim report DIR/summary.csv -o batch.html``: dispatched by the report command for .csv inputs."""
    from rich.console import Console

    from rigslim.runtime.progress import Reporter

    if len(args.metrics) != 1:
        raise InputError("a batch report takes one summary.csv", field="METRICS", fix="give one DIR/summary.csv "
                         "(metrics JSON files of single runs make the run report)")
    try:
        width, height = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise InputError(f"--size '{args.size}' is not WIDTHxHEIGHT", field="--size",
                         fix="write e.g. --size 320x270") from None
    if not (16 <= width <= 4096 and 16 <= height <= 4096):
        raise InputError(f"--size {width}x{height} is out of range", field="--size", fix="give 16 to 4096 pixels")
    reporter = Reporter(Console(stderr=True, quiet=args.quiet))
    report = build_batch_report(args.metrics[0], render=not args.no_renders, width=width, height=height,
                                backend=args.backend, title=args.title, progress=reporter.track)
    written = write_batch_report(args.output, report, args.png_dir)
    rendered = sum(bool(v) for v in report.renders.values())
    print(f"batch report written to {args.output} ({len(report.rows)} assets, {len(report.worst)} worst, "
          f"{rendered} rendered)")
    for p in written:
        print(f"render written to {p}")
    return 0
