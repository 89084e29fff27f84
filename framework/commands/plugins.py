"""``rigslim plugins [NAME] [--json]``: the loaded plugins, or one plugin's parameters.

Without NAME: one row per plugin (stage, name, package, version, summary), then a line per package or
plugin the host skipped and why. With NAME: every plugin of that name (``k-largest`` is a selector and a
solver), its parameters with their types, defaults, constraints and descriptions, and for readers and
writers the file suffixes they take.
"""

from __future__ import annotations

import json
import sys
import types
import typing
from typing import Any

from rigslim.errors import PluginNotFoundError, closest
from rigslim.plugin.host import PluginInfo, get_host


def type_name(annotation: Any) -> str:
    """A field's type as a user reads it: ``int``, ``float | None``, ``'auto' | 'numba'``, ``list[int]``."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return " | ".join(repr(a) for a in args)
    if origin in (typing.Union, types.UnionType):
        return " | ".join(type_name(a) for a in args)
    if origin is typing.Annotated:
        return type_name(args[0])
    if annotation is type(None):
        return "None"
    if origin is not None:
        inner = ", ".join(type_name(a) for a in args)
        return f"{getattr(origin, '__name__', str(origin))}[{inner}]" if args else getattr(origin, "__name__", "?")
    return getattr(annotation, "__name__", str(annotation).replace("typing.", ""))


def _constraints(field: Any) -> str:
    parts = []
    for item in field.metadata:
        for key in ("gt", "ge", "lt", "le", "min_length", "max_length", "multiple_of"):
            value = getattr(item, key, None)
            if value is not None:
                parts.append(f"{key}={value}")
    return ", ".join(parts)


def parameters(info: PluginInfo) -> list[dict[str, Any]]:
    """One record per parameter of the plugin's ``Params``: name, type, required, default, constraints,
    description."""
    from pydantic_core import PydanticUndefined, to_jsonable_python

    from rigslim.plugin.contract import field_descriptions

    described = field_descriptions(info.plugin.Params)
    rows = []
    for name, field in info.plugin.Params.model_fields.items():
        if field.default_factory is not None:
            default: Any = to_jsonable_python(field.default_factory(), fallback=repr)  # type: ignore[call-arg]
        elif field.default is PydanticUndefined:
            default = None
        else:
            default = to_jsonable_python(field.default, fallback=repr)
        rows.append({"name": name, "type": type_name(field.annotation), "required": field.is_required(),
                     "default": default, "constraints": _constraints(field),
                     "description": " ".join(described[name].split())})
    return rows


def describe(info: PluginInfo) -> dict[str, Any]:
    """``rigslim plugins NAME --json``: the plugin's row, its parameters and (readers, writers) suffixes."""
    out = {**info.as_dict(), "params": parameters(info)}
    if info.stage in ("reader", "writer"):
        out["suffixes"] = list(getattr(info.plugin, "suffixes", ()))
    if info.stage == "reader":
        out["role"] = getattr(info.plugin, "role", "")
    return out


def _print_one(console: Any, info: PluginInfo) -> None:
    from rich.table import Table

    console.print(f"[bold]{info.stage} '{info.name}'[/bold]  ({info.origin})  {info.summary}")
    if info.stage in ("reader", "writer"):
        role = f"role {info.plugin.role}, " if info.stage == "reader" else ""  # type: ignore[attr-defined]
        console.print(f"  {role}suffixes: {', '.join(info.plugin.suffixes) or 'none (named only)'}")  # type: ignore
    rows = parameters(info)
    if not rows:
        console.print("  no parameters")
        return
    table = Table(show_header=True, box=None, pad_edge=False)
    for col in ("parameter", "type", "default", "description"):
        table.add_column(col, overflow="fold")
    for r in rows:
        default = "(required)" if r["required"] else json.dumps(r["default"])
        kind = r["type"] + (f" ({r['constraints']})" if r["constraints"] else "")
        table.add_row(r["name"], kind, default, r["description"])
    console.print(table)


def _cmd_plugins(args: Any) -> int:
    host = get_host()
    name = getattr(args, "name", None)
    if name:
        found = sorted(host.find(name), key=lambda i: i.stage)
        if not found:
            raise PluginNotFoundError(f"no plugin named '{name}'", field="NAME",
                                      fix=closest(name, {i.name for i in host.infos()}))
        if args.json:
            print(json.dumps([describe(i) for i in found], indent=2))
            return 0
        from rich.console import Console

        console = Console()
        for n, info in enumerate(found):
            if n:
                console.print()
            _print_one(console, info)
        return 0
    infos = sorted(host.infos(), key=lambda i: (i.stage, i.name))
    if args.json:
        print(json.dumps([i.as_dict() for i in infos], indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="rigslim plugins")
    for col in ("stage", "name", "package", "version", "summary"):
        table.add_column(col, overflow="fold")
    for row in infos:
        table.add_row(row.stage, row.name, row.package, row.version, row.summary)
    Console().print(table)
    if host.disabled:
        print(f"rigslim: not loaded (RIGSLIM_DISABLE_PLUGINS): {', '.join(host.disabled)}", file=sys.stderr)
    return 0
