"""Base classes of plugins, one per stage.

A plugin is a plain object with a ``name``, a one-line ``summary``, a
pydantic ``Params`` model (unknown parameters are errors), and the call of
its stage. Subclass the stage's base class, then return an instance from the
matching hook in :mod:`rigslim.hookspecs`.

Example
-------
::

    from rigslim import hookimpl
    from rigslim.plugin import InfluenceSelector, Params

    class LargestAbs(InfluenceSelector):
        name = "largest-abs"
        summary = "keep the k weights of largest magnitude"

        class Params(Params):
            k: int

        def select(self, asset, params, ctx):
            ...

    @hookimpl
    def rigslim_influence_selectors():
        return [LargestAbs()]
"""

from __future__ import annotations

import types
import typing
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, field_validator
from pydantic_core import PydanticCustomError


def _takes_bool(annotation) -> bool:
    """Whether a field's type admits a bool (``bool``, ``Any``, or a union/Literal holding one)."""
    if annotation is bool or annotation is Any or annotation is object:
        return True
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return any(isinstance(a, bool) for a in args)
    if origin in (typing.Union, types.UnionType, typing.Annotated):
        return any(_takes_bool(a) for a in args)
    return False


class Params(BaseModel):
    """Base of every plugin's parameter model: unknown names are errors, and ``true``/``false``
    is not a number (pydantic would read ``k: true`` as ``k = 1``)."""

    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_as_number(cls, value, info):
        if isinstance(value, bool) and not _takes_bool(cls.model_fields[info.field_name].annotation):
            raise PydanticCustomError("bool_not_number", "a yes/no value is not valid here; give a number or name")
        return value


@dataclass
class StepContext:
    """What a step may use besides the asset.

    Attributes
    ----------
    report : dict
        Free-form statistics of the step, written to the metrics JSON under
        the step (e.g. the ``solver`` section: sweeps, energy, gap).
    base_dir : Path
        Folder of the pipeline file; relative paths resolve against it.
    progress : callable
        ``progress(iterable, total=None, description="")`` wraps a loop in a
        rich progress bar (or passes it through when quiet).
    log : callable
        ``log(message)`` prints a note under the step.
    document : dict or None
        The metrics document as it stands before this step (set for
        ``write``/``report`` steps, so that report writers see the evaluations).
    """

    report: dict = field(default_factory=dict)
    base_dir: Path = field(default_factory=Path.cwd)
    progress: Callable = field(default=lambda it, total=None, description="": it)
    log: Callable[[str], None] = field(default=lambda msg: None)
    document: dict | None = None


class Plugin:
    """Common part of every plugin."""

    stage: ClassVar[str] = ""
    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    Params: ClassVar[type[BaseModel]] = Params

    def parse_params(self, raw: dict) -> BaseModel:
        return self.Params(**raw)

    def __repr__(self) -> str:
        return f"<{self.stage} plugin {self.name!r}>"


class Reader(Plugin):
    """Reads one input role (``mesh``, ``skeleton``, ``cage``, ``weights``, ``animation``...)."""

    stage = "reader"
    role: ClassVar[str] = ""
    suffixes: ClassVar[tuple[str, ...]] = ()
    #: Roles that must be read before this one (e.g. weights need the mesh).
    after: ClassVar[tuple[str, ...]] = ()

    def read(self, path: Path, asset, params, ctx: StepContext) -> None:
        raise NotImplementedError


class Writer(Plugin):
    """Writes results to a file, atomically."""

    stage = "writer"
    suffixes: ClassVar[tuple[str, ...]] = ()

    def write(self, path: Path, asset, params, ctx: StepContext) -> None:
        raise NotImplementedError


class WeightGenerator(Plugin):
    """Dense input weights from a mesh and its handles."""

    stage = "weight-generator"

    def generate(self, asset, params, ctx: StepContext):
        raise NotImplementedError


class InfluenceSelector(Plugin):
    """Chooses the influence set of every vertex."""

    stage = "influence-selection"

    def select(self, asset, params, ctx: StepContext):
        raise NotImplementedError


class WeightSolver(Plugin):
    """Computes reduced weights on the chosen influence sets."""

    stage = "weight-solver"

    def solve(self, asset, params, ctx: StepContext):
        raise NotImplementedError


class Decimator(Plugin):
    """Simplifies an articulated mesh."""

    stage = "articulated-decimation"

    def decimate(self, asset, params, ctx: StepContext) -> None:
        raise NotImplementedError


class Deformer(Plugin):
    """Blends handle transforms on a back end."""

    stage = "deformer"

    def bind(self, mesh, weights, params) -> Callable[[np.ndarray], np.ndarray]:
        """Prepare buffers for one mesh and weights; return ``deform(T) -> (m, 3)``."""
        raise NotImplementedError


class NormalEstimator(Plugin):
    """Normals of a deformed mesh."""

    stage = "normal-estimator"

    def estimate(self, mesh, weights, handles, T: np.ndarray, positions: np.ndarray, params) -> np.ndarray:
        raise NotImplementedError


class Metric(Plugin):
    """A quality measure evaluated over test poses."""

    stage = "metric"

    def compute(self, evaluation, params) -> dict[str, Any]:
        raise NotImplementedError


#: Pipeline step keys and the stage each one runs.
STEP_STAGES = {
    "generate": "weight-generator",
    "select": "influence-selection",
    "solve": "weight-solver",
    "decimate": "articulated-decimation",
    "deform": "deformer",
    "normals": "normal-estimator",
    "evaluate": "metric",
    "write": "writer",
    "report": "writer",
}

#: Hook name of each stage.
STAGE_HOOKS = {
    "reader": "rigslim_readers",
    "writer": "rigslim_writers",
    "weight-generator": "rigslim_weight_generators",
    "influence-selection": "rigslim_influence_selectors",
    "weight-solver": "rigslim_weight_solvers",
    "articulated-decimation": "rigslim_decimators",
    "deformer": "rigslim_deformers",
    "normal-estimator": "rigslim_normal_estimators",
    "metric": "rigslim_metrics",
}


def aggregate(per_frame) -> dict:
    """``{"mean", "max", "per_frame"}`` of a per-frame metric (the metrics JSON form)."""
    values = [float(x) for x in per_frame]
    return {"mean": float(np.mean(values)), "max": float(np.max(values)), "per_frame": values}
