"""Parts removed whole: far levels of many-part meshes that no collapse can bring to their target.

A mesh made of many closed parts (a siege engine's beams, pegs and ropes; a character's buttons, teeth and
straps) stops collapsing when every part is a tetrahedron or otherwise held by the guards: the link condition
keeps each closed part at four faces or more. On the suite's mangonel (1,158 faces, 37 parts) the hierarchy
ends at 248 faces, 31 of its parts at four faces or fewer, so a 10 % target (116 faces) cannot be met by
collapses. meshoptimizer meets such targets by removing small components (``meshopt_SimplifyPrune``); so
does this module, for the levels the hierarchy cannot reach and with the error bound, never beyond it.

**Removal distance.** Removing part C from a level leaves the rest R. The surface of C then lies at its
distance from R, so the removal's error is

    d_C = sqrt( sum_j sum_{s in C} w_s dist(x_s^j, R^j)^2 / (P sum_{s in C} w_s) )

over the example poses j and points s of C's faces (:data:`FACE_POINTS`: corners, edge midpoints and
centroid of each face, weighted by a seventh of its rest area), posed by the level's own weights, R^j the
rest posed likewise: the area-weighted root mean square distance over the example poses, as a collapse's
geometric error is (:func:`rigslim.plugins.decimation.levels.collapse_distances`). A peg sunk into a beam is
near the beam and costs little; a rope hanging free, or a head on its own, costs its whole offset; a torso
between limbs touches them at its corners only, and its faces' middles keep it (measured at its corners
alone, minetest_character's torso went first).

**Greedy removal.** The part whose removal adds the least squared error goes first, ``A_C d_C^2`` (its rest
area times its squared distance: the integral of the squared distance over its surface, what the level's
area-weighted RMS error gains), then the next, until the level has at most its target's faces, the next
removal's distance ``d_C`` would pass the error bound (``max_error``), or one part is left. A small part
near the rest goes before a large one that is as near: minetest_character's torso, a tetrahedron between its
limbs at that level, is about as near to them as they are to it (1.38 against 1.53-1.98), but has twice
their area. Removing a part can only move the others' nearest surface farther away, so a cost measured
earlier is a lower bound of the current one: the parts wait in a queue by their last cost and the one on top
is measured again before it goes (lazy evaluation, exact). The last removal may overshoot the target (a
28-face part where 4 faces were missing): parts that fit in the overshoot are put back, the farthest first
(:func:`kept_back`). Every target takes its removals from the one sequence, so the levels' face counts
strictly decrease.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass

import numpy as np

from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights

__all__ = ["PruneStep", "early_removals", "face_parts", "kept_back", "prune_levels", "prune_sequence", "pruned_level",
           "removal_distance"]


@dataclass(frozen=True, eq=False)
class PruneStep:
    """One part removed: its faces (rows of the level's faces), the faces left after it, and its distance."""

    faces: np.ndarray
    faces_left: int
    distance: float
    peak: float = 0.0
    """The largest distance of one of its points to the rest, over the example poses (``distance`` is their
    area-weighted RMS): a plate lying on a body has both small, a limb's peak is its length."""


def face_parts(F: np.ndarray) -> tuple[int, np.ndarray]:
    """``(n, label)``: the connected parts of the faces ``F`` (faces sharing a vertex) and each face's part."""
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components

    F = np.asarray(F, np.int64).reshape(-1, 3)
    if not len(F):
        return 0, np.zeros(0, np.int64)
    n_v = int(F.max()) + 1
    rows = np.concatenate([F[:, 0], F[:, 1]])
    cols = np.concatenate([F[:, 1], F[:, 2]])
    n, label = connected_components(sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n_v, n_v)),
                                    directed=False)
    _, part = np.unique(label[F[:, 0]], return_inverse=True)
    return int(part.max()) + 1, part.astype(np.int64)


#: Points of a face a removal is measured at, as barycentric coordinates: its corners, edge midpoints and
#: centroid (a part enclosed by others, a torso between limbs, is near them at its corners only).
FACE_POINTS = np.array([[1, 0, 0], [0, 1, 0], [0, 0, 1], [0.5, 0.5, 0], [0, 0.5, 0.5], [0.5, 0, 0.5],
                        [1 / 3, 1 / 3, 1 / 3]])


def face_points(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(f * 7, 3): the :data:`FACE_POINTS` of every face of ``F`` over the positions ``V``, face by face."""
    return np.einsum("kc,fcd->fkd", FACE_POINTS, V[F]).reshape(-1, 3)


def point_weights(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """(f * 7,): each face's area shared by its seven points (1 each where every face is degenerate)."""
    area = Mesh(V, F).face_areas
    if not (area > 0).any():
        area = np.ones(len(F))
    return np.repeat(area / len(FACE_POINTS), len(FACE_POINTS))


def grouped(label: np.ndarray, n: int) -> list[np.ndarray]:
    """Per group 0..n-1 the rows with that ``label``, in increasing order (one sort, not n scans)."""
    order = np.argsort(label, kind="stable")
    return np.split(order, np.cumsum(np.bincount(label, minlength=n))[:-1])


def removal_distance(X: np.ndarray, V: np.ndarray, part_faces: np.ndarray, rest_faces: np.ndarray) -> float:
    """``d_C`` (module docstring) by brute force of the hierarchy: X (P, v, 3) the level's vertices in every
    example pose, V its rest vertices (the points' area weights), ``part_faces`` C's faces, ``rest_faces``
    the faces left without C (at least one). The reference :func:`prune_sequence` is tested against."""
    from rigslim.numerics.point_mesh_distance import build_tree, point_mesh_squared_distances, refit_tree

    w = point_weights(V, part_faces)
    tree = None
    total = 0.0
    for j in range(len(X)):
        tree = build_tree(X[j], rest_faces) if tree is None else refit_tree(tree, X[j], rest_faces)
        total += float(w @ point_mesh_squared_distances(face_points(X[j], part_faces), X[j], rest_faces, tree=tree))
    return float(np.sqrt(total / (len(X) * w.sum())))


#: A part with at least this share of the level's faces (and :data:`LARGE_MIN_FACES`) is measured against a
#: hierarchy of the other live parts' triangles, built for it, instead of the shared one: in the shared one a
#: point on a large part, its own triangles all around it, searches much of its part for the nearest other one
#: (bcn_epileptic's 5,126 faces: the removals' search took 5.1 s of its 6.1 s decimate step, now 0.7 s).
LARGE_SHARE = 1 / 32
LARGE_MIN_FACES = 32


class _PartDistances:
    """``d_C`` of every part of one level against the parts still alive, from one hierarchy of all its
    triangles per pose: a part's points search it skipping their own part's triangles and the removed
    ones' (:func:`rigslim.numerics.point_mesh_distance.distances_to_other_parts`), so measuring a part costs a
    query of its points, not a hierarchy of the rest (which made 6,000 parts take 270 s). Each point keeps,
    per pose, the triangle it found last as the next search's first guess. The few large parts
    (:data:`LARGE_SHARE`) are measured against a hierarchy of the rest instead; both give the exact minima."""

    def __init__(self, X: np.ndarray, V: np.ndarray, F: np.ndarray, part: np.ndarray, n: int):
        from rigslim.numerics.point_mesh_distance import build_tree

        self.X, self.F, self.part = X, F, part
        self.owner = np.repeat(part, len(FACE_POINTS))
        self.weight = point_weights(V, F)
        self.points = grouped(self.owner, n)
        self.area = np.bincount(self.owner, self.weight, minlength=n)     # A_C: the sum of its points' weights
        self.alive = np.ones(n, bool)
        self.trees = [build_tree(X[j], F) for j in range(len(X))]
        self.at = [face_points(X[j], F) for j in range(len(X))]
        self.hint = [np.full(len(self.owner), -1, np.int64) for _ in range(len(X))]
        sizes = np.bincount(part, minlength=n)
        self.large = (sizes >= LARGE_MIN_FACES) & (sizes >= LARGE_SHARE * len(F))

    def __call__(self, points: np.ndarray) -> np.ndarray:
        """Per point (rows of ``face_points``) the sum over the poses of its squared distance to the other
        live parts; :attr:`peak` holds their largest over the poses."""
        from rigslim.numerics.point_mesh_distance import distances_to_other_parts

        d2 = np.empty((len(self.trees), len(points)))
        on_large = self.large[self.owner[points]]
        shared = points[~on_large]
        for j, tree in enumerate(self.trees):
            guess = self.hint[j][shared]
            d2[j, ~on_large] = distances_to_other_parts(self.at[j][shared], self.owner[shared], self.X[j], self.F,
                                                        self.part, self.alive, tree, guess)
            self.hint[j][shared] = guess
        for p in np.unique(self.owner[points[on_large]]):
            mine = on_large & (self.owner[points] == p)
            d2[:, mine] = self._to_the_rest(p, points[mine])
        self.peak = d2.max(axis=0) if len(points) else np.zeros(0)
        return d2.sum(axis=0)

    def _to_the_rest(self, p: int, points: np.ndarray) -> np.ndarray:
        """(poses, len(points)) squared distances of part p's ``points`` to the other live parts, through a
        hierarchy of their triangles (inf when there is none)."""
        from rigslim.numerics.point_mesh_distance import build_tree, point_mesh_squared_distances, refit_tree

        rest = self.F[(self.part != p) & self.alive[self.part]]
        if not len(rest):
            return np.full((len(self.X), len(points)), np.inf)
        out, tree = np.empty((len(self.X), len(points))), None
        guess = np.full(len(points), -1, np.int64)          # each pose's nearest, the next pose's first guess
        for j in range(len(self.X)):
            tree = build_tree(self.X[j], rest) if tree is None else refit_tree(tree, self.X[j], rest)
            out[j] = point_mesh_squared_distances(self.at[j][points], self.X[j], rest, tree, guess)
        return out

    def start(self) -> np.ndarray:
        """Every part's ``d_C`` against all the others, in one query of every point."""
        d2 = self(np.arange(len(self.owner)))
        num = np.bincount(self.owner, self.weight * d2, minlength=len(self.area))
        return np.sqrt(num / (len(self.X) * np.where(self.area > 0, self.area, 1.0)))

    def distance(self, p: int) -> float:
        """``d_C`` of part p against the live others; :attr:`peak` then holds its points' squared maxima."""
        q = self.points[p]
        w = self.weight[q]
        return float(np.sqrt(w @ self(q) / (len(self.X) * w.sum())))


def prune_sequence(level: SimplifiedLevel, T: np.ndarray, min_faces: int, bound: float | None
                   ) -> tuple[list[PruneStep], str | None]:
    """The parts to remove from ``level``, in order, until at most ``min_faces`` faces are left.

    Parameters
    ----------
    level : SimplifiedLevel
        The level no collapse can simplify further (the hierarchy's end).
    T : (P, n, 3, 4) array
        The example poses' bone transforms.
    min_faces : int
        Stop once the faces left are at most this.
    bound : float, optional
        The error bound (units of the positions): no removal farther than this.

    Returns
    -------
    steps, stopped
        The removals (greedy by added squared error, module docstring) and why they stopped short of ``min_faces``:
        None (reached), ``"max_error"`` (the next removal passes the bound) or ``"no collapse"`` (one part
        left).
    """
    from rigslim.numerics.blend import linear_blend

    F = np.asarray(level.mesh.F, np.int64)
    n, part = face_parts(F)
    if len(F) <= min_faces:
        return [], None
    if n < 2:
        return [], "no collapse"
    X = np.stack([linear_blend(level.mesh.V, level.weights, T[j]) for j in range(len(T))])
    faces_of = grouped(part, n)
    measure = _PartDistances(X, np.asarray(level.mesh.V), F, part, n)
    area = measure.area
    queue = [(float(area[p] * d * d), p) for p, d in enumerate(measure.start())]
    heapq.heapify(queue)
    steps: list[PruneStep] = []
    left = len(F)
    while left > min_faces:
        if int(measure.alive.sum()) <= 1:
            return steps, "no collapse"
        _, p = heapq.heappop(queue)
        now = measure.distance(p)
        cost = float(area[p] * now * now)
        if queue and cost > queue[0][0]:        # farther than when measured: wait for its turn again
            heapq.heappush(queue, (cost, p))
            continue
        if bound is not None and now > bound:
            return steps, "max_error"
        measure.alive[p] = False
        left -= len(faces_of[p])
        steps.append(PruneStep(faces_of[p], left, now, float(np.sqrt(measure.peak.max()))))
    return steps, None


def kept_back(steps: list[PruneStep], slack: int) -> list[PruneStep]:
    """The removals ``steps`` that reached a target, less those the target can keep: the last removal may take
    the level ``slack`` faces below its target, so parts of at most that many faces are put back, the farthest
    first (each brings back the most error), while they fit. The largest distance removed cannot grow (the
    rest only gains surface), and the level lands closer to its target."""
    back = set()
    for i in sorted(range(len(steps)), key=lambda i: -steps[i].distance):
        if len(steps[i].faces) <= slack:
            back.add(i)
            slack -= len(steps[i].faces)
    return [s for i, s in enumerate(steps) if i not in back]


def pruned_level(level: SimplifiedLevel, steps: list[PruneStep], label: str) -> SimplifiedLevel:
    """``level`` without the parts of ``steps``: its other faces, their vertices (``vertex_ids`` a subset of
    the level's, so writers map it onto the hierarchy as before) and weights. Its ``error`` stays the largest
    collapse error (the removals' distances are the steps')."""
    F = np.asarray(level.mesh.F, np.int64)
    keep = np.ones(len(F), bool)
    for s in steps:
        keep[s.faces] = False
    used, Fc = np.unique(F[keep], return_inverse=True)
    w = level.weights
    weights = ReducedWeights(w.indices[used], w.values[used], w.n_handles)
    ids = None if level.vertex_ids is None else np.asarray(level.vertex_ids)[used]
    mesh = Mesh(level.mesh.V[used], Fc.reshape(-1, 3), source=level.mesh.source)
    return SimplifiedLevel(mesh, weights, label, ids, level.error, level.method)


def prune_levels(hier, choices: list, levels: list[SimplifiedLevel], T: np.ndarray, bound: float | None,
                 method: str) -> tuple[list, list[SimplifiedLevel]]:
    """The face targets that the hierarchy's last collapse leaves short (``stopped == "no collapse"``) reached
    by removing parts of its final mesh (:func:`prune_sequence`); returns the choices and levels, updated.

    One removal sequence serves them all, finest first: each takes the shortest prefix that meets it, less
    the parts that fit in its overshoot (:func:`kept_back`). A target that ends with no fewer faces than the
    level before it has no level of its own (``same_as``), as in
    :func:`rigslim.plugins.decimation.levels.choose_levels`.
    """
    from dataclasses import replace

    from rigslim.plugins.decimation.levels import SOURCE, level_label

    stuck = [i for i, c in enumerate(choices) if c.stopped == "no collapse"]
    if not stuck:
        return choices, levels
    base = hier.prefix(hier.n_collapses)
    steps, why = prune_sequence(base, T, min(choices[i].target_faces for i in stuck), bound)
    if not steps:
        return choices, levels
    out = list(choices)
    dropped = {choices[i].label for i in stuck if choices[i].same_as is None}
    kept = [lv for lv in levels if lv.label not in dropped]
    finer = [c for c in choices[:stuck[0]] if c.same_as is None]
    last_faces = finer[-1].faces if finer else len(hier.F)
    last_label = finer[-1].label if finer else None
    for i in stuck:
        c = choices[i]
        reach = next((k for k, s in enumerate(steps) if s.faces_left <= c.target_faces), None)
        chosen = steps if reach is None else kept_back(steps[:reach + 1], c.target_faces - steps[reach].faces_left)
        faces = len(base.mesh.F) - sum(len(s.faces) for s in chosen)
        label = level_label(method, c.target, c.target_faces, faces)
        farthest = max(s.distance for s in chosen)
        if faces >= last_faces:                  # no fewer faces than the level before: none of its own
            same = last_label if last_label is not None else SOURCE
            out[i] = replace(c, same_as=same, faces=last_faces, stopped=why if reach is None else None)
            continue
        out[i] = replace(c, faces=faces, label=label, error=max(c.error, farthest), same_as=None,
                         stopped=why if reach is None else None, parts_removed=len(chosen),
                         removal_distance=farthest)
        kept.append(pruned_level(base, chosen, label))
        last_faces, last_label = faces, label
    kept.sort(key=lambda lv: -lv.n_faces)
    return out, kept


def _removal_candidates(hier, steps: list[PruneStep], running: np.ndarray, target_faces: int
                        ) -> tuple[float, int] | None:
    """The cheapest way to ``target_faces`` by a collapse prefix followed by removals, estimated from the source's
    removal sequence ``steps``: the first ``i`` removals take ``R_i`` source faces, so the prefix must reach
    ``target_faces + R_i`` faces; its error is ``max(running[k - 1], max_{s <= i} d_s)``. Returns ``(error, k)``
    of the best ``i >= 1``, or None when no removal count reaches the target."""
    best = None
    removed, farthest = 0, 0.0
    for s in steps:
        removed += len(s.faces)
        farthest = max(farthest, s.peak)
        need = target_faces + removed
        if need >= len(hier.F):
            k = 0
        else:
            hit = np.flatnonzero(hier.n_faces <= need)
            if not hit.size:
                continue
            k = int(hit[0]) + 1
        error = max(float(running[k - 1]) if k else 0.0, farthest)
        if best is None or error < best[0]:
            best = (error, k)
        if k == 0:
            break
    return best


def early_removals(hier, choices: list, levels: list[SimplifiedLevel], T: np.ndarray, distances: np.ndarray,
                   bound: float | None, method: str) -> tuple[list, list[SimplifiedLevel]]:
    """Levels that reach their face target with less error by removing whole parts after fewer collapses.

    A part that lies on another (an armour plate or a clothing layer over the body, a decal, an eye in its
    socket) costs almost nothing to remove, while the collapses that would take its faces' place elsewhere
    cost their geometric error. For each level with collapses (finest first) the source's removal sequence
    (:func:`prune_sequence`, stopped at the level's collapse error) estimates, for every number of removals
    ``i``, the shorter prefix that then reaches the target and the error ``max(collapse error of the prefix,
    farthest removal)`` (:func:`_removal_candidates`). Where the best is below the level's error, that prefix
    is pruned for real (:func:`prune_sequence` on the prefix itself, :func:`kept_back`), and the level is
    replaced when its measured error is still below the level's and its faces still decrease.

    A level the bound stopped short that no prefix and removals bring to its target within the bound gets the
    fewest faces within it instead: its own prefix, then every removal whose distance and farthest point stay
    within the bound (still ``stopped == "max_error"``). A target that then has no fewer faces than the finer
    level before it ends at that level (``same_as``), as :func:`rigslim.plugins.decimation.levels.choose_levels`
    does, instead of at the source or at a level with more faces.

    On a blocky character with an armour layer of separate quads (minetest's 3d_armor, 440 faces, 124 quads)
    the hierarchy's first collapses turn boxes into wedges (0.25 to 1.1 units of geometric error at 436 to
    416 faces) while each quad is within 0.001 units of the body under it.
    """
    from dataclasses import replace

    from rigslim.plugins.decimation.levels import REACHED, SOURCE, level_label

    def stopped_by_bound(c) -> bool:
        return c.stopped == "max_error" and bound is not None

    def limit_of(c) -> float:
        # the bound for a level the bound stopped short, else the level's own collapse error
        if stopped_by_bound(c):
            assert bound is not None            # stopped_by_bound says so; for the type checker
            return float(bound)
        return float(c.error)

    # a level, one that ended at a finer level, or one the bound stopped short (possibly at the source)
    open_ = [i for i, c in enumerate(choices) if (c.collapses > 0 and c.error > 0) or stopped_by_bound(c)]
    if not open_ or len(hier.F) == 0 or face_parts(np.asarray(hier.F, np.int64))[0] < 2:
        return choices, levels
    running = np.maximum.accumulate(distances) if len(distances) else distances
    worst = max(limit_of(choices[i]) for i in open_)
    cap = worst if bound is None else min(worst, bound)
    source = hier.prefix(0)
    steps, _ = prune_sequence(source, T, min(choices[i].target_faces for i in open_), cap)
    if not steps:
        return choices, levels
    out, kept = list(choices), list(levels)
    last_faces, last_label = len(hier.F), None
    for i, c in enumerate(choices):
        if i in open_:
            plan = _level_plan(hier, T, running, bound, steps, c, stopped_by_bound(c), limit_of(c))
            if plan is not None and plan.faces < last_faces:
                label = level_label(method, c.target, c.target_faces, plan.faces)
                level = pruned_level(plan.base, plan.chosen, label)
                if c.same_as is None:          # its level is replaced
                    kept[next(j for j, lv in enumerate(kept) if lv.label == c.label)] = level
                else:                          # it ended at a finer level or the source: now it has its own
                    kept.append(level)
                reached = plan.faces <= (1 + REACHED) * c.target_faces
                out[i] = replace(c, collapses=plan.k, faces=plan.faces, label=label, error=plan.error,
                                 stopped=None if reached else c.stopped, same_as=None,
                                 parts_removed=len(plan.chosen), removal_distance=plan.farthest)
                if c.same_as is None:
                    out = _redirected(out, c.label, out[i])
            elif last_label is not None and last_faces <= c.faces and c.same_as in (None, SOURCE):
                # a finer level that removals took further has no more faces already: this target ends there
                # (the bound stopped it short of that, or it ended where no collapse was left)
                prev = next(d for d in out if d.label == last_label and d.same_as is None)
                if c.same_as is None:
                    kept = [lv for lv in kept if lv.label != c.label]
                    out = _redirected(out, c.label, prev)
                out[i] = replace(c, collapses=prev.collapses, faces=last_faces, error=prev.error, same_as=last_label)
        if out[i].same_as is None:
            last_faces, last_label = out[i].faces, out[i].label
    kept.sort(key=lambda lv: -lv.n_faces)
    return out, kept


@dataclass(frozen=True)
class _Plan:
    """A level made by a collapse prefix and removals: the prefix ``k`` and its level ``base``, the removals
    ``chosen``, the faces left, ``error = max(collapse error of the prefix, farthest removal)``, the farthest
    removal's distance and the largest peak of the removed parts."""

    k: int
    base: SimplifiedLevel
    chosen: list[PruneStep]
    faces: int
    error: float
    farthest: float
    peak: float


def _removal_plan(hier, T: np.ndarray, running: np.ndarray, bound: float | None, k: int, target_faces: int,
                  limit: float, to_target: bool) -> _Plan | None:
    """Prefix ``k`` pruned toward ``target_faces`` (:func:`prune_sequence`, :func:`kept_back`), or None.
    ``to_target``: only removals that reach the target; else as many as the bound ``limit`` allows (each
    removal's farthest point within it too)."""
    base = hier.prefix(k)
    chosen, _ = prune_sequence(base, T, target_faces, bound)
    reach = next((j for j, s in enumerate(chosen) if s.faces_left <= target_faces), None)
    if reach is not None:
        chosen = kept_back(chosen[:reach + 1], target_faces - chosen[reach].faces_left)
    elif to_target:
        return None
    else:
        chosen = chosen[:next((j for j, s in enumerate(chosen) if s.peak > limit), len(chosen))]
    if not chosen:
        return None
    farthest = max(s.distance for s in chosen)
    return _Plan(k, base, chosen, len(base.mesh.F) - sum(len(s.faces) for s in chosen),
                 max(float(running[k - 1]) if k else 0.0, farthest), farthest, max(s.peak for s in chosen))


def _level_plan(hier, T: np.ndarray, running: np.ndarray, bound: float | None, steps: list[PruneStep], c,
                short: bool, limit: float) -> _Plan | None:
    """The early-removal level for choice ``c`` (:func:`early_removals`), or None to keep it.

    The best estimate of :func:`_removal_candidates` is pruned for real and kept when its measured error is
    below ``limit`` (within it, with fewer faces, for a level the bound stopped short: ``short``). Failing
    that, a short level takes the fewest faces within the bound: its own prefix and every removal within it.
    """
    best = _removal_candidates(hier, steps, running, c.target_faces)
    if best is not None and (best[0] <= limit if short else best[0] < limit):
        plan = _removal_plan(hier, T, running, bound, best[1], c.target_faces, limit, True)
        if plan is not None:
            worst = max(plan.error, plan.peak)
            if (worst <= limit and plan.faces < c.faces) if short else \
                    (worst < limit and plan.faces <= max(c.faces, c.target_faces)):
                return plan
    if not short:
        return None
    # no way to the target within the bound: the fewest faces within it, after the level's own collapses
    # (a blocky character whose first collapse passes the bound sheds its layers)
    plan = _removal_plan(hier, T, running, bound, c.collapses, c.target_faces, limit, False)
    return plan if plan is not None and max(plan.error, plan.peak) <= limit and plan.faces < c.faces else None


def _redirected(out: list, old_label: str, level) -> list:
    """``out`` with the targets that ended at level ``old_label`` ending at ``level`` (its label, prefix, faces
    and error) instead."""
    from dataclasses import replace

    return [replace(d, same_as=level.label, faces=level.faces, collapses=level.collapses, error=level.error)
            if d.same_as == old_label else d for d in out]
