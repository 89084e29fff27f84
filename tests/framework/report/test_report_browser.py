"""The elephant report in headless Chromium: no console errors, every image decoded, a non-blank screenshot."""

from __future__ import annotations

import io
from pathlib import Path

import numpy as np
import pytest
from support.report_browser import check_page, find_chromium

pytestmark = [pytest.mark.browser,
              pytest.mark.skipif(find_chromium() is None,
                                 reason="no chromium (tools/setup-chromium.sh installs it; make test runs it)")]


@pytest.fixture(scope="module")
def report_html(tmp_path_factory, data_dir):
    """The report of the bundled example pipeline (examples/elephant-k4.yaml), small renders."""
    import shutil

    from rigslim.commands.cli import main

    folder = tmp_path_factory.mktemp("browser")
    (folder / "data").symlink_to(data_dir, target_is_directory=True)
    shutil.copy(data_dir.parent / "elephant-k4.yaml", folder / "elephant-k4.yaml")
    assert main(["run", str(folder / "elephant-k4.yaml"), "--metrics", str(folder / "m.json"), "-q"]) == 0
    out = folder / "report.html"
    assert main(["report", str(folder / "m.json"), "-o", str(out), "--size", "160x130", "-q"]) == 0
    return out


def test_report_loads_cleanly_in_chromium(report_html, tmp_path):
    from PIL import Image

    check = check_page(report_html, width=1100, height=800)
    assert check.console_errors == []
    assert check.title.startswith("rigslim report")
    # plots (curves, histograms), colour bar, full + reduced + heat map of one frame
    assert check.images_total == 6
    assert check.images_decoded == check.images_total
    # the page's own check ran after load and agrees
    assert check.marker["data-images-ok"] == check.marker["data-images-total"] == "6"
    assert check.marker["data-errors"] == "0"
    shot = np.asarray(Image.open(io.BytesIO(check.screenshot)).convert("RGB"))
    (tmp_path / "shot.png").write_bytes(check.screenshot)
    assert shot.shape[1] >= 1100 and shot.shape[0] > 1000  # the whole page, not just the viewport
    non_white = (shot < 245).any(axis=-1).mean()
    assert 0.03 < non_white < 0.9
    assert len(np.unique(shot.reshape(-1, 3), axis=0)) > 200  # plots and shaded renders, not flat colour


def test_browser_check_catches_errors_and_broken_images(tmp_path):
    page = tmp_path / "bad.html"
    page.write_text('<!DOCTYPE html><html><head><title>bad</title></head><body><p>text</p>'
                    '<img src="data:image/png;base64,AAAA"><img src="missing.png">'
                    '<script>console.error("boom"); console.log("harmless-log-line"); notDefined();</script>'
                    '</body></html>')
    check = check_page(page, width=400, height=300)
    assert check.images_total == 2 and check.images_decoded == 0
    joined = " | ".join(check.console_errors)
    assert "console.error: boom" in joined and "notDefined" in joined and "harmless-log-line" not in joined
    assert any(e.startswith("log:") for e in check.console_errors)  # the missing file


# --- readability (issue 24): checked in the page as a reader at 1280 px sees it ---------------------------------

#: Per image: pixels of the mesh (not the white background) and those drawn in the warm half of YlOrRd
#: (green below 0.6 x red: a colour-scale position above ~0.45; shading scales red and green alike).
_PIXELS_JS = """function(img){ var c = document.createElement('canvas'); c.width = img.naturalWidth;
  c.height = img.naturalHeight; var x = c.getContext('2d'); x.drawImage(img, 0, 0);
  var d = x.getImageData(0, 0, c.width, c.height).data, mesh = 0, warm = 0;
  for (var i = 0; i < d.length; i += 4) { if (d[i] < 250 || d[i+1] < 250 || d[i+2] < 250) { mesh++;
    if (d[i+1] < 0.6 * d[i]) warm++; } }
  return {mesh: mesh, warm: warm}; }"""


def page_values(path, expression: str, *, width: int = 1280, height: int = 900):
    """Open ``path`` in headless Chromium (``width`` x ``height`` CSS pixels), wait for its load event, and return
    the value of the JavaScript ``expression`` (through JSON)."""
    import json

    from support.report_browser import CHROMIUM_FLAGS, devtools_page

    with devtools_page(flags=[*CHROMIUM_FLAGS, f"--window-size={width},{height}"]) as (cdp, session):
        cdp.call("Page.enable", session=session)
        cdp.call("Emulation.setDeviceMetricsOverride", {"width": width, "height": height, "deviceScaleFactor": 1,
                                                         "mobile": False}, session=session)
        cdp.call("Page.navigate", {"url": Path(path).resolve().as_uri()}, session=session)
        cdp.wait_event("Page.loadEventFired")
        reply = cdp.call("Runtime.evaluate", {"expression": f"JSON.stringify({expression})", "returnByValue": True},
                         session=session)
        return json.loads(reply["result"]["value"])


_LAYOUT_JS = """(function(){ var s = document.scrollingElement;
  return {page: s.scrollWidth, window: window.innerWidth,
          boxes: Array.prototype.map.call(document.querySelectorAll('.scroll'), function(b){
            var row = b.querySelectorAll('tr')[1], first = row ? row.cells[0] : null;
            return {scroll: b.scrollWidth, client: b.clientWidth, overflow: getComputedStyle(b).overflowX,
                    frozen: first ? getComputedStyle(first).position : null}; })}; })()"""


@pytest.fixture(scope="module")
def tiny_report(report_html):
    """The report of the same pipeline with k = 14: normal deviations below 0.3 degrees."""
    from rigslim.commands.cli import main

    folder = report_html.parent
    assert main(["run", str(folder / "elephant-k4.yaml"), "--set", "select.k=14", "--set",
                 f"write.write={folder / 'k14.npz'}", "--metrics", str(folder / "k14.json"), "-q"]) == 0
    out = folder / "k14.html"
    assert main(["report", str(folder / "k14.json"), "-o", str(out), "--size", "160x130", "-q"]) == 0
    return out


def test_page_check_is_invisible_but_still_read(report_html):
    seen = page_values(report_html, "{text: document.body.innerText, display: getComputedStyle("
                       "document.getElementById('rigslim-check')).display, images: document.images.length, "
                       "ok: document.getElementById('rigslim-check').getAttribute('data-images-ok')}")
    assert "page check" not in seen["text"] and "images decoded" not in seen["text"]
    assert seen["display"] == "none"
    assert seen["ok"] == str(seen["images"]) == "6"


def test_tables_scroll_inside_their_box_at_1280px(report_html):
    layout = page_values(report_html, _LAYOUT_JS)
    assert layout["page"] <= layout["window"] == 1280
    assert layout["boxes"] and all(b["overflow"] == "auto" and b["frozen"] == "sticky" for b in layout["boxes"])


def test_heat_captions_match_the_colour_bar(report_html):
    figs = page_values(report_html, """Array.prototype.map.call(document.querySelectorAll('figure.heat, figure.scale'),
        function(f){ return {cls: f.className, top: parseFloat(f.dataset.scaleTop), max: parseFloat(f.dataset.max),
                             caption: f.querySelector('figcaption').textContent}; })""")
    bar = [f for f in figs if f["cls"] == "scale"]
    heat = [f for f in figs if f["cls"] == "heat"]
    assert len(bar) == 1 and len(heat) == 1
    top = bar[0]["top"]
    assert f"0° to {top:.3g}°" in bar[0]["caption"]
    for f in heat:
        assert f["top"] == top
        if f["max"] > top:  # k = 4 at its worst frame: a few vertices turn by more than the scale's top
            assert f"clipped at {top:.3g}° (the colour bar's top); max {f['max']:.3g}°" in f["caption"]
        else:
            assert f"max {f['max']:.3g}°, colour bar 0 to {top:.3g}°" in f["caption"]
    assert any(f["max"] > top for f in heat)


def test_tiny_normal_deviation_is_drawn_in_the_low_colours(report_html, tiny_report):
    js = f"Array.prototype.map.call(document.querySelectorAll('figure.heat'), function(f){{ var p = ({_PIXELS_JS})" \
         "(f.querySelector('img')); p.max = parseFloat(f.dataset.max); p.top = parseFloat(f.dataset.scaleTop); " \
         "return p; })"
    (tiny,) = page_values(tiny_report, js)
    (k4,) = page_values(report_html, js)
    assert tiny["max"] < 0.5 and tiny["top"] == 1.0  # the 1 degree floor, not the run's own 99th percentile
    assert tiny["mesh"] > 2000 and tiny["warm"] <= 0.002 * tiny["mesh"]
    assert k4["warm"] > 0.01 * k4["mesh"]  # the same measure sees k = 4's large deviations


# --- the batch page ----------------------------------------------------------------------------------------------

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"
BATCH_TEMPLATE = """\
inputs:
  gltf: "{{input}}"
  fps: 30
poses:
  examples: "0:10:2"
  test: "1:10:2"
steps:
{steps}"""
REDUCE_STEPS = """\
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: "{name}.glb"
"""
LOD_STEPS = """\
  - select: k-largest
    k: 4
  - solve: k-largest
  - decimate: quartic
    targets: [0.3]
    max_bones: 4
  - evaluate: [metro]
    samples: 500
  - write: "{name}.glb"
    lod: true
    clamp_negative: true
"""


def _batch_page(folder: Path, steps: str, assets: dict[str, str], *args: str) -> Path:
    """Run a small batch in this process (the task ``rigslim batch`` submits) and write its page."""
    import shutil

    pytest.importorskip("pyarrow")
    from rigslim.batch.assets import collect_assets, load_template
    from rigslim.batch.options import BatchOptions, BatchResult
    from rigslim.batch.summary import write_summary
    from rigslim.batch.task import run_asset
    from rigslim.commands.cli import main

    lib = folder / "lib"
    lib.mkdir(parents=True)
    for name, source in assets.items():
        (shutil.copytree if (GLTF / source).is_dir() else shutil.copy)(GLTF / source, lib / name)
    template = folder / "t.yaml"
    template.write_text(BATCH_TEMPLATE.format(steps=steps))
    doc = load_template(template)
    rows = [run_asset(j.as_dict(), doc, str(template), str(folder / "out")) for j in collect_assets([str(lib)])]
    assert all(r["status"] == "ok" for r in rows), [r["error"] for r in rows]
    write_summary(BatchOptions(template, [str(lib)], folder / "out"), BatchResult(rows, 1.0))
    page = folder / "batch.html"
    assert main(["report", str(folder / "out" / "summary.csv"), "-o", str(page), "--backend", "numpy",
                 "--size", "160x120", "-q", *args]) == 0
    return page


@pytest.fixture(scope="module")
def reduce_page(tmp_path_factory):
    """k = 2 on three glTF characters: RiggedFigure loses nothing (1e-6 % of the diagonal), bones about 1 %."""
    return _batch_page(tmp_path_factory.mktemp("reduce"), REDUCE_STEPS,
                       {"bones.glb": "huesitos.glb", "walker.glb": "animation_with_skeleton.glb",
                        "figure": "RiggedFigure"})


@pytest.fixture(scope="module")
def lod_folder(tmp_path_factory):
    """A 30 % level of two characters, its Metro error measured; the page ranks by it."""
    pytest.importorskip("pymeshlab")
    folder = tmp_path_factory.mktemp("lod")
    _batch_page(folder, LOD_STEPS, {"walker.glb": "animation_with_skeleton.glb", "figure": "RiggedFigure"})
    return folder


_CARDS_JS = f"""Array.prototype.map.call(document.querySelectorAll('div.card'), function(c){{
  var imgs = c.querySelectorAll('img'), p = imgs.length > 1 ? ({_PIXELS_JS})(imgs[1]) : {{}};
  p.name = c.querySelector('b').textContent; p.data = Object.assign({{}}, c.dataset);
  p.captions = Array.prototype.map.call(c.querySelectorAll('figcaption'), function(f){{ return f.textContent; }});
  return p; }})"""


def test_batch_tiny_error_is_drawn_in_the_low_colours(reduce_page):
    cards = {c["name"]: c for c in page_values(reduce_page, _CARDS_JS)}
    bars = page_values(reduce_page, "Array.prototype.map.call(document.querySelectorAll('figure.scale'), "
                                    "function(f){ return [f.dataset.kind, parseFloat(f.dataset.scaleTop)]; })")
    assert len(bars) == 1 and bars[0][0] == "reduced"
    top = bars[0][1]
    # one scale for the page: every card's heat map is drawn on the colour bar's range
    assert {float(c["data"]["scaleTop"]) for c in cards.values()} == {top}
    tiny, big = cards["RiggedFigure"], max(cards.values(), key=lambda c: float(c["data"]["maxPct"]))
    assert float(tiny["data"]["maxPct"]) < 1e-4 < top
    assert tiny["mesh"] > 500 and tiny["warm"] == 0
    assert big["warm"] > 0.02 * big["mesh"]
    assert f"colour bar 0 to {top:.3g}% of the diagonal" in tiny["captions"][1]


def test_batch_histograms_name_their_quantity_and_use_log_bins(reduce_page):
    caption = page_values(reduce_page, "document.querySelector('figure.histograms figcaption').textContent")
    # position errors from 4e-7 % (RiggedFigure) to 0.4 % span six decades
    assert "position_rms_pct_max: position RMS, max over test frames (% of diagonal), log bins" in caption
    assert "normal_rms_rad_mean: normal RMS, mean over test frames (rad)" in caption


def test_batch_tables_scroll_inside_their_box_at_1280px(reduce_page):
    layout = page_values(reduce_page, _LAYOUT_JS)
    assert layout["page"] <= layout["window"] == 1280
    (table,) = layout["boxes"]  # all assets (no failures here): wider than the window, it scrolls in its box
    assert table["scroll"] > table["client"] and table["overflow"] == "auto" and table["frozen"] == "sticky"


@pytest.mark.slow
@pytest.mark.parametrize("metric", [None, "hausdorff_max_pct@quartic-30pct_max"])
def test_batch_ranked_by_lod_error_renders_the_level(lod_folder, metric, tmp_path):
    import json

    from rigslim.report.batch import build_batch_report, write_batch_report

    page = tmp_path / "lod.html"
    report = build_batch_report(lod_folder / "out" / "summary.csv", metric=metric, backend="numpy", width=160,
                                height=120)
    assert report.rank_metric == (metric or "hausdorff_max_pct_max")
    write_batch_report(page, report)
    cards = page_values(page, _CARDS_JS)
    assert len(cards) == 2
    for card in cards:
        level = json.loads((lod_folder / "out" / card["name"] / "metrics.json").read_text())["evaluations"][-1][
            "levels"][0]
        full_faces = int(next(r for r in (lod_folder / "out" / "summary.csv").read_text().splitlines()
                              if f",{card['name']}," in r).split(",")[7])
        assert card["data"]["kind"] == "level" and card["data"]["level"] == level["name"] == "quartic-30pct"
        assert int(card["data"]["faces"]) == level["faces"] < full_faces
        assert f"level quartic-30pct ({level['faces']} faces, its own weights)" in card["captions"][1]
        assert f"({full_faces} faces)" in card["captions"][0]
