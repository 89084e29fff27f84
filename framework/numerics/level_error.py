"""The animated error of levels of detail: each level posed by its own weights against the full mesh.

For test pose ``j`` (never an example pose), the full mesh is posed with the input weights,
``x_v^j = sum_i a_vi T_i^j [v; 1]``, and level ``l`` with its own weights; the two-sided surface
distance between them (Metro's principle, Cignoni et al. 1998: the vertices and ``samples`` area-uniform
points of each surface, each one's exact distance to the other surface,
:func:`rigslim.numerics.surface_distance.exact_sampled_distance`; each mesh's bounding-volume hierarchy is
built once and refitted to every frame) gives ``rms_j`` and ``max_j``. A level's
error is

    error_rms = mean_j rms_j,   error_max = max_j max_j      (the units of the poses: metres for glTF),

the figures ``rigslim compare`` prints for the written file (which draws its samples with MeshLab's
generator: the same maxima, which lie at vertices, and RMS within sampling noise). Every vertex is a
sample, so the maximum at a vertex is never missed, and the samples come from a fixed generator, so the
figures do not depend on what was measured before. ``bounding_radius`` is half the diagonal of the full
mesh's bounding box in the first test pose
(:mod:`rigslim.numerics.screen_coverage`).
"""

from __future__ import annotations

import numpy as np

from rigslim.numerics.blend import linear_blend
from rigslim.numerics.surface_distance import exact_sampled_distances, surface_samples

__all__ = ["bounding_radius", "level_errors"]


def bounding_radius(V: np.ndarray, weights, T: np.ndarray) -> float:
    """Half the diagonal of the bounding box of the mesh posed by ``T`` (one pose, (n, 3, 4))."""
    X = linear_blend(V, weights, T)
    return 0.5 * float(np.linalg.norm(X.max(axis=0) - X.min(axis=0))) if len(X) else 0.0


def level_errors(mesh, weights, T: np.ndarray, levels, samples: int = 20000, backend: str = "bvh") -> list[dict]:
    """Per level ``{"label", "error_max", "error_rms", "per_frame_max", "per_frame_rms"}`` over the poses ``T``.

    Parameters
    ----------
    mesh : Mesh
        The full rest mesh; ``weights`` its (m, n) input weights.
    T : (p, n, 3, 4) array
        Test poses.
    levels : list of SimplifiedLevel
    samples : int
        Area-uniform samples per surface and frame (besides the vertices).
    backend : {"bvh", "meshlab", "libigl"}
        Who measures the exact distances (:func:`rigslim.numerics.surface_distance.exact_sampled_distance`).
    """
    full = [linear_blend(mesh.V, weights, T[j]) for j in range(len(T))]
    full_samples = [surface_samples(X, mesh.F, samples, seed=1) for X in full]     # shared by every level
    jobs = ((linear_blend(level.mesh.V, level.weights, T[j]), level.mesh.F, full[j], mesh.F, samples, None,
             full_samples[j]) for level in levels for j in range(len(T)))          # posed as they are measured
    d = exact_sampled_distances(jobs, backend=backend)
    out = []
    for i, level in enumerate(levels):
        rms = [x["rms"] for x in d[i * len(T):(i + 1) * len(T)]]
        mx = [x["max"] for x in d[i * len(T):(i + 1) * len(T)]]
        out.append({"label": level.label, "error_max": float(max(mx, default=0.0)),
                    "error_rms": float(np.mean(rms)) if rms else 0.0, "per_frame_max": mx, "per_frame_rms": rms})
    return out
