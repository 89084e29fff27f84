"""The animated error of levels of detail: each level posed by its own weights against the full mesh.

For test pose ``j`` (never an example pose), the full mesh is posed with the input weights,
``x_v^j = sum_i a_vi T_i^j [v; 1]``, and level ``l`` with its own weights; the two-sided surface
distance between them (Metro, Cignoni et al. 1998: :func:`rigslim.numerics.surface_distance.metro_distance`
when pymeshlab is installed, else :func:`sampled_distance` on the same principle) gives ``rms_j`` and
``max_j``. A level's error is

    error_rms = mean_j rms_j,   error_max = max_j max_j      (the units of the poses: metres for glTF),

the figures ``rigslim compare`` prints for the written file. ``bounding_radius`` is half the diagonal of
the full mesh's bounding box in the first test pose (:mod:`rigslim.numerics.screen_coverage`).
"""

from __future__ import annotations

import importlib.util

import numpy as np

from rigslim.numerics.blend import linear_blend

__all__ = ["bounding_radius", "level_errors", "sampled_distance", "surface_distance"]


def _samples(V: np.ndarray, F: np.ndarray, count: int, rng) -> np.ndarray:
    """The vertices and ``count`` area-uniform points of the triangles (fixed generator: repeatable)."""
    if not len(F):
        return V
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    if area.sum() <= 0:
        return V
    f = rng.choice(len(F), size=count, p=area / area.sum())
    u, v = rng.random(count), rng.random(count)
    flip = u + v > 1
    u, v = np.where(flip, 1 - u, u), np.where(flip, 1 - v, v)
    return np.concatenate([V, a[f] + u[:, None] * (b[f] - a[f]) + v[:, None] * (c[f] - a[f])])


def sampled_distance(V1, F1, V2, F2, samples: int = 20000) -> dict:
    """Two-sided distance from surface samples (vertices + ``samples`` area-uniform points per side) to the
    other surface (libigl's exact point-to-triangle distance): ``rms`` over both sides' samples, ``max``."""
    import igl

    V1, V2 = np.asarray(V1, float), np.asarray(V2, float)
    F1, F2 = np.asarray(F1, np.int64).reshape(-1, 3), np.asarray(F2, np.int64).reshape(-1, 3)
    rng = np.random.default_rng(0)
    d2 = []
    for (Va, Fa), (Vb, Fb) in (((V1, F1), (V2, F2)), ((V2, F2), (V1, F1))):
        P = _samples(Va, Fa, samples, rng)
        if len(Fb):
            d2.append(np.asarray(igl.point_mesh_squared_distance(P, Vb, Fb)[0], float).reshape(-1))
        else:
            d2.append(((P[:, None] - Vb[None]) ** 2).sum(axis=2).min(axis=1))
    d = np.sqrt(np.maximum(np.concatenate(d2), 0.0))
    return {"rms": float(np.sqrt((d * d).mean())), "max": float(d.max()), "n_samples": int(len(d))}


def surface_distance(V1, F1, V2, F2, samples: int = 20000) -> dict:
    """Metro (pymeshlab) when installed and the surfaces have area; else :func:`sampled_distance`."""
    if importlib.util.find_spec("pymeshlab") is not None and len(F1) and len(F2):
        from rigslim.numerics.surface_distance import metro_distance

        return metro_distance(V1, F1, V2, F2, samples)
    return sampled_distance(V1, F1, V2, F2, samples)


def bounding_radius(V: np.ndarray, weights, T: np.ndarray) -> float:
    """Half the diagonal of the bounding box of the mesh posed by ``T`` (one pose, (n, 3, 4))."""
    X = linear_blend(V, weights, T)
    return 0.5 * float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))) if len(X) else 0.0


def level_errors(mesh, weights, T: np.ndarray, levels, samples: int = 20000) -> list[dict]:
    """Per level ``{"label", "error_max", "error_rms", "per_frame_max", "per_frame_rms"}`` over the poses ``T``.

    Parameters
    ----------
    mesh : Mesh
        The full rest mesh; ``weights`` its (m, n) input weights.
    T : (p, n, 3, 4) array
        Test poses.
    levels : list of SimplifiedLevel
    """
    full = [linear_blend(mesh.V, weights, T[j]) for j in range(len(T))]
    out = []
    for level in levels:
        rms, mx = [], []
        for j in range(len(T)):
            d = surface_distance(linear_blend(level.mesh.V, level.weights, T[j]), level.mesh.F, full[j], mesh.F,
                                 samples)
            rms.append(d["rms"])
            mx.append(d["max"])
        out.append({"label": level.label, "error_max": float(max(mx, default=0.0)),
                    "error_rms": float(np.mean(rms)) if rms else 0.0, "per_frame_max": mx, "per_frame_rms": rms})
    return out
