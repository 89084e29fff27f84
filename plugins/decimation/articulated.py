"""Articulated decimation plugins on the shared collapse loop: ``quartic``, ``mohr-gleicher``, ``decoro-rusinkiewicz``.

Each builds a :class:`rigslim.model.hierarchy.ProgressiveHierarchy` of the rest
mesh with per-vertex skin weights, fitted to the asset's example poses, and
extracts the levels the step asks for (``targets``: fractions of the input
faces or face counts; ``error_targets``: collapse-error thresholds). Results
are returned as a :class:`rigslim.plugin.Decimation` (``asset.hierarchy`` and ``asset.levels``).
"""

from __future__ import annotations

from typing import Annotated, Literal

import numpy as np
import scipy.sparse as sp
from pydantic import Field, model_validator

from rigslim.errors import StepError
from rigslim.model.asset import Asset
from rigslim.plugin import Decimation, Decimator, Params, StepContext
from rigslim.plugins.decimation.levels import SOURCE, choose_levels, collapse_distances, parse_max_error, target_name
from rigslim.plugins.decimation.twins import back_faces, with_back_faces


class AdaptiveTarget(Params):
    """A level refined by region ([S09] fig. 3): a small error budget inside a ball, a large one outside."""

    center: tuple[float, float, float]
    radius: float = Field(gt=0)
    error_inside: float
    error_outside: float
    label: str | None = None

    def budget(self, V: np.ndarray) -> np.ndarray:
        inside = np.linalg.norm(V - np.asarray(self.center), axis=1) <= self.radius
        return np.where(inside, self.error_inside, self.error_outside)


#: A face target: a fraction of the faces (below 1) or a face count, finite and positive.
FaceTarget = Annotated[float, Field(gt=0, allow_inf_nan=False)]
#: A non-negative finite number (an error threshold, an attribute weight).
NonNegative = Annotated[float, Field(ge=0, allow_inf_nan=False)]


class DecimationParams(Params):
    """Parameters every articulated decimator shares."""

    targets: list[FaceTarget] = Field(default_factory=list)
    """Levels to extract: a number below 1 is a fraction of the input faces, else a face count."""
    error_targets: list[NonNegative] = Field(default_factory=list)
    """Levels to extract by collapse error: the longest prefix of collapses with errors at most this."""
    adaptive_targets: list[AdaptiveTarget] = Field(default_factory=list)
    """Levels by region: per-vertex error budgets (``hierarchy.adaptive``) from a ball around a point."""
    min_faces: int | None = Field(default=None, ge=1)
    """Build the hierarchy down to this many faces (default: the smallest target, or 70)."""
    max_bones: int | None = Field(default=None, ge=1)
    """At most this many non-zero weights per vertex at every level."""
    keep_boundary: bool = True
    """Border vertices (on an edge with one face) never leave the border: they collapse only along it,
    onto a neighbouring border point, and free vertices collapse onto them (false: borders are ordinary)."""
    border_collapses: bool = True
    """With ``keep_boundary``: border vertices may collapse along their border (false fixes every one)."""
    border_weight: float = Field(default=1.0, ge=0.0)
    """With ``keep_boundary``: weight of the planes through each border edge, perpendicular to its face
    (:func:`rigslim.plugins.decimation.quadrics.border_quadrics`), relative to the faces' area weights."""
    normalised_error: bool = True
    """Rank collapses by the error over the merged planes' total area, a mean squared distance
    (meshoptimizer), so that small parts are not collapsed first; false: [S09]'s area-weighted error."""
    source_distance: bool = False
    """With ``normalised_error``: add to each collapse's cost the source-side error, the area-weighted mean
    squared distance of the original vertices it removes from its new faces over the example poses
    (:func:`rigslim.plugins.decimation.compiled.source_error`), so that thin protrusions, whose planes hardly
    see the collapse, are not removed early. On for ``quartic`` (off for the baselines):
    on the suite it met 26 of 30 levels against 22 without (docs/simplification.md)."""
    face_distance: bool = False
    """With ``source_distance``: also add the face-side error, the mean squared distance of the new faces'
    rest-pose centroids and new edges' midpoints from the source faces of the originals their corners stand for
    (:func:`rigslim.plugins.decimation.compiled.face_error`), so that no new face spreads within its plane
    over empty space (a grip's opening covered). On for ``quartic`` (docs/simplification.md, "The face-side
    error")."""
    attribute_weights: dict[str, NonNegative] = Field(default_factory=lambda: dict(ATTRIBUTE_WEIGHTS))
    """For a mesh read from glTF: weight of each vertex attribute's displacement term in the error, by name
    (``TEXCOORD_0``) or family (``TEXCOORD``, ``COLOR``, ``NORMAL``, ``TANGENT``); see :func:`attribute_term`."""
    seams: Literal["move", "lock", "free"] = "move"
    """For a mesh read from glTF, how UV/colour seams and material (primitive) boundaries
    (:func:`rigslim.io.gltf.seams.seam_vertices`) simplify: ``move`` (default) lets seam vertices and seam
    corners collapse like the others, held to their seams by seam planes (``seam_weight``; the level writer
    gives each side of every seam, UV slits included, its own attributes); ``lock`` keeps every seam vertex
    where it is, or lets it collapse only along its seam (``seams_collapse_along``), seam corners fixed;
    ``free`` ignores seams in the error."""
    seam_weight: float = Field(default=0.3, ge=0.0)
    """With ``seams: move``: weight of the seam planes (through each seam edge, perpendicular to its faces;
    :func:`rigslim.plugins.decimation.quadrics.border_quadrics`) relative to the faces' area weights."""
    seams_collapse_along: bool = True
    """With ``seams: lock``: seam vertices may still collapse with each other along their seam (both
    sides keep their own attributes; :func:`rigslim.io.gltf.seams.seam_structure`); false keeps every seam vertex."""
    prune_parts: bool = True
    """A face target that the last collapse leaves short (every part at a tetrahedron or held by the guards)
    is reached by removing whole parts, those adding the least error first (small and near the rest), within
    ``max_error`` (:mod:`rigslim.plugins.decimation.prune`); false: such a level stops where the collapses
    stop."""
    max_error: float | str | None = None
    """Error bound of every level (:mod:`rigslim.plugins.decimation.levels`): a number or ``"E%"`` is % of
    the bounding-box diagonal of the first test pose, ``"Em"`` metres (world units); ``none`` (default) turns
    it off.
    A level whose next collapse would move the surface farther than this (meshoptimizer's normalised
    quadric error, over every example pose) stops there, short of its target. With ``joint_budget`` the
    joints' displacement counts too: a level keeps more joints than its budget rather than pass the bound."""
    joint_budget: float | list[float] | None = None
    """Joints each level's skin may list (:mod:`rigslim.plugins.decimation.joint_budget`): a count (24), a
    fraction of the skin's joints (0.5), or one per face target; the others' vertices are re-fitted."""
    keep_joints: str | None = None
    """With ``joint_budget``: a regular expression; joints whose name it finds are never dropped."""
    joint_choice: Literal["leaf-first", "global", "best"] = "global"
    """With ``joint_budget``: greedy removal of leaf joints only, of any joint, or the better of both."""
    joint_weights: Literal["refit", "parent"] = "refit"
    """With ``joint_budget``: re-fit the dropped joints' vertices over the example poses, or give their
    weights to the nearest kept ancestor (Unreal's way; a baseline)."""
    min_normal_cos: float = Field(default=0.0, ge=-1.0, le=1.0)
    """Refuse collapses that turn a surviving face's normal by more than arccos(this), in any pose."""
    area_weighted: bool = True
    """Weight each face's plane in the quadrics by its area (the usual QSlim refinement)."""
    backend: Literal["numpy", "numba"] = "numba"
    """``numba``: the compiled collapse loop and per-edge solves; ``numpy``: the batched numpy reference."""

    lock_seams: bool | None = None
    """The earlier spelling of ``seams``: true is ``seams: lock``, false ``seams: free``."""

    @model_validator(mode="after")
    def _lock_seams(self):
        """``lock_seams: true|false`` sets ``seams: lock|free``; giving both is refused."""
        if self.lock_seams is not None:
            if "seams" in self.model_fields_set:
                raise ValueError("give seams or lock_seams (its earlier spelling), not both")
            object.__setattr__(self, "seams", "lock" if self.lock_seams else "free")
        return self


def target_faces(targets, n_faces: int) -> list[int]:
    """Face counts of targets (fractions below 1, counts otherwise)."""
    out = []
    for t in targets:
        if t <= 0:
            raise StepError(f"target {t} is not positive", field="targets",
                            fix="give fractions like 0.1 or face counts like 2000")
        out.append(max(1, int(round(t * n_faces))) if t < 1 else int(t))
    return out


def target_label(method: str, t: float, faces: int) -> str:
    return target_name(method, t, faces)


def error_bound(asset, max_error) -> float | None:
    """``max_error`` in the units of the positions: % of the first test pose's bounding-box diagonal, or metres."""
    from rigslim.numerics.blend import linear_blend

    parsed = parse_max_error(max_error)
    if parsed is None:
        return None
    value, unit = parsed
    if unit == "m":
        return value
    T = asset.test_poses().T
    X = linear_blend(asset.mesh.V, asset.weights, T[0]) if len(T) else asset.mesh.V
    return value / 100.0 * float(np.linalg.norm(X.max(axis=0) - X.min(axis=0)))


def target_record(c, bound: float | None, hier=None) -> dict:
    """The report's record of one face target: what was asked, what was reached, and why it stopped.

    A target that stopped with no valid collapse left also gets ``parts`` (connected parts of the level's
    faces) and ``minimal_parts`` (those with at most 4 faces: a closed part at a tetrahedron, which no collapse
    may shrink further without removing the part) when ``hier`` is given; one reached by removing parts
    (``parts_removed``) gets ``faces_collapsed``, the faces where the collapses ended.
    """
    out = {"target": c.target, "target_faces": c.target_faces, "faces": c.faces, "label": c.label,
           "error": c.error, "max_error": bound, "stopped": c.stopped, "same_as": c.same_as,
           "parts_removed": c.parts_removed, "removal_distance": c.removal_distance}
    if hier is not None and c.parts_removed:
        out["faces_collapsed"] = hier.faces_after(c.collapses)
        out["removed_early"] = c.collapses < hier.n_collapses
    if hier is not None and c.stopped == "no collapse" and c.same_as is None and not c.parts_removed:
        out["parts"], out["minimal_parts"] = part_sizes(hier.prefix(c.collapses).mesh.F)
    return out


def part_sizes(F: np.ndarray) -> tuple[int, int]:
    """``(parts, minimal)``: connected parts of the faces ``F`` (sharing a vertex), and how many of them have
    at most 4 faces."""
    from rigslim.plugins.decimation.prune import face_parts

    n, part = face_parts(F)
    return n, int((np.bincount(part, minlength=n) <= 4).sum())


def limited_weights(A, max_bones: int | None) -> np.ndarray:
    """Dense (m, n) weights, each row cut to its ``max_bones`` largest entries and renormalised."""
    from rigslim.plugins.decimation.quadrics import bone_limit

    W = sp.csr_matrix(A).toarray()
    if max_bones is not None and W.shape[1] > max_bones:
        W, _ = bone_limit(W, W != 0, max_bones)
    return W


#: Default attribute weights (relative to the geometric error; see :func:`attribute_term`): off. Measured on the
#: bundled characters (docs/gltf.md), the fixed-value term costs geometry where the new vertices' attributes
#: are resampled anyway (the tube: Hausdorff RMS x40 at lambda 0.01) and helps UVs little (the assimp character at
#: 25 %: UV RMS -19 % at lambda 1 for +2 % geometric error).
ATTRIBUTE_WEIGHTS: dict[str, float] = {"TEXCOORD": 0.0, "COLOR": 0.0, "NORMAL": 0.0, "TANGENT": 0.0}


def attribute_term(asset, weights: dict[str, float], Q, T, X):
    """Append the glTF attribute quadrics to the per-pose quadrics as one pose with identity bone transforms.

    Returns ``(Q, T, X)`` unchanged when the mesh did not come from glTF or every weight is 0.

    Notes
    -----
    :func:`rigslim.io.gltf.seams.attribute_quadrics` gives per vertex
    ``sum lambda_a area (s_a(p) - s_a,i)^2`` (attribute units). It is scaled by
    ``P D^2`` (P example poses, D the first example pose's bounding-box
    diagonal), so that an attribute displacement of 1 (a whole texture) costs
    as much as moving a point by D in every pose; then appended as pose
    ``P + 1`` whose bone transforms are all ``[I | 0]``. Since a vertex's
    weights sum to one, its position in that pose is its rest position
    whatever its weights: the quartic error gains ``E_attr(v)`` and the weight
    step is unchanged, in both decimation backends.
    """
    from rigslim.io.gltf.seams import attribute_quadrics

    source = gltf_source(asset)
    if source is None or not any(w > 0 for w in weights.values()):
        return Q, T, X
    Qa = attribute_quadrics(source, weights)
    if not Qa.any():
        return Q, T, X
    D = float(np.linalg.norm(X[0].max(axis=0) - X[0].min(axis=0)))
    Qa *= len(T) * D * D
    ident = np.zeros((1,) + T.shape[1:])
    ident[..., :3, :3] = np.eye(3)
    return (np.concatenate([Q, Qa[:, None]], axis=1), np.concatenate([T, ident]),
            np.concatenate([X, asset.mesh.V[None]]))


def given_seams(asset) -> tuple[np.ndarray, np.ndarray] | None:
    """``asset.extras["seams"] = (locked, charts)`` (any input, e.g. Blender's arrays: one locked flag per
    vertex, one chart label per face), checked against the mesh; None when not given."""
    given = asset.extras.get("seams")
    if given is None:
        return None
    locked, charts = np.asarray(given[0], bool), np.asarray(given[1], np.int64)
    if locked.shape != (asset.mesh.n_vertices,) or charts.shape != (asset.mesh.n_faces,):
        raise StepError("extras['seams'] does not match the mesh", field="seams",
                        fix="give (locked, charts) with one flag per vertex and one chart per face")
    return locked, charts


def gltf_source(asset):
    """The glTF skin the asset's mesh was read from, or None (other inputs, or a step replaced the mesh)."""
    source = asset.extras.get("gltf")
    return source if source is not None and source.mesh is asset.mesh else None


def seam_lock(asset, along: bool = True, mode: str = "lock"):
    """Seam and material-boundary vertices to lock (``seams: lock``), and how they may collapse.

    They come from :func:`given_seams` (the along-seam vertices follow from the arrays), else from the
    glTF file the mesh was read from.

    Returns ``(locked, seams)``: ``locked`` (m,) bool, the seam vertices, and ``seams`` ``(along, charts)``
    for :func:`rigslim.plugins.decimation.collapse.simplify` (None when ``along`` is false); ``(None, None)``
    for another ``mode`` (``move``: :func:`seam_charts` gives the seam planes instead; ``free``) or input.
    """
    from rigslim.io.gltf.seams import seam_structure, seams_along

    if mode != "lock":
        return None, None
    given = given_seams(asset)
    if given is not None:
        locked, charts = given
        return locked, ((seams_along(asset.mesh.F, charts, locked), charts) if along else None)
    source = gltf_source(asset)
    if source is None:
        return None, None
    locked, may, charts = seam_structure(source)
    return locked, ((may, charts) if along else None)


def seam_charts(asset) -> np.ndarray | None:
    """(f,) chart of every face (UV/material charts) from :func:`given_seams` or the glTF file the mesh was
    read from (:func:`rigslim.io.gltf.seams.face_charts`); None for other inputs."""
    from rigslim.io.gltf.seams import face_charts

    given = given_seams(asset)
    if given is not None:
        return given[1]
    source = gltf_source(asset)
    return face_charts(source) if source is not None else None


class ArticulatedDecimator(Decimator):
    """Shared driver: quadrics of the example poses, the collapse loop, level extraction."""

    Params = DecimationParams

    def model(self, Q, W, T, params):
        raise NotImplementedError

    def decimate(self, asset: Asset, params: DecimationParams, ctx: StepContext) -> Decimation:
        """Quadrics of the example poses, the collapse loop, the levels; each phase timed in the report."""
        asset.require("mesh", "weights", "poses", "split", step=f"decimate: {self.name}")
        assert asset.mesh is not None  # require() raised otherwise
        if asset.mesh.n_faces == 0:
            raise StepError("the mesh has no triangles (its primitives are points or lines): nothing to simplify",
                            field="faces", fix="give a file whose primitives are triangles")
        clock = PhaseClock()
        faces = target_faces(params.targets, asset.mesh.n_faces)
        min_faces = params.min_faces if params.min_faces is not None else (min(faces) if faces else 70)
        with clock("quadrics"):
            back = back_faces(asset.mesh.F)            # double-sided sheets: simplified once (twins.py)
            Q, W, T, X, model = self.setup(asset, params, back)
        with clock("seams"):
            locked, seams = seam_lock(asset, params.seams_collapse_along, params.seams)
            if seams is not None:
                seams = (seams[0], seams[1][~back])
        with clock("collapses"):
            hier = self.collapse(asset, params, W, T, X, model, min_faces, locked, seams, ctx, back)
        with clock("levels"):
            bound = error_bound(asset, params.max_error)
            distances = (np.sqrt(np.maximum(hier.errors, 0.0)) if params.normalised_error
                         else collapse_distances(hier, Q[:, :len(asset.example_poses().T)]))
            choices = choose_levels(hier, list(params.targets), faces, distances, bound, self.name)
            levels = self.levels(asset, params, hier, choices)
            if params.prune_parts:
                from rigslim.plugins.decimation.prune import early_removals, prune_levels

                choices, levels = early_removals(hier, choices, levels, T[:len(asset.example_poses().T)], distances,
                                                 bound, self.name)
                choices, levels = prune_levels(hier, choices, levels, T[:len(asset.example_poses().T)], bound,
                                               self.name)
        if params.joint_budget is not None:
            with clock("joints"):
                from rigslim.plugins.decimation.joint_budget import step_joint_budgets

                levels = step_joint_budgets(asset, params, levels, choices, faces, ctx, bound)
        self.report(asset, params, ctx, hier, levels, choices, bound, locked, seams, len(T))
        ctx.report["seconds"] = clock.seconds
        if hier.faces_after(hier.n_collapses) > min_faces:
            ctx.log(f"stopped at {hier.faces_after(hier.n_collapses)} faces: no valid collapse is left")
        return Decimation(levels, hier)

    def setup(self, asset: Asset, params: DecimationParams, back: np.ndarray | None = None):
        """Per-pose quadrics (and the attribute term), bone-limited weights, the edge cost model; ``back``:
        faces left out of the loop (:func:`rigslim.plugins.decimation.twins.back_faces`)."""
        from rigslim.plugins.decimation.quadrics import border_quadrics, per_pose_quadrics

        mesh = asset.mesh
        assert mesh is not None  # decimate() required it
        front = slice(None) if back is None else ~back
        F = mesh.F[front]
        T = asset.example_poses().T
        Q, X = per_pose_quadrics(mesh.V, F, asset.weights, T, params.area_weighted)
        border = params.border_weight if params.keep_boundary else 0.0
        charts = seam_charts(asset) if params.seams == "move" and params.seam_weight > 0 else None
        if border > 0 or charts is not None:
            Q = Q + border_quadrics(X, F, border, None if charts is None else charts[front], params.seam_weight)
        Q, T, X = attribute_term(asset, params.attribute_weights, Q, T, X)
        W = limited_weights(asset.weights, params.max_bones)
        return Q, W, T, X, self.model(Q, W, T, params)

    def collapse(self, asset, params, W, T, X, model, min_faces, locked, seams, ctx, back=None):
        """The greedy collapse loop (:func:`rigslim.plugins.decimation.collapse.simplify`) on the faces but the
        ``back`` ones, which :func:`rigslim.plugins.decimation.twins.with_back_faces` then puts back: the loop
        runs until the front faces alone meet ``min_faces`` less the back faces, so that all of them do."""
        from rigslim.plugins.decimation.collapse import keep_loop_stats, simplify

        mesh = asset.mesh
        nb = 0 if back is None else int(back.sum())
        F = mesh.F if not nb else mesh.F[~back]
        hier = simplify(mesh.V, F, W, T, X, model, min_faces=max(min_faces - nb, 1),
                        keep_boundary=params.keep_boundary, border_collapses=params.border_collapses,
                        min_normal_cos=params.min_normal_cos, progress=ctx.progress, method=self.name,
                        params=params.model_dump(), backend=params.backend, locked=locked, seams=seams,
                        normalised=params.normalised_error, source_distance=params.source_distance,
                        face_distance=params.face_distance)
        return keep_loop_stats(hier, with_back_faces(hier, mesh.F, back)) if nb else hier

    def levels(self, asset, params, hier, choices) -> list:
        """The face-target levels (:func:`choose_levels`), error-target and adaptive levels, finest first."""
        levels = [hier.prefix(c.collapses, c.label) for c in choices if c.same_as is None]
        levels += [hier.at_error(e, f"{self.name}-err{e:g}") for e in params.error_targets]
        levels += [hier.adaptive(a.budget(asset.mesh.V), a.label or f"{self.name}-adaptive{i + 1}")
                   for i, a in enumerate(params.adaptive_targets)]
        levels.sort(key=lambda lv: -lv.n_faces)
        return levels

    def report(self, asset, params, ctx, hier, levels, choices, bound, locked, seams, n_poses) -> None:
        """The step report: seams, targets (what was asked and reached), the loop's counts, the levels."""
        ctx.report["seams"] = params.seams
        if locked is not None:
            ctx.report["locked_seam_vertices"] = int(locked.sum())
            ctx.report["seam_vertices_collapsing_along"] = int(seams[0].sum()) if seams is not None else 0
        ctx.report["targets"] = [target_record(c, bound, hier) for c in choices]
        from rigslim.plugins.decimation.collapse import loop_stats

        stats = loop_stats(hier)
        if stats:
            ctx.report["loop"] = stats
        for c in choices:
            if c.parts_removed and c.same_as is None:
                when = ("after the last collapse" if c.collapses == hier.n_collapses else
                        f"after {c.collapses} collapses, for less error than collapsing on")
                ctx.log(f"level {c.label}: {c.parts_removed} parts removed whole {when} "
                        f"({c.faces} faces, target {c.target_faces}; the farthest "
                        f"{c.removal_distance:.3g} from the rest of the surface)")
            if c.stopped == "max_error" and c.same_as is None and c.parts_removed:
                ctx.log(f"level {c.label} stopped at {c.faces} faces (target {c.target_faces}): removing the next "
                        f"part exceeds max_error {params.max_error}")
            elif c.stopped == "max_error" and c.same_as is None:
                ctx.log(f"level {c.label} stopped at {c.faces} faces (target {c.target_faces}): the next collapse "
                        f"exceeds max_error {params.max_error}")
            elif c.same_as == SOURCE:
                why = {"max_error": f"the first collapse exceeds max_error {params.max_error}",
                       "no collapse": "no collapse was valid"}.get(c.stopped or "", "the source's faces meet it")
                ctx.log(f"target {c.target:g} ({c.target_faces} faces) ends at the source's {c.faces} faces ({why}): "
                        f"no level")
            elif c.same_as is not None:
                ctx.log(f"target {c.target:g} ({c.target_faces} faces) ends at the same {c.faces} faces as "
                        f"level {c.same_as}: no level of its own")
        ctx.report.update({
            "collapses": hier.n_collapses, "input_faces": asset.mesh.n_faces,
            "final_faces": hier.faces_after(hier.n_collapses), "example_poses": len(asset.example_poses().T),
            "attribute_term": n_poses > len(asset.example_poses().T),
            "levels": [{"label": lv.label, "faces": lv.n_faces, "vertices": lv.n_vertices,
                        "max_bones": int(lv.weights.influence_counts().max()), "error": lv.error}
                       for lv in levels]})


class PhaseClock:
    """Wall seconds of named phases: ``with clock("name"): ...``, then ``clock.seconds``."""

    def __init__(self):
        self.seconds: dict[str, float] = {}

    def __call__(self, name: str):
        from contextlib import contextmanager
        from time import perf_counter

        @contextmanager
        def phase():
            t0 = perf_counter()
            try:
                yield
            finally:
                self.seconds[name] = self.seconds.get(name, 0.0) + perf_counter() - t0

        return phase()


class QuarticParams(DecimationParams):
    iterations: int = Field(default=5, ge=1)
    """Most alternations of the position and weight steps per edge."""
    tol: float = Field(default=1e-4, ge=0.0)
    """Stop alternating once the error falls by less than this (relative)."""
    endpoint_candidates: bool = False
    """Keep an endpoint (its position and weights) when it has a lower quartic error than the alternation's result."""
    nonnegative: bool | None = None
    """Weight steps keep every weight >= 0 (glTF and engines require it). Default: on when the
    input weights have no negative entry; ``false`` is [S09]'s unconstrained step."""
    source_distance: bool = True
    """As for every decimator (:class:`DecimationParams`), but on by default: thin protrusions (horns, elbow
    flaps, tails, fins) survive the far levels; ``false`` ranks by the quadrics alone."""
    face_distance: bool = True
    """As for every decimator (:class:`DecimationParams`), but on by default: new faces stay on the source."""


class Quartic(ArticulatedDecimator):
    """[S09]: quartic error, alternating position/weight solves restricted to the endpoints' bones."""

    name = "quartic"
    summary = "[S09] edge collapses optimising rest position and skin weights for every example pose"
    Params = QuarticParams

    def model(self, Q, W, T, params):
        from rigslim.plugins.decimation.models import QuarticModel

        nonnegative = params.nonnegative if params.nonnegative is not None else bool((W >= 0).all())
        return QuarticModel(Q, iterations=params.iterations, tol=params.tol, max_bones=params.max_bones,
                            endpoints=params.endpoint_candidates, nonnegative=nonnegative, backend=params.backend)


class MohrGleicher(ArticulatedDecimator):
    """Mohr & Gleicher 2003: summed per-pose quadrics, the better endpoint is kept."""

    name = "mohr-gleicher"
    summary = "Mohr-Gleicher 2003: summed per-pose quadrics, collapse to the better endpoint"

    def model(self, Q, W, T, params):
        from rigslim.plugins.decimation.models import MohrGleicherModel

        return MohrGleicherModel(Q, max_bones=params.max_bones, backend=params.backend)


class DeCoroRusinkiewicz(ArticulatedDecimator):
    """DeCoro & Rusinkiewicz 2005: rest-frame quadrics, optimal position, distance-blended weights."""

    name = "decoro-rusinkiewicz"
    summary = "DeCoro-Rusinkiewicz 2005: pose quadrics pulled to the rest frame, weights blended by distance"

    def model(self, Q, W, T, params):
        from rigslim.plugins.decimation.models import DeCoroModel

        return DeCoroModel(Q, W, T, max_bones=params.max_bones, backend=params.backend)
