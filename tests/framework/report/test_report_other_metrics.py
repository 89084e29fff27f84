"""A third-party metric appears in the HTML report (its own table) and in batch summaries (its columns)."""

from __future__ import annotations

from rigslim.batch.task import summary_metrics
from rigslim.report import build_report

DOC = {"schema_version": 2, "name": "run", "frames": {"test": [3, 5]},
       "steps": [{"stage": "read", "seconds": 0.1}, {"stage": "solve", "plugin": "poisson", "k": 4, "seconds": 1.0},
                 {"stage": "evaluate", "seconds": 0.2}],
       "evaluations": [{"name": "poisson-k4", "step": 2, "metrics": {
           "position_rms_pct": {"mean": 0.5, "max": 1.0, "per_frame": [1.0, 0.0]},
           "curvature_error": {"mean": 0.0123, "max": 0.0456, "per_frame": [0.0456, 0.001]},
           "skipped_vertices": 17}}]}


def test_a_third_party_metric_is_in_the_report():
    html = build_report([(DOC, "run.json")], render=False).html
    other = html.split("<h3>Other metrics</h3>", 1)[1].split("</table>", 1)[0]
    assert "<th>curvature_error</th>" in other and "<th>skipped_vertices</th>" in other
    assert "0.0123 (max 0.0456)" in other and "<td>17</td>" in other
    assert "position_rms_pct" not in other  # shown in the main table already


def test_a_third_party_metric_is_in_the_batch_summary_columns():
    cols = summary_metrics(DOC)
    assert cols["curvature_error_mean"] == 0.0123 and cols["curvature_error_max"] == 0.0456
    assert cols["skipped_vertices"] == 17
