"""Check glTF files with outside tools run by node: Khronos's glTF-Validator and three.js.

``tools/setup-gltf-validator.sh`` installs the npm packages ``gltf-validator``
and ``three`` into ``tools/node/``. :func:`validate_gltf` runs the validator
and returns its report (the validator's JSON: ``issues.numErrors``,
``issues.numWarnings``, ``issues.messages``...). :func:`threejs_skinned_positions`
loads a file with three.js's GLTFLoader, plays its first animation and
returns the skinned vertex positions three.js computes, an independent
implementation of the glTF skinning the reader follows. Set
``RIGSLIM_GLTF_VALIDATOR`` to the ``gltf-validator`` package folder to use
another installation.
"""

from __future__ import annotations

import json
import os
import shutil
import subprocess
from pathlib import Path

#: Node program: validate the file named in argv[2] with the package in argv[1]; print the report.
_SCRIPT = r"""
const fs = require('fs');
const path = require('path');
const validator = require(process.argv[1]);
const file = process.argv[2];
const data = new Uint8Array(fs.readFileSync(file));
validator.validateBytes(data, {
    uri: path.basename(file),
    maxIssues: 0,
    externalResourceFunction: (uri) => new Promise((resolve, reject) => {
        fs.readFile(path.join(path.dirname(file), decodeURIComponent(uri)),
                    (err, d) => err ? reject(err.toString()) : resolve(new Uint8Array(d)));
    }),
}).then((report) => {
    process.stdout.write(JSON.stringify(report));
}, (error) => {
    process.stderr.write(String(error));
    process.exit(3);
});
"""


#: Node ES module: load argv[1] with three.js, play the first clip once, print world-space skinned
#: positions of every SkinnedMesh (traversal order) at the times in argv[2] (a JSON list).
_THREE_SCRIPT = r"""
import fs from 'fs';
import * as THREE from 'three';
import { GLTFLoader } from 'three/examples/jsm/loaders/GLTFLoader.js';
const [file, timesArg] = process.argv.slice(1);
const times = JSON.parse(timesArg);
const buf = fs.readFileSync(file);
const data = buf.buffer.slice(buf.byteOffset, buf.byteOffset + buf.byteLength);
new GLTFLoader().parse(data, '', (gltf) => {
  const scene = gltf.scene;
  const mixer = new THREE.AnimationMixer(scene);
  if (gltf.animations.length) {
    const action = mixer.clipAction(gltf.animations[0]);
    action.setLoop(THREE.LoopOnce);
    action.clampWhenFinished = true;
    action.play();
  }
  const meshes = [];
  scene.traverse((o) => { if (o.isSkinnedMesh) meshes.push(o); });
  const out = meshes.map((m) => ({name: m.name, bones: m.skeleton.bones.length, frames: []}));
  const v = new THREE.Vector3();
  for (const t of times) {
    mixer.setTime(t);
    scene.updateMatrixWorld(true);
    meshes.forEach((m, k) => {
      m.skeleton.update();
      const n = m.geometry.attributes.position.count;
      const xyz = new Array(3 * n);
      for (let i = 0; i < n; i++) {
        m.getVertexPosition(i, v);
        v.applyMatrix4(m.matrixWorld);
        xyz[3 * i] = v.x; xyz[3 * i + 1] = v.y; xyz[3 * i + 2] = v.z;
      }
      out[k].frames.push(xyz);
    });
  }
  process.stdout.write(JSON.stringify(out));
}, (error) => { process.stderr.write(String(error)); process.exit(3); });
"""


def _node_modules() -> Path:
    return Path(__file__).resolve().parents[2] / "tools" / "node" / "node_modules"


def threejs_available() -> bool:
    """Whether node and three.js (tools/node) are both there."""
    return shutil.which("node") is not None and (_node_modules() / "three" / "package.json").exists()


def threejs_skinned_positions(path, times, timeout: float = 120.0) -> list[dict]:
    """Skinned vertex positions as three.js computes them.

    Parameters
    ----------
    path : path-like
        A ``.glb`` file.
    times : sequence of float
        Animation times (s) of the first clip, played once (held at its end).

    Returns
    -------
    list of dict
        One per SkinnedMesh in scene traversal order: ``name``, ``bones`` and
        ``positions``, a (len(times), vertices, 3) array in world space
        (``matrixWorld @ getVertexPosition``, i.e. three's bone matrices
        times bone inverses, blended with the skin weights).
    """
    import numpy as np

    node = shutil.which("node")
    if not threejs_available():
        raise RuntimeError("three.js is not installed: run tools/setup-gltf-validator.sh")
    proc = subprocess.run([node, "--input-type=module", "-e", _THREE_SCRIPT, str(Path(path).resolve()),
                           json.dumps([float(t) for t in times])], capture_output=True, text=True,
                          timeout=timeout, cwd=_node_modules().parent)
    if proc.returncode != 0:
        raise RuntimeError(f"three.js could not load {path}: {proc.stderr.strip()[:500]}")
    out = json.loads(proc.stdout)
    for m in out:
        m["positions"] = np.asarray(m.pop("frames"), dtype=np.float64).reshape(len(times), -1, 3)
    return out


def validator_package() -> Path | None:
    """Folder of the installed ``gltf-validator`` package, or None."""
    env = os.environ.get("RIGSLIM_GLTF_VALIDATOR")
    candidates = [Path(env)] if env else []
    candidates.append(Path(__file__).resolve().parents[2] / "tools" / "node" / "node_modules" / "gltf-validator")
    for c in candidates:
        if (c / "package.json").exists():
            return c
    return None


def validator_available() -> bool:
    """Whether node and the validator package are both there."""
    return shutil.which("node") is not None and validator_package() is not None


def validate_gltf(path, timeout: float = 120.0) -> dict:
    """Validate a ``.glb``/``.gltf`` file with the Khronos glTF-Validator.

    Parameters
    ----------
    path : path-like
    timeout : float
        Seconds before giving up.

    Returns
    -------
    dict
        The validator's report; ``report["issues"]["numErrors"] == 0`` means valid.

    Raises
    ------
    RuntimeError
        When node or the package is missing (run tools/setup-gltf-validator.sh)
        or the validator itself fails.
    """
    package = validator_package()
    node = shutil.which("node")
    if package is None or node is None:
        raise RuntimeError("glTF-Validator is not installed: run tools/setup-gltf-validator.sh")
    proc = subprocess.run([node, "-e", _SCRIPT, str(package), str(Path(path).resolve())],
                          capture_output=True, text=True, timeout=timeout)
    if proc.returncode != 0:
        raise RuntimeError(f"glTF-Validator failed on {path}: {proc.stderr.strip()[:500]}")
    return json.loads(proc.stdout)


def validation_errors(report: dict) -> list[str]:
    """The report's error messages (severity 0) as ``"CODE at POINTER: message"`` lines."""
    return [f"{m.get('code')} at {m.get('pointer', '')}: {m.get('message')}"
            for m in report.get("issues", {}).get("messages", []) if m.get("severity") == 0]
