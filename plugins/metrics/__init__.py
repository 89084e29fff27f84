"""Metric plugins: quality of a reduction on test poses."""

from rigslim import hookimpl
from rigslim.plugins.metrics.influences import MaxInfluences
from rigslim.plugins.metrics.metro import Metro
from rigslim.plugins.metrics.normal_deviation import NormalDeviation
from rigslim.plugins.metrics.position_rms import PositionRMS
from rigslim.plugins.metrics.report_writer import ReportWriter


@hookimpl
def rigslim_metrics():
    return [PositionRMS(), NormalDeviation(), MaxInfluences(), Metro()]


@hookimpl
def rigslim_writers():
    return [ReportWriter()]
