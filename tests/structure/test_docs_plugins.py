"""docs/plugins.md names only what exists: every `Class.attribute` of its reference section, every rigslim path."""

from __future__ import annotations

import importlib
import re
from pathlib import Path

import pytest

from rigslim.model import (
    Asset,
    FrameSplit,
    Handles,
    InfluenceSets,
    Mesh,
    Poses,
    ProgressiveHierarchy,
    ReducedWeights,
    SimplifiedLevel,
)
from rigslim.plugin import Decimation, Reader, StepContext
from rigslim.plugin.evaluation import Evaluation

PAGE = (Path(__file__).resolve().parents[2] / "docs" / "plugins.md").read_text()
SECTION = PAGE.split("## What a plugin receives and returns", 1)[1]
CLASSES = {c.__name__: c for c in (Asset, FrameSplit, Handles, InfluenceSets, Mesh, Poses, ProgressiveHierarchy,
                                   ReducedWeights, SimplifiedLevel, Decimation, Reader, StepContext, Evaluation)}
ATTRIBUTES = sorted(set(re.findall(r"`([A-Z]\w+)\.(\w+)", SECTION)) - {("Class", "attribute")})
PATHS = sorted(set(re.findall(r"`(rigslim(?:\.\w+)+)", PAGE)))


def _has(cls: type, name: str) -> bool:
    if hasattr(cls, name) or name in getattr(cls, "__dataclass_fields__", {}):
        return True
    if cls is Evaluation:  # attributes set in __init__
        source = Path(importlib.import_module(cls.__module__).__file__).read_text()
        return re.search(rf"self\.{name}\b\s*(:[^=\n]*)?=", source) is not None
    return name in getattr(cls, "__annotations__", {})


def test_the_section_names_many_attributes():
    assert len(ATTRIBUTES) > 50 and {c for c, _ in ATTRIBUTES} <= set(CLASSES)


@pytest.mark.parametrize("cls,name", ATTRIBUTES, ids=lambda x: x if isinstance(x, str) else "")
def test_every_named_attribute_exists(cls, name):
    assert _has(CLASSES[cls], name), f"docs/plugins.md names {cls}.{name}, which does not exist"


@pytest.mark.parametrize("path", PATHS)
def test_every_named_rigslim_path_resolves(path):
    parts = path.split(".")
    for n in range(len(parts), 0, -1):
        try:
            obj = importlib.import_module(".".join(parts[:n]))
        except ImportError:
            continue
        for attr in parts[n:]:
            obj = getattr(obj, attr)
        return
    pytest.fail(f"{path} does not import")
