"""The plugin contract: what a plugin package implements and what the host gives it.

- :mod:`~rigslim.plugin.contract`: the base class of each stage (:class:`WeightSolver`, :class:`Metric`...),
  :class:`Params`, :class:`StepContext` and the derived tables :data:`STAGES`, :data:`STEP_STAGES`,
  :data:`STAGE_HOOKS`;
- :mod:`~rigslim.plugin.hookspecs`: one typed pluggy hook per stage, and :data:`hookimpl`;
- :mod:`~rigslim.plugin.host`: the plugin manager: loads the ``rigslim`` entry points, looks plugins up;
- :mod:`~rigslim.plugin.evaluation`: the :class:`~rigslim.plugin.evaluation.Evaluation` a metric receives.

``from rigslim.plugin import WeightSolver, Params`` is the path plugin packages use (docs/plugins.md).
"""

from rigslim.plugin.contract import (
    STAGE_HOOKS,
    STAGES,
    STEP_STAGES,
    Decimation,
    Decimator,
    Deformer,
    InfluenceSelector,
    Metric,
    MetricValue,
    NormalEstimator,
    P,
    Params,
    Plugin,
    Reader,
    StepContext,
    WeightGenerator,
    WeightSolver,
    Writer,
    aggregate,
)

__all__ = ["STAGES", "STAGE_HOOKS", "STEP_STAGES", "Decimation", "Decimator", "Deformer", "InfluenceSelector",
           "Metric", "MetricValue", "NormalEstimator", "P", "Params", "Plugin", "Reader", "StepContext",
           "WeightGenerator", "WeightSolver", "Writer", "aggregate"]
