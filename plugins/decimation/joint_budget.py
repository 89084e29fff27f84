"""Joint budgets per level of detail: the joints a level's skin keeps, chosen by the animated error.

``joint_budget:`` of a ``decimate:`` step (``rigslim lod --max-joints 40,24,12``) caps the joints a
level's skin lists, so a far level uploads and blends fewer joint matrices per draw. At each level
the joints to drop are chosen by the example-pose error of the level's vertices once their weights
no longer use them (:mod:`rigslim.plugins.decimation.joint_refit`: re-fitted by the skin's weight
solver on the joints kept, under the level's bone limit, or given to the parent joint):

    E(K) = sum_v a_v sum_p || y'_v^p(K) - y_v^p ||^2,

``a_v`` the vertex's Voronoi area, ``y`` the level's own deformation with every joint. Two
greedy choices remove one joint at a time, the one whose removal raises ``E`` least, until the level
uses at most the budget:

- ``leaf-first``: only joints with no used joint below them (fingers before hands, as InstaLOD's
  leaf-bone weld and Unreal's removal of bone chains from the tip);
- ``global``: any joint of the skeleton (a twist or spine joint between two kept ones, too).

``best`` runs both and keeps the lower ``E`` (docs/results/joint_budget.md measures them). The
costs of candidates whose vertices the last removal did not touch are kept (lazy greedy).

Joints the file needs (:mod:`rigslim.io.gltf.joints`: attached nodes and meshes, joints of other
skins, ``keep_joints``) are never dropped; a budget below their count stops there and says so.

The step's error bound (``max_error``, :mod:`rigslim.plugins.decimation.levels`) holds for the joints too.
A removal moves vertex ``v`` by ``d_v = sqrt(e_v / P)``, its RMS displacement over the P example poses
(``e_v``: :func:`rigslim.plugins.decimation.joint_refit.row_errors`), so a level whose collapses reached
the geometric error ``d_f`` reaches ``d_f + max_v d_v`` without those joints. Only removals that keep it
within the bound are candidates; where none is left before the budget, the level keeps more joints than
its budget (``met: false``, ``stopped: "max_error"``, and ``next_error``: the least the next removal would
reach).
Joints without weight at a level cost nothing: its skin leaves them out anyway. Dropped joints stay
in the node hierarchy and the animation is unchanged; only the level's weights (and, in the glTF
writer, its skin: :mod:`rigslim.io.gltf.level_skins`) change.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from rigslim.errors import StepError
from rigslim.plugins.decimation.joint_refit import (
    LevelTarget,
    level_weights,
    parent_rows,
    refit_rows,
    row_errors,
)

__all__ = ["CHOICES", "DEFAULT_CHOICE", "BudgetChoice", "apply_joint_budgets", "budget_counts",
           "choose_joints", "level_target", "required_joints", "step_joint_budgets"]

#: Joint choices (module docstring).
CHOICES = ("leaf-first", "global", "best")
#: The default, from docs/results/joint_budget.md.
DEFAULT_CHOICE = "global"


@dataclass
class BudgetChoice:
    """One level's joint choice: the weights, the joints used, what was dropped and the example-pose error."""

    indices: np.ndarray
    values: np.ndarray
    errors: np.ndarray
    used: np.ndarray
    dropped: list[int]
    strategy: str
    method: str
    met: bool
    energy: float
    stopped: str | None = None
    """``"max_error"`` when the error bound stopped the removals before the budget, else None."""
    next_error: float | None = None
    """With ``stopped``: the least largest displacement ``max_v d_v`` one more removal would have reached."""

    def displacement(self, target: LevelTarget) -> float:
        """Largest per-vertex RMS example-pose displacement ``max_v sqrt(e_v / P)`` (metres for glTF)."""
        return float(np.sqrt(self.errors.max(initial=0.0) / max(len(target.T), 1)))

    def rms(self, target: LevelTarget) -> float:
        """Area-weighted RMS example-pose error, ``sqrt(E / (P sum_v a_v))`` (metres for glTF)."""
        P = max(len(target.T), 1)
        return float(np.sqrt(self.energy / (P * max(float(target.area.sum()), 1e-300))))


def budget_counts(budget, n_levels: int, n_joints: int) -> list[int | None]:
    """One joint count per level from ``joint_budget`` (a count, a fraction of the joints, or a list of them)."""
    if budget is None:
        return [None] * n_levels
    values = list(budget) if isinstance(budget, (list, tuple)) else [budget] * n_levels
    if len(values) != n_levels:
        raise StepError(f"joint_budget has {len(values)} entries for {n_levels} levels", field="joint_budget",
                        fix="give one joint count per face target, or one for every level")
    out: list[int | None] = []
    for v in values:
        if v is None:
            out.append(None)
            continue
        if isinstance(v, bool) or not v > 0:
            raise StepError(f"joint_budget {v!r} is not a positive count or fraction", field="joint_budget",
                            fix="give joint counts like 24, or fractions of the skin's joints like 0.5")
        count = int(v) if v >= 1 else max(1, int(round(v * n_joints)))
        if v >= 1 and v != int(v):
            raise StepError(f"joint_budget {v} is neither a whole count nor a fraction below 1",
                            field="joint_budget", fix="give e.g. 24 or 0.5")
        out.append(count)
    return out


def level_target(asset, level, k: int) -> LevelTarget:
    """The re-fit problem of one level: its rest mesh and weights, the asset's example poses and joint tree."""
    handles = asset.handles
    mesh = level.mesh
    area = np.asarray(mesh.massmatrix.diagonal(), float) if mesh.n_faces else np.ones(mesh.n_vertices)
    area = np.maximum(area, 1e-3 * float(area.mean()) if area.size and area.mean() > 0 else 1.0)
    joints = np.asarray(handles.joints, float)
    if handles.bones is not None:             # a bone's position is its parent joint's (glTF: the joint itself)
        joints = joints[np.asarray(handles.bones)[:, 0]]
    return LevelTarget(mesh.V, level.weights.to_sparse(), asset.example_poses().T, np.asarray(handles.parents),
                       joints, int(k), area, adjacency=mesh.adjacency)


class _Greedy:
    """One greedy removal (module docstring) on one level."""

    def __init__(self, target: LevelTarget, required: np.ndarray, strategy: str, method: str, solver, handles,
                 limit: float | None = None):
        self.t, self.required, self.strategy, self.method = target, required, strategy, method
        # the bound on max_v d_v as one on e_v = P d_v^2
        self.limit = None if limit is None else max(len(target.T), 1) * max(float(limit), 0.0) ** 2
        self.solver, self.handles = solver, handles
        W = target.W.tocsr()
        m, k = len(target.V), target.k
        counts = np.diff(W.indptr)
        self.idx = np.zeros((m, max(k, int(counts.max(initial=1)))), np.int64)
        self.val = np.zeros(self.idx.shape)
        slot = np.arange(W.nnz) - np.repeat(W.indptr[:-1], counts)
        rows = np.repeat(np.arange(m), counts)
        self.idx[rows, slot], self.val[rows, slot] = W.indices, W.data
        self.err = np.zeros(m)
        self.kept = self.used()
        self.dropped: list[int] = []
        self.cache: dict[int, tuple] = {}

    def used(self) -> np.ndarray:
        u = np.zeros(self.t.n, bool)
        u[np.unique(self.idx[self.val > 0])] = True
        return u

    def affected(self, j: int) -> np.ndarray:
        """Rows whose target or current weights use joint j."""
        return np.flatnonzero(self.t.support[:, j] | ((self.idx == j) & (self.val > 0)).any(axis=1))

    def candidates(self) -> list[int]:
        used = self.used() & self.kept
        free = used & ~self.required
        if self.strategy == "global":
            return [int(j) for j in np.flatnonzero(free)]
        below = np.zeros(self.t.n, bool)            # a used joint somewhere below j
        for j in np.flatnonzero(used):
            a = int(self.t.parents[j])
            while a >= 0 and not below[a]:
                below[a] = True
                a = int(self.t.parents[a])
        return [int(j) for j in np.flatnonzero(free & ~below)]

    def evaluate(self, joints: list[int]) -> None:
        """Cost of dropping each joint not in the cache: one batched re-fit of all their rows."""
        todo = [j for j in joints if j not in self.cache]
        if not todo:
            return
        groups = [self.affected(j) for j in todo]
        rows = np.concatenate(groups) if groups else np.zeros(0, np.int64)
        masks = np.repeat(np.stack([self.kept & (np.arange(self.t.n) != j) for j in todo]),
                          [len(g) for g in groups], axis=0)
        if self.method == "parent":
            idx, val = parent_rows(self.t, rows, masks)
        else:
            idx, val = refit_rows(self.t, rows, masks, self.solver, self.handles)
        err = row_errors(self.t, rows, idx, val)
        start = 0
        for j, g in zip(todo, groups, strict=True):
            sl = slice(start, start + len(g))
            cost = float((self.t.area[g] * (err[sl] - self.err[g])).sum())
            self.cache[j] = (g, idx[sl], val[sl], err[sl], cost)
            start += len(g)

    def drop(self, j: int) -> None:
        g, idx, val, err, _ = self.cache.pop(j)
        self.kept[j] = False
        self.dropped.append(j)
        width = self.idx.shape[1]
        self.idx[g] = np.pad(idx, ((0, 0), (0, width - idx.shape[1])))
        self.val[g] = np.pad(val, ((0, 0), (0, width - val.shape[1])))
        self.err[g] = err
        touched = np.zeros(len(self.t.V), bool)
        touched[g] = True
        near = {j, int(self.t.parents[j])} | {int(c) for c in np.flatnonzero(self.t.parents == j)}
        for c in list(self.cache):
            rows, cidx, cval = self.cache[c][:3]
            if c in near or int(self.t.parents[c]) in near or touched[rows].any() or \
                    ((cidx == j) & (cval > 0)).any():       # a cached re-fit that leans on j is stale
                del self.cache[c]

    def peak(self, j: int) -> float:
        """Largest ``e_v`` of the level once joint j (evaluated) is dropped."""
        g, _, _, err, _ = self.cache[j]
        rest = np.ones(len(self.err), bool)
        rest[g] = False
        return max(float(err.max(initial=0.0)), float(self.err[rest].max(initial=0.0)))

    def run(self, budget: int) -> BudgetChoice:
        stopped, blocked = None, None
        while int(self.used().sum()) > budget:
            cands = self.candidates()
            if not cands:
                break
            self.evaluate(cands)
            if self.limit is not None:
                peaks = {j: self.peak(j) for j in cands}
                within = [j for j in cands if peaks[j] <= self.limit]
                if not within:
                    stopped, blocked = "max_error", min(peaks.values())
                    break
                cands = within
            best = min(cands, key=lambda j: (self.cache[j][4], len(self.cache[j][0]), j))
            self.drop(best)
        used = self.used()
        k = self.t.k
        order = np.argsort(-self.val, axis=1, kind="stable")[:, :k]
        P = max(len(self.t.T), 1)
        return BudgetChoice(np.take_along_axis(self.idx, order, 1), np.take_along_axis(self.val, order, 1),
                            self.err.copy(), used, list(self.dropped), self.strategy, self.method,
                            int(used.sum()) <= budget, float((self.t.area * self.err).sum()), stopped,
                            None if blocked is None else float(np.sqrt(blocked / P)))


def choose_joints(target: LevelTarget, budget: int, required: np.ndarray, *, strategy: str = DEFAULT_CHOICE,
                  method: str = "refit", solver=None, handles=None, limit: float | None = None) -> BudgetChoice:
    """The greedy joint choice of one level (module docstring); ``best`` keeps the better of both (the budget
    met, then fewer joints, then the lower energy).

    ``limit`` (units of the positions, or None) bounds the largest per-vertex RMS example-pose displacement
    ``max_v d_v`` the removals may reach (:meth:`BudgetChoice.displacement`); removals stop before it.
    """
    if strategy == "best":
        tries = [choose_joints(target, budget, required, strategy=s, method=method, solver=solver, handles=handles,
                               limit=limit) for s in ("leaf-first", "global")]
        return min(tries, key=lambda c: (not c.met, int(c.used.sum()), c.energy))
    if strategy not in CHOICES:
        raise StepError(f"unknown joint choice '{strategy}'", field="joint_choice", fix="use " + ", ".join(CHOICES))
    return _Greedy(target, np.asarray(required, bool), strategy, method, solver, handles, limit).run(budget)


def default_solver():
    """``(plugin, params)`` of the ``geometric`` weight solver, non-negative, through the plugin host."""
    from rigslim.plugin.host import get_host

    plugin = get_host().get("weight-solver", "geometric")
    return plugin, plugin.parse_params({"nonnegative": True})


def apply_joint_budgets(asset, levels: list, budgets: list[int | None], required: dict[int, str], *,
                        max_bones: int | None, strategy: str = DEFAULT_CHOICE, method: str = "refit",
                        log=None, bound: float | None = None, face_errors: list[float] | None = None
                        ) -> tuple[list, list[dict]]:
    """Levels with their joint budgets applied, and one report record per level.

    Parameters
    ----------
    asset : Asset
        With handles (a skeleton) and example poses.
    levels : list of SimplifiedLevel
    budgets : list of int or None
        Joints each level's skin may list (None: no budget).
    required : dict handle -> reason
        Joints that are never dropped.
    max_bones : int or None
        The bone limit of the re-fit (default: the level's widest row).
    bound : float or None
        The step's error bound (units of the positions): a level's ``error``, its collapses' geometric error
        (``face_errors``, default 0) plus its largest joint displacement, stays within it (module docstring).

    Returns
    -------
    levels, records
        Each record: ``label``, ``budget``, ``joints_before``, ``joints``, ``dropped``, ``met``; for a level
        the budget changed, ``strategy``, ``method``, ``example_rms``, ``seconds``, ``required``, and
        ``error`` (``face_error + displacement``), ``face_error``, ``displacement``, ``max_error`` (the
        bound), ``stopped`` (``"max_error"`` or None) and ``next_error`` (the error the next removal would
        have reached, when stopped).
    """
    if asset.handles is None or asset.handles.kind != "skeleton" or asset.handles.parents is None:
        raise StepError("joint_budget needs a skeleton (joints and their parents)", field="joint_budget",
                        fix="read a skinned glTF or a TGF skeleton, or leave joint_budget out")
    names = list(asset.handles.names)
    req = np.zeros(asset.handles.n, bool)
    req[list(required)] = True
    solver = default_solver() if method == "refit" else None
    out, records = [], []
    for i, (level, budget) in enumerate(zip(levels, budgets, strict=True)):
        before = int(len(np.unique(level.weights.indices[level.weights.values != 0])))
        record = {"label": level.label, "budget": budget, "joints_before": before, "joints": before}
        if budget is None or before <= budget:
            out.append(level)
            records.append(record | {"dropped": [], "met": True})
            continue
        t0 = time.perf_counter()
        k = max_bones or int(level.weights.influence_counts().max(initial=1))
        target = level_target(asset, level, k)
        face = float(face_errors[i]) if face_errors is not None else 0.0
        choice = choose_joints(target, budget, req, strategy=strategy, method=method, solver=solver,
                               handles=asset.handles, limit=None if bound is None else bound - face)
        weights = level_weights(choice.indices, choice.values, asset.handles.n)
        out.append(dataclasses.replace(level, weights=weights))
        shift = choice.displacement(target)
        record |= {"joints": int(choice.used.sum()), "dropped": [names[j] for j in choice.dropped],
                   "met": choice.met, "strategy": choice.strategy, "method": method,
                   "example_rms": choice.rms(target), "seconds": time.perf_counter() - t0,
                   "required": {names[j]: why for j, why in required.items() if choice.used[j]},
                   "error": face + shift, "face_error": face, "displacement": shift, "max_error": bound,
                   "stopped": choice.stopped,
                   "next_error": None if choice.next_error is None else face + choice.next_error}
        if log is not None and choice.stopped == "max_error":
            log(f"level {level.label}: {record['joints']} joints, above its budget of {budget}: the next removal "
                f"would reach error {record['next_error']:.4g}, above max_error {bound:.4g}")
        elif not choice.met and log is not None:
            log(f"level {level.label}: {int(choice.used.sum())} joints, above its budget of {budget}: the rest "
                f"are joints the file needs ({len(required)}) or carry every vertex left")
        records.append(record)
    return out, records


def required_joints(asset, keep_joints: str | None) -> dict[int, str]:
    """Handle -> reason for the joints never dropped: what a glTF file needs
    (:func:`rigslim.io.gltf.joints.joints_the_file_needs`), or the ``keep_joints`` names of other inputs."""
    from rigslim.io.gltf.joints import joints_the_file_needs, named_joints

    source = asset.extras.get("gltf")
    if source is not None and source.handles is asset.handles:
        return joints_the_file_needs(source, keep_joints)
    return named_joints(list(asset.handles.names), keep_joints)


def step_joint_budgets(asset, params, levels: list, choices, faces: list[int], ctx, bound: float | None = None
                       ) -> list:
    """A decimation step's levels with its ``joint_budget`` applied, its report under ``joint_budget``.

    A list of budgets has one entry per face target (in the step's order); a target that ended at a
    finer level's prefix has no level, so its budget goes unused. Levels of error or adaptive
    targets take a single budget. ``bound`` (the step's ``max_error`` in the units of the positions) caps
    each level's error, its face target's geometric error (``choices``) plus the joints' displacement;
    levels of error or adaptive targets count their displacement alone.
    """
    per_target = isinstance(params.joint_budget, list)
    if per_target and (params.error_targets or params.adaptive_targets):
        raise StepError("a list of joint budgets goes with face targets only", field="joint_budget",
                        fix="give one joint budget for every level")
    n = asset.handles.n if asset.handles is not None else 0
    budgets = budget_counts(params.joint_budget, len(params.targets) if per_target else len(levels), n)
    if per_target:          # the choices are finest first, as choose_levels sorts the targets
        ordered = [b for _, b in sorted(zip(faces, budgets, strict=True), key=lambda x: -x[0])]
        budgets = [b for b, c in zip(ordered, choices, strict=True) if c.same_as is None]
    required = required_joints(asset, params.keep_joints)
    face = {c.label: c.error for c in choices if c.same_as is None}
    out, records = apply_joint_budgets(asset, levels, budgets, required, max_bones=params.max_bones,
                                       strategy=params.joint_choice, method=params.joint_weights, log=ctx.log,
                                       bound=bound, face_errors=[face.get(lv.label, 0.0) for lv in levels])
    names = list(asset.handles.names)
    ctx.report["joint_budget"] = {"choice": params.joint_choice, "weights": params.joint_weights, "max_error": bound,
                                  "required": {names[j]: why for j, why in required.items()}, "levels": records}
    return out
