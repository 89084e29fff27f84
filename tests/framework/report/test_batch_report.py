"""``rigslim report DIR/summary.csv``: the batch view (report_batch.py).

The batch folder is made by the per-asset task run in this process (the
function ``rigslim batch`` submits to Dask) and the summary writer, so these
tests need no cluster; tests/framework/batch/test_batch.py covers the Dask side.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pyarrow")

from rigslim.batch.assets import collect_assets, load_template  # noqa: E402
from rigslim.batch.options import BatchOptions, BatchResult
from rigslim.batch.summary import write_summary  # noqa: E402
from rigslim.batch.task import run_asset  # noqa: E402
from rigslim.commands.cli import main  # noqa: E402
from rigslim.report.batch import axis_label, build_batch_report, measured_level, read_summary  # noqa: E402

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"

TEMPLATE = """\
inputs:
  gltf: "{input}"
  fps: 30
poses:
  examples: "0:10:2"
  test: "1:10:2"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: "{name}.glb"
"""


@pytest.fixture(scope="module")
def batch_dir(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("batch")
    lib = tmp / "lib"
    lib.mkdir()
    shutil.copy(GLTF / "huesitos.glb", lib / "bones.glb")
    shutil.copy(GLTF / "animation_with_skeleton.glb", lib / "walker.glb")
    shutil.copytree(GLTF / "RiggedFigure", lib / "figure")
    (lib / "broken.glb").write_bytes(b"glTF\x02\x00\x00\x00")
    template = tmp / "t.yaml"
    template.write_text(TEMPLATE)
    out = tmp / "out"
    jobs = collect_assets([str(lib)])
    doc = load_template(template)
    rows = [run_asset(j.as_dict(), doc, str(template), str(out)) for j in jobs]
    write_summary(BatchOptions(template, [str(lib)], out), BatchResult(rows, 1.0))
    return out


def test_batch_view(batch_dir, tmp_path):
    page, pngs = tmp_path / "batch.html", tmp_path / "png"
    assert main(["report", str(batch_dir / "summary.csv"), "-o", str(page), "--backend", "numpy",
                 "--png-dir", str(pngs), "--size", "160x120", "-q"]) == 0
    text = page.read_text()
    rows, _ = read_summary(batch_dir / "summary.csv")
    ok = sorted((r for r in rows if r["status"] == "ok"), key=lambda r: -r["position_rms_pct_max"])
    assert len(ok) == 3
    # failures with the one-line error, the worst list in order, every asset in the sortable table
    broken = next(r for r in rows if r["name"] == "broken")
    assert "Failures (1)" in text and broken["error"].split(": error: ")[1][:40] in text.replace("&#x27;", "'")
    worst = re.findall(r"<div class='card'[^>]*><b>([^<]+)</b>", text)
    assert worst == [r["name"] for r in ok]
    assert "class='sortable'" in text and text.count("<tr class='ok'>") == 3 and "<tr class='failed'>" in text
    assert "histograms of the error metrics" in text
    # the histograms, one colour bar, two renders (full, reduced coloured by error) per ok asset, as data URIs
    # and PNG files
    assert text.count("data:image/png;base64,") == 2 + 2 * len(ok)
    assert sorted(p.name for p in pngs.iterdir()) == sorted(f"{r['name']}-{k}.png" for r in ok
                                                            for k in ("full", "reduced"))
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs.iterdir())


def test_worst_by_chosen_metric_and_no_renders(batch_dir):
    report = build_batch_report(batch_dir / "summary.csv", worst=2, metric="normal_rms_rad_mean", render=False)
    values = [r["normal_rms_rad_mean"] for r in report.worst]
    assert len(values) == 2 and values == sorted(values, reverse=True)
    assert report.renders == {}


def test_a_relative_summary_path_renders_the_same_assets(batch_dir, monkeypatch):
    """``rigslim report DIR/summary.csv`` from DIR's parent, as docs/batch.md writes it (rendered nothing)."""
    absolute = build_batch_report(batch_dir / "summary.csv", backend="numpy", width=64, height=48)
    monkeypatch.chdir(batch_dir.parent)
    relative = build_batch_report(Path(batch_dir.name) / "summary.csv", backend="numpy", width=64, height=48)
    assert relative.notes == absolute.notes == {}
    assert sorted(relative.renders) == sorted(absolute.renders) and all(relative.renders.values())


def test_asset_without_reduced_output_is_listed_with_the_reason(batch_dir, tmp_path):
    out = tmp_path / "copy"
    shutil.copytree(batch_dir, out)
    (out / "bones" / "bones.glb").unlink()
    report = build_batch_report(out / "summary.csv", backend="numpy", width=64, height=48)
    assert report.renders["bones"] == [] and "no output holds reduced weights" in report.notes["bones"]


def test_bad_summary_is_one_line(tmp_path, capsys):
    bad = tmp_path / "summary.csv"
    bad.write_text("a,b\n1,2\n")
    assert main(["report", str(bad), "-o", str(tmp_path / "x.html")]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rigslim: error: ") and "not a batch summary" in err and "\n" not in err
    assert not (tmp_path / "x.html").exists()


def test_histogram_bins_are_logarithmic_for_data_spanning_decades():
    from rigslim.report.plots import histogram_bins

    edges, log = histogram_bins([1.3e-10, 2e-3, 0.4, 5.0], 5)
    assert log and edges[0] == 1.3e-10 and edges[-1] == 5.0
    assert np.allclose(np.diff(np.log10(edges)), np.log10(5.0 / 1.3e-10) / 5)  # equal widths in log10 x
    edges, log = histogram_bins([0.0, 1e-3, 0.5], 4)  # zero left out; 1e-3 .. 0.5 spans 2.7 decades
    assert log and edges[0] == 1e-3
    edges, log = histogram_bins([0.2, 0.5, 3.0, 19.0], 3)  # under two decades: linear
    assert not log and np.allclose(edges, 0.2 + np.arange(4) * (19.0 - 0.2) / 3)


def test_axis_label_names_quantity_statistic_level_and_unit():
    assert axis_label("position_rms_pct_max") == "position RMS, max over test frames (% of diagonal)"
    assert axis_label("normal_rms_rad_mean") == "normal RMS, mean over test frames (rad)"
    assert axis_label("step3.hausdorff_max_pct@quartic-10pct_max") == \
        "Metro max distance, max over test frames, level quartic-10pct, evaluation at step 3 (% of diagonal)"
    assert axis_label("hausdorff_rms_m_mean") == "Metro RMS distance, mean over test frames (world units)"


def test_measured_level_follows_the_column():
    values = {"mean": 1.0, "max": 2.0, "per_frame": [1.0, 2.0]}
    doc = {"schema_version": 3, "evaluations": [
        {"name": "reduce", "step": 3, "metrics": {"position_rms_pct": {"mean": 0.1, "max": 0.2}}},
        {"name": "levels", "step": 5, "metrics": {"hausdorff_max_pct": values},
         "levels": [{"name": "q-30pct", "faces": 36, "hausdorff_max_pct": values},
                    {"name": "q-10pct", "faces": 12, "hausdorff_max_pct": {"mean": 3.0, "max": 4.0}}]}]}
    # a plain Hausdorff column of a simplification holds its first level's values: that level is what it measured
    assert measured_level(doc, "hausdorff_max_pct_max")[1]["name"] == "q-30pct"
    assert measured_level(doc, "hausdorff_max_pct@q-10pct_max")[1]["faces"] == 12
    assert measured_level(doc, "step3.position_rms_pct_max") == (doc["evaluations"][0], None)
    assert measured_level(doc, "hausdorff_max_pct@gone_max")[1] == {"name": "gone"}  # no record: said so later
