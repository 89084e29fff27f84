"""Two-sided distance between two triangle surfaces (Metro, Cignoni, Rocchini & Scopigno 1998), via pymeshlab.

Shared by the ``metro`` metric, ``rigslim compare`` and the simplification benchmark.
"""

from __future__ import annotations

import numpy as np

__all__ = ["metro_distance"]


def metro_distance(V1, F1, V2, F2, samples: int = 20000) -> dict:
    """Two-sided Hausdorff distance between two triangle meshes (pymeshlab's Hausdorff filter).

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
    samples of both directions.
    """
    import pymeshlab

    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(np.asarray(V1, float), np.asarray(F1, np.int32)))
    ms.add_mesh(pymeshlab.Mesh(np.asarray(V2, float), np.asarray(F2, np.int32)))
    out = []
    for s, t in ((0, 1), (1, 0)):
        out.append(ms.get_hausdorff_distance(sampledmesh=s, targetmesh=t, samplevert=True, sampleface=True,
                                             samplenum=int(samples), maxdist=pymeshlab.PercentageValue(100)))
    n = np.array([r["n_samples"] for r in out], float)
    rms = float(np.sqrt((n * np.array([r["RMS"] for r in out]) ** 2).sum() / n.sum()))
    return {"rms": rms, "max": float(max(r["max"] for r in out)), "n_samples": int(n.sum())}
