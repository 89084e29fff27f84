# mypy: disable-error-code="empty-body"
"""Hook specifications: one hook per stage of a rigslim pipeline.

A plugin package implements any of these hooks (with ``@rigslim.hookimpl``)
and registers itself through the ``rigslim`` entry-point group::

    [project.entry-points.rigslim]
    mypkg = "mypkg.plugin"

Each hook returns a list of plugin objects of that stage: instances of the
matching base class in :mod:`rigslim.plugin` (name, one-line summary, a
pydantic ``Params`` model, and the stage's call). Built-in plugins are
registered the same way as third-party ones; ``rigslim plugins`` lists them.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import pluggy

if TYPE_CHECKING:
    from rigslim.plugin.contract import (
        Decimator,
        Deformer,
        InfluenceSelector,
        Metric,
        NormalEstimator,
        Reader,
        WeightGenerator,
        WeightSolver,
        Writer,
    )

__all__ = [
    "hookspec", "hookimpl", "rigslim_readers", "rigslim_writers", "rigslim_weight_generators",
    "rigslim_influence_selectors", "rigslim_weight_solvers", "rigslim_decimators", "rigslim_deformers",
    "rigslim_normal_estimators", "rigslim_metrics",
]

hookspec = pluggy.HookspecMarker("rigslim")
hookimpl = pluggy.HookimplMarker("rigslim")

# Hooks are grouped by the phase of a pipeline run they serve: inputs and outputs, the weights,
# the geometry, and the evaluation. Each returns the plugins of one stage (the stage's base class
# in rigslim.plugin names the stage, its step keys and this hook).

# -- inputs and outputs ---------------------------------------------------------------------------


@hookspec
def rigslim_readers() -> list[Reader]:
    """Readers of input files.

    Returns
    -------
    list of rigslim.plugin.Reader
        Each declares the ``role`` it fills (``mesh``, ``skeleton``, ``cage``,
        ``weights``, ``animation``, ...) and the file ``suffixes`` it reads;
        ``read(path, asset, params, ctx)`` fills the asset.
    """


@hookspec
def rigslim_writers() -> list[Writer]:
    """Writers of results (reduced weights, meshes, hierarchies, documents).

    Returns
    -------
    list of rigslim.plugin.Writer
        ``write(path, asset, params, ctx)`` writes atomically; the writer is
        chosen by the output path's suffix unless a step names one.
    """


# -- the weights ----------------------------------------------------------------------------------


@hookspec
def rigslim_weight_generators() -> list[WeightGenerator]:
    """Weight generators (``generate:`` steps): dense input weights from a mesh and handles.

    Returns
    -------
    list of rigslim.plugin.WeightGenerator
        ``generate(asset, params, ctx)`` returns an (m, n) sparse matrix whose
        rows sum to one (mean value, harmonic, bone heat, bounded biharmonic...).
    """


@hookspec
def rigslim_influence_selectors() -> list[InfluenceSelector]:
    """Influence selection (``select:`` steps): which k handles each vertex keeps.

    Returns
    -------
    list of rigslim.plugin.InfluenceSelector
        ``select(asset, params, ctx)`` returns :class:`rigslim.model.weights.InfluenceSets`.
    """


@hookspec
def rigslim_weight_solvers() -> list[WeightSolver]:
    """Weight solvers (``solve:`` steps): the values of the reduced weights.

    Returns
    -------
    list of rigslim.plugin.WeightSolver
        ``solve(asset, params, ctx)`` returns :class:`rigslim.model.weights.ReducedWeights`
        on ``asset.influences``, rows summing to one; statistics (sweeps,
        energy, gap) go into ``ctx.report``.
    """


# -- the geometry ---------------------------------------------------------------------------------


@hookspec
def rigslim_decimators() -> list[Decimator]:
    """Articulated decimation (``decimate:`` steps): simplified meshes with skin weights.

    Returns
    -------
    list of rigslim.plugin.Decimator
        ``decimate(asset, params, ctx)`` returns a :class:`rigslim.plugin.Decimation`
        (``levels``, ``hierarchy``), which the step stores as ``asset.levels`` and
        ``asset.hierarchy``.
    """


# -- the evaluation -------------------------------------------------------------------------------


@hookspec
def rigslim_deformers() -> list[Deformer]:
    """Deformers (``deform:`` steps): blend handle transforms on some back end.

    Returns
    -------
    list of rigslim.plugin.Deformer
        ``bind(mesh, weights, params, handles, ctx)`` returns a callable that maps one
        pose's (n, 3, 4) transforms to (m, 3) positions, reusing its buffers.
    """


@hookspec
def rigslim_normal_estimators() -> list[NormalEstimator]:
    """Normal estimators (``normals:`` steps): normals of a deformed mesh.

    Returns
    -------
    list of rigslim.plugin.NormalEstimator
        ``estimate(mesh, weights, handles, T, positions, params, ctx)`` returns (m, 3)
        unit normals.
    """


@hookspec
def rigslim_metrics() -> list[Metric]:
    """Metrics (``evaluate:`` steps): quality of a reduction or simplification on test poses.

    Returns
    -------
    list of rigslim.plugin.Metric
        ``compute(evaluation, params, ctx)`` returns ``{key: value}`` where a value
        is a number or ``{"mean", "max", "per_frame"}``.
    """
