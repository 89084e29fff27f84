"""The plugin contract (rigslim.plugin, rigslim.plugin.hookspecs): one definition per stage, documented, kept by
plugins."""

from __future__ import annotations

import inspect
import re
import typing
from pathlib import Path

import pytest

from rigslim.plugin import STAGE_HOOKS, STAGES, STEP_STAGES, Plugin, hookspecs
from rigslim.plugin.host import get_host

ROOT = Path(__file__).resolve().parents[3]

#: The stage's call of each base class.
CALLS = {"reader": "read", "writer": "write", "weight-generator": "generate", "influence-selection": "select",
         "weight-solver": "solve", "articulated-decimation": "decimate", "deformer": "bind",
         "normal-estimator": "estimate", "metric": "compute"}


def _hooks() -> dict[str, object]:
    return {name: f for name, f in vars(hookspecs).items() if name.startswith("rigslim_") and callable(f)}


def test_tables_are_derived_from_the_base_classes():
    assert set(STAGE_HOOKS) == {cls.stage for cls in STAGES} == set(CALLS)
    assert set(STAGE_HOOKS.values()) == set(_hooks())
    for cls in STAGES:
        assert STAGE_HOOKS[cls.stage] == cls.hook
        assert all(STEP_STAGES[key] == cls.stage for key in cls.step_keys)
    assert set(STEP_STAGES) == {key for cls in STAGES for key in cls.step_keys}


def test_hookspecs_are_typed_and_documented():
    hints_ns = {cls.__name__: cls for cls in STAGES}
    for name, spec in _hooks().items():
        stage = next(cls for cls in STAGES if cls.hook == name)
        hints = typing.get_type_hints(spec, globalns=hints_ns)
        assert hints["return"] == list[stage], name
        assert "Returns" in (spec.__doc__ or ""), name


def _doc_rows() -> dict[str, str]:
    text = (ROOT / "docs" / "plugins.md").read_text()
    return {m.group(1): m.group(0) for m in re.finditer(r"^\|[^|\n]*\|[^|\n]*\| `(rigslim_\w+)\(\).*$", text, re.M)}


@pytest.mark.parametrize("cls", STAGES, ids=lambda c: c.stage)
def test_every_hook_is_documented_with_its_signature(cls):
    """docs/plugins.md has a row per hook with its return type and the stage call's parameters, in order."""
    rows = _doc_rows()
    assert cls.hook in rows, f"docs/plugins.md does not document {cls.hook}"
    row = rows[cls.hook]
    assert f"`{cls.hook}() -> list[{cls.__name__}]`" in row
    call = CALLS[cls.stage]
    params = [p for p in inspect.signature(getattr(cls, call)).parameters if p != "self"]
    assert f"{call}({', '.join(params)})" in row, f"{cls.hook}: docs/plugins.md should show {call}({', '.join(params)})"
    for key in cls.step_keys:
        assert f"`{key}`" in row


def _plugins():
    return [(info.stage, info.name, info.plugin) for info in get_host().infos()]


@pytest.mark.parametrize("stage,name,plugin", _plugins(), ids=lambda x: x if isinstance(x, str) else "")
def test_every_plugin_keeps_the_contract(stage, name, plugin):
    """Each loaded plugin subclasses its stage's base class and takes the call's parameters, in order."""
    base = next(cls for cls in STAGES if cls.stage == stage)
    assert isinstance(plugin, base) and isinstance(plugin, Plugin)
    assert plugin.name == name and plugin.summary and "\n" not in plugin.summary
    call = CALLS[stage]
    expected = [p for p in inspect.signature(getattr(base, call)).parameters if p != "self"]
    got = [p for p in inspect.signature(getattr(plugin, call)).parameters][:len(expected)]
    assert got == expected, f"{stage} '{name}': {call}{tuple(got)} should take {tuple(expected)}"


def test_no_plugin_package_imports_another_and_the_core_imports_none():
    """Plugin packages meet only through rigslim's public modules and the host (no cross-package imports)."""
    import re

    root = ROOT
    offenders = []
    for package in sorted(p for p in (root / "plugins").iterdir() if (p / "__init__.py").exists()):
        for path in package.rglob("*.py"):
            for other in re.findall(r"rigslim\.plugins\.(\w+)", path.read_text()):
                if other != package.name:
                    offenders.append(f"{path.relative_to(root)} -> rigslim.plugins.{other}")
    for path in (root / "framework").rglob("*.py"):
        text = path.read_text()
        if path.name != "contract.py" and re.search(r"^\s*(from|import) rigslim\.plugins", text, re.M):
            offenders.append(f"{path.relative_to(root)} imports a plugin package")
        if re.search(r"^\s*(from|import) support\b", text, re.M):
            offenders.append(f"{path.relative_to(root)} imports a test helper")
    assert offenders == []
