"""HTML reports: the metrics-JSON additions, the summary, the plots, the pipeline step and the CLI."""

from __future__ import annotations

import base64
import io
import json
import re

import numpy as np
import pytest

from rigslim.commands.cli import main
from rigslim.errors import InputError
from rigslim.report import build_report, heat_colors, load_document, normal_deviation_degrees, render_rows, summarize

PIPELINE = """
name: elephant-small
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses:
  examples: "0:457:45"
  test: "5:457:60"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: out/k2.npz
  - select: k-largest
    k: 4
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: out/k4.npz
  - report: out/report.html
    png_dir: out/renders
    width: 96
    height: 80
    frames: [65, 125]
"""


@pytest.fixture(scope="module")
def run(tmp_path_factory, data_dir):
    """The two-k elephant pipeline with a report step, run once; (folder, run result)."""
    from rigslim.runtime.run import run_pipeline

    folder = tmp_path_factory.mktemp("report")
    (folder / "data").symlink_to(data_dir, target_is_directory=True)
    (folder / "p.yaml").write_text(PIPELINE)
    result = run_pipeline(folder / "p.yaml", metrics_path=folder / "out" / "m.json")
    return folder, result


def _images(html_text):
    return re.findall(r'<img[^>]*src="([^"]*)"', html_text)


def _decode_png(uri_or_bytes):
    from PIL import Image

    data = uri_or_bytes
    if isinstance(data, str):
        assert data.startswith("data:image/png;base64,")
        data = base64.b64decode(data.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(data)).convert("RGB"))


def test_metrics_json_has_influence_histograms(run, elephant):
    folder, result = run
    doc = json.loads((folder / "out" / "m.json").read_text())
    m = elephant.mesh.n_vertices
    for ev, k in zip(doc["evaluations"], (2, 4), strict=False):
        hist = ev["influence_histogram"]
        assert sum(hist["input"]) == sum(hist["reduced"]) == m
        assert len(hist["reduced"]) - 1 == ev["metrics"]["max_influences"] == k
        assert len(hist["input"]) - 1 == ev["metrics"]["input_max_influences"]
        mean = np.dot(np.arange(len(hist["reduced"])), hist["reduced"]) / m
        assert mean == pytest.approx(ev["metrics"]["mean_influences"])
    assert doc["pipeline_file"] == str((folder / "p.yaml").resolve())
    report_step = [s for s in doc["steps"] if s["stage"] == "report"][0]
    assert report_step["plugin"] == "report" and report_step["path"].endswith("report.html")
    assert report_step["report"]["renders"] == 2 * (1 + 2 * 2)


def test_pipeline_report_is_self_contained(run):
    folder, _ = run
    text = (folder / "out" / "report.html").read_text()
    srcs = _images(text)
    # 2 plots (curves, error vs k) + histograms + colour bar + 2 frames x (full + 2 x (reduced + heat))
    assert len(srcs) == 3 + 1 + 2 * 5
    assert all(s.startswith("data:image/png;base64,") for s in srcs)
    assert "http://" not in text and "https://" not in text and "<link" not in text
    for label in ("k-largest-k2", "k-largest-k4"):
        assert f'<td class="l">{label}</td>' in text
    assert "24 &rarr; 2" in text and "24 &rarr; 4" in text
    for uri in srcs:
        img = _decode_png(uri)
        assert img.shape[0] > 10 and img.std() > 1.0  # not a blank image
    renders = sorted(p.name for p in (folder / "out" / "renders").iterdir())
    assert len(renders) == 10 and "elephant-small-frame65-full.png" in renders
    full = _decode_png((folder / "out" / "renders" / "elephant-small-frame65-full.png").read_bytes())
    assert full.shape == (80, 96, 3)


def test_renders_in_report_match_the_written_pngs(run):
    folder, _ = run
    text = (folder / "out" / "report.html").read_text()
    png = (folder / "out" / "renders" / "elephant-small-frame125-k-largest-k4-reduced.png").read_bytes()
    assert "data:image/png;base64," + base64.b64encode(png).decode() in text


def test_summarize_reads_method_k_time_and_metro():
    doc = {"name": "run", "frames": {"test": [3, 5]},
           "steps": [{"stage": "read", "seconds": 9.0},
                     {"stage": "select", "plugin": "k-largest", "k": 3, "seconds": 0.5},
                     {"stage": "solve", "plugin": "poisson", "k": 3, "seconds": 2.0},
                     {"stage": "evaluate", "seconds": 1.0},
                     {"stage": "solve", "plugin": "other", "k": 3, "seconds": 4.0},
                     {"stage": "evaluate", "seconds": 1.0}],
           "evaluations": [
               {"name": "a", "step": 3, "metrics": {"position_rms_pct": {"mean": 1, "max": 2, "per_frame": [2, 1]},
                                                    "metro_hausdorff_pct": {"mean": 0.25, "max": 0.5}}},
               {"name": "b", "step": 5, "metrics": {"normal_rms_rad": {"mean": 1, "max": 2, "per_frame": [1, 2]}}}]}
    a, b = summarize(doc, "x.json")
    assert (a.method, a.selection, a.k, a.seconds) == ("poisson", "k-largest", 3, 2.5)
    assert (b.method, b.k, b.seconds) == ("other", 3, 4.0)
    assert a.metro == {"metro_hausdorff_pct": 0.25} and b.metro == {}
    assert a.worst_frame() == 3 and b.worst_frame() == 5
    assert b.position_mean is None and b.normal_max == 2.0
    report = build_report([(doc, "x.json")], render=False)
    assert "metro_hausdorff_pct" in report.html and "0.25" in report.html
    # error curves only: two methods with one k each give no error-vs-k plot, and there are no histograms
    assert len(_images(report.html)) == 1
    assert any("influence_histogram" in n for n in report.notes)
    assert any("several k" in n for n in report.notes)
    doc["evaluations"][1]["metrics"]["position_rms_pct"] = {"mean": 0.5, "max": 1, "per_frame": [1, 0.5]}
    doc["steps"][4]["plugin"], doc["steps"][4]["k"] = "poisson", 5
    assert len(_images(build_report([(doc, "x.json")], render=False).html)) == 2


def test_normal_deviation_and_heat_colors():
    N = np.array([[0, 0, 1.0], [0, 0, 1.0], [1.0, 0, 0]])
    M = np.array([[0, 0, 1.0], [0, 1.0, 0], [-1.0, 0, 0]])
    np.testing.assert_allclose(normal_deviation_degrees(N, M), [0, 90, 180], atol=1e-12)
    C = heat_colors(np.array([0.0, 5.0, 50.0]), vmax=10.0, cmap="viridis")
    from matplotlib import colormaps

    np.testing.assert_allclose(C, colormaps["viridis"]([0.0, 0.5, 1.0])[:, :3])


def test_reduced_equal_to_full_gives_a_zero_heat_map(elephant):
    """Reduced weights that are the input weights: no normal deviation anywhere."""
    from rigslim.model.weights import ReducedWeights
    from rigslim.report import RenderData

    W = elephant.weights.tocsr()
    k = int(np.diff(W.indptr).max())
    idx = np.zeros((W.shape[0], k), dtype=np.int64)
    val = np.zeros((W.shape[0], k))
    for v in range(W.shape[0]):
        cols, vals = W.indices[W.indptr[v]:W.indptr[v + 1]], W.data[W.indptr[v]:W.indptr[v + 1]]
        idx[v, :len(cols)], val[v, :len(cols)] = cols, vals
        idx[v, len(cols):] = [c for c in range(W.shape[1]) if c not in set(cols)][:k - len(cols)]
    R = ReducedWeights(idx, val, W.shape[1])
    doc = {"name": "same", "frames": {"test": elephant.split.test},
           "steps": [{"stage": "read"}, {"stage": "solve", "plugin": "copy", "k": k}, {"stage": "evaluate"}],
           "evaluations": [{"name": "copy", "step": 2, "metrics": {}}]}
    rows = summarize(doc)
    rs = render_rows(rows, {id(doc): RenderData(elephant, {2: R})}, frames=[40], width=48, height=40,
                     backend="numpy", heat_max=10.0)
    (_, reduced, heat, dmax, drms), = rs.frames[0].reduced
    assert dmax < 1e-6 and drms < 1e-8
    assert np.array_equal(reduced, render_rows(rows, {id(doc): RenderData(elephant, {2: R})}, frames=[40],
                                               width=48, height=40, backend="numpy").frames[0].reduced[0][1])
    # every covered pixel of the heat map has the zero colour, shaded
    zero = heat_colors(np.array([0.0]), 10.0)[0]
    covered = (heat != 255).any(axis=-1)
    rgb = heat[covered].astype(float)
    ratios = rgb / np.maximum(zero * 255, 1e-9)
    assert covered.sum() > 50
    assert np.allclose(ratios / ratios[:, :1], 1.0, atol=0.08)


def test_cli_report_from_metrics_json(run, tmp_path, capsys):
    folder, _ = run
    out = tmp_path / "r.html"
    rc = main(["report", str(folder / "out" / "m.json"), "-o", str(out), "--png-dir", str(tmp_path / "png"),
               "--size", "64x48", "--frames", "65", "-q"])
    assert rc == 0
    text = out.read_text()
    # renders came from the .npz files the pipeline wrote (no 'no reduced weights' note)
    assert "no reduced weights" not in text
    assert len(list((tmp_path / "png").glob("*.png"))) == 5
    assert _decode_png(_images(text)[-1]).shape == (48, 64, 3)
    assert "report written to" in capsys.readouterr().out


def test_cli_report_errors(tmp_path, capsys):
    bad = tmp_path / "bad.json"
    bad.write_text("{not json")
    assert main(["report", str(bad), "-o", str(tmp_path / "r.html")]) == 2
    assert "not JSON" in capsys.readouterr().err
    empty = tmp_path / "empty.json"
    empty.write_text(json.dumps({"evaluations": []}))
    assert main(["report", str(empty), "-o", str(tmp_path / "r.html")]) == 2
    assert main(["report", str(empty), "-o", str(tmp_path / "r.html"), "--size", "big"]) == 2
    assert "WIDTHxHEIGHT" in capsys.readouterr().err
    assert not (tmp_path / "r.html").exists()
    with pytest.raises(InputError):
        load_document(tmp_path / "missing.json")


def test_report_step_needs_an_evaluation(write_pipeline):
    from rigslim.errors import RigslimError
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
steps:
  - select: k-largest
    k: 4
  - report: out/r.html
""")
    with pytest.raises(RigslimError, match="evaluate"):
        run_pipeline(path)
    assert not (path.parent / "out" / "r.html").exists()


def test_report_step_rejects_unknown_parameters(write_pipeline):
    from rigslim.errors import RigslimError
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/elephant.obj
steps:
  - report: out/r.html
    widht: 20
""")
    with pytest.raises(RigslimError, match="widht"):
        run_pipeline(path)


def test_overwritten_npz_is_not_rendered_under_the_wrong_name(run, tmp_path):
    """Two evaluations, one .npz: the k=2 weights file now holds k=4 weights."""
    import shutil

    from rigslim.report import load_render_data

    folder, _ = run
    doc = json.loads((folder / "out" / "m.json").read_text())
    copy = tmp_path / "out"
    shutil.copytree(folder / "out", copy)
    for s in doc["steps"]:
        if s.get("path", "").endswith(".npz"):
            s["path"] = str(copy / ("k2.npz" if s["path"].endswith("k2.npz") else "k4.npz"))
    data = load_render_data(doc)
    assert sorted(data.reduced) == [3, 7] and not data.notes
    # same k, different weights: the recomputed frame error gives it away
    from rigslim.io import read_reduced_npz, write_reduced_npz

    R = read_reduced_npz(copy / "k4.npz")
    write_reduced_npz(copy / "k4.npz", type(R)(R.indices, R.values[:, ::-1].copy(), R.n_handles))
    data = load_render_data(doc)
    assert sorted(data.reduced) == [3]
    assert any("overwritten" in n for n in data.notes)
    shutil.copy(copy / "k4.npz", copy / "k2.npz")
    data = load_render_data(doc)
    assert data.reduced == {} and any("holds k=4" in n for n in data.notes)


def test_simplification_levels_and_metro_curves():
    """A decimation evaluation: Metro per frame and per level, no reduced weights."""
    doc = {"name": "simplify", "frames": {"test": [5, 12, 19]},
           "steps": [{"stage": "read"}, {"stage": "decimate", "plugin": "quartic", "seconds": 3.0},
                     {"stage": "evaluate"}],
           "evaluations": [{"name": "quartic-levels", "step": 2, "metrics": {
               "hausdorff_rms_pct": {"mean": 0.2, "max": 0.3, "per_frame": [0.1, 0.3, 0.2]},
               "hausdorff_max_pct": {"mean": 1.0, "max": 1.5, "per_frame": [1.0, 1.5, 0.5]},
               "hausdorff_rms_pct@10%": {"mean": 0.2, "max": 0.3, "per_frame": [0.1, 0.3, 0.2]},
               "hausdorff_max_pct@10%": {"mean": 1.0, "max": 1.5, "per_frame": [1.0, 1.5, 0.5]},
               "faces@10%": 1206,
               "hausdorff_rms_pct@2%": {"mean": 0.9, "max": 1.2, "per_frame": [0.9, 1.2, 0.6]},
               "faces@2%": 241}}]}
    row, = summarize(doc)
    assert row.method == "quartic" and row.seconds == 3.0 and row.k is None
    assert set(row.levels) == {"10%", "2%"} and row.levels["2%"]["faces"] == 241
    assert row.metro == {"hausdorff_rms_pct": 0.2, "hausdorff_max_pct": 1.0}
    np.testing.assert_allclose(row.metro_per_frame, [0.1, 0.3, 0.2])
    assert row.step == 2
    assert row.worst_frame() == 12  # no position or normal error: the frame of largest Metro RMS
    report = build_report([(doc, "")], render=False)
    assert "Simplified levels" in report.html and "<td>241</td>" in report.html
    assert "Metro RMS % mean" in report.html and report.notes == []
    curves = _decode_png(_images(report.html)[0])
    assert curves.shape[0] == 310  # one panel: Metro (no position or normal error measured)


def test_simplified_level_renders_like_the_same_reduced_weights(run, elephant):
    """A 'level' that is the full mesh with reduced weights draws exactly as those reduced weights do."""
    from dataclasses import replace

    from rigslim.model.hierarchy import SimplifiedLevel
    from rigslim.report import RenderData

    folder, result = run
    R = result.asset.extras["evaluated_reduced"][7]  # the k=4 evaluation
    asset = replace(elephant, levels=[SimplifiedLevel(elephant.mesh, R, "k4-as-level")])
    doc = json.loads((folder / "out" / "m.json").read_text())
    rows = summarize(doc)
    rs = render_rows(rows, {id(doc): RenderData(asset, {7: R})}, frames=[65], width=64, height=56,
                     backend="numpy")
    frame, = rs.frames
    (label, faces, level_img), = frame.levels
    assert (label, faces) == ("k4-as-level", elephant.mesh.n_faces)
    reduced_img = dict((r[0], r[1]) for r in frame.reduced)["k-largest-k4"]
    covered = (level_img != 255).any(axis=-1)
    assert covered.sum() > 100
    # same geometry, different base colour: same silhouette
    assert np.array_equal(covered, (reduced_img != 255).any(axis=-1))


def test_report_without_readable_inputs_keeps_table_and_plots(run, tmp_path):
    """Inputs moved away after the run: the report says so and still has its table and plots."""
    folder, _ = run
    doc = json.loads((folder / "out" / "m.json").read_text())
    doc.pop("pipeline_file")
    doc["pipeline"] = str(tmp_path / "gone.yaml")
    doc["inputs"] = {role: str(tmp_path / "gone" / p.rsplit("/", 1)[-1]) for role, p in doc["inputs"].items()}
    report = build_report([(doc, "")])
    assert any("cannot re-read the inputs" in n for n in report.notes)
    assert report.renders == {} and len(_images(report.html)) == 3


@pytest.mark.parametrize("estimator", ["recomputed", "blended-matrix"])
def test_heat_map_is_the_measured_normal_deviation(write_pipeline, estimator):
    """The RMS of the rendered per-vertex angles is the run's normal_rms_rad for that frame."""
    from rigslim.report import RenderData, load_render_data
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline(f"""
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses:
  examples: "0:457:45"
  test: "5:457:90"
steps:
  - select: k-largest
    k: 3
  - solve: k-largest
  - normals: {estimator}
  - evaluate: [normal-deviation]
  - write: out/k3.npz
""")
    result = run_pipeline(path, metrics_path=path.parent / "m.json")
    doc = result.document
    ev = doc["evaluations"][0]
    assert result.asset.extras["evaluated_normals"][ev["step"]] == (estimator, {})
    frames = doc["frames"]["test"][1:3]
    for data in ({id(doc): RenderData(result.asset, result.asset.extras["evaluated_reduced"],
                                      normals=result.asset.extras["evaluated_normals"])},
                 {id(doc): load_render_data(doc, path.parent / "m.json")}):
        rs = render_rows(summarize(doc), data, frames=frames, width=32, height=24, backend="numpy")
        for rf in rs.frames:
            drms = rf.reduced[0][4]
            assert drms == pytest.approx(ev["metrics"]["normal_rms_rad"]["per_frame"][1 + frames.index(rf.frame)],
                                         rel=1e-6)


def test_runs_with_generated_weights_are_not_rendered_from_their_inputs():
    from rigslim.report import load_render_data

    doc = {"name": "cage", "frames": {"test": [1]}, "inputs": {"mesh": "/nonexistent.off"},
           "steps": [{"stage": "read"}, {"stage": "generate", "plugin": "mean-value"}, {"stage": "evaluate"}],
           "evaluations": [{"name": "e", "step": 2, "metrics": {}}]}
    with pytest.raises(InputError, match="generate"):
        load_render_data(doc)
    report = build_report([(doc, "")])
    assert report.renders == {} and any("report: out/report.html" in n for n in report.notes)


def test_report_step_compares_with_earlier_runs(run, tmp_path):
    """The writer's 'compare' adds other runs' metrics; equal evaluation names get the run's name."""
    from rigslim.plugin import StepContext
    from rigslim.plugins.metrics.report_writer import ReportWriter

    folder, result = run
    writer = ReportWriter()
    params = writer.parse_params({"compare": [str(folder / "out" / "m.json")], "render": False})
    ctx = StepContext(base_dir=tmp_path, document=result.document)
    writer.write(tmp_path / "cmp.html", result.asset, params, ctx)
    text = (tmp_path / "cmp.html").read_text()
    assert ctx.report["evaluations"] == 4 and ctx.report["renders"] == 0
    assert text.count('<td class="l">elephant-small / k-largest-k2</td>') == 1
    assert text.count('<td class="l">elephant-small / k-largest-k2 (2)</td>') == 1
    with pytest.raises(InputError):
        writer.write(tmp_path / "x.html", result.asset,
                     writer.parse_params({"compare": ["missing.json"], "render": False}), ctx)


def test_report_writes_only_an_html_page(tmp_path, capsys):
    """`rigslim report m.json -o x.glb` once wrote a page over a character file that was no input of it."""
    from rigslim.commands.cli import main

    victim = tmp_path / "x.glb"
    victim.write_bytes(b"glTF")
    assert main(["report", str(tmp_path / "m.json"), "-o", str(victim)]) == 2
    assert "the report is an HTML page (fix: write to x.html)" in capsys.readouterr().err
    assert victim.read_bytes() == b"glTF"
