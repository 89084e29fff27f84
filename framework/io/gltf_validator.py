"""Run Khronos's glTF-Validator (npm package ``gltf-validator``) on a file.

``tools/setup-gltf-validator.sh`` installs the package into ``tools/node/``;
:func:`validate_gltf` runs it with node and returns its report (the
validator's JSON: ``issues.numErrors``, ``issues.numWarnings``,
``issues.messages``...). Set ``RIGSLIM_GLTF_VALIDATOR`` to the package folder
to use another installation.
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
