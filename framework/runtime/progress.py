"""Progress and notes on the terminal (rich), shared by the CLI and long plugins."""

from __future__ import annotations

import contextlib
from pathlib import Path

from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from rigslim.plugin.contract import StepContext


class Reporter:
    """Step status lines, progress bars for plugin loops, and notes.

    Parameters
    ----------
    console : rich.console.Console, optional
        Defaults to stderr; pass ``Console(quiet=True)`` to silence.
    """

    def __init__(self, console: Console | None = None):
        self.console = console or Console(stderr=True)

    @contextlib.contextmanager
    def status(self, text: str):
        if self.console.quiet or not self.console.is_terminal:
            yield
            self.console.log(f"[dim]done:[/] {text}") if not self.console.quiet else None
            return
        with self.console.status(text):
            yield
        self.console.log(f"[dim]done:[/] {text}")

    def note(self, text: str) -> None:
        self.console.print(f"[yellow]note:[/] {text}")

    def track(self, iterable, total=None, description: str = ""):
        """Iterate with a progress bar (transient; quiet consoles get none)."""
        if self.console.quiet:
            yield from iterable
            return
        if total is None and hasattr(iterable, "__len__"):
            total = len(iterable)
        columns = [TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn()]
        with Progress(*columns, console=self.console, transient=True) as progress:
            task = progress.add_task(description, total=total)
            for item in iterable:
                yield item
                progress.advance(task)

    def context(self, base_dir: Path) -> StepContext:
        return StepContext(report={}, base_dir=base_dir, progress=self.track, log=self.note)
