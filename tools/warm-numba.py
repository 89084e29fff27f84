"""Compile rigslim's numba kernels once, into numba's on-disk cache: the default reduction's, the vertex normals'
and ``rigslim lod``'s.

``make install`` (and so ``make demo`` and ``make test``) runs this right after installing rigslim, so that
the first ``rigslim reduce`` / ``rigslim.reduce_weights`` and the first ``rigslim lod`` a user runs load the
kernels instead of compiling them. The reduction's kernels are those of the default method on several clips:
best-fit selection by error, the non-negative geometric fit, the guard against k-largest; the area-weighted
vertex normals that every evaluation's normal metrics use (about 4 s of compiling in the first ``make demo``
when they were left out); ``lod``'s are the
decimation loop's (edge costs, the collapse queue), warmed by an LOD chain of the bundled
``examples/data/gltf/huesitos.glb`` written to a temporary folder. ``benchmarks/compile_time.py`` measures
each on a fresh cache and after this warm-up (docs/results/compile_time.md). A pip-installed rigslim compiles
them on its first call instead and caches them where numba may write (``NUMBA_CACHE_DIR`` chooses the folder).
"""

from __future__ import annotations

import time
from pathlib import Path

import numpy as np
import scipy.sparse as sp

HUESITOS = Path(__file__).resolve().parents[1] / "examples" / "data" / "gltf" / "huesitos.glb"


def tube(rings: int = 10, segments: int = 8, bones: int = 4) -> tuple[np.ndarray, np.ndarray, sp.csr_matrix]:
    """A closed-around, open-ended tube along z with ``bones`` Gaussian weight bands (V, F, W)."""
    z = np.linspace(0.0, bones, rings)
    th = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    Z, TH = np.meshgrid(z, th, indexing="ij")
    V = np.stack([0.3 * np.cos(TH), 0.3 * np.sin(TH), Z], axis=-1).reshape(-1, 3)
    F = []
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            F += [[a, b, b + segments], [a, b + segments, a + segments]]
    W = np.exp(-((V[:, 2:3] - (np.arange(bones) + 0.5)[None]) ** 2) / 0.5)
    return V, np.array(F), sp.csr_matrix(W / W.sum(axis=1, keepdims=True))


def clip(frames: int, bones: int, rng: np.random.Generator) -> np.ndarray:
    """(frames, bones, 3, 4) rotations about x through each bone's base."""
    T = np.zeros((frames, bones, 3, 4))
    for f in range(frames):
        for b in range(bones):
            a = rng.uniform(-0.6, 0.6)
            R = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
            T[f, b, :, :3] = R
            T[f, b, :, 3] = np.array([0, 0, b]) - R @ np.array([0, 0, b])
    return T


def warm_reduce() -> float:
    """The default ``rigslim.reduce_weights`` on a small tube with two clips; its seconds."""
    import rigslim

    rng = np.random.default_rng(0)
    V, F, W = tube()
    t0 = time.perf_counter()
    rigslim.reduce_weights((V, F), W, [clip(12, 4, rng), clip(12, 4, rng)], k=2)
    return time.perf_counter() - t0


def warm_normals() -> float:
    """Area-weighted vertex normals (every evaluation's normal metrics, the glTF writer's normals) for the
    argument kinds they get: a mesh's read-only faces or a writable copy, read-only rest positions or posed
    ones; its seconds."""
    from rigslim.numerics.blend import per_vertex_normals

    V, F, _ = tube()
    t0 = time.perf_counter()
    for faces_writable in (False, True):
        faces = F.astype(np.int64)
        faces.setflags(write=faces_writable)
        for positions_writable in (False, True):
            positions = V.copy()
            positions.setflags(write=positions_writable)
            per_vertex_normals(positions, faces)
    return time.perf_counter() - t0


def warm_lod() -> float:
    """``rigslim lod huesitos.glb --ratios 0.5,0.25`` into a temporary folder (its report silenced); its seconds."""
    import contextlib
    import io
    import tempfile

    from rigslim.commands.cli import main as cli

    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="rigslim-warm-") as tmp:
        said = io.StringIO()
        with contextlib.redirect_stdout(said), contextlib.redirect_stderr(said):
            code = cli(["lod", str(HUESITOS), "-o", str(Path(tmp) / "lod.glb"), "--ratios", "0.5,0.25"])
        if code:
            raise SystemExit(f"warm-numba: rigslim lod {HUESITOS.name} failed (exit {code}):\n{said.getvalue()}")
    return time.perf_counter() - t0


def main() -> None:
    reduce_s = warm_reduce()
    normals_s = warm_normals()
    lod_s = warm_lod()
    print(f"warm-numba: kernels compiled and cached: the default reduction ({reduce_s:.1f} s), "
          f"vertex normals ({normals_s:.1f} s), rigslim lod ({lod_s:.1f} s)")


if __name__ == "__main__":
    main()
