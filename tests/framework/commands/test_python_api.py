"""docs/python.md: every code block runs, in order, in one namespace (rigslim.api)."""

from __future__ import annotations

import re
import shutil
import sys
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


def _quoted(block: str) -> dict[int, str]:
    """Line number -> the figure a ``print(...)  # FIGURE`` line of ``block`` quotes."""
    quoted = {}
    for number, line in enumerate(block.splitlines(), start=1):
        match = re.match(r"\s*print\(.*\)\s+#\s*(.+?)\s*$", line)
        if match:
            quoted[number] = match.group(1)
    return quoted


def test_python_md_examples_run(tmp_path, monkeypatch):
    """The page's examples run from a copy of the repository root (outputs land in the copy),
    and every figure the page quotes after a ``print(...)`` is what that line prints."""
    (tmp_path / "examples").mkdir()
    (tmp_path / "examples" / "data").symlink_to(ROOT / "examples" / "data", target_is_directory=True)
    for yaml in (ROOT / "examples").glob("*.yaml"):
        shutil.copy(yaml, tmp_path / "examples" / yaml.name)
    monkeypatch.chdir(tmp_path)
    blocks = _blocks()
    assert len(blocks) >= 4
    printed: dict[tuple[str, int], list[str]] = {}

    def record(*args: object, sep: str = " ", **_: object) -> None:
        caller = sys._getframe(1)
        key = (caller.f_code.co_filename, caller.f_lineno)
        printed.setdefault(key, []).append(sep.join(str(arg) for arg in args))

    namespace: dict = {"print": record}
    for i, block in enumerate(blocks):
        exec(compile(block, f"docs/python.md block {i + 1}", "exec"), namespace)
    quoted = {
        (f"docs/python.md block {i + 1}", line): figure
        for i, block in enumerate(blocks)
        for line, figure in _quoted(block).items()
    }
    assert len(quoted) >= 10
    for (where, line), figure in quoted.items():
        assert printed.get((where, line)) == [figure], f"{where} line {line} quotes {figure!r}"
    # the lines that print a check without quoting it print True
    for key, texts in printed.items():
        if key not in quoted:
            assert "False" not in texts, key
