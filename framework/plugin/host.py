"""The plugin host: loads every ``rigslim`` entry point, holds each package to the contract, looks plugins up.

What the host checks when it loads a package (docs/plugins.md, "What rigslim checks at load"):

1. ``RIGSLIM_DISABLE_PLUGINS=name,...`` (entry-point or distribution names) are not imported at all;
2. a package that fails to import is skipped, with one warning line naming it and its error;
3. ``RIGSLIM_PLUGIN_API = "MAJOR.MINOR"`` in the package's module, when set, must be met by
   :data:`~rigslim.plugin.contract.PLUGIN_API_VERSION` (same major, minor not newer), else the package is skipped;
4. every hook it implements must be a rigslim hook (pluggy's ``check_pending``): a misspelled hook skips
   the package, naming the hook and the closest real one;
5. each hook's result must be a list of the stage's plugins, each with a name, a one-line summary and a
   ``Params`` model (:func:`contract_problem`): a wrong one is dropped with a warning naming the package;
6. two plugins of one stage with one name, or two readers (writers) taking one suffix for one role, are
   ambiguous: a warning at load, and :class:`~rigslim.errors.DuplicatePluginError` when a pipeline
   asks for one of them; nothing is shadowed silently.

Warnings are :class:`PluginLoadWarning` s (the CLI prints them after the command); the same lines are in
:attr:`PluginHost.problems` and in the fix of a :class:`~rigslim.errors.PluginNotFoundError`.

Example
-------
>>> from rigslim.plugin.host import get_host
>>> get_host().get("weight-solver", "k-largest").name
'k-largest'
"""

from __future__ import annotations

import contextlib
import os
import warnings
from collections.abc import Iterable, Iterator
from dataclasses import dataclass
from functools import lru_cache
from importlib.metadata import EntryPoint, entry_points
from typing import Any, cast

import pluggy

from rigslim.errors import (
    DuplicatePluginError,
    PluginError,
    PluginNotFoundError,
    RigslimError,
    brief,
    clip,
    closest,
)
from rigslim.plugin import hookspecs
from rigslim.plugin.contract import PLUGIN_API_VERSION, STAGE_HOOKS, STAGES, Metric, Params, Plugin, Reader, Writer

#: Environment variable naming entry points (or distributions) not to load, comma separated.
DISABLE_ENV = "RIGSLIM_DISABLE_PLUGINS"
#: The entry-point group every plugin package registers in.
GROUP = "rigslim"

_BASE = {cls.stage: cls for cls in STAGES}
_HOOK_STAGE = {cls.hook: cls.stage for cls in STAGES}


class PluginLoadWarning(UserWarning):
    """A plugin package (or one of its plugins) was skipped or is ambiguous; the message says which and why."""


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
        """JSON schema of the plugin's ``Params`` (names, types, defaults, descriptions: the attribute
        docstrings too, :func:`~rigslim.plugin.contract.field_descriptions`)."""
        from rigslim.plugin.contract import field_descriptions

        schema = self.plugin.Params.model_json_schema()
        for name, text in field_descriptions(self.plugin.Params).items():
            prop = schema.get("properties", {}).get(name)
            if text and isinstance(prop, dict):
                prop.setdefault("description", text)
        return schema

    @property
    def origin(self) -> str:
        """``package version``, as messages name it."""
        return f"{self.package} {self.version}".strip()

    def as_dict(self) -> dict[str, Any]:
        return {"stage": self.stage, "name": self.name, "package": self.package,
                "version": self.version, "summary": self.summary}


@dataclass
class _Origin:
    package: str
    version: str
    entry_point: str


def api_problem(required: object) -> str | None:
    """Why a package asking for plugin API ``required`` ("MAJOR.MINOR") cannot load here, or None.

    A package written against ``M.n`` loads into a rigslim whose :data:`PLUGIN_API_VERSION` is ``M.m``
    with ``m >= n``: minor versions only add to the contract, a major version changes it.
    """
    try:
        major, minor = (int(x) for x in str(required).split("."))
    except ValueError:
        return f"RIGSLIM_PLUGIN_API = {brief(required)} is not \"MAJOR.MINOR\""
    have_major, have_minor = (int(x) for x in PLUGIN_API_VERSION.split("."))
    if major != have_major or minor > have_minor:
        return (f"needs rigslim plugin API {major}.{minor}, this rigslim has {PLUGIN_API_VERSION} "
                f"(fix: install a release of the package written for API {have_major}.x, or a rigslim with "
                f"API {major}.{minor})")
    return None


def contract_problem(plugin: object, stage: str) -> str | None:
    """What is wrong with ``plugin`` as a plugin of ``stage`` (returned by that stage's hook), or None."""
    base = _BASE[stage]
    if not isinstance(plugin, base):
        other = next((cls for cls in STAGES if isinstance(plugin, cls)), None)
        where = f" (a {other.__name__}: return it from {other.hook}())" if other else ""
        return f"{brief(plugin)} is not an instance of {base.__name__}{where}"
    name, summary = getattr(plugin, "name", None), getattr(plugin, "summary", None)
    if not isinstance(name, str) or not name or name != name.strip() or any(c.isspace() for c in name):
        return f"{type(plugin).__name__} has no usable name ({brief(name)}; set name = 'my-plugin')"
    if not isinstance(summary, str) or not summary.strip() or "\n" in summary.strip():
        return f"{stage} '{name}' needs a one-line summary (got {brief(summary)})"
    params = getattr(plugin, "Params", None)
    if not (isinstance(params, type) and issubclass(params, Params)):
        return f"{stage} '{name}': Params is {brief(params)}, not a subclass of rigslim.plugin.Params"
    if stage in ("reader", "writer"):
        suffixes = getattr(plugin, "suffixes", ())
        if not isinstance(suffixes, tuple) or not all(isinstance(s, str) and s.startswith(".") for s in suffixes):
            return f"{stage} '{name}': suffixes must be a tuple like ('.obj', '.off'), got {brief(suffixes)}"
        role = getattr(plugin, "role", None)
        if stage == "reader" and (not isinstance(role, str) or not role):
            return f"reader '{name}' has no role (set role = 'mesh', 'weights', ...)"
    return None


def disabled_from_env() -> set[str]:
    """The names in ``RIGSLIM_DISABLE_PLUGINS``."""
    return {n.strip() for n in os.environ.get(DISABLE_ENV, "").split(",") if n.strip()}


class PluginHost:
    """Loads plugins, checks them against the contract, and looks them up by stage and name.

    Parameters
    ----------
    load_entry_points : bool
        Load every module of the ``rigslim`` entry-point group (built-ins and installed third-party packages).
    extra : iterable of modules or objects, optional
        More plugin modules to register (useful in tests); held to the same checks.
    disabled : iterable of str, optional
        Entry-point or distribution names not to load (default: ``RIGSLIM_DISABLE_PLUGINS``).

    Attributes
    ----------
    problems : list of str
        One line per skipped package or plugin and per ambiguity (also issued as :class:`PluginLoadWarning`).
    disabled : list of str
        Entry points not loaded on purpose.
    """

    def __init__(self, load_entry_points: bool = True, extra: Iterable[object] = (),
                 disabled: Iterable[str] | None = None) -> None:
        self.pm = pluggy.PluginManager(GROUP)
        self.pm.add_hookspecs(hookspecs)
        self.problems: list[str] = []
        self.disabled: list[str] = []
        self._origins: dict[int, _Origin] = {}
        self._ambiguous: dict[tuple[str, str], list[PluginInfo]] = {}
        self._registry: dict[str, dict[str, PluginInfo]] | None = None
        skip = set(disabled_from_env() if disabled is None else disabled)
        if load_entry_points:
            for ep in sorted(entry_points(group=GROUP), key=lambda e: (e.dist is None or e.dist.name != "rigslim",
                                                                       e.name)):
                self._load(ep, skip)
        for obj in extra:
            name = getattr(obj, "__name__", type(obj).__name__)
            self._register(obj, _Origin(name, "", name))

    # -- loading -------------------------------------------------------------------------------------------
    def _problem(self, origin: _Origin, text: str) -> None:
        line = f"plugin package '{origin.package}' (entry point '{origin.entry_point}'): {text}"
        self.problems.append(line)
        warnings.warn(line, PluginLoadWarning, stacklevel=3)

    def _load(self, ep: EntryPoint, skip: set[str]) -> None:
        dist = ep.dist
        origin = _Origin(dist.name if dist else ep.value, dist.version if dist else "", ep.name)
        if ep.name in skip or origin.package in skip:
            self.disabled.append(ep.name)
            return
        if self.pm.has_plugin(ep.name):
            self._problem(origin, f"an entry point named '{ep.name}' is already loaded; skipped")
            return
        try:
            module = ep.load()
        except Exception as e:  # any import-time failure of a third-party package: skip it, say why
            self._problem(origin, f"failed to import {ep.value} ({type(e).__name__}: {brief(str(e))}); skipped "
                                  f"(fix: repair or uninstall it, or set {DISABLE_ENV}={ep.name})")
            return
        need = getattr(module, "RIGSLIM_PLUGIN_API", None)
        if need is not None and (why := api_problem(need)) is not None:
            self._problem(origin, why + "; skipped")
            return
        self._register(module, origin, ep.name)

    def _unknown_hooks(self, module: object) -> list[str]:
        names = []
        for attr in dir(module):
            opts = self.pm.parse_hookimpl_opts(module, attr)
            if opts is None:
                continue
            caller = getattr(self.pm.hook, attr, None)
            if (caller is None or caller.spec is None) and not opts.get("optionalhook"):
                names.append(attr)
        return names

    def _register(self, module: object, origin: _Origin, name: str | None = None) -> None:
        unknown = self._unknown_hooks(module)
        if unknown:
            hooks = [h for h in vars(hookspecs) if h.startswith("rigslim_")]
            self._problem(origin, f"'{unknown[0]}' is not a rigslim hook ({closest(unknown[0], hooks)}); skipped")
            return
        try:
            self.pm.register(module, name=name)
            self.pm.check_pending()
        except (pluggy.PluginValidationError, ValueError) as e:
            with contextlib.suppress(Exception):
                self.pm.unregister(module)
            self._problem(origin, f"does not fit the hook specifications ({brief(str(e))}); skipped")
            return
        for attr in dir(module):
            if attr.startswith("rigslim_") and callable(getattr(module, attr, None)) and \
                    self.pm.parse_hookimpl_opts(module, attr) is None:
                self._problem(origin, f"{attr}() has no @rigslim.hookimpl, so it is not called")
        self._origins[id(module)] = origin

    # -- the registry --------------------------------------------------------------------------------------
    def _hook_plugins(self, stage: str) -> Iterator[PluginInfo]:
        hook_name = STAGE_HOOKS[stage]
        for impl in getattr(self.pm.hook, hook_name).get_hookimpls():
            origin = self._origins.get(id(impl.plugin), _Origin(getattr(impl.plugin, "__name__", "?"), "", "?"))
            try:
                result = impl.function()
            except Exception as e:  # a hook that raises: its plugins are skipped, the rest still load
                self._problem(origin, f"{hook_name}() raised {type(e).__name__}: {brief(str(e))}; its plugins "
                                      "are skipped")
                continue
            if result is None:
                continue
            if not isinstance(result, (list, tuple)):
                self._problem(origin, f"{hook_name}() returned {brief(result)}, not a list of "
                                      f"{_BASE[stage].__name__}; skipped")
                continue
            for plugin in result:
                why = contract_problem(plugin, stage)
                if why is not None:
                    self._problem(origin, f"{hook_name}(): {why}; skipped")
                    continue
                yield PluginInfo(stage, plugin.name, origin.package, origin.version, plugin.summary.strip(), plugin)

    def _claims(self, stage: str, plugins: dict[str, PluginInfo]) -> None:
        """Warn about readers (writers) that take the same suffix for the same role."""
        claims: dict[tuple[str, str], list[PluginInfo]] = {}
        for info in plugins.values():
            for suffix in info.plugin.suffixes:  # type: ignore[attr-defined]
                claims.setdefault((getattr(info.plugin, "role", ""), suffix.lower()), []).append(info)
        for (role, suffix), infos in claims.items():
            if len(infos) > 1:
                who = " and ".join(f"'{i.name}' ({i.origin})" for i in infos)
                what = f"{role} files" if role else "files"
                line = f"{stage}s {who} both take '{suffix}' {what}; a pipeline must name one"
                self.problems.append(line)
                warnings.warn(line, PluginLoadWarning, stacklevel=3)

    @property
    def registry(self) -> dict[str, dict[str, PluginInfo]]:
        """``{stage: {name: PluginInfo}}`` of every loaded plugin (for an ambiguous name, the first loaded)."""
        if self._registry is None:
            reg: dict[str, dict[str, PluginInfo]] = {stage: {} for stage in STAGE_HOOKS}
            for stage in STAGE_HOOKS:
                for info in self._hook_plugins(stage):
                    if info.name in reg[stage]:
                        self._ambiguous.setdefault((stage, info.name), [reg[stage][info.name]]).append(info)
                        who = " and ".join(i.origin for i in self._ambiguous[stage, info.name])
                        line = f"two {stage} plugins are named '{info.name}' ({who}); a pipeline cannot use it"
                        self.problems.append(line)
                        warnings.warn(line, PluginLoadWarning, stacklevel=2)
                        continue
                    reg[stage][info.name] = info
                if stage in ("reader", "writer"):
                    self._claims(stage, reg[stage])
            self._registry = reg
        return self._registry

    def _skipped_hint(self) -> str:
        """``; skipped at load: ...`` naming the first package skipped, short enough (under 99 characters) to
        stay in the tail that :func:`rigslim.errors.clip` keeps of a long error line."""
        if not self.problems:
            return ""
        more = f" (+{len(self.problems) - 1}: rigslim plugins)" if len(self.problems) > 1 else ""
        return f"; skipped at load: {clip(self.problems[0], 50)}{more}"

    def info(self, stage: str, name: str) -> PluginInfo:
        """The :class:`PluginInfo` of ``name`` in ``stage``; errors name close names and skipped packages."""
        if stage not in self.registry:
            raise PluginNotFoundError(f"unknown stage '{stage}'", field="stage", fix=closest(stage, self.registry))
        plugins = self.registry[stage]
        if (stage, name) in self._ambiguous:
            who = " and ".join(i.origin for i in self._ambiguous[stage, name])
            raise DuplicatePluginError(f"two {stage} plugins are named '{name}' ({who})", field=stage,
                                       fix=f"uninstall one, or set {DISABLE_ENV} to its entry point")
        if name not in plugins:
            raise PluginNotFoundError(f"no {stage} plugin named '{name}'", field=stage,
                                      fix=closest(str(name), plugins) + self._skipped_hint())
        return plugins[name]

    def get(self, stage: str, name: str) -> Plugin[Any]:
        """The plugin called ``name`` in ``stage``; a PluginNotFoundError suggests close names."""
        return self.info(stage, name).plugin

    def by_suffix(self, stage: str, suffix: str, role: str | None = None) -> list[Any]:
        """The readers (``role`` given) or writers that take ``suffix`` files; more than one is ambiguous.

        Raises
        ------
        DuplicatePluginError
            When two plugins take the suffix (for the role): the message names both and their packages.
        """
        infos = [i for i in self.registry[stage].values() if suffix.lower() in i.plugin.suffixes  # type: ignore
                 and (role is None or getattr(i.plugin, "role", None) == role)]
        if len(infos) > 1:
            who = " and ".join(f"'{i.name}' ({i.origin})" for i in infos)
            key = "reader" if stage == "reader" else "writer"
            raise DuplicatePluginError(f"{stage}s {who} both take '{suffix}' files", field=stage,
                                       fix=f"name one with '{key}: NAME', or set {DISABLE_ENV} to an entry point")
        return [i.plugin for i in infos]

    def reader(self, name: str) -> Reader[Any]:
        """The reader called ``name`` (typed :meth:`get`)."""
        return cast("Reader[Any]", self.get("reader", name))

    def writer(self, name: str) -> Writer[Any]:
        """The writer called ``name`` (typed :meth:`get`)."""
        return cast("Writer[Any]", self.get("writer", name))

    def metric(self, name: str) -> Metric[Any]:
        """The metric called ``name`` (typed :meth:`get`)."""
        return cast("Metric[Any]", self.get("metric", name))

    def readers(self) -> dict[str, Reader[Any]]:
        return {name: cast("Reader[Any]", p) for name, p in self.plugins("reader").items()}

    def writers(self) -> dict[str, Writer[Any]]:
        return {name: cast("Writer[Any]", p) for name, p in self.plugins("writer").items()}

    def plugins(self, stage: str) -> dict[str, Plugin[Any]]:
        return {name: info.plugin for name, info in self.registry.get(stage, {}).items()}

    def infos(self) -> list[PluginInfo]:
        return [info for stage in self.registry.values() for info in stage.values()]

    def find(self, name: str) -> list[PluginInfo]:
        """Every loaded plugin called ``name``, in any stage (``k-largest`` is a selector and a solver)."""
        return [info for info in self.infos() if info.name == name]

    @contextlib.contextmanager
    def calling(self, stage: str, name: str, where: str) -> Iterator[None]:
        """Run a plugin's code: an exception that is not a :class:`RigslimError` becomes a
        :class:`PluginError` naming the plugin, its package and ``where`` (the step), chained to the original."""
        try:
            yield
        except (RigslimError, OSError):  # already one line (the CLI words an OSError with its path)
            raise
        except Exception as e:
            try:
                origin = self.info(stage, name).origin
            except RigslimError:
                origin = "?"
            builtin = origin.startswith("rigslim ")
            raise PluginError(f"{stage} '{name}' ({origin}) failed: {type(e).__name__}: {clip(str(e), 160)}",
                              field=where, fix=("a bug in rigslim: please report it" if builtin else
                                                "report it to the plugin package's authors") +
                              " (RIGSLIM_TRACEBACK=1 prints the traceback)") from e


@lru_cache(maxsize=1)
def get_host() -> PluginHost:
    """The process-wide host with every installed plugin loaded."""
    return PluginHost()


__all__ = ["DISABLE_ENV", "PluginHost", "PluginInfo", "PluginLoadWarning", "api_problem", "contract_problem",
           "disabled_from_env", "get_host"]
