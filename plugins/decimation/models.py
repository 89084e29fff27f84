"""Edge cost models of the articulated simplifiers: [S09] quartic, Mohr-Gleicher 2003, DeCoro-Rusinkiewicz 2005.

Each model says, for a batch of edges (a, b), where the merged vertex goes,
which skin weights it gets and what the collapse costs; the collapse loop
(:mod:`rigslim.plugins.decimation.collapse`) does the rest.
"""

from __future__ import annotations

import numpy as np

from rigslim.plugins.decimation.collapse import EdgeCostModel, SimplifyState, blended_transforms
from rigslim.plugins.decimation.quadrics import (
    WEIGHT_RIDGE,
    alternate,
    bone_limit,
    position_step,
    quadric_error,
    quartic_error,
)

BACKENDS = ("numpy", "numba")


def _check_backend(backend: str) -> str:
    if backend not in BACKENDS:
        raise ValueError(f"unknown backend {backend!r} (use one of {BACKENDS})")
    return backend


def compiled_costs(model, st: SimplifyState, ea, eb):
    """``v (B, 3), w (B, n), E (B,)`` of a model's edges through the compiled per-edge kernel."""
    from rigslim.plugins.decimation.edge_costs import edge_costs

    kind, Qv, ip, fp = model.compiled_spec()
    return edge_costs(kind, np.asarray(ea, np.int64), np.asarray(eb, np.int64), st.V, st.W, Qv, st.T, ip, fp)


def _restricted_bones(mask_full: np.ndarray, K: int) -> tuple[np.ndarray, np.ndarray]:
    """(B, K) bone indices of each row's True entries first, and the matching validity mask."""
    bones = np.argsort(~mask_full, axis=1, kind="stable")[:, :K]
    return bones, np.take_along_axis(mask_full, bones, axis=1)


def endpoint_errors(st: SimplifyState, Qe: np.ndarray, e: np.ndarray) -> np.ndarray:
    """Quartic error of keeping vertex e (its position and weights) under the edge quadrics Qe (B, P, 4, 4)."""
    X = blended_transforms(st.W[e], st.T)                                 # (B, P, 3, 4)
    p = np.einsum("bprc,bc->bpr", X[..., :3], st.V[e]) + X[..., 3]
    return quadric_error(Qe, p).sum(axis=1)


class QuarticModel(EdgeCostModel):
    """[S09]: per-pose quadrics summed over the edge; alternate position and weight solves.

    Parameters
    ----------
    Q : (m, P, 4, 4) per-pose quadrics of the original vertices.
    iterations, tol, max_bones, nonnegative : see :func:`rigslim.plugins.decimation.quadrics.alternate`.
    endpoints : bool
        Also consider keeping either endpoint (position and weights) and take
        whichever of the three candidates has the least quartic error.
    """

    kind = 0   # rigslim.plugins.decimation.setup.QUARTIC

    def __init__(self, Q, *, iterations=10, tol=1e-6, max_bones=None, endpoints=False, nonnegative=False,
                 backend="numpy"):
        m = len(Q)
        self.Q = np.zeros((2 * m,) + Q.shape[1:])
        self.Q[:m] = Q
        self.iterations, self.tol, self.max_bones = iterations, tol, max_bones
        self.endpoints = endpoints
        self.nonnegative = nonnegative
        self.backend = _check_backend(backend)

    def compiled_spec(self):
        """``(method, Qv, ip, fp)`` for :func:`rigslim.plugins.decimation.edge_costs.edge_cost`."""
        ip = np.array([self.iterations, -1 if self.max_bones is None else self.max_bones, int(self.nonnegative),
                       int(self.endpoints)], dtype=np.int64)
        return self.kind, self.Q, ip, np.array([self.tol, WEIGHT_RIDGE])

    def costs(self, st: SimplifyState, ea, eb):
        if self.backend == "numba":
            return compiled_costs(self, st, ea, eb)
        Wa, Wb = st.W[ea], st.W[eb]
        mask_full = (Wa != 0) | (Wb != 0)
        Kb = mask_full.sum(axis=1)
        order = np.argsort(Kb, kind="stable")
        B, n = Wa.shape
        v_out, w_out, E_out = np.zeros((B, 3)), np.zeros((B, n)), np.zeros(B)
        for s in range(0, B, 512):
            idx = order[s:s + 512]
            K = int(Kb[idx].max())
            bones, mask = _restricted_bones(mask_full[idx], K)
            a0 = np.take_along_axis(0.5 * (Wa[idx] + Wb[idx]), bones, axis=1) * mask
            Tb = np.ascontiguousarray(np.transpose(st.T[:, bones], (1, 2, 0, 3, 4)))   # (b, K, P, 3, 4)
            Qe = self.Q[ea[idx]] + self.Q[eb[idx]]
            pa, pb = st.V[ea[idx]], st.V[eb[idx]]
            fallback = np.stack([pa, pb, 0.5 * (pa + pb)], axis=1)
            v, a, E = alternate(Qe, Tb, a0, mask, fallback, iterations=self.iterations, tol=self.tol,
                                max_bones=self.max_bones, nonnegative=self.nonnegative)
            w = np.zeros((len(idx), n))
            np.put_along_axis(w, bones, np.where(mask, a, 0.0), axis=1)   # bones are distinct per row
            v_out[idx], w_out[idx], E_out[idx] = v, w, np.maximum(E, 0.0)
        if self.endpoints:
            # the alternation is a local method started from the mean weights; keep an endpoint
            # (its own position and weights) where that is better, so E never exceeds Mohr-Gleicher's
            Qe = self.Q[ea] + self.Q[eb]
            for e in (ea, eb):
                E_end = np.maximum(endpoint_errors(st, Qe, e), 0.0)
                better = E_end < E_out
                v_out[better], w_out[better], E_out[better] = st.V[e][better], st.W[e][better], E_end[better]
        return v_out, w_out, E_out

    def anchored(self, st, ea, eb, keep):
        return endpoint_errors(st, self.Q[ea] + self.Q[eb], keep)

    def merge(self, st, a, b, c):
        self.Q[c] = self.Q[a] + self.Q[b]


class MohrGleicherModel(QuarticModel):
    """Mohr & Gleicher 2003: the same summed per-pose quadrics; the new vertex is the better endpoint.

    Notes
    -----
    ``cost(a, b) = min(E(v_a, w_a), E(v_b, w_b))`` with E the quartic error
    of the edge's summed quadrics; the winner's position and weights move to
    the merged vertex.
    """

    kind = 1   # rigslim.plugins.decimation.setup.MOHR_GLEICHER

    def costs(self, st, ea, eb):
        if self.backend == "numba":
            return compiled_costs(self, st, ea, eb)
        Qe = self.Q[ea] + self.Q[eb]
        out = [endpoint_errors(st, Qe, e) for e in (ea, eb)]
        take_b = out[1] < out[0]
        v = np.where(take_b[:, None], st.V[eb], st.V[ea])
        w = np.where(take_b[:, None], st.W[eb], st.W[ea])
        return v, w, np.maximum(np.minimum(out[0], out[1]), 0.0)


class DeCoroModel(EdgeCostModel):
    """DeCoro & Rusinkiewicz 2005: per-pose quadrics brought to the rest frame and summed.

    Parameters
    ----------
    Q : (m, P, 4, 4) per-pose quadrics; W : (m, n) weights; T : (P, n, 3, 4) poses.
    max_bones : int, optional

    Notes
    -----
    ``Qr_v = sum_j L_v^{jT} Q_v^j L_v^j`` with ``L_v^j`` vertex v's blended
    4x4 transform in pose j; an edge has ``Qr_a + Qr_b``; the new vertex is
    the QSlim optimum of that quadric and its weights are the endpoints'
    blended by distance, ``w = (|v - v_b| w_a + |v - v_a| w_b) / (|v - v_a| + |v - v_b|)``.
    """

    kind = 2   # rigslim.plugins.decimation.setup.DECORO

    def __init__(self, Q, W, T, *, max_bones=None, backend="numpy"):
        m = len(Q)
        L = np.zeros((m, T.shape[0], 4, 4))
        L[..., :3, :] = blended_transforms(W, T)
        L[..., 3, 3] = 1.0
        self.Q = np.zeros((2 * m, 4, 4))
        self.Q[:m] = np.einsum("mpri,mprs,mpsj->mij", L, Q, L)
        self.max_bones = max_bones
        self.backend = _check_backend(backend)

    def compiled_spec(self):
        """``(method, Qv, ip, fp)``; Qv is a (2m, 1, 4, 4) view of the rest-frame quadrics."""
        ip = np.array([0, -1 if self.max_bones is None else self.max_bones, 0, 0], dtype=np.int64)
        return self.kind, self.Q.reshape(len(self.Q), 1, 4, 4), ip, np.array([0.0, WEIGHT_RIDGE])

    def costs(self, st, ea, eb):
        if self.backend == "numba":
            return compiled_costs(self, st, ea, eb)
        Qe = (self.Q[ea] + self.Q[eb])[:, None]                         # one "pose": identity
        B = len(ea)
        ident = np.zeros((B, 1, 1, 3, 4))
        ident[..., :3, :3] = np.eye(3)
        pa, pb = st.V[ea], st.V[eb]
        v, _ = position_step(Qe, ident, np.ones((B, 1)), np.stack([pa, pb, 0.5 * (pa + pb)], axis=1))
        da, db = np.linalg.norm(v - pa, axis=1), np.linalg.norm(v - pb, axis=1)
        s = da + db
        ta = np.where(s > 0, db / np.where(s > 0, s, 1.0), 0.5)
        w = ta[:, None] * st.W[ea] + (1.0 - ta)[:, None] * st.W[eb]
        if self.max_bones is not None:
            w, _ = bone_limit(w, w != 0, self.max_bones)
        E = quartic_error(Qe, ident, np.ones((B, 1)), v)
        return v, w, np.maximum(E, 0.0)

    def anchored(self, st, ea, eb, keep):
        return quadric_error(self.Q[ea] + self.Q[eb], st.V[keep])

    def merge(self, st, a, b, c):
        self.Q[c] = self.Q[a] + self.Q[b]
