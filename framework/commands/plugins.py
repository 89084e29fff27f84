"""``rigslim plugins``: the loaded plugins."""

from __future__ import annotations

import json


def _cmd_plugins(args) -> int:
    from rigslim.plugin.host import get_host

    infos = sorted(get_host().infos(), key=lambda i: (i.stage, i.name))
    if args.json:
        print(json.dumps([i.as_dict() for i in infos], indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="rigslim plugins")
    for col in ("stage", "name", "package", "version", "summary"):
        table.add_column(col, overflow="fold")
    for i in infos:
        table.add_row(i.stage, i.name, i.package, i.version, i.summary)
    Console().print(table)
    return 0
