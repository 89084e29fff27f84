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


def _grid():
    """A 6 x 6 vertex height field (50 triangles), weights over 3 handles, 4 example poses."""
    import numpy as np

    xs, ys = np.meshgrid(np.linspace(0, 1, 6), np.linspace(0, 1, 6))
    V = np.c_[xs.ravel(), ys.ravel(), 0.1 * np.sin(3 * xs.ravel())]
    F = np.array([f for i in range(5) for j in range(5) for f in
                  ([6 * i + j, 6 * i + j + 1, 6 * i + j + 6], [6 * i + j + 1, 6 * i + j + 7, 6 * i + j + 6])])
    W = np.c_[1 - V[:, 0], V[:, 0] / 2, V[:, 0] / 2]
    T = np.tile(np.eye(3, 4), (4, 3, 1, 1)) + np.random.default_rng(0).normal(0, 0.05, (4, 3, 3, 4))
    return V, F, W, T


def _with(a, value=float("nan"), index=(0, 0)):
    import numpy as np

    a = np.array(a, dtype=float)
    a[index] = value
    return a


# (call, what replaces (V, F), W or T, keyword arguments, words the one line must hold): a sweep of the API with
# bad arrays. 19 of these ended in numpy's, scipy's or pymeshlab's exception, a confusing line (no faces: "all 0
# faces () have zero area") or passed wrong data on in silence (complex parts dropped, face indices truncated,
# examples=0); the others were already one line and stay so.
BAD_ARRAYS = [
    ("reduce", {"mesh": "empty"}, {}, "mesh: vertices: the mesh has no vertices"),
    ("reduce", {"V": "strings"}, {}, "mesh: vertices: vertex positions are not real numbers"),
    ("reduce", {"V": "complex"}, {}, "mesh: vertices: vertex positions are not real numbers (got complex128"),
    ("reduce", {"F": "strings"}, {}, "mesh: faces: face indices are not real numbers"),
    ("reduce", {"F": "fractional"}, {}, "mesh: faces: face indices are not whole numbers"),
    ("reduce", {"F": "none"}, {"solve": "smooth"}, "mesh: faces: the mesh has no faces; the Laplacian"),
    ("reduce", {"W": "3-D"}, {}, "weights: shape: weights have shape (36, 3, 1), expected (m, n)"),
    ("reduce", {"W": "1-D"}, {}, "weights: shape: weights have shape (36,)"),
    ("reduce", {"W": "rows"}, {}, "weights: rows: weights have 35 rows but the mesh has 36 vertices"),
    ("reduce", {"W": "nan"}, {}, "weights: values: weights contain NaN or inf"),
    ("reduce", {"W": "inf"}, {}, "weights: values: weights contain NaN or inf"),
    ("reduce", {"W": "strings"}, {}, "weights: values: weights are not real numbers"),
    ("reduce", {"W": "ragged"}, {}, "weights: values: weights are nested lists of different lengths"),
    ("reduce", {"W": "complex"}, {}, "weights: values: weights are not real numbers (got complex128"),
    ("reduce", {"W": "none"}, {}, "weights: values: weights are not real numbers (got None)"),
    ("reduce", {"V": "nan"}, {}, "mesh: vertices: vertex positions contain NaN or inf"),
    ("reduce", {"V": "inf"}, {}, "mesh: vertices: vertex positions contain NaN or inf"),
    ("reduce", {"T": "3-D"}, {}, "poses: transforms: transform stack has shape (3, 3, 4)"),
    ("reduce", {"T": "4x4"}, {}, "poses: transforms: transform stack has shape (4, 3, 4, 4)"),
    ("reduce", {"T": "handles"}, {}, "poses: poses have 2 handles, the weights 3"),
    ("reduce", {"T": "nan"}, {}, "poses: transforms: transforms contain NaN or inf"),
    ("reduce", {"T": "complex"}, {}, "poses: transforms: poses are not real numbers"),
    ("reduce", {"T": "clips"}, {"examples": 0}, "reduce_weights.examples: input should be a whole number >= 1"),
    ("reduce", {"T": "clips"}, {"examples": "x"}, "reduce_weights.examples"),
    ("reduce", {}, {"validation": "3-D"}, "validation: transforms: transform stack has shape (3, 3, 4)"),
    ("simplify", {"mesh": "empty"}, {}, "mesh: vertices: the mesh has no vertices"),
    ("simplify", {"F": "none"}, {"method": "static-qslim"}, "mesh: faces: the mesh has no faces: nothing to simplify"),
    ("simplify", {"F": "none"}, {}, "mesh: faces: the mesh has no faces: nothing to simplify"),
    ("simplify", {"W": "3-D"}, {}, "weights: shape: weights have shape (36, 3, 1)"),
    ("simplify", {"W": "rows"}, {}, "weights: rows: weights have 35 rows"),
    ("simplify", {"V": "nan"}, {}, "mesh: vertices: vertex positions contain NaN or inf"),
    ("simplify", {"T": "3-D"}, {}, "poses: transforms: transform stack has shape (3, 3, 4)"),
]


@pytest.mark.parametrize(("call", "bad", "kwargs", "words"), BAD_ARRAYS,
                         ids=[f"{c}-{'-'.join(f'{k}={v}' for k, v in b.items()) or 'ok'}-{'-'.join(kw) or 'ok'}"
                              for c, b, kw, _ in BAD_ARRAYS])
def test_bad_arrays_are_one_line_input_errors(call, bad, kwargs, words):
    """Empty meshes, 3-D or mis-sized weights, NaN/inf, strings, complex numbers and mis-shaped poses are one
    RigslimError naming the argument and the fix, checked once where the API builds its asset."""
    import numpy as np

    import rigslim
    from rigslim.errors import MAX_LINE, RigslimError

    V, F, W, T = _grid()
    arrays = {
        "mesh": {"empty": (np.zeros((0, 3)), np.zeros((0, 3), int))},
        "V": {"strings": np.full(V.shape, "x"), "complex": V + 1j, "nan": _with(V), "inf": _with(V, np.inf)},
        "F": {"strings": np.full(F.shape, "a"), "fractional": F + 0.5, "none": np.zeros((0, 3), int)},
        "W": {"3-D": W[:, :, None], "1-D": W[:, 0], "rows": W[:-1], "nan": _with(W), "inf": _with(W, np.inf),
              "strings": np.full(W.shape, "x"), "ragged": [[1.0], [0.5, 0.5]], "complex": W + 1j, "none": None},
        "T": {"3-D": T[0], "4x4": np.tile(np.eye(4), (4, 3, 1, 1)), "handles": T[:, :2],
              "nan": _with(T, index=(0, 0, 0, 0)), "complex": T + 1j, "clips": [T, T]},
    }
    mesh, weights, poses = (V, F), W, T
    for name, key in bad.items():
        value = arrays[name][key]
        if name == "mesh":
            mesh, weights = value, np.zeros((0, 3))
        elif name in ("V", "F"):
            mesh = (value, F) if name == "V" else (V, value)
        elif name == "W":
            weights = value
        else:
            poses = value
    kwargs = {k: (T[0] if v == "3-D" else v) for k, v in kwargs.items()}
    fn = rigslim.reduce_weights if call == "reduce" else rigslim.simplify
    extra = {"k": 2} if call == "reduce" else {}
    with pytest.raises(RigslimError) as info:
        fn(mesh, weights, poses, **extra, **kwargs)
    line = str(info.value)
    assert words in line and "\n" not in line and len(line) <= MAX_LINE
    assert info.value.fix


def test_pipeline_arguments_that_are_not_a_spec():
    """Pipeline.from_yaml with a number for spec, or one string (not a list) of overrides: one PipelineError
    naming the argument (were pathlib's TypeError, and --set 's' is not STEP.PARAM=VALUE, one character each)."""
    import rigslim
    from rigslim.errors import PipelineError

    doc = {"steps": [{"select": "k-largest", "k": 2}]}
    with pytest.raises(PipelineError, match=r"^spec: spec is neither a path nor a mapping \(got 5\)"):
        rigslim.Pipeline.from_yaml(5)
    for overrides in ("select.k=3", [3]):
        with pytest.raises(PipelineError, match=r"^overrides: overrides must be a list of strings"):
            rigslim.Pipeline.from_yaml(doc, overrides=overrides)
    assert rigslim.Pipeline.from_yaml(doc, overrides=["select.k=3"]).steps[0].params == {"k": 3}
