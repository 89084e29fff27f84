"""Two-sided distance between two triangle surfaces (Metro, Cignoni, Rocchini & Scopigno 1998).

Shared by the ``metro`` metric, ``rigslim compare`` and the simplification benchmark. Regular surfaces go to
pymeshlab's Hausdorff filter; degenerate ones (no triangles, zero area or zero extent, where pymeshlab segfaults
or spins) never reach it and are measured exactly with libigl's point-to-mesh distance instead
(:func:`degenerate_distance`).

pymeshlab runs in one long-lived thread of its own (:func:`_pymeshlab_thread`). Its module initialisation loads
MeshLab's plugins into a static ``PluginManager`` whose Qt objects belong to the importing thread; when that
thread ends before the process (a Dask worker's task thread, any ``ThreadPoolExecutor``), Qt frees the thread's
``QThreadData`` and the ``PluginManager`` destructor at exit (``QPluginLoader::unload`` -> ``~QObject`` ->
``QThreadData::deref``) writes into the freed block: the heap corruption glibc reports as
``malloc_consolidate(): unaligned fastbin chunk detected`` at the exit of every batch worker that ran ``metro``.
The rigslim thread is a daemon that lives until the process ends, so the thread data outlives the destructor.
"""

from __future__ import annotations

import queue
import threading

import numpy as np

__all__ = ["degenerate_distance", "is_degenerate", "metro_distance", "pymeshlab_available", "referenced"]


def pymeshlab_available() -> bool:
    """Whether pymeshlab is installed, found without importing it (an import outside the pymeshlab thread
    would bring back the heap corruption described above)."""
    import importlib.util

    return importlib.util.find_spec("pymeshlab") is not None


def is_degenerate(V, F) -> bool:
    """No triangle, a zero (or non-finite) extent, or a total area below ``1e-12`` of the squared diagonal.

    Notes
    -----
    The total area is ``A = 1/2 sum_f |(b - a) x (c - a)|``. Each term is non-negative, so the sum over every
    ``s``-th triangle (``s = ceil(m / 65536)``, ``m`` triangles) is a lower bound of ``A``: when that partial
    sum already exceeds ``1e-12 d^2`` (``d`` the diagonal) the mesh is regular, exactly, at about ``1/s`` of
    the cost (on a posed 2.6M-triangle frame 0.03 s instead of 0.8 s); only the rest is summed in full.
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64).reshape(-1, 3)
    if not len(F) or not len(V) or not np.isfinite(V).all():
        return True
    diag = float(np.linalg.norm(V.max(axis=0) - V.min(axis=0)))
    if diag <= 0:
        return True
    floor = 1e-12 * diag * diag
    step = -(-len(F) // 65536)
    if step > 1 and _total_area(V, F[::step]) > floor:
        return False
    return _total_area(V, F) <= floor


def _total_area(V: np.ndarray, F: np.ndarray) -> float:
    """``1/2 sum_f |(b - a) x (c - a)|`` over the faces ``F``."""
    a = V[F[:, 0]]
    return 0.5 * float(np.linalg.norm(np.cross(V[F[:, 1]] - a, V[F[:, 2]] - a), axis=1).sum())


def metro_distance(V1, F1, V2, F2, samples: int = 20000) -> dict:
    """Two-sided Hausdorff distance between two triangle meshes.

    Parameters
    ----------
    V1, F1, V2, F2 : arrays
        The two meshes.
    samples : int
        Surface samples per direction (vertices are always sampled too).

    Returns
    -------
    dict
        ``rms``, ``max`` (absolute units) and ``n_samples``.

    Notes
    -----
    With ``d(p, S)`` the distance of sample p to surface S,
    ``max = max(max_{p in S1} d(p, S2), max_{q in S2} d(q, S1))`` (Hausdorff), and
    ``rms = sqrt((n1 rms_12^2 + n2 rms_21^2) / (n1 + n2))``, the RMS over the
    samples of both directions. Degenerate meshes (:func:`is_degenerate`) are measured by
    :func:`degenerate_distance`; pymeshlab is never called on them.
    """
    V1, V2 = np.asarray(V1, float), np.asarray(V2, float)
    F1, F2 = np.asarray(F1, np.int64).reshape(-1, 3), np.asarray(F2, np.int64).reshape(-1, 3)
    if is_degenerate(V1, F1) or is_degenerate(V2, F2):
        return degenerate_distance(V1, F1, V2, F2, samples)
    (V1, F1), (V2, F2) = referenced(V1, F1), referenced(V2, F2)
    return _pymeshlab_thread().call(_pymeshlab_distance, V1, F1, V2, F2, int(samples))


def referenced(V: np.ndarray, F: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The faces with three distinct corners, and the vertices they use (renumbered).

    A face that repeats a corner (a glTF's ``(0, 0, 0)``) is a point or a segment that no renderer draws, and
    a vertex only such faces use, or none, is no part of the surface; pymeshlab's vertex sampling would take
    it, and its distance to the other surface would become the Hausdorff maximum (a CSM conversion's lone
    origin vertex: 44 % of the diagonal between a file and its own copy).
    """
    F = F[(F[:, 0] != F[:, 1]) & (F[:, 1] != F[:, 2]) & (F[:, 0] != F[:, 2])]
    used, inverse = np.unique(F, return_inverse=True)
    if len(used) == len(V):
        return V, F
    return V[used], inverse.reshape(F.shape).astype(np.int64)


def _pymeshlab_distance(V1, F1, V2, F2, samples: int) -> dict:
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V1, F1.astype(np.int32)))
    ms.add_mesh(pymeshlab.Mesh(V2, F2.astype(np.int32)))
    out = []
    for s, t in ((0, 1), (1, 0)):
        out.append(ms.get_hausdorff_distance(sampledmesh=s, targetmesh=t, samplevert=True, sampleface=True,
                                             samplenum=samples, maxdist=pymeshlab.PercentageValue(100)))
    n = np.array([r["n_samples"] for r in out], float)
    rms = float(np.sqrt((n * np.array([r["RMS"] for r in out]) ** 2).sum() / n.sum()))
    return {"rms": rms, "max": float(max(r["max"] for r in out)), "n_samples": int(n.sum())}


def surface_samples(V, F, samples: int, seed: int = 0) -> np.ndarray:
    """The vertices used by ``F`` (all of ``V`` without faces) and ``samples`` area-weighted random points.

    A zero-area mesh gets its samples uniformly over its faces instead (points on segments, or the points).
    """
    V = np.asarray(V, float)
    F = np.asarray(F, np.int64).reshape(-1, 3)
    if not len(F):
        return V
    used = V[np.unique(F)]
    rng = np.random.default_rng(seed)
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    area = 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1)
    p = area / area.sum() if area.sum() > 0 else np.full(len(F), 1.0 / len(F))
    f = rng.choice(len(F), size=int(samples), p=p)
    r1, r2 = np.sqrt(rng.random(len(f))), rng.random(len(f))
    pts = (1 - r1)[:, None] * a[f] + (r1 * (1 - r2))[:, None] * b[f] + (r1 * r2)[:, None] * c[f]
    return np.concatenate([used, pts])


def _distances(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Exact distance of each point to the mesh (V, F): libigl's AABB query, which treats a degenerate triangle
    as its segment or point; to the points V when there are no faces."""
    if not len(P):
        return np.zeros(0)
    if not len(F):
        from scipy.spatial import cKDTree

        return cKDTree(V).query(P)[0]
    import igl

    d2 = igl.point_mesh_squared_distance(np.ascontiguousarray(P), np.ascontiguousarray(V),
                                         np.ascontiguousarray(F))[0]
    return np.sqrt(np.maximum(d2, 0.0))


def degenerate_distance(V1, F1, V2, F2, samples: int = 20000) -> dict:
    """:func:`metro_distance` for meshes pymeshlab must not see: the same two-sided RMS and max over
    :func:`surface_samples` of each mesh, each distance exact (:func:`_distances`)."""
    V1, V2 = np.asarray(V1, float), np.asarray(V2, float)
    F1, F2 = np.asarray(F1, np.int64).reshape(-1, 3), np.asarray(F2, np.int64).reshape(-1, 3)
    if not (len(V1) and len(V2)) or not (np.isfinite(V1).all() and np.isfinite(V2).all()):
        from rigslim.errors import StepError

        raise StepError("a surface to compare has no finite vertices", field="positions",
                        fix="check the mesh and its pose (NaN or inf positions)")
    d12 = _distances(surface_samples(V1, F1, samples), V2, F2)
    d21 = _distances(surface_samples(V2, F2, samples, seed=1), V1, F1)
    d = np.concatenate([d12, d21])
    return {"rms": float(np.sqrt(np.mean(d * d))), "max": float(d.max()), "n_samples": int(len(d))}


class _Worker:
    """One daemon thread that runs every pymeshlab call of the process (see the module's docstring)."""

    def __init__(self):
        self._jobs: queue.Queue = queue.Queue()
        self._thread = threading.Thread(target=self._loop, name="rigslim-pymeshlab", daemon=True)
        self._thread.start()

    def _loop(self):
        while True:
            fn, args, box, done = self._jobs.get()
            try:
                box["value"] = fn(*args)
            except BaseException as e:  # noqa: BLE001 - handed back to the caller
                box["error"] = e
            done.set()

    def call(self, fn, *args):
        """``fn(*args)`` on the pymeshlab thread; the caller waits in short slices so that its signal handlers
        (SIGINT, SIGTERM) still run while the native call works."""
        box: dict = {}
        done = threading.Event()
        self._jobs.put((fn, args, box, done))
        while not done.wait(0.1):
            pass
        if "error" in box:
            raise box["error"]
        return box["value"]


_worker: _Worker | None = None
_worker_lock = threading.Lock()


def _pymeshlab_thread() -> _Worker:
    global _worker
    with _worker_lock:
        if _worker is None:
            _worker = _Worker()
        return _worker
