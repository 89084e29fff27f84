"""docs/python.md: every code block runs, in order, in one namespace (rigslim.api)."""

from __future__ import annotations

import re
import shutil
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]


def _blocks() -> list[str]:
    return re.findall(r"```python\n(.*?)```", (ROOT / "docs" / "python.md").read_text(), re.S)


def test_public_names():
    import rigslim

    for name in rigslim.__all__:
        assert getattr(rigslim, name) is not None
    with pytest.raises(AttributeError):
        rigslim.not_a_name  # noqa: B018


def test_python_md_examples_run(tmp_path, monkeypatch, capsys):
    """The page's examples run from a copy of the repository root (outputs land in the copy)."""
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "data").symlink_to(ROOT / "examples" / "data", target_is_directory=True)
    for yaml in (ROOT / "examples").glob("*.yaml"):
        shutil.copy(yaml, tmp_path / "examples" / yaml.name)
    monkeypatch.chdir(tmp_path)
    blocks = _blocks()
    assert len(blocks) >= 4
    namespace: dict = {}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/python.md block {i + 1}", "exec"), namespace)
    out = capsys.readouterr().out
    # the figures the page quotes are the ones it prints
    assert "0.161485 %" in out and "0.0391851 rad" in out
    assert "(6034, 4)" in out and "quartic-10pct 1206 605" in out
    assert "False" not in out
