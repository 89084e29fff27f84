"""``position_weight: auto`` for the Poisson solver: lambda chosen on held-out example poses.

The Poisson energy with a position term ([P10] eq. 5 plus ``lambda s ||X - Y||_W^2``,
:mod:`rigslim.plugins.solvers.problem`) trades normals (the Laplacian term)
against positions (lambda). ``auto`` picks lambda by validation on the example
poses only, so the test poses stay unseen:

1. every third example pose (the 2nd, 5th, ...) is held out, the others fit;
2. for each lambda of a log grid (default 1e-3 ... 10), the weights are fitted
   on the fitting poses and the held-out poses are deformed with them;
3. the score of lambda is ``P(lambda) / min P + N(lambda) / min N``, with P the
   held-out position RMS (% of the diagonal) and N the held-out normal RMS
   angle (area-weighted normals recomputed on both deformations), each
   relative to its best value over the grid;
4. the lambda of least score is refitted on all example poses.

The step's report gets ``position_weight_auto``: the grid, the held-out
frames, each lambda's errors and score, and the choice.
"""

from __future__ import annotations

import dataclasses

import numpy as np

from rigslim.blend import linear_blend, per_vertex_normals
from rigslim.errors import StepError
from rigslim.numerics.normal_error import normal_rms_angle
from rigslim.poses import FrameSplit

#: Default lambda grid (dimensionless; see :func:`rigslim.plugins.solvers.problem.build_problem`).
GRID = (1e-3, 1e-2, 1e-1, 1.0, 10.0)


def held_out_errors(asset, reduced, frames) -> tuple[float, float]:
    """RMS over ``frames`` of the position error (% of the diagonal) and of the normal angle (rad)."""
    V, F = asset.mesh.V, asset.mesh.F
    T = asset.poses.select(frames).T
    pos, nrm = [], []
    for j in range(len(T)):
        full = linear_blend(V, asset.weights, T[j])
        red = linear_blend(V, reduced, T[j])
        pos.append(100.0 * np.sqrt(np.mean(np.sum((full - red) ** 2, axis=1))) / asset.mesh.bbox_diagonal)
        nrm.append(normal_rms_angle(per_vertex_normals(red, F), per_vertex_normals(full, F)))
    return float(np.sqrt(np.mean(np.square(pos)))), float(np.sqrt(np.mean(np.square(nrm))))


def choose_position_weight(asset, params, grid=GRID) -> tuple[float, dict]:
    """Lambda of least held-out score (module docstring) and the report of the search."""
    from rigslim.plugins.solvers.methods import reduce_weights

    examples = list(asset.split.examples)
    if len(examples) < 3:
        raise StepError(f"position_weight: auto holds out example poses, and there are only {len(examples)}",
                        field="position_weight", fix="give at least 3 example poses, or a number")
    held = examples[1::3]
    fit = [f for f in examples if f not in set(held)]
    sub = dataclasses.replace(asset, split=FrameSplit(fit, held, []))
    rows = []
    for lam in grid:
        reduced, rep = reduce_weights(sub, "poisson", params.model_copy(update={"position_weight": float(lam)}))
        p, n = held_out_errors(asset, reduced, held)
        rows.append({"position_weight": float(lam), "position_rms_pct": p, "normal_rms_rad": n,
                     "seconds": rep["seconds"]})
    pmin = max(min(r["position_rms_pct"] for r in rows), 1e-300)
    nmin = max(min(r["normal_rms_rad"] for r in rows), 1e-300)
    for r in rows:
        r["score"] = r["position_rms_pct"] / pmin + r["normal_rms_rad"] / nmin
    best = min(rows, key=lambda r: r["score"])
    report = {"chosen": best["position_weight"], "fit_frames": fit, "held_out_frames": held,
              "held_out_position_rms_pct": best["position_rms_pct"], "held_out_normal_rms_rad": best["normal_rms_rad"],
              "grid": rows}
    return best["position_weight"], report
