"""framework/ by purpose: the import contracts hold, a broken one is caught, the root stays small."""

from __future__ import annotations

import re
import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / "tools" / "lint-imports.sh"
LINT = ROOT / ".venv" / "bin" / "lint-imports"

needs_linter = pytest.mark.skipif(not LINT.exists() and shutil.which("lint-imports") is None,
                                  reason="import-linter is installed by `make install-test` (the lint extra)")

#: What framework/'s root may hold: the package, its errors, the Python API and the old-path table.
ROOT_MODULES = {"__init__.py", "errors.py", "api.py", "compat.py"}


def _lint(source: Path | None = None) -> subprocess.CompletedProcess:
    env = None
    if source is not None:
        import os

        env = dict(os.environ, RIGSLIM_SOURCE=str(source))
    return subprocess.run(["bash", str(SCRIPT)], capture_output=True, text=True, timeout=300, env=env)


@needs_linter
def test_the_import_contracts_hold():
    out = _lint()
    assert out.returncode == 0, out.stdout[-3000:] + out.stderr[-2000:]
    assert re.search(r"Contracts: [1-9]\d* kept, 0 broken", out.stdout)


@needs_linter
def test_an_upward_import_breaks_the_layers_contract(tmp_path):
    """A model module importing the runner (even lazily, inside a function) fails `make lint`."""
    for folder in ("framework", "plugins", "kernels"):
        shutil.copytree(ROOT / folder, tmp_path / folder, ignore=shutil.ignore_patterns("__pycache__"))
    mesh = tmp_path / "framework" / "model" / "mesh.py"
    mesh.write_text(mesh.read_text() + "\n\ndef _upward():\n    from rigslim.runtime.run import run_pipeline\n\n"
                    "    return run_pipeline\n")
    out = _lint(tmp_path)
    assert out.returncode != 0
    assert "rigslim.model.mesh -> rigslim.runtime.run" in out.stdout
    assert "BROKEN" in out.stdout


def test_the_framework_root_holds_only_the_package_files():
    files = {p.name for p in (ROOT / "framework").iterdir() if p.suffix == ".py"}
    assert files == ROOT_MODULES, f"modules belong in a subpackage by purpose (docs/layout.md): {files - ROOT_MODULES}"


def test_every_subpackage_is_on_the_layout_page():
    """docs/layout.md has one line per folder of framework/."""
    page = (ROOT / "docs" / "layout.md").read_text()
    folders = sorted(p.name for p in (ROOT / "framework").rglob("*") if p.is_dir() and (p / "__init__.py").exists())
    for folder in folders:
        rel = next(p for p in (ROOT / "framework").rglob(folder) if p.is_dir()).relative_to(ROOT / "framework")
        assert f"{rel}/" in page, f"docs/layout.md does not describe framework/{rel}/"
