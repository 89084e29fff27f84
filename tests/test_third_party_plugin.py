"""A separately packaged plugin (examples/rigslim-absweights) installs and runs from a pipeline."""

import json
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def test_install_and_use_third_party_plugin(tmp_path):
    pip = [sys.executable, "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation",
           "-e", str(ROOT / "examples/rigslim-absweights")]
    subprocess.run(pip, check=True, capture_output=True)
    listed = subprocess.run([sys.executable, "-m", "rigslim.cli", "plugins", "--json"], capture_output=True,
                            text=True, check=True)
    rows = {r["name"]: r for r in json.loads(listed.stdout)}
    assert rows["largest-abs"]["package"] == "rigslim-absweights"
    assert rows["largest-abs"]["stage"] == "influence-selection"
    metrics = tmp_path / "m.json"
    run = subprocess.run([sys.executable, "-m", "rigslim.cli", "run", "-q",
                          str(ROOT / "examples/elephant-absweights-k4.yaml"), "--metrics", str(metrics)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    m = json.loads(metrics.read_text())["evaluations"][0]["metrics"]
    # Skinning weights are non-negative, so largest-abs selects what k-largest does.
    assert abs(m["position_rms_pct"]["mean"] - 0.1615) < 1e-3
    assert m["max_influences"] == 4
