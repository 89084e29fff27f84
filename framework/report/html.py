"""HTML reports of one or more pipeline runs: table, plots and renders in one file.

A report reads metrics documents (the JSON of ``rigslim run --metrics``, see
docs/pipelines.md), one row per evaluation, and writes a single
self-contained HTML page (every image a ``data:`` URI):

- a summary table: method, k, reduction time, position and normal RMS
  (mean / max over test frames), Metro error when measured, influence counts;
- matplotlib figures (:mod:`rigslim.report.plots`): per-frame error curves,
  error against k when runs with several k are given, and weight-count
  histograms before and after reduction;
- renders of chosen test frames (:mod:`rigslim.report.render`, OpenGL through EGL):
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
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from rigslim.errors import RigslimError
from rigslim.io.atomic import atomic_path, output_transaction
from rigslim.report.data import load_render_data
from rigslim.report.renders import HEAT_CMAP, HEAT_FLOOR_DEGREES, render_rows
from rigslim.report.summary import EvaluationRow, _unique_labels, summarize


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
.pair figure,figure.scale{display:inline-table}.pair figcaption,figure.scale figcaption{display:table-caption;
caption-side:bottom}.frame{margin:10px 0 18px}.pair{display:inline-block;vertical-align:top;margin-right:14px}
td{white-space:nowrap}.notes{color:#8a5a00;font-size:.85em}
.scroll{overflow-x:auto;max-width:100%;margin:8px 0}.scroll table{margin:0}
.scroll th:first-child,.scroll td:first-child{position:sticky;left:0;z-index:1;background:#fff;
box-shadow:inset -1px 0 0 #bbb}.scroll th:first-child{background:#f3f4f6}
.scroll tr:nth-child(even) td:first-child{background:#fafafa}
"""

# Marks the page once loaded: how many images decoded, and errors caught, as data attributes of a hidden
# element (the browser test reads them; a reader never sees them).
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
    el.setAttribute('data-state', 'loaded');
  });
})();
"""


#: Metric keys the main table shows in columns of its own.
_TABLE_KEYS = {"position_rms_pct", "normal_rms_rad", "normal_median_rad", "normal_p95_rad", "normal_p99_rad",
               "normal_flipped", "normal_area_rms_rad", "max_influences", "input_max_influences", "mean_influences",
               "input_mean_influences"}


def _other_metrics(rows: list[EvaluationRow], shown: set[str]) -> list[str]:
    """A table of every other metric key (third-party metrics among them): mean and max, or the value."""
    keys = sorted({k for r in rows for k in r.metrics} - _TABLE_KEYS - shown)
    if not keys:
        return []
    out = ['<h3>Other metrics</h3><div class="scroll"><table><thead><tr><th class="l">run / evaluation</th>' +
           "".join(f"<th>{html.escape(k)}</th>" for k in keys) + "</tr></thead><tbody>"]
    for r in rows:
        cells = []
        for k in keys:
            v = r.metrics.get(k)
            text = f"{_fmt(v.get('mean'))} (max {_fmt(v.get('max'))})" if isinstance(v, dict) else \
                _fmt(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else "&ndash;"
            cells.append(f"<td>{text}</td>")
        out.append(f'<tr><th class="l" scope="row">{html.escape(r.label)}</th>' + "".join(cells) + "</tr>")
    out.append("</tbody></table></div>")
    return out


def _table(rows: list[EvaluationRow]) -> str:
    metro_keys = sorted({k for r in rows for k in r.metro})
    names = {"hausdorff_rms_pct": "Metro RMS % mean", "hausdorff_max_pct": "Metro max % mean"}
    head = ["run / evaluation", "method", "k", "reduction (s)", "position RMS % mean", "position RMS % max",
            "normal RMS rad mean", "normal RMS rad max", "normal median rad", "normal p95 rad", "normal p99 rad",
            "normals &gt; 90&deg; (max)", "normal area RMS rad"] + [names.get(k, k) for k in metro_keys] + \
        ["max influences (input &rarr; reduced)", "mean influences"]
    out = ['<div class="scroll"><table><thead><tr>' + "".join(f'<th class="{"l" if i < 2 else ""}">{h}</th>'
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
    out.append("</tbody></table></div>")
    out += _other_metrics(rows, set(metro_keys))
    if any(r.levels for r in rows):
        out.append("<h3>Simplified levels</h3><div class=\"scroll\"><table><thead><tr>"
                   "<th class=\"l\">run / evaluation</th><th class=\"l\">level</th><th>faces</th>"
                   "<th>Metro RMS % mean</th><th>Metro RMS % max</th>"
                   "<th>Metro max % mean</th><th>Metro max % max</th></tr></thead><tbody>")
        for r in rows:
            for level, vals in r.levels.items():
                rms, mx = vals.get("hausdorff_rms_pct") or {}, vals.get("hausdorff_max_pct") or {}
                out.append(f'<tr><td class="l">{html.escape(r.label)}</td><td class="l">{html.escape(level)}</td>'
                           f"<td>{_fmt(vals.get('faces'))}</td><td>{_fmt(rms.get('mean'))}</td>"
                           f"<td>{_fmt(rms.get('max'))}</td><td>{_fmt(mx.get('mean'))}</td>"
                           f"<td>{_fmt(mx.get('max'))}</td></tr>")
        out.append("</tbody></table></div>")
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
    from rigslim.report.gltf import lod_section, world_units_section
    from rigslim.report.input import check_render_size

    check_render_size(width, height)

    rows: list[EvaluationRow] = []
    for doc, source in documents:
        rows += summarize(doc, source)
    _unique_labels(rows)
    notes: list[str] = []
    renders: dict[str, bytes] = {}
    rset = None
    if render:
        rset = _render_documents(documents, rows, dict(data or {}), notes, frames=frames, width=width,
                                 height=height, backend=backend, projection=projection, azimuth=azimuth,
                                 elevation=elevation, up_axis=up_axis, progress=progress)
    # HTML
    title = title or ("rigslim report: " + ", ".join(dict.fromkeys(r.run for r in rows)))
    parts = _page_head(title, documents, rows, rset)
    parts += _plots_section(rows, notes)
    if rset is not None and rset.frames:
        parts += _renders_section(rset, renders)
    parts.append(world_units_section(documents))

    parts.append(lod_section(documents))
    if notes:
        parts.append("<h2>Notes</h2><ul class=\"notes\">" + "".join(f"<li>{html.escape(n)}</li>" for n in notes)
                     + "</ul>")
    parts.append(f"<div id=\"rigslim-check\" hidden></div><script>{_CHECK_JS}</script></body></html>")
    return Report("\n".join(parts), renders, rows, notes)


def _render_documents(documents: list[tuple[dict, str]], rows: list[EvaluationRow], data: dict, notes: list[str],
                      **options: Any):
    """The renders of :func:`build_report`: each document's inputs re-read (unless ``data`` holds them; a
    document whose inputs cannot be re-read is noted and left out), then :func:`render_rows` with ``options``."""
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
    rset = render_rows(rows, data, **options)
    notes += rset.notes
    return rset


def _page_head(title: str, documents: list[tuple[dict, str]], rows: list[EvaluationRow], rset) -> list[str]:
    """The page up to the summary: title, version and time, sources, the mesh and its test frames."""
    from rigslim import __version__

    when = _dt.datetime.now(_dt.UTC).strftime("%Y-%m-%d %H:%M UTC")
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
    return parts


def _plots_section(rows: list[EvaluationRow], notes: list[str]) -> list[str]:
    """The summary table and the plots: error per test frame, error against k (runs of one method with
    several k), weight-count histograms; what cannot be drawn is noted."""
    from rigslim.report import plots

    parts = ["<h2>Summary</h2>", _table(rows),
             "<div class=\"meta\">Position RMS: RMS vertex distance between reduced and full deformation, "
             "% of the bounding-box diagonal of the full deformation in the first test frame (documents of "
             "schema 1 and 2: of the rest mesh's); normal RMS: RMS angle between their normals (radians). "
             "Mean and max over test frames. Reduction time: generate, select, solve and decimate steps "
             "since the previous evaluation.</div>",
             "<h2>Plots</h2><div class=\"plots\">",
             f"<img alt=\"error per test frame\" src=\"{_data_uri(plots.error_curves(rows))}\">"]
    ks: dict[str, set[int]] = {}
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
    return parts


def _renders_section(rset, renders: dict[str, bytes]) -> list[str]:
    """The renders: the heat maps' colour scale, then per frame the full weights, each evaluation's reduced
    weights with its normal deviation heat map, or each level; every image also goes to ``renders``."""
    from rigslim.report import plots

    parts = ["<h2>Renders</h2><div class=\"meta\">First: the full input weights. Then per evaluation: "
             "the reduced weights, and the reduced deformation coloured by the angle between its "
             "normals and the full deformation's; or each simplified level with its own weights.</div>"]
    top = rset.heat_max
    if any(rf.reduced for rf in rset.frames):
        clipped = any(dmax > top for rf in rset.frames for _, _, _, dmax, _ in rf.reduced)
        bar = plots.colorbar(top, HEAT_CMAP, f"normal deviation (degrees), 0 to {top:.3g}", clipped=clipped)
        parts.append(f"<figure class=\"scale\" data-scale-top=\"{top!r}\"><img alt=\"normal deviation scale, "
                     f"0 to {top:.3g} degrees\" src=\"{_data_uri(bar)}\"><figcaption>colour scale of the normal "
                     f"deviation heat maps: 0&deg; to {top:.3g}&deg; (the largest 99th percentile of their "
                     f"per-vertex angles, at least {HEAT_FLOOR_DEGREES:g}&deg;)"
                     + ("; larger angles are drawn in the top colour" if clipped else "")
                     + "</figcaption></figure>")
    for rf in rset.frames:
        parts.append(_frame_figures(rf, top, renders))
    return parts


def _frame_figures(rf, top: float, renders: dict[str, bytes]) -> str:
    """One frame's figures (full, then reduced with heat map, then levels), their PNGs added to ``renders``."""
    base = _slug(f"{rf.run.split(',')[0]}-frame{rf.frame}")
    png = _png_of(rf.full)
    renders[f"{base}-full.png"] = png
    figs = [f"<div class=\"pair\"><figure><img alt=\"full frame {rf.frame}\" src=\"{_data_uri(png)}\">"
            f"<figcaption>full weights</figcaption></figure></div>"]
    for label, img, heat, dmax, _ in rf.reduced:
        p1, p2 = _png_of(img), _png_of(heat)
        renders[f"{base}-{_slug(label)}-reduced.png"] = p1
        renders[f"{base}-{_slug(label)}-normals.png"] = p2
        scale = (f"clipped at {top:.3g}&deg; (the colour bar's top); max {dmax:.3g}&deg;" if dmax > top
                 else f"max {dmax:.3g}&deg;, colour bar 0 to {top:.3g}&deg;")
        figs.append(f"<div class=\"pair\"><figure><img alt=\"{html.escape(label)} frame {rf.frame}\" "
                    f"src=\"{_data_uri(p1)}\"><figcaption>{html.escape(label)}</figcaption></figure>"
                    f"<figure class=\"heat\" data-max=\"{dmax!r}\" data-scale-top=\"{top!r}\">"
                    f"<img alt=\"{html.escape(label)} normal deviation\" src=\"{_data_uri(p2)}\">"
                    f"<figcaption>{html.escape(label)}: normal deviation, {scale}</figcaption></figure></div>")
    for label, faces, img in rf.levels:
        p1 = _png_of(img)
        renders[f"{base}-{_slug(label)}-level.png"] = p1
        figs.append(f"<div class=\"pair\"><figure><img alt=\"{html.escape(label)} frame {rf.frame}\" "
                    f"src=\"{_data_uri(p1)}\"><figcaption>{html.escape(label)} ({faces} faces, "
                    f"own weights)</figcaption></figure></div>")
    place = f" ({html.escape(rf.place)})" if rf.place else ""
    return f"<div class=\"frame\"><h3>{html.escape(rf.run)}, frame {rf.frame}{place}</h3>{''.join(figs)}</div>"


def _png_of(image) -> bytes:
    from rigslim.report.render import png_bytes

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
