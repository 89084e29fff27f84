"""The Python API: the plugin registry, pipelines, and one function per common job.

Everything here is re-exported by the :mod:`rigslim` package (see its ``__all__``)
and documented with runnable examples in docs/python.md.

- :func:`registry`: every loaded plugin, by stage, with its ``Params`` schema;
- :class:`Pipeline`: a pipeline from a YAML file or a mapping; ``run()`` returns the
  metrics document and the asset;
- :func:`reduce_weights`: k weights per vertex from a mesh, its weights and example poses
  ([P10]; docs/solvers.md);
- :func:`simplify`: simplified levels with skin weights ([S09]; docs/simplification.md).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError, PipelineError, brief
from rigslim.model.asset import Asset
from rigslim.model.handles import Handles
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit, Poses
from rigslim.model.weights import ReducedWeights, validate_weights
from rigslim.plugin.contract import Decimation, Decimator, StepContext
from rigslim.plugin.host import PluginHost, PluginInfo, get_host
from rigslim.runtime.clips import (
    DEFAULT_EXAMPLE_COUNT,
    EXAMPLE_CAP,
    pose_descriptors,
    sample_clip_frames,
    thin_examples,
)
from rigslim.runtime.document import PipelineDoc, Step, check_params, load_pipeline
from rigslim.runtime.run import RunResult, run_pipeline

__all__ = ["Pipeline", "reduce_weights", "registry", "simplify"]


def registry(host: PluginHost | None = None) -> dict[str, dict[str, PluginInfo]]:
    """Every loaded plugin, by stage and name.

    Parameters
    ----------
    host : PluginHost, optional
        Defaults to the process-wide host (built-ins and installed plugin packages).

    Returns
    -------
    dict
        ``{stage: {name: PluginInfo}}``; a :class:`rigslim.plugin.host.PluginInfo` has ``stage``,
        ``name``, ``package``, ``version``, ``summary``, the ``plugin`` object, and
        ``params_schema`` (the JSON schema of its ``Params``).
    """
    host = host or get_host()
    return {stage: dict(plugins) for stage, plugins in host.registry.items()}


class Pipeline:
    """A parsed, validated pipeline, ready to run.

    Build one with :meth:`from_yaml`; the document is checked (stages, plugin names,
    parameters) before anything runs, with the same errors as ``rigslim run``.
    """

    def __init__(self, doc: PipelineDoc, steps: list[Step], source: Path, raw: dict[str, Any] | None,
                 overrides: Sequence[str], host: PluginHost):
        self.doc = doc
        self.steps = steps
        self.source = source
        self._raw = raw
        self._overrides = list(overrides)
        self._host = host

    @classmethod
    def from_yaml(cls, spec: str | Path | Mapping[str, Any], *, base_dir: str | Path | None = None,
                  overrides: Sequence[str] = (), host: PluginHost | None = None) -> Pipeline:
        """A pipeline from a YAML file, or from a mapping with the same keys.

        Parameters
        ----------
        spec : path or mapping
            A pipeline file (docs/pipelines.md), or the document itself as a ``dict``
            (``{"inputs": ..., "poses": ..., "steps": [...]}``).
        base_dir : path, optional
            For a mapping: the folder relative input and output paths resolve against
            (default: the current directory). A file's paths resolve against its folder.
        overrides : list of str
            ``"STEP.PARAM=VALUE"`` settings, as ``rigslim run --set``.
        """
        host = host or get_host()
        if isinstance(overrides, (str, bytes)) or not all(isinstance(o, str) for o in overrides):
            raise PipelineError(f"overrides must be a list of strings (got {brief(overrides)})", field="overrides",
                                fix="give e.g. overrides=['select.k=6'], as rigslim run --set")
        if isinstance(spec, Mapping):
            raw: dict[str, Any] | None = dict(spec)
            source = Path(base_dir if base_dir is not None else Path.cwd()).resolve() / "<python>"
        elif isinstance(spec, (str, Path)):
            raw, source = None, Path(spec)
        else:
            raise PipelineError(f"spec is neither a path nor a mapping (got {brief(spec)})", field="spec",
                                fix="give a pipeline file's path or the document as a dict")
        doc, steps = load_pipeline(source, list(overrides), host, raw=raw)
        return cls(doc, steps, source, raw, overrides, host)

    def run(self, *, metrics_path: str | Path | None = None, console: Any = None) -> RunResult:
        """Run every step.

        Parameters
        ----------
        metrics_path : path, optional
            Also write the metrics document there (atomically, at the end).
        console : rich.console.Console, optional
            Where progress goes; default: none (quiet).

        Returns
        -------
        RunResult
            ``document`` (the metrics document, docs/pipelines.md) and ``asset`` (mesh,
            weights, ``reduced``, ``levels``, ``hierarchy``...).
        """
        if console is None:
            from rich.console import Console

            console = Console(stderr=True, quiet=True)
        return run_pipeline(self.source, overrides=self._overrides, metrics_path=metrics_path, host=self._host,
                            console=console, raw=self._raw)


def _real_array(value: Any, source: str, field: str, what: str, fix: str) -> np.ndarray:
    """``value`` as an array of real numbers, or one :class:`InputError` naming the argument.

    Strings, ``None``, objects, ragged nesting (numpy's ``ValueError``) and complex numbers (which
    numpy would cast to real in silence, dropping the imaginary part) are refused here, before any
    numpy, scipy or pymeshlab code sees them.
    """
    try:
        arr = np.asarray(value)
    except (TypeError, ValueError):  # ragged nesting: "inhomogeneous shape"
        raise InputError(f"{what} are nested lists of different lengths", source=source, field=field,
                         fix=fix) from None
    if arr.dtype.kind not in "biuf":
        got = "None" if value is None else f"{arr.dtype} values" if arr.dtype.kind != "O" else type(value).__name__
        raise InputError(f"{what} are not real numbers (got {got})", source=source, field=field, fix=fix)
    return arr


def _mesh_arg(mesh: Any) -> Mesh:
    """The ``mesh`` argument as a :class:`Mesh` with at least one vertex (shapes, indices, finiteness checked)."""
    if not isinstance(mesh, Mesh):
        if not (isinstance(mesh, tuple) and len(mesh) == 2):
            raise InputError("mesh must be a rigslim.model.mesh.Mesh or a (V, F) pair", field="mesh",
                             fix="pass Mesh(V, F) or (V, F)")
        V = _real_array(mesh[0], "mesh", "vertices", "vertex positions", "give V as an (m, 3) array of floats")
        F = _real_array(mesh[1], "mesh", "faces", "face indices", "give F as an (f, 3) array of vertex indices")
        if F.dtype.kind == "f" and not (np.isfinite(F).all() and np.array_equal(F, np.round(F))):
            raise InputError("face indices are not whole numbers (they would be truncated)", source="mesh",
                             field="faces", fix="give F as an (f, 3) array of integer vertex indices")
        mesh = Mesh(V, F, source="mesh")
    if mesh.n_vertices == 0:
        raise InputError("the mesh has no vertices", source="mesh", field="vertices",
                         fix="give V as an (m, 3) array with m >= 1 (and the weights' m rows)")
    return mesh


def _weights_arg(weights: Any, mesh: Mesh) -> sp.csr_matrix:
    """The ``weights`` argument as checked (m, n) CSR weights: 2-D, real, finite, one row per vertex."""
    fix = "give an (m, n) array or sparse matrix: one row per vertex, one column per handle"
    if sp.issparse(weights):
        if weights.dtype.kind not in "biuf":
            raise InputError(f"weights are not real numbers (got {weights.dtype} values)", source="weights",
                             field="values", fix=fix)
    else:
        weights = _real_array(weights, "weights", "values", "weights", fix)
        if weights.ndim != 2:
            raise InputError(f"weights have shape {weights.shape}, expected (m, n) with m = {mesh.n_vertices}",
                             source="weights", field="shape", fix=fix)
        weights = sp.csr_matrix(weights.astype(np.float64))
    return validate_weights(weights, mesh.n_vertices, source="weights")


def _as_poses(poses, n: int, field: str) -> Poses:
    if not isinstance(poses, Poses):
        arr = _real_array(poses, field, "transforms", f"{field}", "give (p, n, 3, 4) transforms, one per handle")
        poses = Poses(arr.astype(np.float64), source=field)
    if not len(poses):
        raise InputError(f"{field} hold no pose", field=field,
                         fix="give at least one (n, 3, 4) pose, or poses=None for the methods that need none")
    if poses.n_handles != n:
        raise InputError(f"{field} have {poses.n_handles} handles, the weights {n}", field=field,
                         fix="give (p, n, 3, 4) transforms, one per handle")
    return poses


def _asset(mesh: Mesh | tuple[np.ndarray, np.ndarray], weights: Any, poses: Any, handles: Handles | None,
           validation: Any = None, examples: int | None = None) -> Asset:
    """The asset of an API call: every array argument checked here, once (shapes, real numbers, finiteness),
    so that bad input is one :class:`InputError` naming the argument, never numpy's or a plugin's exception."""
    mesh = _mesh_arg(mesh)
    W = _weights_arg(weights, mesh)
    n = W.shape[1]
    if handles is None:
        handles = Handles("skeleton", [f"handle{i}" for i in range(n)])
    elif handles.n != n:
        raise InputError(f"{handles.n} handles for weights of {n} columns", field="handles",
                         fix="give one handle per weight column")
    asset = Asset(mesh=mesh, handles=handles, weights=W)
    if isinstance(poses, (list, tuple)):
        if validation is not None:
            raise InputError("validation poses are given and poses is a list of clips", field="validation",
                             fix="give clips (held-out frames are taken from them) or validation poses, not both")
        clips = [_as_poses(c, n, f"poses[{i}]") for i, c in enumerate(poses)]
        if not clips:
            raise InputError("poses is an empty list of clips", field="poses", fix="give at least one clip")
        if examples is not None and (isinstance(examples, bool) or not isinstance(examples, (int, np.integer))
                                     or examples < 1):
            raise PipelineError(f"input should be a whole number >= 1 (got {brief(examples)})",
                                field="reduce_weights.examples", fix="give the example poses in all, e.g. examples=24")
        count = DEFAULT_EXAMPLE_COUNT if examples is None else examples
        sampled = thin_examples(sample_clip_frames([len(c) for c in clips], count),
                                lambda c, frames: pose_descriptors(asset, clips[c].T[frames]), EXAMPLE_CAP * count)
        starts = np.cumsum([0] + [len(c) for c in clips])
        ex = [int(starts[i] + f) for i, (e, _, _) in enumerate(sampled) for f in e]
        val = [int(starts[i] + f) for i, (_, v, _) in enumerate(sampled) for f in v]
        te = [int(starts[i] + f) for i, (_, _, t) in enumerate(sampled) for f in t]
        asset.poses = Poses(np.concatenate([c.T for c in clips], axis=0), source="poses")
        asset.split = FrameSplit(ex, te, [], validation=val, segments=[
            {"clip": f"clip {i}", "start": int(starts[i]), "frames": len(c)} for i, c in enumerate(clips)])
    elif poses is not None:
        poses = _as_poses(poses, n, "poses")
        frames = [int(f) for f in np.asarray(poses.frames)]
        if validation is None:
            # every pose given is an example pose (fitting); measuring is the caller's choice
            asset.poses, asset.split = poses, FrameSplit(frames, [], [])
        else:
            held = _as_poses(validation, n, "validation")
            asset.poses = Poses(np.concatenate([poses.T, held.T], axis=0), source="poses + validation")
            asset.split = FrameSplit(list(range(len(poses))), [], [],
                                     validation=list(range(len(poses), len(poses) + len(held))))
    return asset


def _selector(select: str, select_params: Mapping[str, Any] | None) -> tuple[str, dict[str, Any]]:
    """``"NAME"`` or ``"NAME:BY"`` (``by`` of best-fit) and more parameters -> (plugin name, parameters)."""
    name, _, by = select.partition(":")
    params = dict(select_params or {})
    if by:
        params["by"] = by
    return name, params


#: The default selection of :func:`reduce_weights` and ``rigslim reduce``: best-fit by error.
DEFAULT_SELECT = "best-fit:error"


def reduce_weights(mesh: Mesh | tuple[np.ndarray, np.ndarray], weights: Any, poses: Any, *, k: int = 4,
                   select: str | None = None, solve: str = "geometric", validation: Any = None,
                   examples: int | None = None, select_params: Mapping[str, Any] | None = None,
                   handles: Handles | None = None, report: dict[str, Any] | None = None,
                   host: PluginHost | None = None, **params: Any) -> ReducedWeights:
    """Reduce weights to at most k per vertex ([P10]), as a ``select`` then a ``solve`` step would.

    By default the influence sets are best-fit by error (each vertex keeps the k influences whose
    re-solved fit of the example poses has the least error) and the weights geometric
    (``min sum_p ||sum_l w_l T_l^p [v; 1] - y_v^p||^2`` per vertex, ``w >= 0``, ``sum w = 1``);
    with held-out poses (``validation``, or clips), a vertex whose weights do worse there than the
    k largest input weights renormalised takes those (the guard); vertices with at most k input
    influences (all of them when k >= n) keep their weights exactly.

    Parameters
    ----------
    mesh : Mesh or (V, F)
        The rest mesh, V (m, 3) and F (f, 3).
    weights : (m, n) array or sparse matrix
        The input weights, rows summing to one.
    poses : Poses or (p, n, 3, 4) array, list of those, or None
        Example poses (every one is used for fitting); a list: clips, from which ``examples``
        example poses are sampled evenly and held-out poses of each clip kept for the guard
        (as ``rigslim reduce`` does); ``None`` for the methods that need none (``k-largest``, ``smooth``).
    k : int
        Influences per vertex.
    select : str, optional
        Influence-selection plugin, ``"NAME"`` or ``"NAME:BY"`` (``"best-fit:error"``,
        ``"best-fit:weight"``, ``"k-largest"``: the baseline). Default: ``"best-fit:error"``,
        ``"k-largest"`` without poses.
    solve : str
        Weight-solver plugin (``rigslim.registry()["weight-solver"]`` lists them).
    validation : Poses or (q, n, 3, 4) array, optional
        Held-out poses for the guard (with ``poses`` one array).
    examples : int, optional
        With clips: example poses in all (default 24).
    select_params : mapping, optional
        More parameters of the selector (e.g. ``{"swaps": 1}``).
    handles : Handles, optional
        Default: n skeleton handles; pass ``Handles.from_cage(cage)`` for cage coordinates.
    report : dict, optional
        Filled with the solver's statistics (sweeps, energy, ``fallback_vertices``...), and
        ``select`` / ``solve`` (the plugins) and ``select_report`` (the selector's).
    **params
        More parameters of the solver (e.g. ``nonnegative=True``, ``guard="off"``).

    Returns
    -------
    ReducedWeights
        (m, k) indices and values, rows summing to one.
    """
    host = host or get_host()
    asset = _asset(mesh, weights, poses, handles, validation, examples)
    name, sparams = _selector(select or (DEFAULT_SELECT if poses is not None else "k-largest"), select_params)
    selector = host.get("influence-selection", name)
    sctx = StepContext()
    selector.apply(asset, check_params(selector, {"k": k, **sparams}, None, "reduce_weights"), sctx)
    solver = host.get("weight-solver", solve)
    ctx = StepContext()
    solver.apply(asset, check_params(solver, params, None, "reduce_weights"), ctx)
    if report is not None:
        report.update(ctx.report)
        report.update(select=name, select_params=sparams, solve=solve, select_report=dict(sctx.report))
    assert asset.reduced is not None
    return asset.reduced


def simplify(mesh: Mesh | tuple[np.ndarray, np.ndarray], weights: Any, poses: Poses | np.ndarray, *,
             targets: Sequence[float] = (0.1,), method: str = "quartic", handles: Handles | None = None,
             report: dict[str, Any] | None = None, host: PluginHost | None = None, **params: Any) -> Decimation:
    """Simplify a skinned mesh into levels whose vertices keep fitted skin weights ([S09]).

    Parameters
    ----------
    mesh : Mesh or (V, F)
    weights : (m, n) array or sparse matrix
    poses : Poses or (p, n, 3, 4) array
        Example poses the new vertices' positions and weights are fitted to.
    targets : sequence of float
        Levels: a number below 1 is a fraction of the faces, else a face count.
    method : str
        An articulated-decimation plugin (``quartic``, ``mohr-gleicher``,
        ``decoro-rusinkiewicz``, ``static-qslim``).
    handles, report, host
        As in :func:`reduce_weights`.
    **params
        More parameters of the decimator (e.g. ``max_bones=4``).

    Returns
    -------
    Decimation
        ``levels`` (finest first; each has ``mesh``, ``weights``, ``label``...) and
        ``hierarchy`` (every collapse, or None).
    """
    host = host or get_host()
    asset = _asset(mesh, weights, poses, handles)
    assert asset.mesh is not None
    if asset.mesh.n_faces == 0:
        raise InputError("the mesh has no faces: nothing to simplify", source="mesh", field="faces",
                         fix="give F as an (f, 3) array of triangles, f >= 1")
    decimator = host.get("articulated-decimation", method)
    assert isinstance(decimator, Decimator)
    ctx = StepContext()
    if isinstance(targets, (int, float)):
        targets = [targets]
    result = decimator.decimate(asset, check_params(decimator, {"targets": list(targets), **params}, None,
                                                    "simplify"), ctx)
    if report is not None:
        report.update(ctx.report)
    return result
