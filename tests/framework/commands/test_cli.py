import json
import subprocess
import sys

from rigslim.commands.cli import main


def test_plugins_json(capsys):
    assert main(["plugins", "--json"]) == 0
    rows = json.loads(capsys.readouterr().out)
    assert {"stage", "name", "package", "version", "summary"} <= set(rows[0])
    stages = {r["stage"] for r in rows}
    assert {"reader", "writer", "influence-selection", "weight-solver", "deformer", "normal-estimator",
            "metric"} <= stages


def test_console_script_runs():
    out = subprocess.run([sys.executable, "-m", "rigslim.commands.cli", "plugins"], capture_output=True, text=True)
    assert out.returncode == 0 and "k-largest" in out.stdout


def test_import_is_light():
    code = ("import sys, rigslim, rigslim.plugin.host; rigslim.plugin.host.get_host().registry; "
            "heavy = [m for m in ('pyopencl', 'OpenGL', 'pymeshlab', 'pygltflib', 'matplotlib') if m in sys.modules]; "
            "print(heavy)")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "[]"
