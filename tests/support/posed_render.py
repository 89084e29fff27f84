"""Render skinned .glb files posed at a clip and time with three.js in headless Chromium, with silhouette masks.

One :class:`PosedRenderer` starts Chromium once (the DevTools client of
:mod:`support.report_browser`) and serves a page, three.js r160 and the .glb
files from a loopback HTTP server; each :meth:`PosedRenderer.render` then

1. loads the file with three.js's ``GLTFLoader`` and plays one clip
   (``AnimationMixer``, clip by name or index) to time ``t`` (clamped to the
   clip's duration), so three.js's own skinning poses the mesh;
2. frames a camera on the posed character: the precise (skinned) bounding box
   ``B`` of the scene, its bounding sphere (centre ``c``, radius ``r``), a view
   direction ``d`` from azimuth ``a`` (about +y, 0 = from +z, the glTF front) and
   elevation ``e``, and the eye at ``c + d r / sin(fov / 2)``; the camera is
   returned so that other files (levels of detail, peers' outputs) are rendered
   from exactly the same one;
3. renders a lit colour image and a silhouette: the same scene with every
   material replaced by an unlit white double-sided one on black, thresholded.

:func:`mask_difference` compares two silhouettes:

- ``iou = |A & B| / |A | B|``;
- ``sym_diff = |A ^ B| / |A|`` (pixels, relative to the reference's silhouette area);
- ``shape_diff = (|A \\ D_w(B)| + |B \\ D_w(A)|) / |A|``, where ``D_w`` dilates a
  mask by ``w`` pixels (default 2, a 3 x 3 square ``w`` times): the pixels of
  each silhouette farther than ``w`` pixels from the other one (a thresholded
  Hausdorff distance), so that an outline shifted by a pixel or two counts
  nothing, while webbing between legs, a spike, a lost tail or limb count in
  full, however thin.

Example
-------
>>> with PosedRenderer(size=(256, 256)) as r:          # doctest: +SKIP
...     ref = r.render("a.glb", clip="walk", time=0.5)
...     lod = r.render("a-10.glb", clip="walk", time=0.5, camera=ref.camera)
...     print(mask_difference(ref.mask, lod.mask))
"""

from __future__ import annotations

import base64
import io
import json
import threading
import time
from dataclasses import dataclass
from functools import partial
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
THREE = ROOT / "tools" / "node" / "node_modules" / "three"

#: Chromium flags: software WebGL (SwiftShader), no GPU needed.
FLAGS = ["--headless", "--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--no-first-run",
         "--disable-dev-shm-usage", "--disable-background-networking", "--disable-component-update",
         "--disable-sync", "--mute-audio", "--hide-scrollbars"]

PAGE = """<!doctype html><html><head><meta charset="utf-8">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
                                      "three/addons/": "/three/examples/jsm/"}}</script>
</head><body style="margin:0;background:#000">
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
const renderer = new THREE.WebGLRenderer({antialias: false, preserveDrawingBuffer: true});
renderer.setPixelRatio(1);
document.body.appendChild(renderer.domElement);
const white = new THREE.MeshBasicMaterial({color: 0xffffff, side: THREE.DoubleSide});
function pickClip(gltf, clip) {
  if (clip === null || clip === undefined) return gltf.animations.length ? gltf.animations[0] : null;
  const c = typeof clip === 'number' ? gltf.animations[clip] : gltf.animations.find(a => a.name === clip);
  if (!c) throw new Error('no clip ' + JSON.stringify(clip) + ' (clips: ' +
                          gltf.animations.map(a => a.name).join(', ') + ')');
  return c;
}
function cameraFor(scene, view, aspect) {
  const box = new THREE.Box3().setFromObject(scene, true);
  const sphere = box.getBoundingSphere(new THREE.Sphere());
  const a = THREE.MathUtils.degToRad(view.azimuth), e = THREE.MathUtils.degToRad(view.elevation);
  const d = new THREE.Vector3(Math.sin(a) * Math.cos(e), Math.sin(e), Math.cos(a) * Math.cos(e));
  const half = THREE.MathUtils.degToRad(view.fov) / 2 * Math.min(1, aspect);
  const dist = sphere.radius * view.margin / Math.sin(half);
  const eye = sphere.center.clone().addScaledVector(d, dist);
  return {eye: eye.toArray(), target: sphere.center.toArray(), fov: view.fov,
          near: Math.max(dist - 2 * sphere.radius, dist * 1e-3), far: dist + 2 * sphere.radius,
          box: [box.min.toArray(), box.max.toArray()]};
}
window.renderPosed = async function (req) {
  const gltf = await new GLTFLoader().loadAsync(req.url);
  const scene = gltf.scene;
  scene.traverse(o => { if (o.isMesh) o.frustumCulled = false; });
  const clip = pickClip(gltf, req.clip);
  let t = 0;
  if (clip) {
    const mixer = new THREE.AnimationMixer(scene);
    mixer.clipAction(clip).play();
    t = Math.min(Math.max(req.time, 0), clip.duration);
    mixer.setTime(t);
  }
  scene.updateMatrixWorld(true);
  renderer.setSize(req.width, req.height);
  const cam = req.camera || cameraFor(scene, req.view, req.width / req.height);
  const camera = new THREE.PerspectiveCamera(cam.fov, req.width / req.height, cam.near, cam.far);
  camera.position.fromArray(cam.eye);
  camera.lookAt(new THREE.Vector3().fromArray(cam.target));
  const world = new THREE.Scene();
  world.add(scene);
  world.background = new THREE.Color(req.background);
  world.add(new THREE.HemisphereLight(0xffffff, 0x404040, 2.0));
  const sun = new THREE.DirectionalLight(0xffffff, 2.0);
  sun.position.copy(camera.position).add(new THREE.Vector3(0, cam.far, 0));
  world.add(sun);
  renderer.render(world, camera);
  const png = renderer.domElement.toDataURL('image/png');
  world.background = new THREE.Color(0x000000);
  world.overrideMaterial = white;
  renderer.render(world, camera);
  const mask = renderer.domElement.toDataURL('image/png');
  let faces = 0;
  scene.traverse(o => { if (o.isMesh) faces += (o.geometry.index ? o.geometry.index.count
                                                 : o.geometry.attributes.position.count) / 3; });
  return JSON.stringify({png, mask, camera: cam, clip: clip ? clip.name : null, time: t, faces,
                         clips: gltf.animations.map(a => [a.name, a.duration])});
};
window.__ready = true;
</script></body></html>"""


@dataclass(frozen=True)
class View:
    """Camera direction and framing: azimuth about +y (0 = from +z), elevation, vertical field of view (degrees)."""

    azimuth: float = 0.0
    elevation: float = 10.0
    fov: float = 30.0
    margin: float = 1.02


@dataclass
class Render:
    """One posed render: ``rgb`` (h, w, 3) uint8, ``mask`` (h, w) bool, the camera used, clip, time, faces."""

    rgb: np.ndarray
    mask: np.ndarray
    camera: dict
    clip: str | None
    time: float
    faces: int
    clips: list


class _Files(BaseHTTPRequestHandler):
    """Serves ``/`` (the page), ``/three/...`` (three.js) and ``/f/N.glb`` (registered files) on loopback."""

    def __init__(self, *args, renderer=None, **kwargs):
        self.renderer = renderer
        super().__init__(*args, **kwargs)

    def log_message(self, *args):  # quiet
        pass

    def do_GET(self):  # noqa: N802 (http.server's name)
        path = self.path.split("?", 1)[0]
        body, kind = None, "application/octet-stream"
        if path in ("/", "/index.html"):
            body, kind = PAGE.encode(), "text/html"
        elif path.startswith("/three/"):
            f = (THREE / path[len("/three/"):]).resolve()
            if THREE.resolve() in f.parents and f.is_file():
                body, kind = f.read_bytes(), "text/javascript"
        elif path.startswith("/f/"):
            f = self.renderer.files.get(path[3:])
            if f is not None:
                body, kind = Path(f).read_bytes(), "model/gltf-binary"
        if body is None:
            self.send_error(404)
            return
        self.send_response(200)
        self.send_header("Content-Type", kind)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)


def available() -> str | None:
    """None when Chromium and three.js are there; otherwise why not (a skip reason)."""
    from support.report_browser import find_chromium

    if find_chromium() is None:
        return "no chromium (tools/setup-chromium.sh)"
    if not (THREE / "build" / "three.module.js").exists():
        return "three.js missing (tools/setup-gltf-validator.sh)"
    return None


class PosedRenderer:
    """A headless Chromium page that renders .glb files posed (use as a context manager)."""

    def __init__(self, size: tuple[int, int] = (320, 320), *, background: int = 0x30343A, timeout: float = 120.0):
        self.size = size
        self.background = background
        self.timeout = timeout
        self.files: dict[str, Path] = {}
        self._stack = None

    def __enter__(self) -> PosedRenderer:
        from contextlib import ExitStack

        from support.report_browser import devtools_page

        why = available()
        if why:
            from support.report_browser import BrowserUnavailable

            raise BrowserUnavailable(why, field="chromium", fix="run make test-tools")
        self._stack = ExitStack()
        self.server = ThreadingHTTPServer(("127.0.0.1", 0), partial(_Files, renderer=self))
        threading.Thread(target=self.server.serve_forever, daemon=True).start()
        self._stack.callback(self.server.server_close)
        self._stack.callback(self.server.shutdown)
        self.cdp, self.session = self._stack.enter_context(devtools_page(flags=FLAGS, timeout=self.timeout))
        self.cdp.call("Page.enable", session=self.session)
        self.cdp.call("Page.navigate", {"url": f"http://127.0.0.1:{self.server.server_port}/"}, session=self.session)
        end = time.monotonic() + self.timeout
        while not self._eval("window.__ready === true"):
            if time.monotonic() > end:
                raise TimeoutError("the three.js page did not load")
            time.sleep(0.05)
        return self

    def __exit__(self, *exc) -> None:
        self._stack.close()

    def _eval(self, expression: str, await_promise: bool = False):
        reply = self.cdp.call("Runtime.evaluate", {"expression": expression, "returnByValue": True,
                                                   "awaitPromise": await_promise}, session=self.session,
                              timeout=self.timeout)
        if "exceptionDetails" in reply:
            d = reply["exceptionDetails"]
            raise RuntimeError("three.js: " + str(d.get("exception", {}).get("description") or d.get("text")))
        return reply["result"].get("value")

    def render(self, path, *, clip: str | int | None = None, time: float = 0.0, camera: dict | None = None,
               view: View = View(), size: tuple[int, int] | None = None) -> Render:
        """Render ``path`` at ``clip`` (name, index or None for the first) and ``time`` seconds.

        ``camera`` (a previous :attr:`Render.camera`) fixes the camera; without
        it the camera frames this file's posed bounding sphere from ``view``.
        """
        from PIL import Image

        key = f"{len(self.files)}.glb"
        self.files[key] = Path(path)
        w, h = size or self.size
        req = {"url": f"/f/{key}", "clip": clip, "time": float(time), "camera": camera, "width": w, "height": h,
               "background": self.background, "view": {"azimuth": view.azimuth, "elevation": view.elevation,
                                                       "fov": view.fov, "margin": view.margin}}
        out = json.loads(self._eval(f"window.renderPosed({json.dumps(req)})", await_promise=True))
        rgb = np.asarray(Image.open(io.BytesIO(base64.b64decode(out["png"].split(",", 1)[1]))).convert("RGB"))
        m = np.asarray(Image.open(io.BytesIO(base64.b64decode(out["mask"].split(",", 1)[1]))).convert("L"))
        return Render(rgb=rgb, mask=m > 127, camera=out["camera"], clip=out["clip"], time=out["time"],
                      faces=int(out["faces"]), clips=out["clips"])


def mask_difference(reference: np.ndarray, candidate: np.ndarray, band: int = 2) -> dict:
    """Silhouette agreement of ``candidate`` with ``reference`` (bool masks of one size).

    Returns
    -------
    dict
        ``iou``, ``sym_diff`` (``|A ^ B| / |A|``), ``missing`` (``|A \\ D(B)| / |A|``:
        reference pixels farther than ``band`` pixels from the candidate),
        ``extra`` (``|B \\ D(A)| / |A|``), ``shape_diff`` (their sum), ``area``
        (``|A|`` in pixels).
    """
    from scipy import ndimage

    a, b = np.asarray(reference, bool), np.asarray(candidate, bool)
    if a.shape != b.shape:
        raise ValueError(f"masks differ in size: {a.shape} and {b.shape}")
    area = int(a.sum())
    if area == 0:
        raise ValueError("the reference silhouette is empty (camera or pose wrong)")
    square = np.ones((3, 3), bool)
    near_a = ndimage.binary_dilation(a, structure=square, iterations=band) if band > 0 else a
    near_b = ndimage.binary_dilation(b, structure=square, iterations=band) if band > 0 else b
    missing, extra = int((a & ~near_b).sum()), int((b & ~near_a).sum())
    return {"iou": float((a & b).sum() / (a | b).sum()), "sym_diff": float((a ^ b).sum() / area),
            "shape_diff": (missing + extra) / area, "missing": missing / area, "extra": extra / area, "area": area}


def difference_image(reference: np.ndarray, candidate: np.ndarray) -> np.ndarray:
    """RGB picture of two silhouettes: both white, only the reference red, only the candidate cyan."""
    a, b = np.asarray(reference, bool), np.asarray(candidate, bool)
    out = np.zeros(a.shape + (3,), np.uint8)
    out[a & b] = (200, 200, 200)
    out[a & ~b] = (255, 40, 40)
    out[b & ~a] = (40, 230, 255)
    return out
