"""The elephant report in headless Chromium: no console errors, every image decoded, a non-blank screenshot."""

from __future__ import annotations

import io

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
