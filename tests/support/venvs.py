"""Temporary virtual environments for tests that install plugin packages (never into the test environment)."""

from __future__ import annotations

import subprocess
import sys
import sysconfig
from pathlib import Path


def layered_venv(tmp_path: Path) -> Path:
    """A fresh venv that sees this environment's packages after its own; returns its python."""
    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, capture_output=True)
    python = venv / "bin" / "python"
    site = subprocess.run([str(python), "-c", "import sysconfig; print(sysconfig.get_paths()['purelib'])"],
                          check=True, capture_output=True, text=True).stdout.strip()
    outer = sysconfig.get_paths()["purelib"]
    Path(site, "zz-outer-environment.pth").write_text(f"import site; site.addsitedir({outer!r})\n")
    return python
