"""``position_weight: auto`` for the Poisson solver: lambda chosen on held-out example poses.

The Poisson energy with a position term ([P10] eq. 5 plus ``lambda s ||X - Y||_W^2``,
:mod:`rigslim.plugins.solvers.problem`) trades normals (the Laplacian term)
against positions (lambda). ``auto`` picks lambda by validation on the example
poses only, so the test poses stay unseen:

1. K-fold cross-validation over the m example poses: across clips when they
   come from two or more clips (``poses: examples: {clips: ...}``;
   :func:`clip_splits`: fold i holds out clip i's examples), else
   (:func:`kfold_splits`) leave-one-out when m <= 8 (K = m), else K = 4
   interleaved folds (fold i holds out the examples i, i + K, i + 2K, ...).
   Every example pose is held out exactly once;
2. for each lambda of a log grid (default 1e-3 ... 10) and each fold, the
   weights are fitted on the fold's other example poses and the held-out
   poses are deformed with them;
3. P(lambda) and N(lambda) are the position RMS (% of the diagonal) and the
   normal RMS angle (area-weighted normals recomputed on both deformations,
   over the vertices whose normal is defined at rest and in the full
   deformation, as in the ``normal-deviation`` metric) pooled over all
   held-out poses of all folds,
   ``P = sqrt(sum_folds sum_held e_f^2 / m)``;
   the score of lambda is ``P(lambda) / min P + N(lambda) / min N``, each term
   relative to its best value over the grid;
4. the lambda of least score is refitted on all example poses.

Cost: ``K x len(grid) + 1`` solves. A single split (one third held out) was
used before; with 6 example poses it chose poorly on the armadillo cage,
because 2 held-out poses judged lambda on too little motion.

The step's report gets ``position_weight_auto``: the grid, the folds and
their held-out frames, each lambda's pooled and per-fold errors and score,
and the choice.
"""

from __future__ import annotations

import dataclasses
from typing import Any

import numpy as np

from rigslim.errors import StepError
from rigslim.model.poses import FrameSplit
from rigslim.numerics.blend import linear_blend, per_vertex_normals
from rigslim.numerics.normal_error import (
    DEGENERATE_RATIO,
    normal_conditioning,
    normal_rms_angle,
    vertex_face_incidence,
)
from rigslim.plugins.solvers.reduction import solve_weights

#: Default lambda grid (dimensionless; see :func:`rigslim.plugins.solvers.problem.build_problem`).
GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0)


def held_out_errors(asset, reduced, frames) -> tuple[float, float]:
    """RMS over ``frames`` of the position error (% of the diagonal) and of the normal angle (rad); the
    normal angle over vertices whose normal is defined (conditioning >= ``DEGENERATE_RATIO``, at rest and in
    the full deformation; :mod:`rigslim.numerics.normal_error`)."""
    V, F = asset.mesh.V, asset.mesh.F
    T = asset.poses.select(frames).T
    incidence = vertex_face_incidence(F, len(V))
    rest_ok = normal_conditioning(V, F, incidence) >= DEGENERATE_RATIO
    pos, nrm = [], []
    for j in range(len(T)):
        full = linear_blend(V, asset.weights, T[j])
        red = linear_blend(V, reduced, T[j])
        pos.append(100.0 * np.sqrt(np.mean(np.sum((full - red) ** 2, axis=1))) / asset.mesh.bbox_diagonal)
        valid = rest_ok & (normal_conditioning(full, F, incidence) >= DEGENERATE_RATIO)
        nrm.append(normal_rms_angle(per_vertex_normals(red, F), per_vertex_normals(full, F), valid))
    return float(np.sqrt(np.mean(np.square(pos)))), float(np.sqrt(np.mean(np.square(nrm))))


#: Leave-one-out up to this many example poses; above it, :data:`FOLDS` folds.
LEAVE_ONE_OUT_MAX = 8
FOLDS = 4


def kfold_splits(examples, folds: int | None = None) -> list[tuple[list[int], list[int]]]:
    """``(fit, held_out)`` frame lists of the K folds over ``examples`` (module docstring, step 1).

    ``folds=None`` picks leave-one-out for at most :data:`LEAVE_ONE_OUT_MAX` examples, else
    :data:`FOLDS`. Fold i holds out ``examples[i::K]``; every example is held out exactly once.
    """
    examples = list(examples)
    m = len(examples)
    K = (m if m <= LEAVE_ONE_OUT_MAX else FOLDS) if folds is None else int(folds)
    if not 2 <= K <= m:
        raise ValueError(f"need 2 <= folds <= {m} example poses, got {K}")
    out = []
    for i in range(K):
        held = examples[i::K]
        hs = set(held)
        out.append(([f for f in examples if f not in hs], held))
    return out


def clip_splits(groups) -> list[tuple[list[int], list[int]]]:
    """Leave-one-clip-out folds: fold i holds out the example frames of clip i (``groups[i]``)."""
    return [([f for j, g in enumerate(groups) if j != i for f in g], list(held)) for i, held in enumerate(groups)]


def choose_position_weight(asset, params, grid=GRID) -> tuple[float, dict]:
    """Lambda of least held-out score (module docstring) and the report of the search."""
    examples = list(asset.split.examples)
    if len(examples) < 3:
        raise StepError(f"position_weight: auto holds out example poses, and there are only {len(examples)}",
                        field="position_weight", fix="give at least 3 example poses, or a number")
    groups = asset.split.clip_groups(examples)
    splits = clip_splits(groups) if len(groups) >= 2 else kfold_splits(examples)
    subs = [dataclasses.replace(asset, split=FrameSplit(fit, held, [])) for fit, held in splits]
    rows: list[dict[str, Any]] = []  # one JSON row of the report per lambda
    for lam in grid:
        p2 = n2 = secs = 0.0
        per_fold = []
        lam_params = params.model_copy(update={"position_weight": float(lam)})
        for (_fit, held), sub in zip(splits, subs, strict=False):
            reduced, rep = solve_weights(sub, "poisson", lam_params)
            p, n = held_out_errors(asset, reduced, held)
            p2 += len(held) * p * p
            n2 += len(held) * n * n
            secs += rep["seconds"]
            per_fold.append({"position_rms_pct": p, "normal_rms_rad": n})
        rows.append({"position_weight": float(lam), "position_rms_pct": float(np.sqrt(p2 / len(examples))),
                     "normal_rms_rad": float(np.sqrt(n2 / len(examples))), "seconds": secs, "folds": per_fold})
    pmin = max(min(r["position_rms_pct"] for r in rows), 1e-300)
    nmin = max(min(r["normal_rms_rad"] for r in rows), 1e-300)
    for r in rows:
        r["score"] = r["position_rms_pct"] / pmin + r["normal_rms_rad"] / nmin
    best = min(rows, key=lambda r: r["score"])
    report = {"chosen": best["position_weight"], "fold_count": len(splits),
              "folds": [{"fit_frames": fit, "held_out_frames": held} for fit, held in splits],
              "held_out_position_rms_pct": best["position_rms_pct"], "held_out_normal_rms_rad": best["normal_rms_rad"],
              "grid": rows}
    return best["position_weight"], report
