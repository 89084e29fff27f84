"""The module paths of rigslim before framework/ was split by purpose, kept importable.

``import rigslim.mesh`` gives the module :mod:`rigslim.model.mesh` itself: the same object, so
``isinstance``, pickling and ``monkeypatch.setattr`` behave as they did. A module that was split into
several (``rigslim.pipeline`` into :mod:`rigslim.runtime.document`, :mod:`~rigslim.runtime.inputs` and
:mod:`~rigslim.runtime.run`) gives a read-only view whose names come from its parts, in order.
:data:`MOVED` is the whole table (docs/layout.md, "Old import paths"); new code uses the new paths,
which are also the only ones type checkers see. :data:`RENAMED` lists the few public names renamed since.
"""

from __future__ import annotations

import importlib
import importlib.abc
import importlib.machinery
import sys
import types
from typing import Any

#: Old module -> its new module, or the new modules it was split into (names are looked up in order).
MOVED: dict[str, tuple[str, ...]] = {
    "rigslim.mesh": ("rigslim.model.mesh",),
    "rigslim.handles": ("rigslim.model.handles",),
    "rigslim.poses": ("rigslim.model.poses",),
    "rigslim.weights": ("rigslim.model.weights",),
    "rigslim.asset": ("rigslim.model.asset",),
    "rigslim.hierarchy": ("rigslim.model.hierarchy",),
    "rigslim.blend": ("rigslim.numerics.blend",),
    "rigslim.numerics.k_largest": ("rigslim.numerics.largest_entries",),
    "rigslim.yamlio": ("rigslim.io.yamlio",),
    "rigslim.jsonsafe": ("rigslim.io.jsonsafe",),
    "rigslim.io.gltf_schema": ("rigslim.io.gltf.schema",),
    "rigslim.io.gltf_write": ("rigslim.io.gltf.write",),
    "rigslim.io.gltf_lod": ("rigslim.io.gltf.lod", "rigslim.io.gltf.primitives", "rigslim.io.gltf.seams",
                            "rigslim.io.gltf.write"),
    "rigslim.hookspecs": ("rigslim.plugin.hookspecs",),
    "rigslim.host": ("rigslim.plugin.host",),
    "rigslim.evaluation": ("rigslim.plugin.evaluation",),
    "rigslim.pipeline": ("rigslim.runtime.document", "rigslim.runtime.inputs", "rigslim.runtime.run"),
    "rigslim.clips": ("rigslim.runtime.clips",),
    "rigslim.metrics_document": ("rigslim.runtime.metrics_document",),
    "rigslim.progress": ("rigslim.runtime.progress",),
    "rigslim.opencl": ("rigslim.device.opencl",),
    "rigslim.egl": ("rigslim.device.egl",),
    "rigslim.native": ("rigslim.device.native",),
    "rigslim.numba_threads": ("rigslim.device.numba_threads",),
    "rigslim.render": ("rigslim.report.render",),
    "rigslim.batch_task": ("rigslim.batch.task",),
    "rigslim.batch_assets": ("rigslim.batch.assets",),
    "rigslim.cli": ("rigslim.commands.cli", "rigslim.commands.run", "rigslim.commands.report",
                    "rigslim.commands.plugins"),
    "rigslim.gltf_commands": ("rigslim.commands.gltf_common", "rigslim.commands.reduce", "rigslim.commands.lod",
                              "rigslim.commands.compare", "rigslim.commands.inspect", "rigslim.commands.cli"),
}

#: Public names renamed after the move so that one name says one thing: (module, old name) -> new name.
#: Internal helpers no document names; the old name is gone (docs/layout.md, "Old import paths").
RENAMED: dict[tuple[str, str], str] = {
    ("rigslim.batch.task", "metric_columns"): "summary_metrics",
    ("rigslim.report.batch", "metric_columns"): "error_columns",
}


class _SplitModule(types.ModuleType):
    """An old module that was split: its names are looked up in the new modules, in order."""

    def __init__(self, name: str, parts: tuple[str, ...]) -> None:
        super().__init__(name, f"Moved: see {', '.join(parts)}.")
        self.__dict__["_parts"] = parts

    def __getattr__(self, name: str) -> Any:
        if name.startswith("__"):
            raise AttributeError(name)
        for part in self.__dict__["_parts"]:
            module = importlib.import_module(part)
            if hasattr(module, name):
                return getattr(module, name)
        raise AttributeError(f"module {self.__name__!r} has no attribute {name!r} "
                             f"(it moved to {', '.join(self.__dict__['_parts'])})")

    def __dir__(self) -> list[str]:
        names: set[str] = set()
        for part in self.__dict__["_parts"]:
            names.update(n for n in dir(importlib.import_module(part)) if not n.startswith("_"))
        return sorted(names)


class _MovedFinder(importlib.abc.MetaPathFinder, importlib.abc.Loader):
    """Finds the old module names of :data:`MOVED` and loads them as their new modules."""

    def __init__(self) -> None:
        self._specs: dict[str, Any] = {}

    def find_spec(self, fullname: str, path: Any = None, target: Any = None) -> importlib.machinery.ModuleSpec | None:
        if fullname not in MOVED:
            return None
        return importlib.machinery.ModuleSpec(fullname, self)

    def create_module(self, spec: importlib.machinery.ModuleSpec) -> types.ModuleType:
        parts = MOVED[spec.name]
        if len(parts) > 1:
            return _SplitModule(spec.name, parts)
        module = importlib.import_module(parts[0])
        self._specs[spec.name] = module.__spec__  # the import system sets __spec__: restored in exec_module
        return module

    def exec_module(self, module: types.ModuleType) -> None:
        name = module.__spec__.name if module.__spec__ else ""
        if name in self._specs:
            module.__spec__ = self._specs.pop(name)


def install() -> None:
    """Put the finder on ``sys.meta_path`` (once; :mod:`rigslim` does it on import)."""
    if not any(isinstance(f, _MovedFinder) for f in sys.meta_path):
        sys.meta_path.insert(0, _MovedFinder())
