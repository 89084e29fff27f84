"""HTML reports of pipeline runs (``rigslim report``, ``report:`` steps), one job per module.

- :mod:`~rigslim.report.input`: reading and checking metrics documents (any schema version);
- :mod:`~rigslim.report.summary`: one table row per evaluation (:func:`summarize`);
- :mod:`~rigslim.report.data`: re-reading a run's inputs for the renders (:func:`load_render_data`);
- :mod:`~rigslim.report.renders`: full, reduced and normal-deviation renders (:func:`render_rows`);
- :mod:`~rigslim.report.plots`: the matplotlib figures;
- :mod:`~rigslim.report.html`: the self-contained page (:func:`build_report`, :func:`write_report`);
- :mod:`~rigslim.report.batch` and :mod:`~rigslim.report.gltf`: the batch view and the glTF LOD rows.
"""

from rigslim.report.data import RenderData, load_render_data
from rigslim.report.html import Report, build_report, write_report
from rigslim.report.renders import (
                                    FULL_COLOR,
                                    HEAT_CMAP,
                                    LEVEL_COLOR,
                                    REDUCED_COLOR,
                                    RenderedFrame,
                                    RenderSet,
                                    heat_colors,
                                    normal_deviation_degrees,
                                    render_rows,
)
from rigslim.report.summary import EvaluationRow, load_document, summarize

__all__ = ["EvaluationRow", "FULL_COLOR", "HEAT_CMAP", "LEVEL_COLOR", "REDUCED_COLOR", "RenderData", "RenderSet",
           "RenderedFrame", "Report", "build_report", "heat_colors", "load_document", "load_render_data",
           "normal_deviation_degrees", "render_rows", "summarize", "write_report"]
