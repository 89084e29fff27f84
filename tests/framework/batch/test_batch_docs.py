"""The job templates of docs/batch.md: the Open Job Description template validates, and both the
Kubernetes indexed Job's and the OpenJD task's scripts run ``rigslim run`` for an asset."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

ROOT = Path(__file__).resolve().parents[3]
GLTF = ROOT / "examples" / "data" / "gltf"
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
  - evaluate: [position-rms, max-influences]
  - write: "{name}-k2.glb"
"""


def _blocks(lang: str) -> list[str]:
    text = (ROOT / "docs" / "batch.md").read_text()
    return re.findall(rf"```{lang}\n(.*?)```", text, flags=re.S)


def _block(lang: str, start: str) -> dict:
    (found,) = [b for b in _blocks(lang) if b.startswith(start)]
    return yaml.safe_load(found)


def _env() -> dict:
    env = dict(os.environ)
    env["PATH"] = str(Path(sys.executable).parent) + os.pathsep + env.get("PATH", "")
    return env


def test_openjd_template_is_valid_and_its_task_runs_rigslim(tmp_path):
    model = pytest.importorskip("openjd.model")
    doc = _block("yaml", "specificationVersion")
    model.decode_job_template(template=doc)
    script = doc["steps"][0]["script"]["embeddedFiles"][0]["data"]
    asset = tmp_path / "lib" / "bones.glb"
    asset.parent.mkdir()
    shutil.copy(GLTF / "huesitos.glb", asset)
    template = tmp_path / "template.yaml"
    template.write_text(TEMPLATE)
    out = tmp_path / "out"
    script = (script.replace("{{Task.Param.Asset}}", str(asset)).replace("{{Param.OutDir}}", str(out))
              .replace("{{Param.Template}}", str(template)))
    subprocess.run(["bash", "-c", script], check=True, env=_env(), capture_output=True, timeout=300)
    metrics = json.loads((out / "bones" / "metrics.json").read_text())
    assert metrics["evaluations"][0]["metrics"]["max_influences"] == 2
    assert (out / "bones" / "bones-k2.glb").read_bytes()[:4] == b"glTF"


def test_kubernetes_indexed_job_runs_rigslim_per_index(tmp_path):
    job = _block("yaml", "apiVersion: batch/v1")
    spec = job["spec"]
    assert job["kind"] == "Job" and spec["completionMode"] == "Indexed"
    assert spec["template"]["spec"]["restartPolicy"] == "Never"
    (container,) = spec["template"]["spec"]["containers"]
    mounts = {m["mountPath"] for m in container["volumeMounts"]}
    assert mounts == {"/library", "/out", "/config"}
    script = container["args"][0]
    lib, out, config = tmp_path / "library", tmp_path / "out", tmp_path / "config"
    lib.mkdir()
    config.mkdir()
    for name in ("a", "b"):
        shutil.copy(GLTF / "huesitos.glb", lib / f"{name}.glb")
    (lib / "assets.txt").write_text(f"{lib / 'a.glb'}\n{lib / 'b.glb'}\n")
    (config / "template.yaml").write_text(TEMPLATE)
    script = (script.replace("/library/", f"{lib}/").replace("/out/", f"{out}/")
              .replace("/config/", f"{config}/").replace('"/out/', f'"{out}/'))
    env = _env() | {"JOB_COMPLETION_INDEX": "1"}
    subprocess.run(["bash", "-c", script], check=True, env=env, capture_output=True, timeout=300)
    assert (out / "b" / "metrics.json").is_file() and (out / "b" / "b-k2.glb").is_file()
    assert not (out / "a").exists()
    # a bad asset: rigslim run's one line and exit status 2, nothing written
    (lib / "a.glb").write_bytes(b"not a glb")
    run = subprocess.run(["bash", "-c", script], env=env | {"JOB_COMPLETION_INDEX": "0"}, capture_output=True,
                         text=True, timeout=300)
    assert run.returncode == 2 and run.stderr.strip().startswith("rigslim: error: ")
    assert not (out / "a" / "metrics.json").exists()


def test_the_documented_template_runs_the_default_method(tmp_path):
    """docs/batch.md's template: best-fit by error + geometric, examples from every clip, guarded."""
    from rigslim.runtime.run import run_pipeline

    (text,) = [b for b in _blocks("yaml") if b.startswith('name: "{name}-k4"')]
    path = tmp_path / "huesitos.yaml"
    path.write_text(text.replace("{input}", str(GLTF / "huesitos.glb")).replace("{name}", "huesitos"))
    doc = run_pipeline(path).document
    solve = next(s for s in doc["steps"] if s["stage"] == "solve")
    assert [s.get("plugin") for s in doc["steps"][1:3]] == ["best-fit", "geometric"]
    assert solve["solver"]["guard"] == "k-largest" and solve["solver"]["validation_frames"] > 0
    assert (tmp_path / "huesitos-k4.glb").exists()
