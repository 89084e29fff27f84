"""Iterative alternatives to Poisson's direct factorisation on the armadillo cage (110 -> 8), measured.

The direct path (``benchmarks/poisson_speed.py``) spends about 9 s of a 12 s Poisson solve factorising the
7 x 7 block system ``A z = -g`` of :mod:`rigslim.plugins.solvers.nullspace` (the 2-ring pattern of
``Q = L^T M^-1 L``; about 200M non-zeros in the factor). Issue 22 asks for Poisson <= 3x geometric with the
same optimum (relative energy gap <= 1e-6). This benchmark records what three cheaper routes give on that
problem, each against the direct optimum ``E*``:

1. **Range-projected bilaplacian** preconditioned CG. ``A = Bn (I_D (x) Q) Bn^T + E`` with the per-vertex
   null-space basis ``Bn_v`` (r x D, D = 3 x poses). If ``Bn_v`` were the same at every vertex,

       P = S^T (Q + delta I)^-1 S,     S_v = Bn_v^T (Bn_v Bn_v^T + tau I)^-1

   would be ``A^-1`` exactly, for the price of one scalar factorisation of ``Q`` (18 right-hand sides per
   application). ``tau`` (relative to the mean of ``tr(Bn_v Bn_v^T) / r``) regularises the local inverses.
2. **Subspace split** preconditioned CG: per vertex, the right singular vectors of ``Bn_v`` split the r
   unknowns into the ``split`` well-seen directions and the rest; ``A`` rotated into them, with the coupling
   between the two groups dropped, is factorised exactly as two block systems of block sizes ``split`` and
   ``r - split`` ((3^3 + 4^3) / 7^3 = 27 % of the direct path's block flops).
3. **Single precision** factorisation (PARDISO ``iparm(28) = 1``) as the preconditioner of iterative
   refinement.

Writes ``docs/results/poisson_preconditioners.{json,md}``: the gap after given iteration counts, the seconds,
and how each route ended. Iteration counts and gaps do not depend on the machine's load; seconds do.

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/poisson_preconditioners.py [--iterations 60]
"""

from __future__ import annotations

import argparse
import sys
import time
from dataclasses import replace
from pathlib import Path
from types import SimpleNamespace

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402
from benchmarks.poisson_speed import armadillo_asset  # noqa: E402

OUT = ROOT / "docs" / "results"
#: Iterations after which the gap is recorded (besides the last).
CHECKPOINTS = (1, 11, 21, 41)


def pcg(Amul, Pmul, b: np.ndarray, z: np.ndarray, gap, iterations: int) -> dict:
    """Preconditioned conjugate gradients from ``z``; ``gap(z)`` the relative energy gap, recorded after
    the :data:`CHECKPOINTS` iterations and the last (stops below 1e-6)."""
    t0 = time.perf_counter()
    res = b - Amul(z)
    y = Pmul(res)
    p, rho = y.copy(), float(np.sum(res * y))
    trace = {}
    for it in range(iterations):
        Ap = Amul(p)
        step = rho / float(np.sum(p * Ap))
        z = z + step * p
        res = res - step * Ap
        y = Pmul(res)
        rho_next = float(np.sum(res * y))
        if it + 1 in CHECKPOINTS or it == iterations - 1:
            g = gap(z)
            trace[it + 1] = g
            print(f"  iteration {it + 1}: gap {g:.3e} ({time.perf_counter() - t0:.1f} s)", flush=True)
            if g <= 1e-6:
                break
        p = y + (rho_next / rho) * p
        rho = rho_next
    return {"gaps": trace, "iterations": max(trace), "final_gap": trace[max(trace)],
            "seconds": time.perf_counter() - t0}


def pardiso_factor(indptr, indices, values, block: int, rows: int, single: bool = False):
    """Factorise an SPD upper (block) triangle of ``rows`` scalar rows with PARDISO; returns ``solve(x)``, or
    raises PARDISO's error."""
    from rigslim.plugins.solvers.global_solver import pardiso_solver

    dtype = np.float32 if single else np.float64
    if block > 1:
        matrix = SimpleNamespace(indptr=indptr, indices=indices, data=values.astype(dtype),
                                 shape=(len(indptr) - 1,) * 2)
    else:
        matrix = sp.csr_matrix((values.astype(dtype), indices, indptr))
    solver = pardiso_solver(block if block > 1 else 0)
    if single:
        solver.set_iparm(28, 1)
    solver.set_phase(12)
    solver._call_pardiso(matrix, np.zeros((rows, 1), dtype, order="F"))

    def solve(x: np.ndarray) -> np.ndarray:
        solver.set_phase(33)
        rhs = np.asfortranarray(x.reshape(rows, -1).astype(dtype))
        return np.asarray(solver._call_pardiso(matrix, rhs), np.float64)
    return solve


def range_projected(prob, system, A, Bn, tau: float, delta: float, iterations: int, gap) -> dict:
    """Route 1 (module docstring): CG from the k-largest weights."""
    m, r, _ = system.N.shape
    t = time.perf_counter()
    G = np.einsum("mid,mjd->mij", Bn, Bn)
    scale = float(np.einsum("mii->m", G).mean()) / r
    eye = np.eye(r)[None]
    Ginv = np.linalg.inv(G + tau * scale * eye + system.dummy[:, :, None] * eye)
    S = np.einsum("mid,mij->mdj", Bn, Ginv)
    Q = sp.csr_matrix(prob.Q)
    U = sp.triu(Q + delta * float(Q.diagonal().mean()) * sp.identity(m), format="csr")
    U.sort_indices()
    solve = pardiso_factor(U.indptr, U.indices, U.data, 1, m)
    setup = time.perf_counter() - t

    def Pmul(res):
        Z = solve(np.einsum("mdj,mj->md", S, res.reshape(m, r)))
        return (np.einsum("mdj,md->mj", S, Z) + system.dummy * res.reshape(m, r)).ravel()
    z0 = np.einsum("mrk,mk->mr", system.N, prob.alpha0 - system.base).ravel()
    out = pcg(lambda z: A @ z, Pmul, system.rhs, z0, gap, iterations)
    return out | {"setup_seconds": setup, "tau": tau, "delta": delta}


def subspace_split(system, A, Bn, split: int, iterations: int, gap) -> dict:
    """Route 2 (module docstring): CG from the split preconditioner's own solution."""
    m, r, _ = system.N.shape
    t = time.perf_counter()
    Ur = np.linalg.svd(Bn, full_matrices=False)[0]                       # (m, r, r)
    rows = np.repeat(np.arange(m), np.diff(system.indptr))
    cols = system.indices
    rotated = np.einsum("pji,pjk,pkl->pil", Ur[rows], system.blocks, Ur[cols])
    groups = [np.arange(split), np.arange(split, r)]
    # the group's blocks on the same pattern: NullSpaceSystem.upper_blocks writes their upper triangle
    solves = [pardiso_factor(*replace(system, blocks=np.ascontiguousarray(rotated[:, g][:, :, g])).upper_blocks(),
                             len(g), m * len(g)) for g in groups]
    setup = time.perf_counter() - t

    def rotate(z, back=False):
        return np.einsum("mij,mj->mi" if back else "mji,mj->mi", Ur, z.reshape(m, r)).ravel()

    def Pmul(res):
        res = res.reshape(m, r)
        out = np.empty_like(res)
        for g, solve in zip(groups, solves, strict=True):
            out[:, g] = solve(np.ascontiguousarray(res[:, g])).reshape(m, len(g))
        return out.ravel()
    b = rotate(system.rhs)
    out = pcg(lambda z: rotate(A @ rotate(z, back=True)), Pmul, b, Pmul(b), lambda z: gap(rotate(z, back=True)),
              iterations)
    return out | {"setup_seconds": setup, "split": split}


def single_precision(system) -> dict:
    """Route 3 (module docstring): whether PARDISO factorises the system in single precision."""
    r = system.N.shape[1]
    t = time.perf_counter()
    try:
        pardiso_factor(*system.upper_blocks(), r, system.unknowns, single=True)
    except Exception as err:  # noqa: BLE001 - PARDISO's error is the finding
        return {"factorised": False, "error": str(err), "seconds": time.perf_counter() - t}
    return {"factorised": True, "seconds": time.perf_counter() - t}


def main(argv=None) -> None:
    from rigslim.plugins.solvers.global_solver import global_solve
    from rigslim.plugins.solvers.nullspace import nullspace_system
    from rigslim.plugins.solvers.problem import build_problem

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--iterations", type=int, default=60, help="CG iterations per route at most (>= 1)")
    args = ap.parse_args(argv)
    if args.iterations < 1:
        ap.error(f"--iterations {args.iterations}: give at least 1")
    asset, _ = armadillo_asset()
    prob = build_problem(asset, "poisson", nonnegative=False)
    t = time.perf_counter()
    a_star, rep = global_solve(prob)
    direct_s = time.perf_counter() - t
    E_star = prob.energy(a_star)
    system = nullspace_system(prob)
    A = system.matrix().tocsr()          # the system the routes iterate on, in scalar CSR once
    Bn = np.einsum("mrk,mkd->mrd", system.N, prob.B)
    sv = np.linalg.svd(Bn, compute_uv=False)

    def gap(z):
        return (prob.energy(np.where(prob.valid, system.weights(z), 0.0)) - E_star) / E_star
    routes = {}
    for tau in (1e-10, 1e-4, 1e-2):
        print(f"range-projected bilaplacian, tau {tau:g}", flush=True)
        routes[f"range-projected, tau {tau:g}"] = range_projected(prob, system, A, Bn, tau, 1e-6,
                                                                  args.iterations, gap)
    print("subspace split 3 + 4", flush=True)
    routes["subspace split 3 + 4"] = subspace_split(system, A, Bn, 3, args.iterations, gap)
    single = single_precision(system)
    result = {"machine": machine(), "vertices": asset.mesh.n_vertices, "unknowns": system.unknowns,
              "direct_seconds": direct_s, "direct_energy": E_star, "direct_factorisation": rep.get("factorisation"),
              "singular_values_relative": np.percentile(sv / sv[:, :1], [5, 50, 95], axis=0).tolist(),
              "routes": routes, "single_precision": single}
    text = "\n".join(report_lines(result)) + "\n"
    write_results(OUT / "poisson_preconditioners", result, text)
    print(text)


def report_lines(result: dict) -> list[str]:
    """The markdown page."""
    mach = result["machine"]
    median = ", ".join(f"{x:.3g}" for x in result["singular_values_relative"][1])
    lines = ["# Iterative alternatives to Poisson's direct solve (armadillo cage, 110 -> 8)", "",
             f"Machine: {mach['cpu']}, nproc {mach['nproc']} (seconds: one run on a shared machine). "
             "`benchmarks/poisson_preconditioners.py`; the routes are described in its docstring. "
             f"{result['vertices']:,} vertices, {result['unknowns']:,} null-space unknowns; the direct optimum "
             f"(PARDISO) E* = {result['direct_energy']:.10g} in {result['direct_seconds']:.2f} s. Gap: "
             "(E - E*) / E*; the issue's target needs <= 1e-6 in under about 3.8 s.", "",
             "| route | setup (s) | CG (s) | " + " | ".join(f"gap after {i}" for i in CHECKPOINTS)
             + " | last: iterations, gap |", "|---|---|---|" + "---|" * (len(CHECKPOINTS) + 1)]
    for name, r in result["routes"].items():
        gaps = {int(i): g for i, g in r["gaps"].items()}          # JSON keys are strings
        cells = [f"{gaps[i]:.2e}" if i in gaps else "" for i in CHECKPOINTS]
        lines.append(f"| {name} | {r['setup_seconds']:.2f} | {r['seconds']:.2f} | " + " | ".join(cells)
                     + f" | {r['iterations']}: {r['final_gap']:.2e} |")
    single = result["single_precision"]
    lines += ["", "Single-precision factorisation: " + ("factorised" if single["factorised"] else
              f"refused ({single['error']} -4 is a zero pivot: the 1e-9 ridge is below single precision)") + ".",
              "",
              f"Why: the median vertex's null-space basis has singular values {median} (relative to its largest): "
              "three directions (the local affine motion of the cage) are well seen by the example poses and four "
              "are 10-1000 times weaker. The weak directions carry the bilaplacian coupling with "
              "small coefficients, and the k-largest sets change from vertex to vertex, so a preconditioner that "
              "treats each vertex's basis as locally constant (route 1) or drops the coupling between the two "
              "groups (route 2) leaves CG far from 1e-6 after dozens of iterations, each costing about as much as "
              "a factorisation's solve; single precision cannot hold the 1e-9 ridge that makes the system "
              "definite. The direct factorisation stays the default."]
    return lines


if __name__ == "__main__":
    main()
