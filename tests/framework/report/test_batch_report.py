"""``rigslim report DIR/summary.csv``: the batch view (report_batch.py).

The batch folder is made by the per-asset task run in this process (the
function ``rigslim batch`` submits to Dask) and the summary writer, so these
tests need no cluster; tests/framework/batch/test_batch.py covers the Dask side.
"""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

pytest.importorskip("pyarrow")

from rigslim.batch.assets import collect_assets, load_template  # noqa: E402
from rigslim.batch.options import BatchOptions, BatchResult
from rigslim.batch.summary import write_summary  # noqa: E402
from rigslim.batch.task import run_asset  # noqa: E402
from rigslim.commands.cli import main  # noqa: E402
from rigslim.report.batch import build_batch_report, read_summary  # noqa: E402

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
    worst = re.findall(r"<div class='card'><b>([^<]+)</b>", text)
    assert worst == [r["name"] for r in ok]
    assert "class='sortable'" in text and text.count("<tr class='ok'>") == 3 and "<tr class='failed'>" in text
    assert "histograms of the error metrics" in text
    # two renders (full, reduced coloured by error) per ok asset, as data URIs and PNG files
    assert text.count("data:image/png;base64,") == 1 + 2 * len(ok)
    assert sorted(p.name for p in pngs.iterdir()) == sorted(f"{r['name']}-{k}.png" for r in ok
                                                            for k in ("full", "reduced"))
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" for p in pngs.iterdir())


def test_worst_by_chosen_metric_and_no_renders(batch_dir):
    report = build_batch_report(batch_dir / "summary.csv", worst=2, metric="normal_rms_rad_mean", render=False)
    values = [r["normal_rms_rad_mean"] for r in report.worst]
    assert len(values) == 2 and values == sorted(values, reverse=True)
    assert report.renders == {}


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
