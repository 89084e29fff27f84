"""Errors a user can cause, with messages that say where and how to fix them.

Every error that bad input can trigger is a :class:`RigslimError`. Its message
is one line naming the file, the field and the fix, at most
:data:`MAX_LINE` characters (values inside it are shortened by :func:`brief`);
the CLI prints exactly that line and exits with status 2. Programming errors stay ordinary Python
exceptions (and tracebacks).
"""

from __future__ import annotations

import difflib
import reprlib
from pathlib import Path

#: Longest error line the CLI prints (characters); longer messages are clipped in the middle.
MAX_LINE = 300
#: Longest rendering of one offending value inside a message (characters).
MAX_VALUE = 80


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
        self.problem = clip(problem, 4 * MAX_LINE)
        self.source = None if source is None else str(source)
        self.field = None if field is None else clip(field, MAX_LINE // 2)
        self.fix = None if fix is None else clip(fix, MAX_LINE)
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
        return clip(" ".join(text.split()), MAX_LINE)


def clip(text: str, limit: int = MAX_LINE) -> str:
    """``text`` shortened to at most ``limit`` characters by cutting its middle (``" ... "``).

    The start (file, field) and the end (the fix) of a message are what a
    reader needs, so the middle goes.
    """
    text = str(text)
    if len(text) <= limit:
        return text
    keep = limit - 5
    head = keep * 2 // 3
    return text[:head] + " ... " + text[len(text) - (keep - head):]


_repr = reprlib.Repr()
_repr.maxstring = MAX_VALUE
_repr.maxother = MAX_VALUE
_repr.maxlist = _repr.maxtuple = _repr.maxdict = _repr.maxset = 6
_repr.maxlevel = 3


def brief(value) -> str:
    """A short ``repr`` of a value for messages: nested containers and long strings are elided,
    so an alias bomb or a megabyte string never makes a megabyte message."""
    try:
        return clip(_repr.repr(value), MAX_VALUE)
    except Exception:  # a hostile object whose repr fails
        return f"<{type(value).__name__}>"


class InputError(RigslimError):
    """A file is missing, unreadable, malformed or inconsistent with the rest."""


class PipelineError(RigslimError):
    """A pipeline document is malformed or asks for something impossible."""


class PluginNotFoundError(PipelineError):
    """A stage or plugin name that no loaded plugin provides."""


class DuplicatePluginError(PipelineError):
    """Two loaded plugins answer to one name, or take one file suffix: rigslim never picks one silently."""


class StepError(RigslimError):
    """A step cannot run on what the pipeline produced so far."""


class PluginError(StepError):
    """A plugin's code failed, or returned what its stage does not take; the message names the plugin and package."""


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
