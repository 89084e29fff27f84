"""The out-of-process half of the extension: runs in a Python that has rigslim, never inside Blender.

Blender writes a request (``.npz``: arrays only, no pickles) into a temporary
folder and runs::

    PYTHON worker.py version
    PYTHON worker.py reduce REQUEST.npz RESULT.npz
    PYTHON worker.py lod REQUEST.npz RESULT.npz

Every line this prints on stdout is one JSON object: ``{"progress": f,
"message": s}`` while it works, ``{"version": ...}`` for ``version``, and on a
user error ``{"error": "one line"}`` (exit code 2; the one line is
rigslim's own :class:`rigslim.RigslimError` message). Anything else
(a bug) exits 1 with the traceback on stderr. The result is written to a
temporary name and renamed, so Blender never reads half a file.

Only rigslim's public API does the work: :func:`rigslim.reduce_weights` with
the library's defaults (whatever it selects and solves by default), and
:func:`rigslim.simplify`; the UVs of new LOD vertices are resampled with
:func:`rigslim.io.gltf.lod.projected_attributes`, the function rigslim's glTF
writer uses.

This file must not import bpy, and must run on numpy 1.26 and 2.x alike.
"""

from __future__ import annotations

import inspect
import json
import os
import sys
import time
from typing import Any

import numpy as np

PROTOCOL = 1


def emit(**fields) -> None:
    """Print one JSON line (flushed: Blender reads it while the work goes on)."""
    sys.stdout.write(json.dumps(fields, allow_nan=False, default=float) + "\n")
    sys.stdout.flush()


def progress(fraction: float, message: str) -> None:
    emit(progress=float(fraction), message=message)


def load_request(path: str) -> dict[str, np.ndarray]:
    with np.load(path, allow_pickle=False) as z:
        req = {k: z[k] for k in z.files}
    if int(req.get("protocol", -1)) != PROTOCOL:
        raise SystemExit(f"request {path}: protocol {req.get('protocol')} is not {PROTOCOL}; "
                         "install the same version of the extension and its worker")
    return req


def save_result(path: str, **arrays) -> None:
    tmp = path + ".part.npz"
    np.savez(tmp, protocol=np.int64(PROTOCOL), **arrays)
    os.replace(tmp, path)


def sparse_weights(req: dict[str, np.ndarray]):
    """The (m, n) input weights from the request's triplets (rows sum to one)."""
    import scipy.sparse as sp

    m, n = int(req["n_vertices"]), int(req["n_handles"])
    return sp.csr_matrix((req["w_values"], (req["w_rows"], req["w_cols"])), shape=(m, n))


def api_defaults(func) -> dict[str, object]:
    """Keyword defaults of a rigslim API function (what it does when Blender passes nothing)."""
    return {k: p.default for k, p in inspect.signature(func).parameters.items()
            if p.default is not inspect.Parameter.empty and p.kind == p.KEYWORD_ONLY}


def decimator_parameters() -> list[str]:
    """The parameters the default decimator accepts (``max_bones``, ``error_targets``, joint budgets...)."""
    import rigslim

    plugin = rigslim.registry()["articulated-decimation"][api_defaults(rigslim.simplify)["method"]]
    return sorted(plugin.params_schema.get("properties", {}))


def cmd_version() -> int:
    import rigslim

    reduce_defaults = {k: v for k, v in api_defaults(rigslim.reduce_weights).items() if k in ("k", "select", "solve")}
    emit(version=rigslim.__version__, protocol=PROTOCOL, python=sys.executable, reduce_defaults=reduce_defaults,
         simplify_method=api_defaults(rigslim.simplify)["method"], decimator_parameters=decimator_parameters())
    return 0


def cmd_reduce(request: str, result: str) -> int:
    """k weights per vertex with :func:`rigslim.reduce_weights` (its default selection and solver unless named)."""
    import rigslim
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import Poses

    req = load_request(request)
    k = int(req["k"])
    defaults = api_defaults(rigslim.reduce_weights)
    chosen = {key: str(req[key]) for key in ("select", "solve") if key in req and str(req[key]).strip()}
    methods = {**{key: defaults[key] for key in ("select", "solve")}, **chosen}
    progress(0.05, f"fitting {k} weights per vertex to {len(req['poses'])} poses "
                   f"(select {methods['select']}, solve {methods['solve']})")
    mesh = Mesh(req["V"], req["F"], source="blender mesh")
    poses = Poses(req["poses"], frames=np.arange(len(req["poses"])), source="blender poses")
    stats: dict = {}
    t0 = time.perf_counter()
    reduced = rigslim.reduce_weights(mesh, sparse_weights(req), poses, k=k, report=stats, **chosen)
    seconds = time.perf_counter() - t0
    progress(0.95, f"fitted in {seconds:.1f} s")
    save_result(result, indices=reduced.indices.astype(np.int64), values=reduced.values.astype(np.float64),
                seconds=np.float64(seconds), select=np.str_(methods["select"]), solve=np.str_(methods["solve"]))
    return 0


def seam_free_pairs(F: np.ndarray, corner_keys: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Pairs of triangles ``(fa, fb)`` sharing an edge whose two endpoints carry the same corner label in both.

    ``corner_keys`` (f, 3) labels each corner (its UVs in every layer and the face's material), so no pair
    crosses a UV seam or a material boundary; the connected components of the pairs are the UV charts.
    """
    nf = len(F)
    he = np.concatenate([np.stack([F[:, i], F[:, (i + 1) % 3], corner_keys[:, i], corner_keys[:, (i + 1) % 3],
                                   np.arange(nf)], 1) for i in range(3)])
    flip = he[:, 0] > he[:, 1]
    lo, hi = np.where(flip, he[:, 1], he[:, 0]), np.where(flip, he[:, 0], he[:, 1])
    kl, kh = np.where(flip, he[:, 3], he[:, 2]), np.where(flip, he[:, 2], he[:, 3])
    order = np.lexsort((kh, kl, hi, lo))
    s = np.stack([lo, hi, kl, kh], 1)[order]
    same = np.flatnonzero((s[1:] == s[:-1]).all(axis=1))
    return he[order[same], 4], he[order[same + 1], 4]


def level_corners(hier, level, F: np.ndarray, L: np.ndarray, pairs: tuple[np.ndarray, np.ndarray], X: np.ndarray):
    """One level's triangles, their source triangles, and every corner's attributes.

    Parameters
    ----------
    hier : rigslim.model.hierarchy.ProgressiveHierarchy
        Built on the rest mesh (V, F).
    level : rigslim.model.hierarchy.SimplifiedLevel
    F, L : (f, 3) int arrays
        Source triangles by vertex and by Blender loop (face corner).
    pairs : (fa, fb) triangles joined across seam-free edges (:func:`seam_free_pairs`).
    X : (loops, C) per-loop attributes (every UV layer side by side).

    Returns
    -------
    faces : (g, 3) level-vertex rows; source : (g,) source triangle of each; corner_values : (g, 3, C)

    Notes
    -----
    A level triangle is a source triangle whose three corners map to three distinct level vertices
    (:func:`rigslim.io.gltf.lod.level_representatives`). A corner whose vertex the level kept keeps its
    loop's values; a corner at a vertex made by collapses takes the values at the closest point of the
    source triangles it replaced on its side of every seam through it (:func:`rigslim.io.gltf.lod.corner_sides`,
    so that the two sides of a UV slit stay apart; :func:`rigslim.io.gltf.lod.projected_attributes`).
    """
    from rigslim.io.gltf.lod import corner_sides, level_representatives, projected_attributes

    m = hier.n_original
    ids = np.asarray(level.vertex_ids, np.int64)
    rep = level_representatives(hier, ids)
    R_all = rep[F]
    sides, side_vertex = corner_sides(F, R_all, pairs[0], pairs[1], m)
    keep = (R_all >= 0).all(axis=1) & (R_all[:, 0] != R_all[:, 1]) & (R_all[:, 1] != R_all[:, 2]) \
        & (R_all[:, 2] != R_all[:, 0])
    source = np.flatnonzero(keep)
    level_keys = set(map(tuple, np.sort(ids[np.asarray(level.mesh.F)], axis=1).tolist()))
    inlevel = np.array([tuple(r) in level_keys for r in np.sort(R_all[source], axis=1).tolist()], bool)
    source = source[inlevel] if len(source) else source
    R = R_all[source]
    faces = np.searchsorted(ids, R)
    values = np.empty((len(source), 3, X.shape[1]))
    kept = R < m
    values[kept] = X[L[source][kept]]
    if (~kept).any():
        owners = sides[source][~kept]
        uniq, inv = np.unique(owners, return_inverse=True)
        Y = projected_attributes(hier.V[side_vertex[uniq]], uniq, hier.V[:m], F, L, sides, X, 0)
        values[~kept] = Y[inv.ravel()]
    if np.isnan(values).any():
        raise RuntimeError(f"level {level.label}: a corner got no attribute value")
    return faces.astype(np.int64), source.astype(np.int64), values


def cmd_lod(request: str, result: str) -> int:
    """Levels of detail with :func:`rigslim.simplify` (its default method), bone limit and UVs per corner."""
    import rigslim
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import Poses

    req = load_request(request)
    ratios = [float(r) for r in req["ratios"]]
    params: dict = {}
    if int(req["max_bones"]) > 0:
        params["max_bones"] = int(req["max_bones"])
    extra = json.loads(str(req["extra_params"])) if "extra_params" in req else {}
    params.update(extra)
    method = api_defaults(rigslim.simplify)["method"]
    mesh = Mesh(req["V"], req["F"], source="blender mesh")
    poses = Poses(req["poses"], frames=np.arange(len(req["poses"])), source="blender poses")
    progress(0.05, f"simplifying {mesh.n_faces} triangles ({method}, {len(poses.T)} poses) to "
                   + ", ".join(f"{r:g}" for r in ratios))
    t0 = time.perf_counter()
    out = rigslim.simplify(mesh, sparse_weights(req), poses, targets=ratios, method=method, **params)
    seconds = time.perf_counter() - t0
    if out.hierarchy is None:
        raise SystemExit(f"decimator {method} records no hierarchy; the extension needs one")
    progress(0.8, f"simplified in {seconds:.1f} s; resampling UVs")
    F, L = np.asarray(req["F"], np.int64), np.asarray(req["L"], np.int64)
    X = np.asarray(req["loop_values"], np.float64).reshape(int(req["n_loops"]), -1)
    pairs = seam_free_pairs(F, np.asarray(req["corner_keys"], np.int64))
    arrays: dict[str, Any] = {"n_levels": np.int64(len(out.levels)), "seconds": np.float64(seconds),
                                     "method": np.str_(method)}
    for i, level in enumerate(out.levels):
        faces, source, values = level_corners(out.hierarchy, level, F, L, pairs, X)
        arrays.update({f"l{i}_V": level.mesh.V, f"l{i}_faces": faces, f"l{i}_source": source,
                       f"l{i}_values": values, f"l{i}_indices": level.weights.indices.astype(np.int64),
                       f"l{i}_weights": level.weights.values.astype(np.float64),
                       f"l{i}_label": np.str_(level.label), f"l{i}_error": np.float64(level.error)})
    save_result(result, **arrays)
    return 0


def main(argv: list[str]) -> int:
    if not argv or argv[0] not in ("version", "reduce", "lod"):
        emit(error="usage: worker.py version | reduce REQUEST RESULT | lod REQUEST RESULT")
        return 2
    try:
        import rigslim
    except ImportError as exc:
        emit(error=f"{sys.executable} cannot import rigslim ({exc}); "
                   "install it there (pip install rigslim) or choose another Python in the add-on's preferences")
        return 2
    try:
        if argv[0] == "version":
            return cmd_version()
        if len(argv) != 3:
            emit(error=f"usage: worker.py {argv[0]} REQUEST RESULT")
            return 2
        return (cmd_reduce if argv[0] == "reduce" else cmd_lod)(argv[1], argv[2])
    except rigslim.RigslimError as exc:
        emit(error=exc.one_line())
        return 2
    except SystemExit as exc:
        if isinstance(exc.code, str):
            emit(error=exc.code)
            return 2
        raise


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
