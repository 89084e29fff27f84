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


def test_bad_arguments_are_one_line_rigslim_errors():
    """The API checks parameters as pipelines do: a bad k, a misspelt option or a NaN target is a RigslimError
    naming the argument (they were raw pydantic ValidationErrors); no example pose is refused (it gave a
    one-influence-per-vertex result in silence)."""
    import numpy as np

    import rigslim
    from rigslim.errors import RigslimError

    V = np.random.default_rng(0).random((10, 3))
    F = np.array([[0, 1, 2], [2, 3, 4], [4, 5, 6]])
    W = np.zeros((10, 3))
    W[:, :2] = 0.5
    T = np.tile(np.eye(3, 4), (2, 3, 1, 1))
    cases = [(rigslim.reduce_weights, {"k": 0}, "reduce_weights.k"),
             (rigslim.reduce_weights, {"k": 2, "nonnegativ": True}, "did you mean 'nonnegative'"),
             (rigslim.reduce_weights, {"k": 2, "select_params": {"swapz": 1}}, "did you mean 'swaps'"),
             (rigslim.simplify, {"targets": [float("nan")]}, "simplify.targets.0"),
             (rigslim.simplify, {"max_bones": 0}, "simplify.max_bones")]
    for call, kwargs, words in cases:
        with pytest.raises(RigslimError, match=re.escape(words)):
            call((V, F), W, T, **kwargs)
    with pytest.raises(RigslimError, match="hold no pose"):
        rigslim.reduce_weights((V, F), W, T[:0], k=2)
    rep: dict = {}
    rigslim.simplify((V, F), W, T, targets=0.5, report=rep)             # one target needs no list
    assert [t["target"] for t in rep["targets"]] == [0.5]
