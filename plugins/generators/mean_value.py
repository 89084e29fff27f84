"""Mean value coordinates of points with respect to a closed triangle cage.

Ju, Schaefer & Warren 2005, "Mean value coordinates for closed triangular
meshes": a numpy reference, vectorised over points and cage faces, and the
same computation as the OpenCL kernel ``kernels/mvc.cl`` (one work item per
point). Both handle the paper's special cases: a point on a cage vertex, on a
cage face or edge (2D barycentric coordinates of that face), and in a face's
plane but outside it (the face contributes nothing); points outside the cage
get the (well-defined, possibly negative) exterior coordinates.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

import numpy as np
import scipy.sparse as sp

from rigslim.errors import InputError
from rigslim.plugin import WeightGenerator
from rigslim.plugins.generators.cage_setup import CageParams, prepare_cage

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext

#: A point closer than ``PLANE_EPS * sqrt(2 * area)`` to a face's plane is "in the plane"
#: (on the face: barycentric coordinates; outside it: the face is skipped).
PLANE_EPS = 1e-12


def _check_cage(V, F, source="cage"):
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3 or len(F) < 4:
        raise InputError(f"cage has vertices {V.shape} and faces {F.shape}", source=source, field="cage",
                         fix="give a closed triangle cage with at least 4 faces")
    return V, F


def _incidence(F: np.ndarray, n: int) -> sp.csr_matrix:
    """(3f, n) matrix scattering per-corner weights onto cage vertices."""
    f = len(F)
    return sp.csr_matrix((np.ones(3 * f), (np.arange(3 * f), F.ravel())), shape=(3 * f, n))


def mean_value_coordinates(P, V, F, *, chunk: int = 1024, progress=None) -> np.ndarray:
    """Mean value coordinates of points P with respect to the triangle cage (V, F).

    Parameters
    ----------
    P : (m, 3) array
        Query points (inside, on or outside the cage).
    V : (n, 3) array
        Cage vertices.
    F : (f, 3) int array
        Cage triangles, consistently oriented (either way).
    chunk : int
        Points per vectorised block (memory ~ 40 * chunk * f doubles).
    progress : callable, optional
        ``progress(iterable, total=..., description=...)`` wrapper.

    Returns
    -------
    (m, n) float64 array
        Rows sum to one; ``W @ V == P`` (linear precision).

    Notes
    -----
    With ``d_j = |p_j - x|`` and ``u_j = (p_j - x) / d_j``, each face
    (corners 1, 2, 3) adds to its corners' weights (Ju et al. 2005, sec. 3)

    .. math::

        m = \\frac12 \\sum_{e=(a,b)} \\theta_e \\frac{u_a \\times u_b}{|u_a \\times u_b|}, \\quad
        \\theta_e = 2 \\operatorname{atan2}(|u_a - u_b|, |u_a + u_b|),

        w_i \\mathrel{+}= \\frac{\\lambda_i}{d_i}, \\quad
        \\lambda = [u_1\\, u_2\\, u_3]^{-1} m, \\quad
        \\lambda_i = \\frac{(u_{i+1} \\times u_{i+2}) \\cdot m}{\\det[u_1, u_2, u_3]},

    and the coordinates are ``w / sum(w)``: ``m`` is the integral of the
    unit direction over the face's spherical triangle. This is the paper's
    vector form rather than its angle pseudo-code: with the determinant
    taken as ``(p_1 - x) . ((p_2 - p_1) x (p_3 - p_1)) / (d_1 d_2 d_3)``
    its rounding error scales the near face's three weights alike, so a
    point 1e-9 from a face keeps linear precision to round-off (the
    pseudo-code's ``pi - h`` is O(distance^2) and underflows there). Points
    within ``PLANE_EPS`` (relative to the face size) of a face's plane are
    the special cases: on the face they take its barycentric coordinates
    (which covers points on edges and vertices), outside it the face adds
    nothing.

    Example
    -------
    >>> import numpy as np
    >>> V = np.array([[0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1.]])
    >>> F = np.array([[0, 2, 1], [0, 1, 3], [0, 3, 2], [1, 2, 3]])
    >>> W = mean_value_coordinates(np.array([[0.2, 0.2, 0.2]]), V, F)
    >>> bool(np.allclose(W @ V, [[0.2, 0.2, 0.2]]))
    True
    """
    V, F = _check_cage(V, F)
    P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 3)
    m, n = len(P), len(V)
    S = _incidence(F, n)
    out = np.empty((m, n))
    starts = range(0, m, chunk)
    if progress is not None:
        starts = progress(starts, total=len(starts), description="mean value coordinates")
    for s in starts:
        out[s:s + chunk] = _mvc_block(P[s:s + chunk], V, F, S, PLANE_EPS)
    return out


def _mvc_block(P, V, F, S, tol):
    b, f = len(P), len(F)
    D = V[None, :, :] - P[:, None, :]              # (b, n, 3): p_j - x
    d = np.linalg.norm(D, axis=2)                  # (b, n)
    Df = D[:, F]                                   # (b, f, 3 corners, 3)
    dd = d[:, F]                                   # (b, f, 3)
    N = np.cross(V[F[:, 1]] - V[F[:, 0]], V[F[:, 2]] - V[F[:, 0]])   # (f, 3), |N| = 2 area
    area2 = np.linalg.norm(N, axis=1)
    plane = np.einsum("bfi,fi->bf", Df[:, :, 0], N)                  # (p_1 - x) . N
    near = np.abs(plane) < tol * (area2 * np.sqrt(area2))[None, :]                      # in the face's plane
    with np.errstate(divide="ignore", invalid="ignore"):
        u = Df / dd[..., None]
        ua, ub = u, np.roll(u, -1, axis=2)         # edge e_i = (corner i, corner i+1)
        theta = 2.0 * np.arctan2(np.linalg.norm(ua - ub, axis=3), np.linalg.norm(ua + ub, axis=3))
        ne = np.cross(ua, ub)
        nlen = np.linalg.norm(ne, axis=3, keepdims=True)
        ne = np.where(nlen > 0.0, ne / np.where(nlen > 0.0, nlen, 1.0), 0.0)
        m = 0.5 * np.einsum("bfe,bfei->bfi", theta, ne)               # mean vector of the face
        cof = np.cross(np.roll(u, -1, axis=2), np.roll(u, -2, axis=2))  # rows of det * U^-1
        det = plane / (dd[..., 0] * dd[..., 1] * dd[..., 2])
        w = np.einsum("bfci,bfi->bfc", cof, m) / det[..., None] / dd
    w[near | ~np.isfinite(w).all(axis=2)] = 0.0
    W = np.asarray((S.T @ w.reshape(b, 3 * f).T).T)
    # points in a face's plane: on the face (its barycentric coordinates) or outside it (skipped)
    if near.any():
        rows, faces = np.nonzero(near)
        A, B, C = V[F[faces, 0]], V[F[faces, 1]], V[F[faces, 2]]
        bary = _barycentric(P[rows], A, B, C, N[faces])
        inside = (bary >= -1e-9).all(axis=1)
        rows, faces, bary = rows[inside], faces[inside], bary[inside]
        first = np.unique(rows, return_index=True)[1]
        rows, faces, bary = rows[first], faces[first], np.clip(bary[first], 0.0, None)
        W[rows] = 0.0
        np.add.at(W, (np.repeat(rows, 3), F[faces].ravel()), bary.ravel())
    return W / W.sum(axis=1, keepdims=True)


def _barycentric(X, A, B, C, N):
    """Barycentric coordinates of the projections of X onto triangles ABC with normals N."""
    nn = np.einsum("ij,ij->i", N, N)
    la = np.einsum("ij,ij->i", np.cross(B - X, C - X), N) / nn
    lb = np.einsum("ij,ij->i", np.cross(C - X, A - X), N) / nn
    return np.stack([la, lb, 1.0 - la - lb], axis=1)


def mean_value_coordinates_opencl(P, V, F, *, device: str | None = None, precision: str = "auto") -> np.ndarray:
    """Mean value coordinates on an OpenCL device (kernel ``kernels/mvc.cl``).

    Parameters
    ----------
    P, V, F
        As in :func:`mean_value_coordinates`.
    device : str, optional
        ``auto``, ``gpu``, ``cpu`` or part of a device name (see :mod:`rigslim.device.opencl`).
    precision : {"auto", "double", "single"}
        ``auto`` uses float64 where the device supports it.

    Returns
    -------
    (m, n) float64 array
        The same coordinates as the numpy reference (to round-off in float64).

    Notes
    -----
    One work item per point evaluates the formula of
    :func:`mean_value_coordinates` over every cage face and normalises its
    row; the m x n evaluations are independent.
    """
    import pyopencl as cl

    from rigslim.device.opencl import build_program, get_runtime

    V, F = _check_cage(V, F)
    P = np.ascontiguousarray(P, dtype=np.float64).reshape(-1, 3)
    rt = get_runtime(device)
    has_fp64 = "cl_khr_fp64" in rt.device.extensions or bool(getattr(rt.device, "double_fp_config", 0))
    if precision == "double" and not has_fp64:
        raise InputError(f"OpenCL device {rt.name} has no float64", field="precision",
                         fix="use precision: single or auto, or another device")
    double = has_fp64 and precision != "single"
    dtype = np.float64 if double else np.float32
    prg = build_program(rt, "mvc.cl", ["-DUSE_DOUBLE"] if double else [])
    m, n, f = len(P), len(V), len(F)
    mf = cl.mem_flags
    ctx, queue = rt.context, rt.queue
    Pb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=P.astype(dtype))
    Vb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=V.astype(dtype))
    Fb = cl.Buffer(ctx, mf.READ_ONLY | mf.COPY_HOST_PTR, hostbuf=F.astype(np.int32))
    out = np.empty((m, n), dtype=dtype)
    Wb = cl.Buffer(ctx, mf.WRITE_ONLY, out.nbytes)
    kernel = cl.Kernel(prg, "mean_value_coordinates")
    kernel(queue, (m,), None, Pb, np.int32(m), Vb, np.int32(n), Fb, np.int32(f), dtype(PLANE_EPS), Wb)
    cl.enqueue_copy(queue, out, Wb).wait()
    return out.astype(np.float64)


class MeanValueGenerator(WeightGenerator):
    """``generate: mean-value``: mean value coordinates of the mesh vertices in a cage."""

    name = "mean-value"
    summary = "mean value coordinates in a closed triangle cage (Ju et al. 2005; numpy or OpenCL)"

    class Params(CageParams):
        backend: Literal["numpy", "opencl"] = "numpy"
        """Where to evaluate the coordinates: the numpy reference or the OpenCL kernel (mvc.cl)."""
        device: str | None = None
        """OpenCL device spec (opencl backend only): auto, gpu, cpu or part of a device/platform name."""

    def generate(self, asset: Asset, params: Params, ctx: StepContext) -> sp.spmatrix | np.ndarray:
        cage = prepare_cage(asset, params, ctx, "generate.mean-value")
        assert asset.mesh is not None  # WeightGenerator.apply required it
        if params.backend == "opencl":
            W = mean_value_coordinates_opencl(asset.mesh.V, cage.V, cage.F, device=params.device)
        else:
            W = mean_value_coordinates(asset.mesh.V, cage.V, cage.F, progress=ctx.progress)
        ctx.report["coordinates"] = {"backend": params.backend, "min": float(W.min()), "max": float(W.max()),
                                     "negative_fraction": float((W < 0).mean())}
        return W
