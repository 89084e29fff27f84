"""Benchmark inputs: the bundled elephant, and the elephant subdivided with weights interpolated.

Midpoint subdivision (``igl.upsample``: each triangle into four, new vertices
at edge midpoints, old vertices unmoved) keeps the surface and the motion:
a new vertex's weights are the mean of its edge's endpoint weights, exactly
what linear interpolation of the weight functions gives.

| levels | vertices | triangles |
|---|---|---|
| 0 | 6,034 | 12,064 |
| 1 | 24,130 | 48,256 |
| 2 | ~96.5k | ~193k |
| 3 | ~386k | ~772k |

Example
-------
>>> from benchmarks.datasets import elephant
>>> asset = elephant(levels=1)   # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
EXAMPLES = "0:457:45"
TEST = "5:457:7"


def elephant(levels: int = 0, examples: str = EXAMPLES, test: str = TEST):
    """The elephant asset, subdivided ``levels`` times (weights interpolated).

    Returns
    -------
    rigslim.model.asset.Asset
        mesh, skeleton handles, weights (csr, rows sum to 1), all 457 poses and
        the split (example frames ``0:457:45``, test frames ``5:457:7`` minus 180).
    """
    from rigslim.io import read_dmat, read_mesh, read_stacked_animation, read_tgf
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit
    from rigslim.model.weights import validate_weights

    mesh = read_mesh(DATA / "elephant.obj")
    handles = read_tgf(DATA / "elephant.tgf")
    W = validate_weights(read_dmat(DATA / "elephant-weights.dmat"), mesh.n_vertices, n_handles=handles.n)
    if levels > 0:
        mesh, W = subdivide(mesh, W, levels)
    poses = read_stacked_animation(DATA / "elephant-anim.dmat", n_handles=handles.n)
    split = FrameSplit.from_specs(examples, test, len(poses))
    return Asset(mesh=mesh, handles=handles, weights=W, poses=poses, split=split,
                 provenance={"inputs": {"mesh": f"elephant.obj subdivided {levels}x"}})


def subdivide(mesh, W, levels: int):
    """Midpoint-subdivide a mesh ``levels`` times, interpolating the weights linearly."""
    import igl

    from rigslim.model.mesh import Mesh

    V, F = mesh.V, mesh.F
    Wd = sp.csr_matrix(W).toarray()
    stacked = np.hstack([V, Wd])
    S, F2 = igl.upsample(stacked, F, levels)
    V2, W2 = S[:, :3], S[:, 3:]
    W2[np.abs(W2) < 1e-12] = 0.0
    return Mesh(V2, F2, source=f"{mesh.source} (subdivided {levels}x)"), sp.csr_matrix(W2)


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), for the machine line of every results table."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict:
    """``{"cpu", "nproc", "python"}`` of this machine."""
    return {"cpu": cpu_model(), "nproc": os.cpu_count(), "python": platform.python_version()}


def write_results(stem, doc: dict, markdown: str) -> None:
    """Write ``stem.json`` (the document) and ``stem.md`` (its table) atomically."""
    from rigslim.io.atomic import atomic_path

    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(stem.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
    with atomic_path(stem.with_suffix(".md")) as tmp:
        tmp.write_text(markdown)
