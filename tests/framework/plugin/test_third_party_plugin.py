"""A separately packaged plugin (examples/rigslim-absweights) installs and runs from a pipeline.

The package is installed into a temporary virtual environment layered over this one (its
site-packages are added through a ``.pth`` file), never into the environment running the tests.
"""

import json
import shutil
import subprocess
from pathlib import Path

from support.venvs import layered_venv

ROOT = Path(__file__).resolve().parents[3]


def test_install_and_use_third_party_plugin(tmp_path):
    python = layered_venv(tmp_path)
    source = tmp_path / "rigslim-absweights"
    shutil.copytree(ROOT / "examples/rigslim-absweights", source,
                    ignore=shutil.ignore_patterns("build", "*.egg-info", "__pycache__"))
    pip = [str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", str(source)]
    subprocess.run(pip, check=True, capture_output=True)
    where = subprocess.run([str(python), "-c", "import rigslim_absweights; print(rigslim_absweights.__file__)"],
                           check=True, capture_output=True, text=True).stdout.strip()
    assert Path(where).is_relative_to(tmp_path / "venv")
    listed = subprocess.run([str(python), "-m", "rigslim.commands.cli", "plugins", "--json"], capture_output=True,
                            text=True, check=True)
    rows = {r["name"]: r for r in json.loads(listed.stdout)}
    assert rows["largest-abs"]["package"] == "rigslim-absweights"
    assert rows["largest-abs"]["stage"] == "influence-selection"
    metrics = tmp_path / "m.json"
    run = subprocess.run([str(python), "-m", "rigslim.commands.cli", "run", "-q",
                          str(ROOT / "examples/elephant-absweights-k4.yaml"), "--metrics", str(metrics)],
                         capture_output=True, text=True)
    assert run.returncode == 0, run.stderr
    m = json.loads(metrics.read_text())["evaluations"][0]["metrics"]
    # Skinning weights are non-negative, so largest-abs selects what k-largest does.
    assert abs(m["position_rms_pct"]["mean"] - 0.1615) < 1e-3
    assert m["max_influences"] == 4


def test_the_example_package_uses_only_public_api():
    """The example imports from rigslim's public modules only (no built-in plugin's internals)."""
    source = (ROOT / "examples/rigslim-absweights/rigslim_absweights/__init__.py").read_text()
    imports = [line.split()[1] for line in source.splitlines() if line.startswith(("from rigslim", "import rigslim"))]
    assert imports and all(not name.startswith("rigslim.plugins") for name in imports), imports
