"""The plugin host: a pluggy manager that loads every ``rigslim`` entry point.

Example
-------
>>> from rigslim.plugin.host import get_host
>>> get_host().get("weight-solver", "k-largest").name
'k-largest'
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import pluggy

from rigslim.errors import PluginNotFoundError, closest
from rigslim.plugin import hookspecs
from rigslim.plugin.contract import STAGE_HOOKS, Plugin


@dataclass(frozen=True)
class PluginInfo:
    """A loaded plugin and where it came from."""

    stage: str
    name: str
    package: str
    version: str
    summary: str
    plugin: Plugin[Any]

    @property
    def params_schema(self) -> dict[str, Any]:
        """JSON schema of the plugin's ``Params`` (names, types, defaults, descriptions)."""
        return self.plugin.Params.model_json_schema()

    def as_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "name": self.name, "package": self.package,
                "version": self.version, "summary": self.summary}


class PluginHost:
    """Loads plugins and looks them up by stage and name.

    Parameters
    ----------
    load_entry_points : bool
        Load every module of the ``rigslim`` entry-point group (built-ins and
        installed third-party packages).
    extra : iterable of modules or objects, optional
        More plugin modules to register (useful in tests).
    """

    def __init__(self, load_entry_points: bool = True, extra=()):
        self.pm = pluggy.PluginManager("rigslim")
        self.pm.add_hookspecs(hookspecs)
        if load_entry_points:
            self.pm.load_setuptools_entrypoints("rigslim")
        for obj in extra:
            self.pm.register(obj)
        self._registry: dict[str, dict[str, PluginInfo]] | None = None

    def _origin(self) -> dict[int, tuple[str, str]]:
        return {id(mod): (dist.metadata["name"], dist.version) for mod, dist in self.pm.list_plugin_distinfo()}

    @property
    def registry(self) -> dict[str, dict[str, PluginInfo]]:
        """``{stage: {name: PluginInfo}}`` of every loaded plugin."""
        if self._registry is None:
            origin = self._origin()
            reg: dict[str, dict[str, PluginInfo]] = {stage: {} for stage in STAGE_HOOKS}
            for stage, hook_name in STAGE_HOOKS.items():
                hook = getattr(self.pm.hook, hook_name)
                for impl in hook.get_hookimpls():
                    package, version = origin.get(id(impl.plugin), (getattr(impl.plugin, "__name__", "?"), ""))
                    for plugin in impl.function() or []:
                        if plugin.name in reg[stage]:
                            # A later registration (a third-party package) may not silently shadow one.
                            raise PluginNotFoundError(
                                f"two plugins are named '{plugin.name}' in stage '{stage}' "
                                f"({reg[stage][plugin.name].package} and {package})",
                                field=stage, fix="uninstall or rename one of them")
                        reg[stage][plugin.name] = PluginInfo(stage, plugin.name, package, version,
                                                             plugin.summary, plugin)
            self._registry = reg
        return self._registry

    def get(self, stage: str, name: str) -> Plugin:
        """The plugin called ``name`` in ``stage``; a PluginNotFoundError suggests close names."""
        if stage not in self.registry:
            raise PluginNotFoundError(f"unknown stage '{stage}'", field="stage", fix=closest(stage, self.registry))
        plugins = self.registry[stage]
        if name not in plugins:
            raise PluginNotFoundError(f"no {stage} plugin named '{name}'", field=stage,
                                      fix=closest(str(name), plugins))
        return plugins[name].plugin

    def plugins(self, stage: str) -> dict[str, Plugin]:
        return {name: info.plugin for name, info in self.registry.get(stage, {}).items()}

    def infos(self) -> list[PluginInfo]:
        return [info for stage in self.registry.values() for info in stage.values()]


@lru_cache(maxsize=1)
def get_host() -> PluginHost:
    """The process-wide host with every installed plugin loaded."""
    return PluginHost()
