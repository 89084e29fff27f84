"""The global solver: the exact optimum of a reduction energy with equality constraints only.

With ``a = vec(alpha)`` (m k unknowns), the energy of
:mod:`rigslim.plugins.solvers.problem` is ``a^T H a + 2 f^T a + const`` with
the sparse block matrix

    H_{(v,l),(w,l')} = Q_vw (B_v^T B_w)_{l l'} + eps [v = w, l = l']
    f_v = -B_v^T (Q Y)_v - eps alpha0_v

(padding slots are decoupled identity rows, so they solve to zero). The
per-vertex constraints ``C_v alpha_v = d_v`` are eliminated:
``alpha_v = C_v^+ d_v + N_v z_v`` with ``N_v`` an orthonormal basis of the
null space of ``C_v`` (SVD, so redundant rows are harmless), leaving the
symmetric positive definite system

    (N^T H N) z = -N^T (H a_p + f)

assembled blockwise in the null-space coordinates without forming ``H``
(:func:`rigslim.plugins.solvers.nullspace.nullspace_system`; ``H`` and ``f``
are kept here, :func:`assemble_hessian` and :func:`linear_term`, as the
reference the tests check that system against) and solved by a sparse direct
factorisation: Intel MKL PARDISO's supernodal Cholesky (``pypardiso``, the ``fast-direct`` extra; nested-dissection
ordering, real symmetric positive definite mode on the upper block triangle, read as r x r block sparse rows) when
it is installed, SuperLU otherwise (symmetric minimum-degree ordering, no
pivoting). This is the exact minimiser without inequality constraints, and
the reference every iterative solver is checked against.

SuperLU's fill grows fast with the mesh (the 386k-vertex elephant's
factorisation was stopped at 15 GB; PARDISO needs 6.8 GB there), so above
``max_direct_unknowns`` (:func:`default_max_direct_unknowns`) the
same system is solved by conjugate gradients preconditioned with the
multilevel V-cycle of :mod:`rigslim.plugins.solvers.multilevel_solver`
(smoothed-aggregation hierarchy from ``pyamg``), to a relative
reduced-gradient norm ``tolerance``: memory linear in the mesh size.
"""

from __future__ import annotations

import glob
import os
import sys
import time

import numpy as np
import scipy.sparse as sp
import scipy.sparse.linalg as spla

from rigslim.plugins.solvers.nullspace import nullspace_system


def assemble_hessian(prob, chunk: int = 100_000) -> sp.csr_matrix:
    """The (m k, m k) sparse Hessian ``H`` of the module docstring.

    Blocks ``Q_vw B_v^T B_w`` are formed ``chunk`` vertex pairs at a time, so
    memory stays at ``chunk * k * D`` doubles beyond the result.
    """
    m, k = prob.m, prob.k
    Q = sp.coo_matrix(prob.Q)
    parts = []
    kk = np.arange(k)
    for lo in range(0, Q.nnz, chunk):
        rows, cols, q = Q.row[lo:lo + chunk], Q.col[lo:lo + chunk], Q.data[lo:lo + chunk]
        blocks = np.einsum("pkd,pld->pkl", prob.B[rows], prob.B[cols]) * q[:, None, None]
        r = np.broadcast_to(rows[:, None, None] * k + kk[None, :, None], blocks.shape)
        c = np.broadcast_to(cols[:, None, None] * k + kk[None, None, :], blocks.shape)
        parts.append(sp.csr_matrix((blocks.ravel(), (r.ravel(), c.ravel())), shape=(m * k, m * k)))
    H = parts[0] if len(parts) == 1 else sp.csr_matrix(sum(parts[1:], parts[0]))
    pad = (~prob.valid).ravel()
    diag = np.where(pad, 1.0, prob.eps)
    return (H + sp.diags(diag)).tocsr()


def linear_term(prob) -> np.ndarray:
    """``f`` (m k,) of the module docstring (zero on padding)."""
    QY = np.asarray(prob.Q @ prob.Y)
    f = -np.einsum("mkd,md->mk", prob.B, QY) - prob.eps * prob.alpha0
    return np.where(prob.valid, f, 0.0).ravel()


#: Direct-solve size limits (m k unknowns) by factorisation back end, the default of the
#: solvers' ``global_max_unknowns``. Measured on the 2-core machine: SuperLU took ~41 s for
#: the 96.5k-vertex elephant (386k unknowns) and was stopped after 5.5 min and 15 GB on the
#: 386k-vertex one (1.54M), which PARDISO solves in 34 s and 6.8 GB.
MAX_DIRECT_UNKNOWNS = {"pardiso": 2_000_000, "superlu": 500_000}


def _locate_mkl_rt() -> None:
    """Point pypardiso at ``mkl_rt`` in this environment's ``lib`` (``PYPARDISO_MKL_RT``) when it is there.

    Without it pypardiso walks ``sys.prefix`` recursively for the library on import and again for
    every solver it creates: 1.4-1.9 s a solve on the 2-core machine (profiled on the armadillo cage),
    paid ``K x grid + 1`` times by ``position_weight: auto``.
    """
    if os.environ.get("PYPARDISO_MKL_RT"):
        return
    found = sorted(glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt.so*")) +
                   glob.glob(os.path.join(sys.prefix, "lib", "libmkl_rt*.dylib")), key=len)
    if found:
        os.environ["PYPARDISO_MKL_RT"] = found[0]


def pardiso_available() -> bool:
    """Whether MKL PARDISO (``pypardiso``) can be imported."""
    _locate_mkl_rt()
    try:
        import pypardiso  # noqa: F401
    except Exception:  # noqa: BLE001 - any import failure means: not usable
        return False
    return True


def default_max_direct_unknowns() -> int:
    """The ``auto`` direct/AMG-CG switch for the factorisation back end that is installed."""
    return MAX_DIRECT_UNKNOWNS["pardiso" if pardiso_available() else "superlu"]


#: MKL PARDISO settings (1-based ``iparm`` numbers) for a real symmetric positive definite matrix:
#: our own values (1), METIS nested dissection (2), no scaling or matching (11, 13; unsymmetric
#: options), report the factor's non-zeros and flops (18, 19). Iterative refinement stays at
#: PARDISO's "only after perturbed pivots" (8 = 0): on the 43k-vertex armadillo cage the default
#: settings refined after every solve (0.81 s against 0.15 s) for the same 4e-15 residual.
PARDISO_SPD_IPARM = {1: 1, 2: 2, 8: 0, 10: 8, 11: 0, 13: 0, 18: -1, 19: -1}


def pardiso_solver(block_size: int = 0):
    """A pypardiso solver for a real SPD matrix (``mtype = 2``) with :data:`PARDISO_SPD_IPARM`;
    ``block_size`` > 1 reads block sparse rows of that block size (``iparm(37)``)."""
    import pypardiso

    _locate_mkl_rt()
    solver = pypardiso.PyPardisoSolver(mtype=2)
    for i, value in {**PARDISO_SPD_IPARM, 37: block_size}.items():
        solver.set_iparm(i, value)
    return solver


def pardiso_block_solve(indptr: np.ndarray, indices: np.ndarray, values: np.ndarray, block: int,
                        b: np.ndarray) -> np.ndarray:
    """Solve ``A x = b`` for a block-sparse SPD ``A`` given as its upper block triangle.

    PARDISO's block sparse row input (``iparm(37) = block``): the ordering and the symbolic
    factorisation run on the block graph (m nodes, not m r), and the supernodes are whole blocks. On
    the armadillo cage (43k vertices, 7 x 7 blocks) analysis 0.28 s and solve 0.12 s against 1.85 s
    and 0.81 s on the scalar upper triangle, the same factorisation flops and residual
    (``benchmarks/poisson_speed.py``).

    Parameters
    ----------
    indptr, indices : int32 arrays
        Block CSR pattern of the upper triangle (block columns ``w >= v``, sorted, diagonal present).
    values : (nnz block^2,) float64 array
        The blocks, each stored column by column.
    block : int
        The block size r (>= 2).
    b : (m r,) array

    Returns
    -------
    x : (m r,) array
    """
    from types import SimpleNamespace

    m = len(indptr) - 1
    # pypardiso's matrix check accepts only scipy CSR/CSC; its PARDISO call reads indptr, indices,
    # data and the equation count (block rows for block input), which is all this passes it.
    matrix = SimpleNamespace(indptr=indptr, indices=indices, data=np.ascontiguousarray(values, np.float64),
                             shape=(m, m))
    solver = pardiso_solver(block)
    try:
        solver.set_phase(13)
        x = solver._call_pardiso(matrix, np.asfortranarray(np.asarray(b, np.float64)[:, None]))
    finally:
        solver.free_memory(everything=True)
    return np.asarray(x).ravel()


def spd_solve(A: sp.spmatrix | None, b: np.ndarray, backend: str = "auto", *,
              upper: sp.csr_matrix | None = None) -> tuple[np.ndarray, str]:
    """Solve ``A x = b`` for a sparse symmetric positive definite ``A``.

    Parameters
    ----------
    A : (n, n) sparse matrix, symmetric positive definite
        May be None for ``pardiso`` when ``upper`` is given.
    b : (n,) array
    backend : {"auto", "pardiso", "superlu"}
        ``pardiso``: MKL PARDISO, matrix type 2 (real SPD), given the upper
        triangle; ``superlu``: SuperLU with a symmetric ordering and no
        pivoting; ``auto``: PARDISO when installed.
    upper : (n, n) csr_matrix, optional
        The upper triangle of ``A`` (diagonal included, sorted indices), when the caller has it:
        PARDISO reads only that, and forming it from ``A`` (``scipy.sparse.triu``) took 3-7 s of a
        43k-vertex Poisson solve.

    Returns
    -------
    x : (n,) array
    backend : str
        The back end that solved it.
    """
    if backend == "auto":
        backend = "pardiso" if pardiso_available() else "superlu"
    if backend == "pardiso":
        solver = pardiso_solver()
        if upper is not None:
            U = upper
        else:
            U = sp.triu(A, format="csr")
            U.sort_indices()
        try:
            x = solver.solve(U, np.asarray(b, dtype=np.float64))
        finally:
            solver.free_memory(everything=True)
        return np.asarray(x).ravel(), "pardiso"
    if backend != "superlu":
        raise ValueError(f"unknown direct back end {backend!r}")
    if A is None:
        A = upper + sp.triu(upper, k=1, format="csr").T
    lu = spla.splu(sp.csc_matrix(A), permc_spec="MMD_AT_PLUS_A", diag_pivot_thresh=0.0,
                   options=dict(SymmetricMode=True))
    return lu.solve(b), "superlu"


def global_solve(prob, *, method: str = "direct", max_direct_unknowns: int | None = None,
                 tolerance: float = 1e-6, max_iterations: int = 500, coordinates=None,
                 start=None) -> tuple[np.ndarray, dict]:
    """Minimiser under the equality constraints (``prob.nonneg`` is ignored).

    Parameters
    ----------
    prob : ReductionProblem
    method : {"direct", "amg-cg", "auto"}
        SuperLU, multilevel-preconditioned CG, or direct up to
        ``max_direct_unknowns`` (m k) unknowns and AMG-CG above.
    tolerance, max_iterations, coordinates, start
        AMG-CG only (see :func:`rigslim.plugins.solvers.multilevel_solver.multilevel_solve`).

    Returns
    -------
    alpha : (m, k) array
    report : dict
        ``energy``, ``unknowns``, ``nonzeros``, ``kkt_residual`` (relative
        norm of the reduced gradient ``N^T (H a + f)``), ``seconds``,
        ``solver`` (``direct`` or ``amg-cg``; AMG-CG adds its iterations and levels).
    """
    if max_direct_unknowns is None:
        max_direct_unknowns = default_max_direct_unknowns()
    if method == "auto":
        method = "direct" if prob.m * prob.k <= max_direct_unknowns else "amg-cg"
    if method == "amg-cg":
        from rigslim.plugins.solvers.multilevel_solver import multilevel_solve

        alpha, rep = multilevel_solve(prob, start, tolerance=tolerance, max_iterations=max_iterations,
                                      coordinates=coordinates)
        rep.pop("energy_start", None)
        return alpha, dict(solver="amg-cg", **rep)
    if method != "direct":
        raise ValueError(f"unknown global method {method!r}")
    t0 = time.perf_counter()
    # The eliminated system N^T H N z = -N^T (H a_p + f), assembled blockwise in the
    # null-space coordinates (no (m k)^2 Hessian; rigslim.plugins.solvers.nullspace).
    system = nullspace_system(prob)
    if system.unknowns == 0:  # k = 1 (or every slot fixed): the constraints alone give the weights
        alpha = np.where(prob.valid, system.base, 0.0)
        return alpha, dict(solver="direct", factorisation="none", energy=prob.energy(alpha), unknowns=0, nonzeros=0,
                           kkt_residual=0.0, seconds=time.perf_counter() - t0)
    r = system.N.shape[1]
    if pardiso_available() and r > 1:   # PARDISO on the upper block triangle (block sparse rows)
        z, backend = pardiso_block_solve(*system.upper_blocks(), r, system.rhs), "pardiso"
    elif pardiso_available():   # scalar unknowns: the upper triangle, written straight from the blocks
        z, backend = spd_solve(None, system.rhs, "pardiso", upper=system.upper_triangle())
    else:
        z, backend = spd_solve(system.matrix().tocsr(), system.rhs, "superlu")
    alpha = system.weights(z)
    grad = system.reduced_gradient(prob, alpha)
    kkt = float(np.linalg.norm(grad) / max(float(np.linalg.norm(system.rhs)), 1e-300))
    alpha = np.where(prob.valid, alpha, 0.0)
    report = dict(solver="direct", factorisation=backend, energy=prob.energy(alpha), unknowns=system.unknowns,
                  nonzeros=int(system.blocks.size), kkt_residual=kkt, seconds=time.perf_counter() - t0)
    return alpha, report
