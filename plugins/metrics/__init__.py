"""Metric plugins: quality of a reduction on test poses."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.metrics.influences import MaxInfluences
from rigslim.plugins.metrics.metro import Metro
from rigslim.plugins.metrics.normal_deviation import NormalDeviation
from rigslim.plugins.metrics.position_rms import PositionRMS
from rigslim.plugins.metrics.report_writer import ReportWriter

if TYPE_CHECKING:
    from rigslim.plugin import Metric, Writer


@hookimpl
def rigslim_metrics() -> list[Metric]:
    return [PositionRMS(), NormalDeviation(), MaxInfluences(), Metro()]


@hookimpl
def rigslim_writers() -> list[Writer]:
    return [ReportWriter()]
