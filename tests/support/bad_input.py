"""Shared checks of the hostile-input tests (tests/hostile/test_bad_input_*.py).

The promise for any bad input: exit status 2, exactly one stderr line of at
most :data:`rigslim.errors.MAX_LINE` characters (plus the ``rigslim: error: ``
prefix) naming the file and the field, no traceback, earlier outputs
byte-identical and no temporary file left behind.
"""

from __future__ import annotations

import json
import os
import resource
import subprocess
import sys
from pathlib import Path

from rigslim.errors import MAX_LINE

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "examples" / "data"
PREFIX = "rigslim: error: "
#: Address-space limit of CLI subprocesses: a blow-up fails fast instead of swapping the machine.
MEMORY_LIMIT = 3 << 30


def snapshot(folder: Path) -> dict[str, bytes]:
    """Every file under ``folder`` (hidden temporaries included) with its bytes."""
    return {str(p.relative_to(folder)): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file()}


def run_cli(args, capfd):
    """``rigslim ARGS`` in this process; returns (exit status, stderr lines)."""
    from rigslim.commands.cli import main

    capfd.readouterr()
    code = main([str(a) for a in args])
    err = capfd.readouterr().err
    return code, [line for line in err.splitlines() if line.strip()]


def _limit():  # pragma: no cover - runs in the child
    resource.setrlimit(resource.RLIMIT_AS, (MEMORY_LIMIT, MEMORY_LIMIT))


def run_cli_subprocess(args, *, timeout: float = 120.0, cwd=None):
    """``rigslim ARGS`` in a child under a memory limit and a timeout (hangs and blow-ups fail)."""
    env = dict(os.environ, PYTHONWARNINGS="default")
    proc = subprocess.run([sys.executable, "-m", "rigslim.commands.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=timeout, preexec_fn=_limit, cwd=cwd, env=env)
    return proc.returncode, [line for line in proc.stderr.splitlines() if line.strip()]


def assert_one_line(code, lines, *must_contain):
    """Exit 2, one line, short, no traceback, naming what it must (file, field...)."""
    text = "\n".join(lines)
    assert code == 2, f"exit {code}: {text[:2000]}"
    assert "Traceback" not in text, text[:2000]
    assert len(lines) == 1, f"{len(lines)} stderr lines: {text[:2000]}"
    line = lines[0]
    assert line.startswith(PREFIX), line
    assert len(line) <= len(PREFIX) + MAX_LINE, f"{len(line)} characters: {line[:400]}"
    for s in must_contain:
        assert str(s) in line, f"{s!r} not in {line!r}"
    return line


def assert_unchanged(folder: Path, before: dict[str, bytes]):
    """The folder holds exactly the files it held before, byte-identical (no temp files)."""
    after = snapshot(folder)
    assert sorted(after) == sorted(before), f"files changed: {sorted(set(after) ^ set(before))}"
    for name, data in before.items():
        assert after[name] == data, f"{name} changed"


def write_json(path: Path, doc) -> Path:
    path.write_text(json.dumps(doc))
    return path
