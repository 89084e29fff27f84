"""Private names stay private: a ``_name`` is imported only inside its own subpackage, and the glTF
modules (rigslim.io.gltf) share nothing private at all: what one of them needs from another is public,
with keyword-only flags (``skin_from_document(doc, animation=..., weld=False)``, not ``_read_gltf_skin(doc,
clip, 30.0, None, s, True, False)``)."""

from __future__ import annotations

import ast
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
TREES = {ROOT / "framework": "rigslim", ROOT / "plugins": "rigslim.plugins"}

#: Private imports across subpackages that are still there, each with the reason; the list only shrinks.
KNOWN = {
    # best's sparse_fit / geometric_kernel rewrite (issue 22) no longer uses these kernels
    ("rigslim.numerics.simplex_nnls", "_gradient", "rigslim.plugins.selection.sparse_fit"),
    ("rigslim.numerics.simplex_nnls", "_inverse", "rigslim.plugins.selection.sparse_fit"),
    ("rigslim.numerics.simplex_nnls", "_lawson_hanson", "rigslim.plugins.selection.sparse_fit"),
    ("rigslim.numerics.simplex_nnls", "_lawson_hanson", "rigslim.plugins.solvers.geometric_kernel"),
}


def _module_name(path: Path, trees: dict[Path, str]) -> str:
    for tree, package in trees.items():
        if path.is_relative_to(tree):
            parts = path.relative_to(tree).with_suffix("").parts
            return ".".join([package, *parts]).removesuffix(".__init__")
    raise AssertionError(path)


def private_imports(trees: dict[Path, str] = TREES) -> list[tuple[str, str, str]]:
    """(module imported from, private name, importing module) for every ``from rigslim... import _name``."""
    found = []
    for tree in trees:
        for path in sorted(tree.rglob("*.py")):
            importer = _module_name(path, trees)
            for node in ast.walk(ast.parse(path.read_text())):
                if isinstance(node, ast.ImportFrom) and node.module and node.module.startswith("rigslim."):
                    for alias in node.names:
                        if alias.name.startswith("_") and not alias.name.startswith("__"):
                            found.append((node.module, alias.name, importer))
    return found


def _package(module: str) -> str:
    """The subpackage a module belongs to: rigslim.io.gltf.skin -> rigslim.io.gltf."""
    return module.rsplit(".", 1)[0]


def crossing(imports: list[tuple[str, str, str]]) -> set[tuple[str, str, str]]:
    """The private imports that leave their subpackage (a package's own modules may use its private names)."""
    return {(m, n, who) for m, n, who in imports if _package(m) != _package(who) and not who.startswith(m + ".")}


def gltf_shared(imports: list[tuple[str, str, str]]) -> list[tuple[str, str, str]]:
    """The private imports into or out of a rigslim.io.gltf module."""
    return [(m, n, who) for m, n, who in imports
            if m.startswith("rigslim.io.gltf") or who.startswith("rigslim.io.gltf")]


def test_private_names_stay_in_their_subpackage():
    imports = private_imports()
    assert crossing(imports) <= KNOWN, sorted(crossing(imports) - KNOWN)
    assert KNOWN <= set(imports), f"gone, drop from KNOWN: {sorted(KNOWN - set(imports))}"


def test_gltf_modules_share_nothing_private():
    assert not gltf_shared(private_imports()), gltf_shared(private_imports())


def test_the_rules_catch_a_private_import(tmp_path):
    """The scan and both rules on a made-up tree: the private imports are found, the allowed one is not."""
    (tmp_path / "io" / "gltf").mkdir(parents=True)
    (tmp_path / "commands").mkdir()
    (tmp_path / "io" / "gltf" / "skin.py").write_text("from rigslim.io.gltf.document import _parse\n")
    (tmp_path / "commands" / "compare.py").write_text(
        "from rigslim.commands.common import _header\nfrom rigslim.io.gltf.skin import _read, public\n")
    imports = private_imports({tmp_path: "rigslim"})
    assert sorted(imports) == [("rigslim.commands.common", "_header", "rigslim.commands.compare"),
                               ("rigslim.io.gltf.document", "_parse", "rigslim.io.gltf.skin"),
                               ("rigslim.io.gltf.skin", "_read", "rigslim.commands.compare")]
    assert crossing(imports) == {("rigslim.io.gltf.skin", "_read", "rigslim.commands.compare")}
    assert len(gltf_shared(imports)) == 2
