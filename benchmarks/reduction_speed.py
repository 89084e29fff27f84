"""Reduction speed: every method and solver path on the elephant at three sizes, and Dem Bones.

Meshes: the elephant (6,034 vertices) and the elephant midpoint-subdivided
2x (~96.5k) and 3x (~386k) with weights interpolated
(:mod:`benchmarks.datasets`). k = 4 from the k-largest influence sets;
example frames ``0:457:45`` (11 poses); skeleton default ``nonnegative: true``
except on the ``global`` rows (equality constraints only, by definition).

Rows (seconds of wall time, including building the energy):
- ``k-largest``: renormalised selected weights;
- ``geometric local`` (numpy / OpenCL): one exact pass (independent vertices);
- ``smooth`` / ``poisson`` ``global direct``: the exact factorisation of the
  equality-constrained null-space system (MKL PARDISO when ``pypardiso`` is
  installed, SuperLU otherwise; the ``factorisation`` field says which;
  levels <= ``--no-global-above``);
- ``smooth`` / ``poisson`` ``global amg-cg``: the same system by CG with the
  multilevel V-cycle (per-vertex solves as smoother, pyamg smoothed
  aggregation below; ``residual_tolerance`` 1e-6, at most ``CG_CAPS`` iterations on the
  larger meshes); ``gap`` against the direct row;
- ``smooth`` / ``poisson`` ``local sweeps`` (numpy / OpenCL on PoCL): the
  paper's plain block-SOR sweeps (relaxation 1.85) with non-negativity from
  the k-largest weights, to ``tolerance`` 1e-5 on the 6k mesh, a fixed sweep
  budget above (levels <= ``--sweeps-up-to``);
- ``poisson local multilevel`` / ``poisson auto`` (non-negative): the
  equality-only optimum (multilevel CG / direct-or-AMG-CG), projected per
  vertex, then projected local sweeps (caps ``CG_CAPS``, ``SWEEP_CAPS`` on the larger meshes);
  KKT residual relative to the k-largest start; ``poisson auto opencl``: the
  same with the projected sweeps on OpenCL;
- Dem Bones (py-dem-bones 0.13, ``DemBones.computeWeights``): its weight
  update only, bone transforms fixed to the true ones, nnz = 4, 11 example
  frames, default smoothness (weightsSmooth 1e-4, 3 inner iterations).
Test-frame errors (``5:457:7``, all 64 frames on the 6k mesh, every 4th on
the subdivided meshes) for k-largest, geometric, Poisson global and auto,
and Dem Bones.

Run: ``PYTHONPATH=. .venv/bin/python benchmarks/reduction_speed.py [--levels 0 2 3]``
Writes docs/results/reduction_speed.{json,md}.
"""

from __future__ import annotations

import argparse
import gc
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.datasets import elephant
from benchmarks.reduction_quality import OUT, frame_errors, machine

K = 4
#: Plain local sweeps (paper's solver) on the larger meshes: a fixed budget.
SWEEP_BUDGET = {2: 10, 3: 5}
#: Non-negative Poisson on the larger meshes (``auto``: AMG-CG above global_max_unknowns, projection,
#: sweeps): caps on CG iterations and projected sweeps that keep the 386k mesh near the 60 s target.
CG_CAPS = {2: {"max_iterations": 150}, 3: {"max_iterations": 40}}
SWEEP_CAPS = {2: {"max_sweeps": 20}, 3: {"max_sweeps": 5}}
#: Test frames used for errors on the subdivided meshes (every 4th of 5:457:7; all on the 6k mesh).
TEST_STRIDE = {2: 4, 3: 4}


def dem_bones_weights(asset, k):
    """Dem Bones' weight update with the true bone transforms held fixed; returns (csr, seconds)."""
    import py_dem_bones as pdb
    import scipy.sparse as sp

    from rigslim.numerics.blend import linear_blend

    V = asset.mesh.V
    T = asset.example_poses().T
    nF, nB = T.shape[:2]
    w = pdb.DemBonesWrapper()
    w.set_rest_pose(V.T.copy())
    M = np.zeros((nF, nB, 4, 4))
    M[:, :, :3, :] = T
    M[:, :, 3, 3] = 1.0
    w.set_transformations(M)
    w.set_weights(asset.weights.toarray().T.copy())
    d = w._dem_bones
    d.nS = 1
    d.fStart = np.array([0, nF])
    d.subjectID = np.zeros(nF, dtype=int)
    d.nnz = k
    d.set_rest_pose(V.T.copy())
    d.set_animated_poses(np.concatenate([linear_blend(V, asset.weights, T[j]).T for j in range(nF)], axis=0))
    t0 = time.perf_counter()
    d.computeWeights()
    seconds = time.perf_counter() - t0
    return sp.csr_matrix(np.asarray(d.get_weights()).T), seconds


def run_method(asset, method, **params):
    from rigslim.plugins.solvers.methods import LaplacianParams, PoissonParams, ReductionParams, solve_weights
    from rigslim.plugins.solvers.renormalised import renormalised_weights

    t0 = time.perf_counter()
    if method == "k-largest":
        red = renormalised_weights(asset.weights, asset.influences)
        return red, {"seconds": time.perf_counter() - t0}
    cls = {"geometric": ReductionParams, "smooth": LaplacianParams, "poisson": PoissonParams}[method]
    red, rep = solve_weights(asset, method, cls(**params))
    rep["seconds"] = time.perf_counter() - t0
    return red, rep


def main():
    ap = argparse.ArgumentParser()
    ap.add_argument("--levels", type=int, nargs="*", default=[0, 2, 3])
    ap.add_argument("--no-global-above", type=int, default=3,
                    help="skip the direct global rows above this subdivision level (factorisation memory: "
                         "SuperLU needs > 15 GB at level 3, PARDISO 6.8 GB)")
    ap.add_argument("--sweeps-up-to", type=int, default=2,
                    help="run the plain local sweep rows (paper's solver) up to this subdivision level")
    args = ap.parse_args()
    from rigslim.device.opencl import get_runtime
    from rigslim.numerics.largest_entries import k_largest

    try:
        cl_name = get_runtime(None).name
    except Exception as e:  # noqa: BLE001 - recorded in the results
        cl_name = f"unavailable: {e}"
    results = {"machine": machine(), "opencl_device": cl_name, "k": K, "rows": []}
    table = []
    for level in args.levels:
        asset = elephant(level)
        asset.influences = k_largest(asset.weights, K)
        m = asset.mesh.n_vertices
        budget = SWEEP_BUDGET.get(level)
        sweep = {} if budget is None else {"max_sweeps": budget, "tolerance": 1e-30}
        plan = [("k-largest", "k-largest", {}),
                ("geometric local numpy", "geometric", {}),
                ("geometric local opencl", "geometric", {"device": "opencl"})]
        for method in ("smooth", "poisson"):
            if level <= args.no_global_above:
                plan.append((f"{method} global direct", method, {"solver": "global", "nonnegative": False}))
            plan.append((f"{method} global amg-cg", method, {"solver": "global", "nonnegative": False,
                                                             "global_max_unknowns": 0,
                                                             **CG_CAPS.get(level, {})}))
            if level <= args.sweeps_up_to:
                plan.append((f"{method} local sweeps numpy", method, {"solver": "local", "multilevel": False,
                                                                      **sweep}))
                plan.append((f"{method} local sweeps opencl", method, {"solver": "local", "multilevel": False,
                                                                       "device": "opencl", **sweep}))
        caps = {**CG_CAPS.get(level, {}), **SWEEP_CAPS.get(level, {})}
        plan.append(("poisson local multilevel", "poisson", {"solver": "local", **caps}))
        plan.append(("poisson auto", "poisson", {"solver": "auto", **caps}))
        plan.append(("poisson auto opencl", "poisson", {"solver": "auto", "device": "opencl", **caps}))
        test = asset.split.test[::TEST_STRIDE.get(level, 1)]
        direct_energy = {}
        with_errors = ("k-largest", "geometric local numpy", "poisson auto", "poisson global")
        for name, method, params in plan:
            gc.collect()
            red, rep = run_method(asset, method, **params)
            row = {"vertices": m, "level": level, "row": name, "params": params, "seconds": rep["seconds"],
                   "path": rep.get("path"), "sweeps": rep.get("sweeps"),
                   "iterations": rep.get("iterations", rep.get("equality_iterations")),
                   "energy": rep.get("energy"), "energy_start": rep.get("energy_start"),
                   "converged": rep.get("converged"), "kkt_residual": rep.get("kkt_residual"),
                   "equality_optimum": rep.get("equality_optimum"),
                   "gap_above_equality_optimum": rep.get("gap_above_equality_optimum"),
                   "colors": rep.get("colors"), "backend": rep.get("backend"), "levels": rep.get("levels"),
                   "factorisation": rep.get("factorisation")}
            ref = direct_energy.get(method)
            if ref is not None and rep.get("energy") is not None and params.get("nonnegative") is False:
                row["gap_to_direct"] = (rep["energy"] - ref) / abs(ref)
            if name.endswith("global direct"):
                direct_energy[method] = rep["energy"]
            if level == 0 or name.startswith(with_errors):
                p, n = frame_errors(asset, red, test)
                row.update(position_pct=float(p.mean()), normal_rad=float(n.mean()), test_frames=len(test))
            results["rows"].append(row)
            table.append(row)
            extra = "" if row.get("sweeps") is None else f" sweeps {row['sweeps']}"
            extra += "" if row.get("iterations") is None else f" CG {row['iterations']}"
            extra += "" if row.get("kkt_residual") is None else f" kkt {row['kkt_residual']:.2e}"
            extra += "" if row.get("gap_to_direct") is None else f" gap {row['gap_to_direct']:.2e}"
            print(f"{m:>7} {name:<24} {rep['seconds']:8.2f} s{extra}", flush=True)
            del red
        try:
            W, secs = dem_bones_weights(asset, K)
            row = {"vertices": m, "level": level, "row": "Dem Bones computeWeights", "seconds": secs}
            p, n = frame_errors(asset, W, test)
            row.update(position_pct=float(p.mean()), normal_rad=float(n.mean()), test_frames=len(test))
        except ImportError as e:
            row = {"vertices": m, "level": level, "row": "Dem Bones computeWeights", "error": str(e)}
        results["rows"].append(row)
        table.append(row)
        print(f"{m:>7} {'Dem Bones computeWeights':<24} {row.get('seconds', float('nan')):8.2f} s", flush=True)
        del asset
    from rigslim.io.atomic import atomic_path

    with atomic_path(OUT / "reduction_speed.json") as tmp:
        Path(tmp).write_text(json.dumps(results, indent=1, default=float))
    mach = results["machine"]
    lines = ["# Reduction speed: elephant, k = 4", "",
             f"Machine: {mach['cpu']}, nproc {mach['nproc']} (shared with other jobs). OpenCL: {cl_name}.", "",
             "Energies are each method's own (not comparable across methods). `sweeps` on the larger meshes is a fixed "
             "budget, not convergence: see `energy / start`. Test errors: all 64 test frames on the 6k mesh, every "
             "4th (16) on the subdivided meshes.", "",
             "`CG` = conjugate-gradient iterations of the multilevel / AMG-CG equality solve; `gap` = relative energy "
             "gap to the direct solve (equality-only rows); `KKT` = relative KKT residual (non-negative rows: relative "
             "to the k-largest start; equality rows: reduced-gradient norm relative to the start).", "",
             "| vertices | method / solver | seconds | CG | sweeps | energy / start | gap | KKT | "
             "test position (% diag) | test normal (rad) |", "|---|---|---|---|---|---|---|---|---|---|"]
    for r in table:
        ratio = (f"{r['energy'] / r['energy_start']:.4f}" if r.get("energy") is not None and r.get("energy_start")
                 else "")
        pos = f"{r['position_pct']:.4f}" if "position_pct" in r else ""
        nrm = f"{r['normal_rad']:.4f}" if "normal_rad" in r else ""
        sw = "" if r.get("sweeps") is None else str(r["sweeps"])
        cg = "" if r.get("iterations") is None else str(r["iterations"])
        gap = "" if r.get("gap_to_direct") is None else f"{r['gap_to_direct']:.1e}"
        kkt = "" if r.get("kkt_residual") is None else f"{r['kkt_residual']:.1e}"
        secs = f"{r['seconds']:.2f}" if "seconds" in r else r.get("error", "")
        lines.append(f"| {r['vertices']:,} | {r['row']} | {secs} | {cg} | {sw} | {ratio} | {gap} | {kkt} | {pos} | "
                     f"{nrm} |")
    with atomic_path(OUT / "reduction_speed.md") as tmp:
        Path(tmp).write_text("\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
