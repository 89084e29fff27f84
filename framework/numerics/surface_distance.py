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

__all__ = ["degenerate_distance", "exact_sampled_distance", "exact_sampled_distances", "is_degenerate",
           "metro_distance", "pymeshlab_available", "referenced", "surface_samples"]


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
        Random surface samples per direction; every vertex is sampled too.

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
    used = _used(F, len(V))
    if used.all():
        return V, F
    renumber = np.cumsum(used) - 1
    return V[used], renumber[F].astype(np.int64)


def _used(F: np.ndarray, n: int) -> np.ndarray:
    """Which of ``n`` vertices the faces ``F`` use (a mask; a count, not a sort)."""
    return np.bincount(np.asarray(F, np.int64).ravel(), minlength=n)[:n] > 0


def _pymeshlab_distance(V1, F1, V2, F2, samples: int) -> dict:
    """Both directions of the Hausdorff filter. Each samples every vertex of its mesh and ``samples`` random
    points of its faces: the filter's ``samplenum`` counts both, and with fewer than the mesh's vertices its
    vertex sampling draws that many of them at random (``VertexUniform``) and can miss the one where the
    maximum lies, so a larger mesh's vertices are measured in a call of their own (``samplenum`` = their
    count: all of them, no random draw) before its face samples."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(V1, F1.astype(np.int32)))
    ms.add_mesh(pymeshlab.Mesh(V2, F2.astype(np.int32)))
    out = []
    for s, t, n_vertices in ((0, 1, len(V1)), (1, 0, len(V2))):
        passes = ([(True, True, samples)] if samples >= n_vertices
                  else [(True, False, n_vertices), (False, True, samples)])
        for vert, face, num in passes:
            out.append(ms.get_hausdorff_distance(sampledmesh=s, targetmesh=t, samplevert=vert, sampleface=face,
                                                 samplenum=num, maxdist=pymeshlab.PercentageValue(100)))
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
    used = V[_used(F, len(V))]
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
    return exact_sampled_distance(V1, F1, V2, F2, samples, backend="libigl")


class _Worker:
    """One daemon thread that runs every pymeshlab call of the process (see the module's docstring).

    One, not several: pymeshlab silences MeshLab's output around each filter by swapping process-wide
    ``std::cout``/``std::cerr`` redirections that it allocates and frees per call, so two filters at once
    can free one redirection twice."""

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

    def submit(self, fn, *args) -> tuple[dict, threading.Event]:
        """Queues ``fn(*args)``; :meth:`result` waits for it."""
        box: dict = {}
        done = threading.Event()
        self._jobs.put((fn, args, box, done))
        return box, done

    @staticmethod
    def result(box: dict, done: threading.Event):
        """Waits in short slices so that the caller's signal handlers (SIGINT, SIGTERM) still run while the
        native call works."""
        while not done.wait(0.1):
            pass
        if "error" in box:
            raise box["error"]
        return box["value"]

    def call(self, fn, *args):
        """``fn(*args)`` on the pymeshlab thread."""
        return self.result(*self.submit(fn, *args))


_worker: _Worker | None = None
_worker_lock = threading.Lock()


def _pymeshlab_thread() -> _Worker:
    global _worker
    with _worker_lock:
        if _worker is None:
            _worker = _Worker()
        return _worker


def _pymeshlab_cloud(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """``[sum of squares, max, count]`` of the exact distances of the points ``P`` to the mesh (V, F): the
    Hausdorff filter with the points as a vertex-only mesh, every vertex sampled (``samplenum`` >= their
    count), nearest points from MeshLab's uniform grid, exact."""
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(P, float)))
    ms.add_mesh(pymeshlab.Mesh(np.ascontiguousarray(V, float), np.ascontiguousarray(F, np.int32)))
    r = ms.get_hausdorff_distance(sampledmesh=0, targetmesh=1, samplevert=True, sampleface=False,
                                  samplenum=len(P), maxdist=pymeshlab.PercentageValue(100))
    n = float(r["n_samples"])
    return np.array([n * float(r["RMS"]) ** 2, float(r["max"]), n])


def _sides(V1, F1, V2, F2, samples: int, P1, P2, meshlab: bool):
    """The two one-sided measurements of :func:`exact_sampled_distance`: whether MeshLab takes them, and
    ``(points, target vertices, target faces)`` for each."""
    V1, V2 = np.asarray(V1, float), np.asarray(V2, float)
    F1, F2 = np.asarray(F1, np.int64).reshape(-1, 3), np.asarray(F2, np.int64).reshape(-1, 3)
    if not (len(V1) and len(V2)) or not (np.isfinite(V1).all() and np.isfinite(V2).all()):
        from rigslim.errors import StepError

        raise StepError("a surface to compare has no finite vertices", field="positions",
                        fix="check the mesh and its pose (NaN or inf positions)")
    meshlab = meshlab and pymeshlab_available() and not (is_degenerate(V1, F1) or is_degenerate(V2, F2))
    P1 = surface_samples(V1, F1, samples) if P1 is None else P1
    P2 = surface_samples(V2, F2, samples, seed=1) if P2 is None else P2
    if meshlab:         # pymeshlab gets the faces with three corners (:func:`referenced`), libigl every face
        (V1, F1), (V2, F2) = referenced(V1, F1), referenced(V2, F2)
    return meshlab, ((P1, V2, F2), (P2, V1, F1))


def _libigl_side(P: np.ndarray, V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """:func:`_pymeshlab_cloud`'s figures from libigl (:func:`_distances`)."""
    d = _distances(P, V, F)
    return np.array([float((d * d).sum()), float(d.max()) if len(d) else 0.0, float(len(d))])


def _combined(a: np.ndarray, b: np.ndarray) -> dict:
    n = a[2] + b[2]
    return {"rms": float(np.sqrt((a[0] + b[0]) / n)), "max": float(max(a[1], b[1])), "n_samples": int(n)}


def exact_sampled_distance(V1, F1, V2, F2, samples: int = 5000, P1=None, P2=None, *,
                           backend: str = "bvh") -> dict:
    """:func:`degenerate_distance`'s figures for any two surfaces, repeatable.

    Each side's :func:`surface_samples` (seeds 0 and 1; ``P1``, ``P2``: the same, computed before) and each
    sample's exact distance to the other surface. ``backend``: ``"bvh"`` (default) rigslim's compiled,
    threaded bounding-volume hierarchy (:mod:`rigslim.numerics.point_mesh_distance`), ``"meshlab"`` MeshLab's
    grid (:func:`_pymeshlab_cloud`; regular surfaces only, others go to libigl), ``"libigl"`` libigl's AABB
    (:func:`_distances`); the three agree to round-off (float32's for MeshLab). Then
    ``rms = sqrt(sum_i d_i^2 / n)`` over both sides' ``n`` samples and ``max = max_i d_i``. Unlike
    :func:`metro_distance` every vertex is a sample and no sample comes from MeshLab's random generator, so
    the figures do not depend on what ran before.
    """
    return exact_sampled_distances([(V1, F1, V2, F2, samples, P1, P2)], backend=backend)[0]


def exact_sampled_distances(jobs, *, backend: str = "bvh") -> list[dict]:
    """``[exact_sampled_distance(*args) for args in jobs]``, each ``args`` ``(V1, F1, V2, F2, samples, P1,
    P2)``. With ``bvh`` each triangle list (by identity: a level's faces, the full mesh's) gets one hierarchy,
    refitted to each job's positions (the posed frames of one mesh share it). With ``meshlab`` the jobs are
    pipelined: while MeshLab measures one job on the pymeshlab thread (its filter runs without the
    interpreter lock), this thread samples the next."""
    if backend not in ("bvh", "meshlab", "libigl"):
        raise ValueError(f"backend {backend!r}: use 'bvh', 'meshlab' or 'libigl'")
    if backend == "bvh":
        trees = _Trees()
        figures = []
        for V1, F1, V2, F2, samples, P1, P2 in jobs:
            (Q1, W2, G2), (Q2, W1, G1) = _sides(V1, F1, V2, F2, samples, P1, P2, False)[1]
            figures.append(_combined(trees.side(Q1, W2, G2, F2), trees.side(Q2, W1, G1, F1)))
        return figures
    pool = _pymeshlab_thread() if backend == "meshlab" and pymeshlab_available() else None
    pending: list[list] = []        # per job, its two sides: MeshLab's queued calls or libigl's figures
    for args in jobs:
        V1, F1, V2, F2, samples, P1, P2 = args
        on_meshlab, sides = _sides(V1, F1, V2, F2, samples, P1, P2, pool is not None)
        pending.append([pool.submit(_pymeshlab_cloud, *side) if on_meshlab and pool is not None
                        else _libigl_side(*side) for side in sides])
    return [_combined(*(_Worker.result(*x) if isinstance(x, tuple) else x for x in sides)) for sides in pending]


class _Trees:
    """The bounding-volume hierarchies of one run of jobs, one per triangle list (kept by identity, with a
    reference so the identity stays that list's), refitted when the positions change; and the nearest
    triangles found for the last point set of each size measured against each list, the first guesses of the
    next (the same samples in the next frame: the search then mostly confirms the guess)."""

    def __init__(self) -> None:
        self._by: dict[int, tuple] = {}
        self._guess: dict[tuple[int, int], np.ndarray] = {}     # nearest triangles found last, by target, count

    def side(self, P: np.ndarray, V: np.ndarray, F: np.ndarray, key) -> np.ndarray:
        """:func:`_libigl_side`'s figures from the hierarchy of ``F`` (``key``: the caller's face array)."""
        from rigslim.numerics.point_mesh_distance import build_tree, point_mesh_squared_distances, refit_tree

        if not len(F) or not len(P):
            return _libigl_side(P, V, F)
        held = self._by.get(id(key))
        if held is None or held[0] is not key:
            tree = build_tree(V, F)
        else:
            tree = held[1] if held[2] is V else refit_tree(held[1], V, F)
        self._by[id(key)] = (key, tree, V)
        guess = self._guess.setdefault((id(key), len(P)), np.full(len(P), -1, np.int64))
        d2 = np.maximum(point_mesh_squared_distances(P, V, F, tree, guess), 0.0)
        return np.array([float(d2.sum()), float(np.sqrt(d2.max())), float(len(d2))])
