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


def test_an_unexpected_exception_is_one_line_naming_a_bug(monkeypatch, capsys):
    """A defect no check turned into an error (once: --fps inf, an OverflowError) prints one line, exit 1."""
    import rigslim.commands.cli as cli

    def broken(args):
        raise OverflowError("cannot convert float infinity to integer")

    monkeypatch.setattr(cli, "cmd_reduce", broken)          # build_parser binds the name when main() runs
    monkeypatch.setenv("RIGSLIM_TRACEBACK", "0")             # off, as unset (it once printed the traceback)
    assert main(["reduce", "x.glb", "-o", "y.glb"]) == cli.EXIT_BUG
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "OverflowError" in err and "a bug in rigslim" in err


def test_fps_inf_is_refused(capsys):
    from pathlib import Path

    glb = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "huesitos.glb"
    for cmd in (["reduce", str(glb), "-o", "/tmp/never-written.glb", "-k", "2"], ["compare", str(glb), str(glb)]):
        assert main([*cmd, "--fps", "inf"]) == 2
        assert "--fps inf is not a positive frame rate" in capsys.readouterr().err
