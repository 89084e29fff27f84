"""No function over 80 lines in framework/ or plugins/ (issue 20), numba kernels aside.

A function's length is ``end_lineno - lineno`` of its ``def`` (docstring included; a decorator's lines are
not). Numba kernels are let off by rule: a function decorated with one of :data:`KERNEL_DECORATORS`
(``@njit``, ``@numba.jit(...)``, ``@vectorize``..., ``@intrinsic``, whose body numba compiles or generates
code from), however long. The others over the limit are listed in :data:`KNOWN`, which only shrinks: the test
fails when a function not on it goes over, and when one on it is gone or back under the limit (take it off
the list in the change that splits it).
"""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TREES = ("framework", "plugins")
LIMIT = 80
KERNEL_DECORATORS = frozenset({"njit", "jit", "vectorize", "guvectorize", "intrinsic"})

#: ``path::qualified name`` of the functions still over the limit; split one into phases, then take it off.
#: Empty since issue 20 split the last three (solve_small_qps, local_solve, methods._solve): none may go over.
KNOWN: frozenset[str] = frozenset()


def _decorator_name(node: ast.expr) -> str:
    """``njit`` for ``@njit``, ``@njit(cache=True)``, ``@numba.njit`` and ``@numba.njit(...)``."""
    if isinstance(node, ast.Call):
        node = node.func
    if isinstance(node, ast.Attribute):
        return node.attr
    return node.id if isinstance(node, ast.Name) else ""


def is_kernel(node: ast.FunctionDef | ast.AsyncFunctionDef) -> bool:
    """Whether a function is a numba kernel (decorated with one of :data:`KERNEL_DECORATORS`)."""
    return any(_decorator_name(d) in KERNEL_DECORATORS for d in node.decorator_list)


def function_lengths(source: str) -> dict[str, int]:
    """Length (``end_lineno - lineno``) of every function and method of ``source``, by qualified name
    (``Class.method``, ``outer.inner``), numba kernels left out."""
    lengths: dict[str, int] = {}

    def visit(node: ast.AST, prefix: str) -> None:
        for child in ast.iter_child_nodes(node):
            if isinstance(child, (ast.FunctionDef, ast.AsyncFunctionDef)):
                name = prefix + child.name
                if not is_kernel(child):
                    assert child.end_lineno is not None
                    lengths[name] = max(lengths.get(name, 0), child.end_lineno - child.lineno)
                visit(child, name + ".")
            elif isinstance(child, ast.ClassDef):
                visit(child, prefix + child.name + ".")
            else:
                visit(child, prefix)

    visit(ast.parse(source), "")
    return lengths


def long_functions(root: Path = ROOT, limit: int = LIMIT) -> dict[str, int]:
    """``path::name`` -> length of every function over ``limit`` lines in framework/ and plugins/."""
    found = {}
    for tree in TREES:
        for path in sorted((root / tree).rglob("*.py")):
            for name, length in function_lengths(path.read_text()).items():
                if length > limit:
                    found[f"{path.relative_to(root).as_posix()}::{name}"] = length
    return found


def test_no_new_long_function():
    new = {name: n for name, n in long_functions().items() if name not in KNOWN}
    assert not new, (f"over {LIMIT} lines (split into phases: helper functions named for what they do): "
                     + ", ".join(f"{name} ({n})" for name, n in sorted(new.items())))


def test_known_list_only_shrinks():
    gone = KNOWN - set(long_functions())
    assert not gone, f"no longer over {LIMIT} lines (or renamed): take off KNOWN: {', '.join(sorted(gone))}"


def test_lengths_and_kernel_rule():
    source = (
        "import numba\n"
        "from numba import njit\n"
        "def short():\n    return 1\n"
        "class A:\n    def method(self):\n" + "        x = 1\n" * 81 + "        return x\n"
        "@njit(cache=True)\ndef kernel(a):\n" + "    a += 1\n" * 90 + "    return a\n"
        "@numba.vectorize\ndef ufunc(a):\n" + "    a += 1\n" * 90 + "    return a\n"
        "def outer():\n    def inner():\n        return 2\n    return inner\n"
    )
    lengths = function_lengths(source)
    assert lengths == {"short": 1, "A.method": 82, "outer": 3, "outer.inner": 1}
