"""Articulated decimation plugins ([S09] quartic and the baselines) and the writers of their results."""

from rigslim import hookimpl
from rigslim.plugins.decimation.articulated import DeCoroRusinkiewicz, MohrGleicher, Quartic
from rigslim.plugins.decimation.static_qslim import StaticQSlim
from rigslim.plugins.decimation.writers import WRITERS


@hookimpl
def rigslim_decimators():
    return [Quartic(), MohrGleicher(), DeCoroRusinkiewicz(), StaticQSlim()]


@hookimpl
def rigslim_writers():
    return [cls() for cls in WRITERS]
