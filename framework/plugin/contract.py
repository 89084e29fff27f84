"""Base classes of plugins, one per stage: the typed plugin contract.

A plugin is a plain object with a ``name``, a one-line ``summary``, a
pydantic ``Params`` model (unknown parameters are errors), and the call of
its stage. Subclass the stage's base class, then return an instance from the
matching hook in :mod:`rigslim.plugin.hookspecs`.

Each stage is defined once, by its base class: the stage name (``stage``),
the pipeline step keys that run it (``step_keys``), the hook that returns
its plugins (``hook``), the stage's call (typed), and :meth:`apply`, which
runs the call for a pipeline step and stores the result in the asset. The
tables the host and the pipeline use (:data:`STAGES`, :data:`STEP_STAGES`,
:data:`STAGE_HOOKS`) are derived from these classes.

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
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any, ClassVar, Generic, TypeVar

import numpy as np
import scipy.sparse as sp
from pydantic import BaseModel, ConfigDict, field_validator
from pydantic_core import PydanticCustomError


def _takes_bool(annotation: Any) -> bool:
    """Whether a field's type admits a bool (``bool``, ``Any``, or a union/Literal holding one)."""
    if annotation is bool or annotation is Any or annotation is object:
        return True
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Literal:
        return any(isinstance(a, bool) for a in args)
    if origin in (typing.Union, types.UnionType, typing.Annotated):
        return any(_takes_bool(a) for a in args)
    return False

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.model.handles import Handles
    from rigslim.model.hierarchy import ProgressiveHierarchy, SimplifiedLevel
    from rigslim.model.mesh import Mesh
    from rigslim.model.weights import InfluenceSets, ReducedWeights
    from rigslim.plugin.evaluation import Evaluation

#: Version of this contract (the stage classes, their calls, hooks and what the host checks; docs/plugins.md,
#: "What is stable"). A plugin package may set ``RIGSLIM_PLUGIN_API = "1.0"`` in its entry-point module: it
#: loads where the major version is the same and the minor version is at least its own.
PLUGIN_API_VERSION = "1.0"

__all__ = [
    "PLUGIN_API_VERSION", "Params", "StepContext", "Plugin", "Reader", "Writer", "WeightGenerator", "InfluenceSelector",
    "WeightSolver", "Decimation", "Decimator", "Deformer", "NormalEstimator", "Metric", "STAGES",
    "STEP_STAGES", "STAGE_HOOKS", "MetricValue", "aggregate", "field_descriptions",
]


class Params(BaseModel):
    """Base of every plugin's parameter model: unknown names are errors, and ``true``/``false``
    is not a number (pydantic would read ``k: true`` as ``k = 1``). A string literal under a field
    is its description (``rigslim plugins NAME`` prints it)."""

    # Attribute docstrings are read on demand (field_descriptions), not by pydantic at class creation: that
    # reads and tokenises the source of every plugin's Params on every start (0.15 s of each command).
    model_config = ConfigDict(extra="forbid", arbitrary_types_allowed=True)

    @field_validator("*", mode="before")
    @classmethod
    def _no_bool_as_number(cls, value, info):
        if isinstance(value, bool) and not _takes_bool(cls.model_fields[info.field_name].annotation):
            raise PydanticCustomError("bool_not_number", "a yes/no value is not valid here; give a number or name")
        return value


def field_descriptions(model: type[BaseModel]) -> dict[str, str]:
    """Each field's description: ``Field(description=...)``, else the string literal under the field in the
    class body (its attribute docstring; the nearest class of the MRO that has one), else ``""``.

    Read from the source with :mod:`ast` when asked (``rigslim plugins``, :meth:`PluginInfo.params_schema`);
    a class whose source cannot be read (built at run time, a frozen module) gives no attribute docstrings.
    """
    import ast
    import inspect
    import textwrap

    found: dict[str, str] = {}
    for cls in reversed(model.__mro__):
        if not (isinstance(cls, type) and issubclass(cls, BaseModel)) or cls is BaseModel:
            continue
        try:
            tree = ast.parse(textwrap.dedent(inspect.getsource(cls)))
        except (OSError, TypeError, SyntaxError):
            continue
        body = tree.body[0].body if tree.body and isinstance(tree.body[0], ast.ClassDef) else []
        for node, after in zip(body, body[1:], strict=False):
            if (isinstance(node, ast.AnnAssign) and isinstance(node.target, ast.Name)
                    and isinstance(after, ast.Expr) and isinstance(after.value, ast.Constant)
                    and isinstance(after.value.value, str)):
                found[node.target.id] = inspect.cleandoc(after.value.value)
    return {name: field.description or found.get(name, "") for name, field in model.model_fields.items()}


P = TypeVar("P", bound=Params)

#: A step's entry fields for the metrics document (``{"k": 4}``...).
StepEntry = dict[str, Any]


def returned(plugin: Plugin[Any], call: str, value: object, kind: type | tuple[type, ...], what: str) -> None:
    """Raise a :class:`~rigslim.errors.PluginError` when ``plugin.call()`` returned something not of ``kind``."""
    if not isinstance(value, kind):
        from rigslim.errors import PluginError, brief

        raise PluginError(f"{plugin.stage} '{plugin.name}': {call}() returned {brief(value)} "
                          f"({type(value).__name__}), not {what}")


def _no_progress(iterable: Iterable[Any], total: int | None = None, description: str = "") -> Iterable[Any]:
    return iterable


def _no_log(message: str) -> None:
    return None


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

    report: dict[str, Any] = field(default_factory=dict)
    base_dir: Path = field(default_factory=Path.cwd)
    progress: Callable[..., Iterable[Any]] = field(default=_no_progress)
    log: Callable[[str], None] = field(default=_no_log)
    document: dict[str, Any] | None = None


class Plugin(Generic[P]):
    """Common part of every plugin.

    Class attributes set by each stage's base class: ``stage`` (its name in
    ``rigslim plugins`` and error messages), ``hook`` (the hook of
    :mod:`rigslim.plugin.hookspecs` that returns its plugins) and ``step_keys`` (the
    pipeline step keys that run it). Set by each plugin: ``name``, ``summary``
    and ``Params``.
    """

    stage: ClassVar[str] = ""
    hook: ClassVar[str] = ""
    step_keys: ClassVar[tuple[str, ...]] = ()
    name: ClassVar[str] = ""
    summary: ClassVar[str] = ""
    Params: ClassVar[type[Params]] = Params

    def __init_subclass__(cls, **kwargs: Any) -> None:
        """``class MySolver(WeightSolver[MyParams])`` sets ``Params = MyParams`` (the typed idiom, docs/plugins.md)."""
        super().__init_subclass__(**kwargs)
        if "Params" in cls.__dict__:
            return
        for base in cls.__dict__.get("__orig_bases__", ()):
            args = typing.get_args(base)
            if args and isinstance(args[0], type) and issubclass(args[0], Params):
                cls.Params = args[0]
                return

    def parse_params(self, raw: dict[str, Any]) -> P:
        """Validate raw parameters (from YAML) into the plugin's ``Params`` model."""
        return self.Params(**raw)  # type: ignore[return-value]

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        """Run the stage's call for a pipeline step, store its result in ``asset``, return entry fields."""
        raise NotImplementedError(f"stage '{self.stage}' is not run by apply()")

    def __repr__(self) -> str:
        return f"<{self.stage} plugin {self.name!r}>"


class Reader(Plugin[P]):
    """Reads one input role (``mesh``, ``skeleton``, ``cage``, ``weights``, ``animation``...)."""

    stage = "reader"
    hook = "rigslim_readers"
    role: ClassVar[str] = ""
    suffixes: ClassVar[tuple[str, ...]] = ()
    #: Roles that must be read before this one (e.g. weights need the mesh).
    after: ClassVar[tuple[str, ...]] = ()

    def read(self, path: Path, asset: Asset, params: P, ctx: StepContext) -> None:
        """Read ``path`` and fill the asset's fields of this role."""
        raise NotImplementedError


class Writer(Plugin[P]):
    """Writes results to a file, atomically."""

    stage = "writer"
    hook = "rigslim_writers"
    step_keys = ("write", "report")
    suffixes: ClassVar[tuple[str, ...]] = ()

    def write(self, path: Path, asset: Asset, params: P, ctx: StepContext) -> None:
        """Write the asset's results to ``path`` (through :func:`rigslim.io.atomic_path`)."""
        raise NotImplementedError


class WeightGenerator(Plugin[P]):
    """Dense input weights from a mesh and its handles."""

    stage = "weight-generator"
    hook = "rigslim_weight_generators"
    step_keys = ("generate",)

    def generate(self, asset: Asset, params: P, ctx: StepContext) -> sp.spmatrix | np.ndarray:
        """(m, n) weights of the asset's mesh for its handles, rows summing to one."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        from rigslim.model.weights import validate_weights

        asset.require("mesh", "handles", step=f"generate: {self.name}")
        assert asset.mesh is not None and asset.handles is not None
        W = self.generate(asset, params, ctx)
        returned(self, "generate", W, (np.ndarray, sp.spmatrix, sp.sparray), "an (m, n) array or sparse matrix")
        asset.weights = validate_weights(W, asset.mesh.n_vertices, n_handles=asset.handles.n,
                                         source=f"generate: {self.name}")
        return {}


class InfluenceSelector(Plugin[P]):
    """Chooses the influence set of every vertex."""

    stage = "influence-selection"
    hook = "rigslim_influence_selectors"
    step_keys = ("select",)

    def select(self, asset: Asset, params: P, ctx: StepContext) -> InfluenceSets:
        """The k handles each vertex keeps."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        from rigslim.model.weights import InfluenceSets

        influences = self.select(asset, params, ctx)
        returned(self, "select", influences, InfluenceSets, "InfluenceSets (rigslim.model.weights)")
        asset.influences = influences
        asset.reduced = None
        return {"k": asset.influences.k}


class WeightSolver(Plugin[P]):
    """Computes reduced weights on the chosen influence sets."""

    stage = "weight-solver"
    hook = "rigslim_weight_solvers"
    step_keys = ("solve",)

    def solve(self, asset: Asset, params: P, ctx: StepContext) -> ReducedWeights:
        """Reduced weights on ``asset.influences``, rows summing to one."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        from rigslim.model.weights import ReducedWeights

        reduced = self.solve(asset, params, ctx)
        returned(self, "solve", reduced, ReducedWeights, "ReducedWeights (rigslim.model.weights)")
        asset.reduced = reduced
        asset.provenance["solver"] = self.name
        return {"k": asset.reduced.k}


@dataclass
class Decimation:
    """What a decimator returns.

    Attributes
    ----------
    levels : list of SimplifiedLevel
        The levels the step asked for, finest first.
    hierarchy : ProgressiveHierarchy or None
        Every collapse, replayable to any resolution (None when the method
        records none, e.g. a static QSlim run by another library).
    """

    levels: list[SimplifiedLevel]
    hierarchy: ProgressiveHierarchy | None = None


class Decimator(Plugin[P]):
    """Simplifies an articulated mesh."""

    stage = "articulated-decimation"
    hook = "rigslim_decimators"
    step_keys = ("decimate",)

    def decimate(self, asset: Asset, params: P, ctx: StepContext) -> Decimation:
        """Simplified levels (and their hierarchy) of the asset's skinned mesh."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        result = self.decimate(asset, params, ctx)
        returned(self, "decimate", result, Decimation, "a Decimation (rigslim.plugin)")
        asset.levels, asset.hierarchy = list(result.levels), result.hierarchy
        asset.provenance["decimator"] = self.name
        return {}


class Deformer(Plugin[P]):
    """Blends handle transforms on a back end."""

    stage = "deformer"
    hook = "rigslim_deformers"
    step_keys = ("deform",)

    def bind(self, mesh: Mesh, weights: ReducedWeights | sp.spmatrix, params: P | None = None,
             handles: Handles | None = None, ctx: StepContext | None = None) -> Callable[[np.ndarray], np.ndarray]:
        """Prepare buffers for one mesh and weights; return ``deform(T) -> (m, 3)``."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        """Evaluations after this step deform through this plugin."""
        asset.deformer, asset.deformer_params = self.name, params.model_dump(exclude_unset=True)
        return {}


class NormalEstimator(Plugin[P]):
    """Normals of a deformed mesh."""

    stage = "normal-estimator"
    hook = "rigslim_normal_estimators"
    step_keys = ("normals",)

    def estimate(self, mesh: Mesh, weights: ReducedWeights, handles: Handles | None, T: np.ndarray,
                 positions: np.ndarray, params: P, ctx: StepContext | None = None) -> np.ndarray:
        """(m, 3) unit normals of ``mesh`` deformed to ``positions`` by the transforms ``T``."""
        raise NotImplementedError

    def apply(self, asset: Asset, params: P, ctx: StepContext) -> StepEntry:
        """Evaluations after this step estimate normals through this plugin."""
        asset.normal_estimator, asset.normal_params = self.name, params.model_dump(exclude_unset=True)
        return {}


#: A metric's value: a number, or ``{"mean", "max", "per_frame"}`` (:func:`aggregate`).
MetricValue = Any


class Metric(Plugin[P]):
    """A quality measure evaluated over test poses."""

    stage = "metric"
    hook = "rigslim_metrics"
    step_keys = ("evaluate",)

    def compute(self, evaluation: Evaluation, params: P, ctx: StepContext | None = None) -> dict[str, MetricValue]:
        """``{key: value}`` over the evaluation's test frames.

        A metric of simplified levels (``evaluation.levels``) returns their values under the key
        ``levels``: a list of ``{"name": level label, key: value, ...}`` records, which the
        evaluation entry of the metrics document holds as its ``levels`` (schema version 2,
        :mod:`rigslim.runtime.metrics_document`).
        """
        raise NotImplementedError


#: Every stage's base class, in the order ``rigslim plugins`` lists them.
STAGES: tuple[type[Plugin[Any]], ...] = (Reader, Writer, WeightGenerator, InfluenceSelector, WeightSolver, Decimator,
                                         Deformer, NormalEstimator, Metric)

#: Pipeline step keys and the stage each one runs, in pipeline order (writers last).
_STEP_ORDER: tuple[type[Plugin[Any]], ...] = (*STAGES[2:], Writer)
STEP_STAGES: dict[str, str] = {key: cls.stage for cls in _STEP_ORDER for key in cls.step_keys}

#: Hook name of each stage.
STAGE_HOOKS: dict[str, str] = {cls.stage: cls.hook for cls in STAGES}


def aggregate(per_frame: Iterable[float]) -> dict[str, Any]:
    """``{"mean", "max", "per_frame"}`` of a per-frame metric (the metrics JSON form)."""
    values = [float(x) for x in per_frame]
    return {"mean": float(np.mean(values)), "max": float(np.max(values)), "per_frame": values}
