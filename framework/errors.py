"""Errors a user can cause, with messages that say where and how to fix them.

Every error that bad input can trigger is a :class:`RigslimError`. Its message
is one line naming the file, the field and the fix; the CLI prints exactly
that line and exits with status 2. Programming errors stay ordinary Python
exceptions (and tracebacks).
"""

from __future__ import annotations

import difflib
from pathlib import Path


class RigslimError(Exception):
    """Base class of every user-facing error.

    Parameters
    ----------
    problem : str
        What is wrong, e.g. ``"weights have 6033 rows but the mesh has 6034 vertices"``.
    source : str or Path, optional
        The file (or pipeline) the problem was found in.
    field : str, optional
        The field, key or section inside ``source``.
    fix : str, optional
        What the user can do about it.
    """

    def __init__(self, problem: str, *, source: str | Path | None = None,
                 field: str | None = None, fix: str | None = None):
        self.problem = problem
        self.source = None if source is None else str(source)
        self.field = field
        self.fix = fix
        super().__init__(self.one_line())

    def one_line(self) -> str:
        """The message as printed by the CLI: ``source: field: problem; fix``."""
        parts = []
        if self.source:
            parts.append(self.source)
        if self.field:
            parts.append(self.field)
        head = ": ".join(parts)
        text = f"{head}: {self.problem}" if head else self.problem
        if self.fix:
            text += f" (fix: {self.fix})"
        return " ".join(text.split())


class InputError(RigslimError):
    """A file is missing, unreadable, malformed or inconsistent with the rest."""


class PipelineError(RigslimError):
    """A pipeline document is malformed or asks for something impossible."""


class PluginNotFoundError(PipelineError):
    """A stage or plugin name that no loaded plugin provides."""


class StepError(RigslimError):
    """A step cannot run on what the pipeline produced so far."""


def closest(name: str, choices, n: int = 3) -> str:
    """Phrase a 'did you mean' hint for ``name`` among ``choices``.

    Returns
    -------
    str
        ``"did you mean 'x'?"`` for close matches, otherwise the valid names.
    """
    choices = sorted(set(choices))
    near = difflib.get_close_matches(name, choices, n=n, cutoff=0.5)
    if near:
        return "did you mean " + " or ".join(f"'{c}'" for c in near) + "?"
    return "valid names: " + ", ".join(choices) if choices else "none are available"
