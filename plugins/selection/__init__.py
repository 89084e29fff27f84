"""Influence selection plugins."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.selection.best_fit import BestFitSelector
from rigslim.plugins.selection.k_largest import KLargestSelector

if TYPE_CHECKING:
    from rigslim.plugin import InfluenceSelector


@hookimpl
def rigslim_influence_selectors() -> list[InfluenceSelector]:
    return [KLargestSelector(), BestFitSelector()]
