"""Reduction quality on the elephant ([P10] figures 10 and 12).

Methods k-largest, geometric, smooth, Poisson and Poisson with the best
position weight lambda, for k in {4, 5, 6, 8}, all non-negative (the
skeleton default), solver ``auto``. Fitting uses the example frames
``0:457:45``; errors are measured on the test frames ``5:457:7`` (never
used for fitting); lambda is chosen on separate validation frames
``2:457:7`` (neither example nor test frames) by the smallest sum of
position and normal error, each relative to k-largest's.

Errors: position RMS over vertices as % of the bounding-box diagonal;
normal RMS angle (rad) between area-weighted normals recomputed on the
reduced and on the full deformation; per frame, then averaged over frames.
A reference row fits plain NNLS without sum-to-one (the issue's orientation
figure), which is not a valid reduction (rows do not sum to one).

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/reduction_quality.py``; with ``best-fit`` as
first argument it runs :mod:`benchmarks.reduction_best_fit` instead (best-fit influence sets
with every solver, Dem Bones in the same run; docs/results/reduction_quality_best_fit.{json,md}).
Writes docs/results/reduction_quality.{json,md} and reduction_quality_fig10.png,
reduction_quality_fig12.png.
"""

from __future__ import annotations

import json
import time
from pathlib import Path

import numpy as np

from benchmarks.datasets import elephant, machine

OUT = Path(__file__).resolve().parents[1] / "docs" / "results"
KS = (4, 5, 6, 8)
LAMBDAS = (1e-3, 1e-2, 1e-1, 1.0, 10.0)
VALIDATION = "2:457:7"




def frame_errors(asset, reduced, frames):
    """Per-frame (position % of diagonal, normal rad) on the given frame numbers."""
    from rigslim.numerics.blend import linear_blend, per_vertex_normals
    from rigslim.numerics.normal_error import normal_rms_angle

    V, F = asset.mesh.V, asset.mesh.F
    diag = asset.mesh.bbox_diagonal
    T = asset.poses.select(frames).T
    pos, nrm = [], []
    for j in range(len(T)):
        full = linear_blend(V, asset.weights, T[j])
        red = linear_blend(V, reduced, T[j])
        pos.append(100.0 * float(np.sqrt(np.mean(np.sum((full - red) ** 2, axis=1)))) / diag)
        nrm.append(normal_rms_angle(per_vertex_normals(red, F), per_vertex_normals(full, F)))
    return np.array(pos), np.array(nrm)


def rms(x):
    return float(np.sqrt(np.mean(np.asarray(x) ** 2)))


def nnls_reference(asset):
    """Per-vertex non-negative least squares on the example poses WITHOUT sum-to-one
    (scipy.optimize.nnls; the issue's orientation figure). Not a rigslim method:
    its rows do not sum to one, so the rest pose is not reproduced exactly."""
    from scipy.optimize import nnls

    from rigslim.model.weights import ReducedWeights
    from rigslim.plugins.solvers.problem import pose_basis

    t0 = time.perf_counter()
    B, Y = pose_basis(asset, asset.influences)
    alpha = np.array([nnls(B[v].T, Y[v])[0] for v in range(len(B))])
    red = ReducedWeights.from_influences(asset.influences, alpha, asset.weights.shape[1])
    return red, {"seconds": time.perf_counter() - t0, "row_sum_min": float(alpha.sum(1).min()),
                 "row_sum_max": float(alpha.sum(1).max())}


def solve(asset, method, **params):
    from rigslim.plugins.solvers.methods import LaplacianParams, PoissonParams, ReductionParams, solve_weights
    from rigslim.plugins.solvers.renormalised import renormalised_weights

    t0 = time.perf_counter()
    if method == "nnls":
        return nnls_reference(asset)
    if method == "k-largest":
        return renormalised_weights(asset.weights, asset.influences), {"seconds": time.perf_counter() - t0}
    cls = {"geometric": ReductionParams, "smooth": LaplacianParams, "poisson": PoissonParams}[method]
    red, rep = solve_weights(asset, method, cls(**params))
    rep["seconds"] = time.perf_counter() - t0
    return red, rep


def main():
    from rigslim.model.poses import parse_frames
    from rigslim.numerics.largest_entries import k_largest

    asset = elephant(0)
    test = asset.split.test
    val = [f for f in parse_frames(VALIDATION, len(asset.poses)) if f not in set(asset.split.examples)]
    results = {"machine": machine(), "examples": asset.split.examples, "test_frames": test,
               "validation_frames": val, "vertices": asset.mesh.n_vertices, "runs": []}
    rows = []
    for k in KS:
        asset.influences = k_largest(asset.weights, k)
        base_red, _ = solve(asset, "k-largest")
        bp, bn = frame_errors(asset, base_red, val)
        # Lambda on the validation frames.
        scores = {}
        for lam in LAMBDAS:
            red, _ = solve(asset, "poisson", position_weight=lam)
            p, n = frame_errors(asset, red, val)
            scores[lam] = rms(p) / rms(bp) + rms(n) / rms(bn)
        best = min(scores, key=scores.get)
        for name, method, params in [("k-largest", "k-largest", {}), ("geometric", "geometric", {}),
                                     ("smooth", "smooth", {}), ("poisson", "poisson", {}),
                                     ("poisson+lambda", "poisson", {"position_weight": best}),
                                     ("nnls, no sum-to-one (reference)", "nnls", {})]:
            red, rep = solve(asset, method, **params)
            p, n = frame_errors(asset, red, test)
            neg = float(red.values.min())
            run = {"k": k, "method": name, "params": params, "position_pct_mean": float(p.mean()),
                   "normal_rad_mean": float(n.mean()), "position_pct_rms_over_frames": rms(p),
                   "normal_rad_rms_over_frames": rms(n), "position_per_frame": p.tolist(),
                   "normal_per_frame": n.tolist(),
                   "seconds": rep["seconds"], "min_weight": neg,
                   "solver": {kk: v for kk, v in rep.items() if kk != "seconds"}}
            if name == "poisson+lambda":
                run["lambda_scores"] = {str(l): s for l, s in scores.items()}
            results["runs"].append(run)
            rows.append((k, name + (f" ({best:g})" if name == "poisson+lambda" else ""), p.mean(), n.mean(),
                         rep["seconds"]))
            print(f"k={k} {rows[-1][1]:<34} pos {p.mean():.4f}%  normal {n.mean():.4f} rad  "
                  f"{rep['seconds']:.2f} s", flush=True)
    OUT.mkdir(parents=True, exist_ok=True)
    from rigslim.io.atomic import atomic_path

    with atomic_path(OUT / "reduction_quality.json") as tmp:
        Path(tmp).write_text(json.dumps(results, indent=1))
    m = results["machine"]
    lines = [f"# Reduction quality: elephant ({asset.mesh.n_vertices} vertices, 24 bones)", "",
             f"Machine: {m['cpu']}, nproc {m['nproc']}. Example frames `0:457:45` (11), test frames "
             f"`5:457:7` ({len(test)}, never used for fitting), lambda chosen on validation frames "
             f"`{VALIDATION}` ({len(val)}). All methods non-negative, solver `auto`, mass-weighted Laplacian.", "",
             "Errors are per-frame RMS over vertices, averaged over the test frames (the metrics JSON `mean`).", "",
             "| k | method | position RMS (% diag) | normal RMS (rad) | solve time (s) |", "|---|---|---|---|---|"]
    lines += [f"| {k} | {n} | {p:.4f} | {nr:.4f} | {s:.2f} |" for k, n, p, nr, s in rows]
    with atomic_path(OUT / "reduction_quality.md") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))
    plots(results)


def plots(results):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rigslim.io.atomic import atomic_path

    runs = results["runs"]
    frames = results["test_frames"]
    fig, ax = plt.subplots(1, 2, figsize=(12, 4))
    for r in runs:
        if r["k"] == 4:
            ax[0].plot(frames, r["position_per_frame"], label=r["method"])
            ax[1].plot(frames, r["normal_per_frame"], label=r["method"])
    ax[0].set(xlabel="test frame", ylabel="position RMS (% bbox diagonal)", title="k = 4")
    ax[1].set(xlabel="test frame", ylabel="normal RMS (rad)", title="k = 4")
    ax[0].legend()
    fig.tight_layout()
    with atomic_path(OUT / "reduction_quality_fig10.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)
    fig, ax = plt.subplots(1, 2, figsize=(12, 4))
    for name in dict.fromkeys(r["method"] for r in runs):
        sel = [r for r in runs if r["method"] == name]
        ax[0].plot([r["k"] for r in sel], [r["position_pct_mean"] for r in sel], "o-", label=name)
        ax[1].plot([r["k"] for r in sel], [r["normal_rad_mean"] for r in sel], "o-", label=name)
    ax[0].set(xlabel="k", ylabel="position RMS (% bbox diagonal)")
    ax[1].set(xlabel="k", ylabel="normal RMS (rad)")
    ax[0].legend()
    fig.tight_layout()
    with atomic_path(OUT / "reduction_quality_fig12.png") as tmp:
        fig.savefig(tmp, format="png", dpi=100)


if __name__ == "__main__":
    import sys

    if len(sys.argv) > 1 and sys.argv[1] == "best-fit":
        # best-fit influence sets against k-largest sets and Dem Bones: benchmarks/reduction_best_fit.py
        from benchmarks.reduction_best_fit import main as best_fit_main

        sys.argv.pop(1)
        best_fit_main()
    else:
        main()
