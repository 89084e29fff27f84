"""The ``report`` writer: an HTML report of the pipeline's evaluations (``report: out/report.html``)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

from rigslim.errors import StepError
from rigslim.plugin import Params, Writer

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext


class ReportWriterParams(Params):
    frames: list[int] | None = None
    """Animation frames to render (default: the worst test frame of the first evaluation)."""
    width: int = 320
    """Width of each render in pixels."""
    height: int = 270
    """Height of each render in pixels."""
    png_dir: str | None = None
    """Also write the renders as PNG files here (relative to the pipeline file)."""
    compare: list[str] = []
    """Metrics JSON files of other runs to compare with (relative to the pipeline file)."""
    title: str | None = None
    """Page title (default: 'rigslim report: ' and the runs' names)."""
    backend: Literal["auto", "opengl", "numpy"] = "auto"
    """Renderer: auto is OpenGL through EGL when available, else the numpy rasteriser."""
    projection: Literal["perspective", "orthographic"] = "perspective"
    """Camera projection of the renders."""
    azimuth: float = 30.0
    """Viewing direction in degrees around the up axis, from the axis after it."""
    elevation: float = 15.0
    """Viewing direction in degrees above the horizon."""
    up_axis: Literal[0, 1, 2] = 1
    """World axis that points up in the images (0 x, 1 y, 2 z)."""
    render: bool = True
    """False leaves the renders out (table and plots only)."""


class ReportWriter(Writer[ReportWriterParams]):
    name = "report"
    summary = ("self-contained HTML report of the evaluations so far: table, error curves, error against k, "
               "weight-count histograms, OpenGL renders (full, reduced, normal deviation)")
    suffixes = (".html", ".htm")

    def write(self, path: Path, asset: Asset, params: ReportWriterParams, ctx: StepContext) -> None:
        from rigslim.report import RenderData, build_report, load_document, write_report

        document = ctx.document
        if not document or not document.get("evaluations"):
            raise StepError("a report needs evaluations before it", field="report",
                            fix="put an 'evaluate' step before the 'report' step")
        base = Path(ctx.base_dir)
        documents = [(document, document.get("pipeline", ""))]
        for other in params.compare:
            p = Path(other) if Path(other).is_absolute() else base / other
            documents.append((load_document(p), str(p)))
        data = {id(document): RenderData(asset, dict(asset.extras.get("evaluated_reduced", {})),
                                         normals=dict(asset.extras.get("evaluated_normals", {})))}
        report = build_report(documents, data=data, frames=params.frames, width=params.width,
                              height=params.height, backend=params.backend, projection=params.projection,
                              azimuth=params.azimuth, elevation=params.elevation, up_axis=params.up_axis,
                              title=params.title, render=params.render, progress=ctx.progress)
        png_dir = None
        if params.png_dir:
            png_dir = Path(params.png_dir) if Path(params.png_dir).is_absolute() else base / params.png_dir
        written = write_report(path, report, png_dir)
        ctx.report.update({"evaluations": len(report.rows), "renders": len(report.renders),
                           "png_files": [str(p) for p in written], "notes": report.notes})
