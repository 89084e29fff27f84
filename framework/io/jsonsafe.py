"""Strict JSON for the documents rigslim writes.

Python's :func:`json.dumps` writes ``NaN`` and ``Infinity``, which are not
JSON (RFC 8259) and which most parsers reject. :func:`dumps_strict` writes
every non-finite number as ``null`` instead and lists where it did so in the
document's ``notes``, so a reader sees both that a value is missing and why.
"""

from __future__ import annotations

import json
import math

import numpy as np


def finite_copy(obj, where: str = "", found: list[str] | None = None):
    """A copy of ``obj`` with non-finite floats replaced by None; their JSON paths appended to ``found``."""
    if found is None:
        found = []
    if isinstance(obj, dict):
        return {k: finite_copy(v, f"{where}.{k}" if where else str(k), found) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [finite_copy(v, f"{where}[{i}]", found) for i, v in enumerate(obj)]
    if isinstance(obj, np.ndarray):
        return finite_copy(obj.tolist(), where, found)
    if isinstance(obj, (float, np.floating)):
        if not math.isfinite(float(obj)):
            found.append(where or "value")
            return None
        return float(obj)
    if isinstance(obj, np.integer):
        return int(obj)
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def dumps_strict(document: dict, **kwargs) -> str:
    """``json.dumps`` of ``document`` with NaN/inf as ``null`` and a note naming where (``allow_nan=False``)."""
    found: list[str] = []
    clean = finite_copy(document, "", found)
    if found and isinstance(clean, dict):
        shown = ", ".join(found[:5]) + (f" and {len(found) - 5} more" if len(found) > 5 else "")
        note = (f"{len(found)} values were not finite (NaN or infinite; e.g. an animation with huge "
                f"transforms) and are written as null: {shown}")
        clean["notes"] = list(clean.get("notes") or []) + [note]
    return json.dumps(clean, allow_nan=False, **kwargs)
