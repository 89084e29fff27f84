"""Poisson against geometric on the armadillo cage (110 -> 8), side by side in one run, and where Poisson's time goes.

Sets up ``examples/armadillo-k8.yaml`` once (mean value coordinates, k-largest sets of 8;
6 example poses), then times in one process:

1. ``geometric`` (``solve_weights``, the pipeline's ``solve`` step);
2. ``poisson`` (lambda = 0, the paper's method) as it runs now: energy, null-space system,
   PARDISO on the upper triangle written from the blocks;
3. the direct path phase by phase, now (the upper block triangle read by PARDISO as 7 x 7 block
   sparse rows, ``iparm(37)``, with rigslim's settings) and as it was before (the scalar upper triangle
   written from the blocks, PARDISO's default settings): symbolic analysis (ordering), numerical
   factorisation (with PARDISO's factor size, ``iparm(18)``) and the triangular solves.

Writes ``docs/results/poisson_speed.{json,md}``: seconds, the ratio to geometric, the relative energy gaps
(the same optimum), the factor's size and flops.

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/poisson_speed.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402
from benchmarks.reduction_cage import PipelineSteps  # noqa: E402

OUT = ROOT / "docs" / "results"
PIPELINE = ROOT / "examples" / "armadillo-k8.yaml"


def armadillo_asset():
    """The asset after the pipeline's ``generate`` and ``select`` steps, and their seconds."""
    run = PipelineSteps(PIPELINE)
    t = time.perf_counter()
    for key in ("generate", "select"):
        run.run(key)
    return run.asset, time.perf_counter() - t


def direct_phases(prob, *, previous: bool) -> dict:
    """The direct solve phase by phase: as it runs now (upper block triangle, block sparse rows, rigslim's
    PARDISO settings) or as it was (``previous``: the scalar upper triangle, PARDISO's default settings)."""
    from types import SimpleNamespace

    import numpy as np
    import pypardiso

    from rigslim.plugins.solvers.global_solver import pardiso_available, pardiso_solver
    from rigslim.plugins.solvers.nullspace import nullspace_system

    pardiso_available()  # sets PYPARDISO_MKL_RT, as the solver does
    out: dict = {}
    t0 = time.perf_counter()
    system = nullspace_system(prob)
    out["system_seconds"] = time.perf_counter() - t0
    r = system.N.shape[1]
    t = time.perf_counter()
    if previous:
        U = system.upper_triangle()
        nnz = U.nnz
    else:
        ptr, idx, vals = system.upper_blocks()
        U = SimpleNamespace(indptr=ptr, indices=idx, data=vals, shape=(len(ptr) - 1,) * 2)
        nnz = vals.size
    out["triu_seconds"] = time.perf_counter() - t
    n = system.unknowns
    t = time.perf_counter()
    solver = pypardiso.PyPardisoSolver(mtype=2) if previous else pardiso_solver(r)
    out["solver_init_seconds"] = time.perf_counter() - t
    zero = np.zeros((n, 1))
    for phase, key in ((11, "analysis_seconds"), (22, "factorisation_seconds")):
        solver.set_phase(phase)
        t = time.perf_counter()
        solver._call_pardiso(U, zero)
        out[key] = time.perf_counter() - t
    solver.set_phase(33)
    t = time.perf_counter()
    z = solver._call_pardiso(U, np.asfortranarray(system.rhs[:, None])).ravel()
    out["solve_seconds"] = time.perf_counter() - t
    # iparm(18): non-zeros of the factor (blocks with block input); previous: scalars
    out["factor_nonzeros"] = int(solver.get_iparm(18)) * (1 if previous else r * r)
    solver.free_memory(everything=True)
    alpha = np.where(prob.valid, system.weights(z), 0.0)
    out["energy"] = prob.energy(alpha)
    out["seconds"] = time.perf_counter() - t0
    out["unknowns"] = n
    out["nonzeros_upper"] = int(nnz)
    return out


def timed_solves(asset) -> dict:
    """Geometric and Poisson (lambda = 0) through ``solve_weights``, one after the other."""
    from rigslim.plugins.solvers.methods import PoissonParams, ReductionParams, solve_weights

    rows = {}
    t = time.perf_counter()
    _, rep = solve_weights(asset, "geometric", ReductionParams())
    rows["geometric"] = {"seconds": time.perf_counter() - t, "path": rep.get("path"), "energy": rep.get("energy")}
    print(f"geometric {rows['geometric']['seconds']:.2f} s", flush=True)
    t = time.perf_counter()
    _, rep = solve_weights(asset, "poisson", PoissonParams())
    rows["poisson"] = {"seconds": time.perf_counter() - t, "path": rep.get("path"),
                       "factorisation": rep.get("factorisation"), "energy": rep["energy"],
                       "unknowns": rep.get("unknowns"), "kkt_residual": rep.get("kkt_residual")}
    print(f"poisson {rows['poisson']['seconds']:.2f} s", flush=True)
    return rows


def main() -> None:
    from rigslim.plugins.solvers.problem import build_problem

    asset, setup_s = armadillo_asset()
    print(f"setup (MVC + select) {setup_s:.1f} s", flush=True)
    rows = timed_solves(asset)
    t = time.perf_counter()
    prob = build_problem(asset, "poisson", nonnegative=False)
    build_s = time.perf_counter() - t
    prev = direct_phases(prob, previous=True)
    now = direct_phases(prob, previous=False)
    prev["seconds_with_energy"] = prev["seconds"] + build_s
    prev["build_seconds"] = now["build_seconds"] = build_s
    gap = (rows["poisson"]["energy"] - prev["energy"]) / abs(prev["energy"])
    geo = rows["geometric"]["seconds"]
    result = {"machine": machine(), "pipeline": str(PIPELINE.relative_to(ROOT)), "k": 8,
              "vertices": asset.mesh.n_vertices, "handles": asset.handles.n, "examples": asset.split.examples,
              "setup_seconds": setup_s, "rows": rows, "previous_direct_path": prev, "direct_path_phases": now,
              "poisson_over_geometric": rows["poisson"]["seconds"] / geo,
              "previous_over_geometric": prev["seconds_with_energy"] / geo, "gap_to_previous": gap,
              "target_poisson_over_geometric": 3.0}
    write_results(OUT / "poisson_speed", result, "\n".join(report_lines(result, asset)) + "\n")
    print("\n".join(report_lines(result, asset)))


def report_lines(result: dict, asset) -> list[str]:
    """The markdown page of ``docs/results/poisson_speed.md``."""
    rows, prev, now = result["rows"], result["previous_direct_path"], result["direct_path_phases"]
    geo = rows["geometric"]["seconds"]
    mach = result["machine"]
    return ["# Poisson speed on the armadillo cage (110 -> 8)", "",
            f"Machine: {mach['cpu']}, nproc {mach['nproc']}, shared with other jobs (timings are of one run, "
            f"side by side). Pipeline `{result['pipeline']}`: {result['vertices']:,} vertices, "
            f"{result['handles']}-vertex cage, k-largest sets of 8, {len(asset.split.examples)} example poses. "
            "`benchmarks/poisson_speed.py`.", "",
            "| solve | seconds | x geometric | energy |", "|---|---|---|---|",
            f"| geometric | {geo:.2f} | 1.00 | |",
            f"| poisson (now: upper block triangle, PARDISO block sparse rows) | {rows['poisson']['seconds']:.2f} | "
            f"{result['poisson_over_geometric']:.1f} | {rows['poisson']['energy']:.10g} |",
            f"| poisson, previous direct path | {prev['seconds_with_energy']:.2f} | "
            f"{result['previous_over_geometric']:.1f} | {prev['energy']:.10g} |", "",
            f"Relative energy gap now - previous: {result['gap_to_previous']:.1e} (the same optimum). "
            "Target: Poisson <= 3x geometric.", "",
            "Where the time goes, phase by phase (the direct path now, and as it was):", "",
            "| phase | now (s) | previous (s) |", "|---|---|---|",
            f"| energy (`build_problem`) | {now['build_seconds']:.2f} | {prev['build_seconds']:.2f} |",
            f"| null-space system (7 x 7 blocks on the pattern of L^T M^-1 L) | {now['system_seconds']:.2f} | "
            f"{prev['system_seconds']:.2f} |",
            f"| upper triangle (now: blocks; previous: scalar CSR from the blocks) | {now['triu_seconds']:.2f} | "
            f"{prev['triu_seconds']:.2f} |",
            f"| PARDISO analysis (ordering, symbolic) | {now['analysis_seconds']:.2f} | "
            f"{prev['analysis_seconds']:.2f} |",
            f"| PARDISO factorisation (now {now['factor_nonzeros'] / 1e6:.0f}M, previous "
            f"{prev['factor_nonzeros'] / 1e6:.0f}M non-zeros in L) | {now['factorisation_seconds']:.2f} | "
            f"{prev['factorisation_seconds']:.2f} |",
            f"| PARDISO solve | {now['solve_seconds']:.2f} | {prev['solve_seconds']:.2f} |",
            "", f"{prev['unknowns']:,} unknowns, {prev['nonzeros_upper'] / 1e6:.1f}M non-zeros in the upper triangle."]


if __name__ == "__main__":
    main()
