"""A metric plugin rigslim does not ship, run by a pipeline: its values reach the run's HTML report (the
"Other metrics" table) and a batch summary's columns (:func:`rigslim.batch.task.summary_metrics`).

The plugin is registered the way a package's entry point would be, through the host's ``extra`` objects.
"""

from __future__ import annotations

import types
from pathlib import Path

import numpy as np

from rigslim import hookimpl
from rigslim.batch.task import summary_metrics
from rigslim.numerics.blend import linear_blend
from rigslim.plugin import Metric, Params, aggregate
from rigslim.plugin.host import PluginHost
from rigslim.runtime.run import run_pipeline

DATA = Path(__file__).resolve().parents[3] / "examples" / "data"


class WorstVertexParams(Params):
    scale: float = 1.0
    """Multiply the distances by this (e.g. 100 for centimetres from metres)."""


class WorstVertex(Metric[WorstVertexParams]):
    """``max_v |x_v - xhat_v|`` per test frame: the vertex that moved furthest from the full deformation."""

    name = "worst-vertex"
    summary = "largest vertex distance between the full and the reduced deformation, per test frame"

    def compute(self, evaluation, params: WorstVertexParams, ctx=None):
        per_frame = [params.scale * float(np.max(np.linalg.norm(evaluation.reduced_positions(j)
                                                                - evaluation.full_positions(j), axis=1)))
                     for j in range(len(evaluation))]
        return {"worst_vertex_m": aggregate(per_frame), "worst_vertex_frames": len(per_frame)}


def _package() -> types.ModuleType:
    module = types.ModuleType("rigslim_worst_vertex")

    @hookimpl
    def rigslim_metrics():
        return [WorstVertex()]

    module.rigslim_metrics = rigslim_metrics
    return module


def test_a_plugin_metric_reaches_the_report_and_the_batch_summary(tmp_path):
    host = PluginHost(extra=[_package()])
    raw = {"name": "worst-vertex-run",
           "inputs": {"mesh": str(DATA / "elephant.obj"), "skeleton": str(DATA / "elephant.tgf"),
                      "weights": str(DATA / "elephant-weights.dmat"), "animation": str(DATA / "elephant-anim.dmat")},
           "poses": {"examples": "0:457:45", "test": "5:457:35"},
           "steps": [{"select": "k-largest", "k": 3}, {"solve": "k-largest"},
                     {"evaluate": ["position-rms", {"worst-vertex": {"scale": 100.0}}]},
                     {"report": "out/report.html", "render": False}]}
    result = run_pipeline(tmp_path / "pipeline.yaml", raw=raw, host=host, console=None)

    # the value, computed here from the asset the run left
    asset = result.asset
    poses = asset.test_poses()
    expected = [100.0 * float(np.max(np.linalg.norm(linear_blend(asset.mesh.V, asset.reduced, T)
                                                      - linear_blend(asset.mesh.V, asset.weights, T), axis=1)))
                for T in poses.T]
    metrics = result.document["evaluations"][0]["metrics"]
    assert np.allclose(metrics["worst_vertex_m"]["per_frame"], expected, rtol=1e-9)
    assert metrics["worst_vertex_frames"] == len(poses) > 1

    html = (tmp_path / "out" / "report.html").read_text()
    other = html.split("<h3>Other metrics</h3>", 1)[1].split("</table>", 1)[0]
    assert "<th>worst_vertex_m</th>" in other and "<th>worst_vertex_frames</th>" in other
    assert f"<td>{len(poses)}</td>" in other

    columns = summary_metrics(result.document)
    assert columns["worst_vertex_m_mean"] == metrics["worst_vertex_m"]["mean"]
    assert columns["worst_vertex_m_max"] == max(metrics["worst_vertex_m"]["per_frame"])
    assert columns["worst_vertex_frames"] == len(poses)
