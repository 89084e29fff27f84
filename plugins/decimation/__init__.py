"""Articulated decimation plugins ([S09] quartic and the baselines) and the writers of their results."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim import hookimpl
from rigslim.plugins.decimation.articulated import DeCoroRusinkiewicz, MohrGleicher, Quartic
from rigslim.plugins.decimation.static_qslim import StaticQSlim
from rigslim.plugins.decimation.writers import WRITERS

if TYPE_CHECKING:
    from rigslim.plugin import Decimator, Writer


@hookimpl
def rigslim_decimators() -> list[Decimator]:
    return [Quartic(), MohrGleicher(), DeCoroRusinkiewicz(), StaticQSlim()]


@hookimpl
def rigslim_writers() -> list[Writer]:
    return [cls() for cls in WRITERS]
