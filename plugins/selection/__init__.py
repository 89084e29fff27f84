"""Influence selection plugins."""

from rigslim import hookimpl
from rigslim.plugins.selection.best_fit import BestFitSelector
from rigslim.plugins.selection.k_largest import KLargestSelector


@hookimpl
def rigslim_influence_selectors():
    return [KLargestSelector(), BestFitSelector()]
