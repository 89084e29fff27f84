"""Lengths given as a percentage of a diagonal or in metres: ``1``, ``"1%"``, ``"0.02m"``, ``"none"``.

Errors everywhere in rigslim are % of the world-space bounding-box diagonal of the first test frame, or
metres (glTF's world unit); this module reads such a bound from a YAML value or a command-line option.
"""

from __future__ import annotations

import re

from rigslim.errors import StepError

_LENGTH = re.compile(r"^\s*([0-9]*\.?[0-9]+(?:[eE][-+]?[0-9]+)?)\s*(%|m)?\s*$")


def parse_length_bound(value, field: str = "max_error") -> tuple[float, str] | None:
    """``(number, "%" | "m")`` of a bound: a number or ``"E%"`` is % of the diagonal, ``"Em"`` metres.

    ``None``, ``"none"`` and ``"off"`` give None (no bound). Anything else, or a bound that is not
    positive, is a :class:`rigslim.errors.StepError` naming ``field``.
    """
    if value is None or (isinstance(value, str) and value.strip().lower() in ("none", "off")):
        return None
    if isinstance(value, (int, float)) and not isinstance(value, bool):
        number, unit = float(value), "%"
    else:
        match = _LENGTH.match(str(value))
        if not match:
            raise StepError(f"{field} '{value}' is not an error bound", field=field,
                            fix="give a percentage of the diagonal (1 or '1%') or metres ('0.02m'), or 'none'")
        number, unit = float(match.group(1)), match.group(2) or "%"
    if not number > 0:
        raise StepError(f"{field} {value} is not positive", field=field,
                        fix="give a positive bound, e.g. 1 (% of the diagonal) or '0.02m', or 'none'")
    return number, "m" if unit == "m" else "%"
