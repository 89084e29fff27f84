"""three.js renders an LOD level like the original: textured, same pose, small image difference (headless Chromium).

The page imports three.js r160 and its GLTFLoader (tools/node, installed by
tools/setup-gltf-validator.sh) through an import map of data URLs, parses
the .glb from a base64 string, plays the first clip to a given time, and
renders with WebGL (SwiftShader, software) into a canvas whose pixels the
test reads over the DevTools protocol (the client of support.report_browser).
"""

from __future__ import annotations

import base64
import io
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
from support.report_browser import find_chromium

from rigslim.commands.cli import main

ROOT = Path(__file__).resolve().parents[3]
THREE = ROOT / "tools" / "node" / "node_modules" / "three"
TUBE = ROOT / "examples" / "data" / "gltf" / "tube_two_materials.glb"

pytestmark = [pytest.mark.skipif(find_chromium() is None, reason="no chromium (tools/setup-chromium.sh)"),
              pytest.mark.skipif(not (THREE / "build" / "three.module.js").exists(),
                                 reason="three.js missing (tools/setup-gltf-validator.sh)")]

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "%(three)s", "gltfloader": "%(loader)s", "bgu": "%(bgu)s"}}</script>
</head><body style="margin:0;background:#000">
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'gltfloader';
window.__result = null;
try {
  const bytes = Uint8Array.from(atob('%(glb)s'), c => c.charCodeAt(0));
  const renderer = new THREE.WebGLRenderer({antialias: false, preserveDrawingBuffer: true});
  renderer.setPixelRatio(1);
  renderer.setSize(%(w)d, %(h)d);
  document.body.appendChild(renderer.domElement);
  new GLTFLoader().parse(bytes.buffer, '', (gltf) => {
    const scene = new THREE.Scene();
    scene.background = new THREE.Color(0x000000);
    scene.add(gltf.scene);
    scene.add(new THREE.AmbientLight(0xffffff, 1.5));
    const sun = new THREE.DirectionalLight(0xffffff, 1.5);
    sun.position.set(1, 2, 3);
    scene.add(sun);
    const mixer = new THREE.AnimationMixer(gltf.scene);
    if (gltf.animations.length) { mixer.clipAction(gltf.animations[0]).play(); mixer.setTime(%(t)f); }
    gltf.scene.updateMatrixWorld(true);
    const camera = new THREE.PerspectiveCamera(35, %(w)d / %(h)d, 0.01, 100);
    camera.position.set(%(eye)s);
    camera.lookAt(%(target)s);
    renderer.render(scene, camera);
    window.__result = renderer.domElement.toDataURL('image/png');
  }, (err) => { window.__result = 'error: ' + err; });
} catch (e) { window.__result = 'error: ' + e; }
</script></body></html>"""


def _data_url(text: str) -> str:
    return "data:text/javascript;base64," + base64.b64encode(text.encode()).decode()


def render_glb(path: Path, t: float, *, eye=(3.2, 1.4, 3.2), target=(0.0, 1.0, 0.0), size=(240, 240),
               timeout: float = 90.0) -> np.ndarray:
    """RGB image (h, w, 3) of a .glb as three.js renders it at clip time t."""
    from PIL import Image
    from support.report_browser import devtools_page

    loader = (THREE / "examples/jsm/loaders/GLTFLoader.js").read_text()
    loader = loader.replace("'../utils/BufferGeometryUtils.js'", "'bgu'")
    html = PAGE % {"three": _data_url((THREE / "build/three.module.js").read_text()), "loader": _data_url(loader),
                   "bgu": _data_url((THREE / "examples/jsm/utils/BufferGeometryUtils.js").read_text()),
                   "glb": base64.b64encode(path.read_bytes()).decode(), "w": size[0], "h": size[1], "t": t,
                   "eye": ", ".join(map(str, eye)), "target": ", ".join(map(str, target))}
    flags = ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-first-run",
             "--disable-dev-shm-usage", "--disable-background-networking"]
    with tempfile.TemporaryDirectory(prefix="rigslim-three-") as tmp, \
            devtools_page(flags=flags, timeout=timeout) as (cdp, session):
        page = Path(tmp) / "page.html"
        page.write_text(html)
        cdp.call("Page.enable", session=session)
        cdp.call("Page.navigate", {"url": page.as_uri()}, session=session)
        value = None
        end = time.monotonic() + timeout
        while time.monotonic() < end:
            value = cdp.call("Runtime.evaluate", {"expression": "window.__result", "returnByValue": True},
                             session=session)["result"].get("value")
            if value:
                break
            time.sleep(0.2)
        assert value and value.startswith("data:image/png"), f"three.js did not render: {str(value)[:300]}"
    png = base64.b64decode(value.split(",", 1)[1])
    return np.asarray(Image.open(io.BytesIO(png)).convert("RGB"), dtype=np.float64)


@pytest.fixture(scope="module")
def renders(tmp_path_factory):
    """The tube's original and its 50 % level (``lod --split``) at t = 0.8 s, same camera."""
    folder = tmp_path_factory.mktemp("three")
    assert main(["lod", str(TUBE), "-o", str(folder / "tube.glb"), "--ratios", "0.5,0.25", "--split"]) == 0
    return {name: render_glb(path, 0.8) for name, path in
            (("original", TUBE), ("level1", folder / "tube-50.glb"), ("level2", folder / "tube-25.glb"))}


def test_level_renders_like_the_original(renders):
    """Mean absolute pixel difference below 2 % of full scale (measured 0.32 %); silhouettes agree to 3 % of pixels."""
    a, b = renders["original"], renders["level1"]
    fg_a, fg_b = a.sum(axis=2) > 30, b.sum(axis=2) > 30
    assert fg_a.mean() > 0.05                                   # the character fills part of the picture
    assert np.abs(a - b).mean() / 255 < 0.02
    assert (fg_a ^ fg_b).mean() < 0.03


def test_level_is_textured_not_blank(renders):
    """The checker texture shows on the level: colour variation inside the silhouette like the original's."""
    a, b = renders["original"], renders["level1"]
    fg_a, fg_b = a.sum(axis=2) > 30, b.sum(axis=2) > 30
    assert fg_b.sum() > 0.9 * fg_a.sum()
    spread_a, spread_b = a[fg_a].std(axis=0).mean(), b[fg_b].std(axis=0).mean()
    assert spread_b > 0.7 * spread_a and spread_b > 20          # an untextured tube would be nearly flat


def test_coarser_level_differs_more(renders):
    a = renders["original"]
    d1 = np.abs(a - renders["level1"]).mean()
    d2 = np.abs(a - renders["level2"]).mean()
    assert d2 >= d1 * 0.9
