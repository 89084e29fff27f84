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

import pluggy

hookspec = pluggy.HookspecMarker("rigslim")
hookimpl = pluggy.HookimplMarker("rigslim")


@hookspec
def rigslim_readers():
    """Readers of input files.

    Returns
    -------
    list of rigslim.plugin.Reader
        Each declares the ``role`` it fills (``mesh``, ``skeleton``, ``cage``,
        ``weights``, ``animation``, ...) and the file ``suffixes`` it reads;
        ``read(path, asset, params, ctx)`` fills the asset.
    """


@hookspec
def rigslim_writers():
    """Writers of results (reduced weights, meshes, hierarchies, documents).

    Returns
    -------
    list of rigslim.plugin.Writer
        ``write(path, asset, params, ctx)`` writes atomically; the writer is
        chosen by the output path's suffix unless a step names one.
    """


@hookspec
def rigslim_weight_generators():
    """Weight generators (``generate:`` steps): dense input weights from a mesh and handles.

    Returns
    -------
    list of rigslim.plugin.WeightGenerator
        ``generate(asset, params, ctx)`` returns an (m, n) sparse matrix whose
        rows sum to one (mean value, harmonic, bone heat, bounded biharmonic...).
    """


@hookspec
def rigslim_influence_selectors():
    """Influence selection (``select:`` steps): which k handles each vertex keeps.

    Returns
    -------
    list of rigslim.plugin.InfluenceSelector
        ``select(asset, params, ctx)`` returns :class:`rigslim.weights.InfluenceSets`.
    """


@hookspec
def rigslim_weight_solvers():
    """Weight solvers (``solve:`` steps): the values of the reduced weights.

    Returns
    -------
    list of rigslim.plugin.WeightSolver
        ``solve(asset, params, ctx)`` returns :class:`rigslim.weights.ReducedWeights`
        on ``asset.influences``, rows summing to one; statistics (sweeps,
        energy, gap) go into ``ctx.report``.
    """


@hookspec
def rigslim_decimators():
    """Articulated decimation (``decimate:`` steps): simplified meshes with skin weights.

    Returns
    -------
    list of rigslim.plugin.Decimator
        ``decimate(asset, params, ctx)`` stores its hierarchy/levels in
        ``asset.extras``.
    """


@hookspec
def rigslim_deformers():
    """Deformers (``deform:`` steps): blend handle transforms on some back end.

    Returns
    -------
    list of rigslim.plugin.Deformer
        ``bind(mesh, weights, params)`` returns a callable that maps one pose's
        (n, 3, 4) transforms to (m, 3) positions, reusing its buffers.
    """


@hookspec
def rigslim_normal_estimators():
    """Normal estimators (``normals:`` steps): normals of a deformed mesh.

    Returns
    -------
    list of rigslim.plugin.NormalEstimator
        ``estimate(mesh, weights, handles, T, positions, params)`` returns (m, 3)
        unit normals.
    """


@hookspec
def rigslim_metrics():
    """Metrics (``evaluate:`` steps): quality of a reduction or simplification on test poses.

    Returns
    -------
    list of rigslim.plugin.Metric
        ``compute(evaluation, params)`` returns ``{key: value}`` where a value
        is a number or ``{"mean", "max", "per_frame"}``.
    """
