"""The batch view: ``rigslim report DIR/summary.csv -o batch.html``.

One self-contained HTML page (every image a ``data:`` URI) of a
``rigslim batch`` run (docs/batch.md):

- counts (ok / skipped / failed) and the failures with their one-line errors;
- histograms of each error metric over the assets (matplotlib);
- the worst assets by one error metric (default: the largest of
  ``hausdorff_max_pct_max``, ``position_rms_pct_max``, ``normal_rms_rad_max``
  present), each with two renders at its worst test frame: the deformation
  with the full input weights, and with the reduced weights its outputs hold,
  coloured by each vertex's distance to the full deformation (% of that
  frame's world-space bounding-box diagonal);
- every row in a table sorted by clicking a column header.

The renders re-read the asset's inputs through ``DIR/<name>/pipeline.yaml``
and the reduced weights from the first ``.npz`` (reduced weights) or
``.glb``/``.gltf`` output in ``DIR/<name>/`` whose mesh matches the input's;
an asset without such an output is listed without renders, with the reason.
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
        row = {}
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


def _histograms(rows: list[dict], metrics: list[str]) -> bytes | None:
    from rigslim.report.plots import _figure, _png, color

    metrics = [m for m in metrics if any(isinstance(r.get(m), float) for r in rows)][:6]
    if not metrics:
        return None
    cols = min(3, len(metrics))
    nrows = math.ceil(len(metrics) / cols)
    fig = _figure(3.4 * cols, 2.6 * nrows)
    for i, m in enumerate(metrics):
        ax = fig.add_subplot(nrows, cols, i + 1)
        values = np.array([r[m] for r in rows if isinstance(r.get(m), float)])
        ax.hist(values, bins=min(30, max(5, len(values) // 3)), color=color(i))
        ax.set_title(m, fontsize=9)
        ax.set_xlabel("value", fontsize=8)
        ax.set_ylabel("assets", fontsize=8)
        ax.tick_params(labelsize=7)
    return _png(fig)


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
            if out.mesh.n_vertices == m and out.weights is not None and out.weights.shape[1] == n and \
                    np.allclose(out.mesh.V, asset.mesh.V, atol=1e-4 * asset.mesh.bbox_diagonal):
                return sp.csr_matrix(out.weights), p.name
            tried.append(p.name)
    return None, ("no output holds reduced weights of this mesh" +
                  (f" (tried {', '.join(tried)})" if tried else " (write a .npz or .glb after the solve)"))


def render_asset(folder: Path, width: int = 320, height: int = 270, backend: str = "auto"):
    """Two renders of an asset at its worst test frame: full weights, and reduced weights coloured by error.

    Returns
    -------
    (renders, note)
        ``renders`` is a list of (caption, PNG bytes); ``note`` says why there are none.
    """
    from rigslim.numerics.blend import linear_blend
    from rigslim.plugin.contract import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.report.render import Camera, png_bytes, render_mesh
    from rigslim.report.renders import HEAT_CMAP, heat_colors
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs

    try:
        metrics = json.loads((folder / "metrics.json").read_text())
        doc, _ = load_pipeline(folder / "pipeline.yaml")
        asset = read_inputs(doc, folder, get_host(), StepContext(base_dir=folder), folder / "pipeline.yaml")
    except Exception as e:  # noqa: BLE001 - the page still lists the asset, with the reason
        return [], f"inputs not re-readable ({' '.join(str(e).split())[:200]})"
    if asset.weights is None or asset.poses is None or asset.handles is None:
        return [], "the asset has no input weights or animation to render"
    R, where = _reduced_from_outputs(folder, asset)
    if R is None:
        return [], where
    test = (metrics.get("frames") or {}).get("test") or list(asset.poses.frames)
    ev = (metrics.get("evaluations") or [{}])[-1].get("metrics", {})
    per_frame = (ev.get("position_rms_pct") or {}).get("per_frame")
    frame = int(test[int(np.argmax(per_frame))]) if per_frame and len(per_frame) == len(test) else int(test[0])
    T = asset.poses.select([frame]).T[0]
    full = linear_blend(asset.mesh.V, asset.weights, T)
    reduced = linear_blend(asset.mesh.V, R, T)
    from rigslim.numerics.units import diagonal

    err = 100.0 * np.linalg.norm(full - reduced, axis=1) / max(diagonal(full), 1e-300)  # % of the world diagonal
    camera = Camera.fit(np.vstack([full, reduced]), width, height)
    grey = np.array([0.75, 0.75, 0.78])
    img_full, _ = render_mesh(full, asset.mesh.F, grey, camera, backend=backend)
    vmax = float(err.max()) or 1.0
    img_red, _ = render_mesh(reduced, asset.mesh.F, heat_colors(err, vmax, HEAT_CMAP), camera, backend=backend)
    return [(f"frame {frame}, full weights", png_bytes(img_full)),
            (f"reduced weights from {where}; colour: distance to full, 0 to {vmax:.3g}% of the diagonal",
             png_bytes(img_red))], ""


def build_batch_report(summary, *, worst: int = 10, metric: str | None = None, render: bool = True,
                       width: int = 320, height: int = 270, backend: str = "auto", title: str | None = None,
                       progress=lambda it, total=None, description="": it) -> BatchReport:
    """Read a batch summary.csv and build its report (see the module docstring)."""
    summary = Path(summary)
    rows, columns = read_summary(summary)
    metrics = error_columns(columns)
    if metric is not None and metric not in columns:
        raise InputError(f"the summary has no column '{metric}'", source=summary, field="--metric",
                         fix="one of: " + ", ".join(metrics or columns))
    rank = metric or next((m for m in RANK_METRICS if m in columns), metrics[0] if metrics else None)
    ranked = sorted((r for r in rows if r["status"] in ("ok", "skipped") and isinstance(r.get(rank), float)),
                    key=lambda r: -r[rank]) if rank else []
    report = BatchReport(title or f"rigslim batch: {summary.parent.name}", str(summary), rows, columns, rank,
                         ranked[:worst], _histograms(rows, metrics))
    if render:
        for r in progress(report.worst, total=len(report.worst), description="rendering the worst assets"):
            imgs, note = render_asset(summary.parent / r["name"], width, height, backend)
            report.renders[r["name"]] = imgs
            if note:
                report.notes[r["name"]] = note
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
        out.append("<table><thead><tr><th>asset</th><th>error</th><th>attempts</th></tr></thead><tbody>")
        for r in failed:
            out.append(f"<tr class='failed'><td class='s'>{e(r['asset'])}</td><td class='s'>{e(r.get('error') or '')}"
                       f"</td><td>{_cell(r.get('attempts'))}</td></tr>")
        out.append("</tbody></table>")
    else:
        out.append("<p>None.</p>")
    if report.histograms:
        out.append("<h2>Errors over the assets</h2>")
        out.append(f"<img alt='histograms of the error metrics' src='{_uri(report.histograms)}'>")
    if report.rank_metric:
        out.append(f"<h2>The {len(report.worst)} worst by {e(report.rank_metric)}</h2><div class='worst'>")
        for r in report.worst:
            out.append(f"<div class='card'><b>{e(r['name'])}</b>: {e(report.rank_metric)} = "
                       f"{_cell(r[report.rank_metric])}<br><small>{e(r['asset'])}</small><br>")
            for caption, png in report.renders.get(r["name"], []):
                out.append(f"<figure><img alt='{e(caption)}' src='{_uri(png)}'><figcaption>{e(caption)}"
                           "</figcaption></figure>")
            if r["name"] in report.notes:
                out.append(f"<p><small>not rendered: {e(report.notes[r['name']])}</small></p>")
            out.append("</div>")
        out.append("</div>")
    out.append("<h2>All assets</h2><p>Click a column header to sort.</p><table class='sortable'><thead><tr>")
    cols = [c for c in report.columns if c != "error"] + ["error"]
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
    out.append(f"</tbody></table><script>{_SORT_JS}</script></body></html>")
    return "\n".join(out)


def write_batch_report(path, report: BatchReport, png_dir=None) -> list[Path]:
    """Write the page (and the renders as PNG files into ``png_dir``), atomically; return the PNG paths."""
    from rigslim.io.atomic import atomic_path

    written = []
    if png_dir is not None:
        for name, imgs in report.renders.items():
            for i, (_, png) in enumerate(imgs):
                p = Path(png_dir) / f"{name}-{'full' if i == 0 else 'reduced'}.png"
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
