"""Harmonic coordinates (Joshi, Meyer, DeRose, Green & Sanocki 2007) on a regular grid.

Each cage vertex's coordinate is the harmonic function inside the cage whose
boundary value is that vertex's piecewise-linear hat function on the cage.
As Joshi et al. did, Laplace's equation is solved by finite differences on a
regular grid covering the cage: no tetrahedral mesher is needed (TetGen, the
usual one, is AGPL), the discretisation is the same for every cage, and the
7-point Laplacian is an M-matrix, so the discrete coordinates keep the
continuous ones' non-negativity and partition of unity exactly.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

import numpy as np
import scipy.sparse as sp
from pydantic import Field
from scipy.sparse.linalg import splu

from rigslim.plugin import WeightGenerator
from rigslim.plugins.generators.cage_setup import CageParams, prepare_cage

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext

#: Offsets of the 7-point stencil's neighbours.
_NEIGHBOURS = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]])


def conjugate_gradient(A, B, *, tol: float = 1e-10, maxiter: int = 10000):
    """Solve ``A X = B`` for a symmetric positive definite A, all columns of B at once.

    Parameters
    ----------
    A : (N, N) sparse matrix
    B : (N, n) array
    tol : float
        Stop when every column's residual satisfies ``|b - A x| <= tol |b|``.

    Returns
    -------
    X : (N, n) array
    iterations : int

    Notes
    -----
    Conjugate gradients run independently per column but vectorised: with
    ``r = b - A x`` and search direction ``p``, each step is
    ``alpha = r.r / p.A p``, ``x += alpha p``, ``r -= alpha A p``,
    ``p = r + (r'.r' / r.r) p`` (Hestenes & Stiefel 1952), one sparse
    matrix times dense block product per iteration.
    """
    B = np.asarray(B, dtype=np.float64)
    X = np.zeros_like(B)
    R = B.copy()
    Pd = R.copy()
    rr = np.einsum("ij,ij->j", R, R)
    stop = tol**2 * np.maximum(rr, 1e-300)
    for it in range(1, maxiter + 1):
        Q = A @ Pd
        alpha = rr / np.maximum(np.einsum("ij,ij->j", Pd, Q), 1e-300)
        X += Pd * alpha
        R -= Q * alpha
        rn = np.einsum("ij,ij->j", R, R)
        if (rn <= stop).all():
            return X, it
        Pd = R + Pd * (rn / np.maximum(rr, 1e-300))
        rr = rn
    return X, maxiter


def hat_values(X: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Hat functions of the cage vertices at the closest cage points of X.

    Returns
    -------
    (q, n) array
        Row q holds the barycentric coordinates of the point of the cage
        closest to ``X[q]`` on its face's three vertices (zero elsewhere).
    """
    import igl

    X = np.ascontiguousarray(X, dtype=np.float64)
    _, faces, C = igl.point_mesh_squared_distance(X, V, F)
    tri = F[faces]
    bary = igl.barycentric_coordinates(C, V[tri[:, 0]], V[tri[:, 1]], V[tri[:, 2]])
    bary = np.clip(bary, 0.0, None)
    bary /= bary.sum(axis=1, keepdims=True)
    out = np.zeros((len(X), len(V)))
    np.add.at(out, (np.repeat(np.arange(len(X)), 3), tri.ravel()), bary.ravel())
    return out


class HarmonicGrid:
    """Harmonic coordinates of a cage, solved once on a regular grid.

    Parameters
    ----------
    V : (n, 3) array
        Cage vertices.
    F : (f, 3) int array
        Cage triangles (closed).
    resolution : int
        Grid cells along the cage's longest side.
    solver : {"cg", "lu"}
        Conjugate gradients (default: fast and light) or a sparse LU
        factorisation (exact, slow beyond ~20,000 unknowns).

    Attributes
    ----------
    h : float
        Grid spacing.
    values : (n_inside, n) array
        Coordinates at the grid nodes inside the cage.

    Notes
    -----
    Grid nodes ``x`` with winding number ``w(x) > 1/2`` are unknowns; every
    other node ``x_b`` takes the boundary value ``h_i(c(x_b))``, the hat
    functions at its closest cage point. For each inside node

    .. math::

        6\\, a_i(x) - \\sum_{y \\in N_6(x)} a_i(y) = 0,

    the 7-point discrete Laplace equation, is solved for all n coordinates
    at once. The matrix is a symmetric M-matrix and
    every boundary row of values is non-negative and sums to one, so the
    solution is too (discrete maximum principle; conjugate gradients stop at
    a relative residual of 1e-10). Linear functions satisfy
    the stencil exactly, so linear precision holds up to the boundary
    values' error, ``|x_b - c(x_b)| <= sqrt(3) h``. Values between nodes are
    trilinear.
    """

    def __init__(self, V, F, resolution: int = 64, solver: str = "cg"):
        import igl

        self.V = np.ascontiguousarray(V, dtype=np.float64)
        self.F = np.ascontiguousarray(F, dtype=np.int64)
        lo, hi = self.V.min(0), self.V.max(0)
        self.h = float((hi - lo).max() / resolution)
        self.origin = lo - 2 * self.h
        self.shape = tuple(int(c) for c in np.ceil((hi + 2 * self.h - self.origin) / self.h).astype(int) + 1)
        ijk = np.indices(self.shape).reshape(3, -1).T
        nodes = self.origin + self.h * ijk
        w = igl.fast_winding_number(self.V, self.F, nodes)
        inside = w > 0.5
        self.index = np.full(len(nodes), -1, dtype=np.int64)
        self.index[inside] = np.arange(int(inside.sum()))
        n_in = int(inside.sum())
        ids = np.flatnonzero(inside)
        rows, cols, bnd_rows, bnd_nodes = [], [], [], []
        for off in _NEIGHBOURS:
            nb = self._flat(ijk[ids] + off)
            nb_index = self.index[nb]
            is_in = nb_index >= 0
            rows.append(np.flatnonzero(is_in))
            cols.append(nb_index[is_in])
            bnd_rows.append(np.flatnonzero(~is_in))
            bnd_nodes.append(nb[~is_in])
        r = np.concatenate(rows)
        c = np.concatenate(cols)
        L = sp.csr_matrix((-np.ones(len(r)), (r, c)), shape=(n_in, n_in)) + 6.0 * sp.identity(n_in, format="csr")
        br = np.concatenate(bnd_rows)
        bn = np.concatenate(bnd_nodes)
        unique_bn, inverse = np.unique(bn, return_inverse=True)
        hv = hat_values(nodes[unique_bn], self.V, self.F)
        B = sp.csr_matrix((np.ones(len(br)), (br, inverse)), shape=(n_in, len(unique_bn))) @ hv
        self.unknowns = n_in
        self.boundary_nodes = len(unique_bn)
        B = np.asarray(B)
        if solver == "lu":
            self.values = splu(sp.csc_matrix(L), permc_spec="MMD_AT_PLUS_A").solve(B)
            self.iterations = 0
        else:
            self.values, self.iterations = conjugate_gradient(L, B)

    def _flat(self, ijk):
        ijk = np.clip(ijk, 0, np.array(self.shape) - 1)
        return np.ravel_multi_index(ijk.T, self.shape)

    def __call__(self, P) -> np.ndarray:
        """(m, n) coordinates at points P, trilinear between grid nodes."""
        P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 3)
        g = (P - self.origin) / self.h
        base = np.clip(np.floor(g).astype(np.int64), 0, np.array(self.shape) - 2)
        frac = g - base
        out = np.zeros((len(P), len(self.V)))
        corners = [np.array(c) for c in np.ndindex(2, 2, 2)]
        flats = np.stack([self._flat(base + c) for c in corners], axis=1)    # (m, 8)
        idx = self.index[flats]
        # corners outside the cage take the boundary values (hat functions at the closest cage point)
        missing = np.unique(flats[idx < 0])
        extra = {}
        if missing.size:
            nodes = self.origin + self.h * np.stack(np.unravel_index(missing, self.shape), axis=1)
            hv = hat_values(nodes, self.V, self.F)
            extra = dict(zip(missing.tolist(), range(len(missing)), strict=False))
        for k, c in enumerate(corners):
            wt = np.prod(np.where(c == 1, frac, 1.0 - frac), axis=1)
            inside = idx[:, k] >= 0
            out[inside] += wt[inside, None] * self.values[idx[inside, k]]
            if (~inside).any():
                rows = np.flatnonzero(~inside)
                out[rows] += wt[rows, None] * hv[[extra[f] for f in flats[rows, k].tolist()]]
        return out


def harmonic_coordinates(P, V, F, *, resolution: int = 64, solver: str = "cg",
                         report: dict | None = None) -> np.ndarray:
    """Harmonic coordinates of points P in the cage (V, F).

    Parameters
    ----------
    P : (m, 3) array
        Points inside the cage.
    V, F : cage
    resolution : int
        Grid cells along the cage's longest side.
    solver : {"cg", "lu"}
    report : dict, optional
        Receives the grid size, spacing and unknown count.

    Returns
    -------
    (m, n) float64 array
        Non-negative, rows summing to one; see :class:`HarmonicGrid`.
    """
    grid = HarmonicGrid(V, F, resolution, solver=solver)
    if report is not None:
        report.update({"grid": list(grid.shape), "spacing": grid.h, "unknowns": grid.unknowns,
                       "boundary_nodes": grid.boundary_nodes, "solver": solver, "iterations": grid.iterations})
    return grid(P)


class HarmonicGenerator(WeightGenerator):
    """``generate: harmonic``: harmonic coordinates of the mesh vertices in a cage."""

    name = "harmonic"
    summary = "harmonic coordinates in a closed cage (Joshi et al. 2007), finite differences on a regular grid"

    class Params(CageParams):
        resolution: int = Field(64, ge=8, le=256, description="grid cells along the cage's longest side")
        solver: Literal["cg", "lu"] = Field("cg", description="conjugate gradients or sparse LU")

    def generate(self, asset: Asset, params: Params, ctx: StepContext) -> sp.spmatrix | np.ndarray:
        cage = prepare_cage(asset, params, ctx, "generate.harmonic")
        assert asset.mesh is not None  # WeightGenerator.apply required it
        ctx.report["harmonic"] = {}
        W = harmonic_coordinates(asset.mesh.V, cage.V, cage.F, resolution=params.resolution, solver=params.solver,
                                 report=ctx.report["harmonic"])
        W[W < 0] = 0.0  # round-off only: the discrete maximum principle keeps them >= 0
        return W / W.sum(axis=1, keepdims=True)
