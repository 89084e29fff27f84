"""Every module path and public name rigslim had before framework/ was split by purpose still imports.

``old_public_names.json`` lists, per module of the flat layout, the public names it defined (recorded
from that layout before the move). Old paths of moved modules resolve through :mod:`rigslim.compat`.
"""

from __future__ import annotations

import importlib
import json
import subprocess
import sys
from pathlib import Path

import pytest

from rigslim.compat import MOVED, RENAMED

OLD = json.loads((Path(__file__).with_name("old_public_names.json")).read_text())

#: Names that moved up to the command line, which a library module may not import (docs/layout.md).
TO_COMMANDS = {("rigslim.batch", "add_parser"): "rigslim.commands.batch",
               ("rigslim.batch", "cmd_batch"): "rigslim.commands.batch"}


@pytest.mark.parametrize("module", sorted(OLD))
def test_old_module_paths_keep_their_names(module):
    mod = importlib.import_module(module)
    new_module = MOVED.get(module, (module,))[0]
    for name in OLD[module]:
        if (new_module, name) in RENAMED:
            assert hasattr(mod, RENAMED[new_module, name]) and not hasattr(mod, name), (module, name)
            continue
        if (module, name) in TO_COMMANDS:
            assert hasattr(importlib.import_module(TO_COMMANDS[module, name]), name)
            continue
        assert hasattr(mod, name), f"{module}.{name} no longer imports"


@pytest.mark.parametrize("old", sorted(k for k, v in MOVED.items() if len(v) == 1))
def test_a_moved_module_is_the_new_module_itself(old):
    """Same object: isinstance checks, pickles and monkeypatching through the old path behave as before."""
    (new,) = MOVED[old]
    module = importlib.import_module(old)
    assert module is importlib.import_module(new)
    assert module.__spec__.name == new and module.__name__ == new


def test_split_modules_name_their_parts_when_a_name_is_missing():
    pipeline = importlib.import_module("rigslim.pipeline")
    assert pipeline.run_pipeline is importlib.import_module("rigslim.runtime.run").run_pipeline
    with pytest.raises(AttributeError, match="rigslim.runtime.document"):
        pipeline.no_such_name  # noqa: B018


def test_from_imports_of_old_paths_work_in_a_fresh_interpreter():
    """The documented forms, in a process where nothing has imported the new modules yet."""
    code = ("from rigslim.mesh import Mesh; from rigslim import hookspecs; import rigslim.host as host; "
            "from rigslim.pipeline import run_pipeline; from rigslim.plugin import WeightSolver, Params; "
            "from rigslim.io.gltf import read_gltf_skin; import rigslim; "
            "assert rigslim.reduce_weights and Mesh.__module__ == 'rigslim.model.mesh'; "
            "assert host.get_host and hookspecs.hookimpl and run_pipeline and WeightSolver and Params; "
            "print('ok')")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0 and out.stdout.strip() == "ok", out.stderr


def test_the_console_script_and_python_m_use_the_new_path():
    text = (Path(__file__).resolve().parents[2] / "pyproject.toml").read_text()
    assert 'rigslim = "rigslim.commands.cli:main"' in text
    out = subprocess.run([sys.executable, "-m", "rigslim.commands.cli", "--version"], capture_output=True, text=True,
                         timeout=120)
    assert out.returncode == 0 and out.stdout.startswith("rigslim ")
