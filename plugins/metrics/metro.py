"""Metro error (Cignoni et al. 1998): two-sided surface distance on test poses, via pymeshlab.

For a simplification, each level deformed by its own skin weights is
compared with the original mesh deformed by the input weights, per test
pose; for a weight reduction, the mesh deformed by the reduced weights is
compared with the full deformation.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from rigslim.errors import StepError
from rigslim.plugin import Metric, Params, aggregate


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


class Metro(Metric):
    name = "metro"
    summary = "two-sided Metro/Hausdorff distance (pymeshlab) per test pose, RMS and max as % of the bbox diagonal"

    class Params(Params):
        samples: int = Field(default=20000, ge=100)
        """Surface samples per direction and pose."""

    def compute(self, evaluation, params, ctx=None):
        try:
            import pymeshlab  # noqa: F401
        except ImportError:  # pragma: no cover - pymeshlab is in the 'metro' extra
            raise StepError("the metro metric needs pymeshlab", field="evaluate",
                            fix="pip install 'rigslim[metro]'") from None
        mesh = evaluation.mesh
        scale = 100.0 / mesh.bbox_diagonal
        frames = range(len(evaluation))
        if evaluation.levels:
            out: dict = {"levels": []}
            for i, level in enumerate(evaluation.levels):
                rms, mx = [], []
                for j in frames:
                    d = metro_distance(level_positions(evaluation, i, j), level.mesh.F,
                                       evaluation.full_positions(j), mesh.F, params.samples)
                    rms.append(scale * d["rms"])
                    mx.append(scale * d["max"])
                if i == 0:
                    out["hausdorff_rms_pct"], out["hausdorff_max_pct"] = aggregate(rms), aggregate(mx)
                out["levels"].append({"name": level.label, "faces": level.n_faces,
                                      "hausdorff_rms_pct": aggregate(rms), "hausdorff_max_pct": aggregate(mx)})
            return out
        rms, mx = [], []
        for j in frames:
            d = metro_distance(evaluation.reduced_positions(j), mesh.F, evaluation.full_positions(j), mesh.F,
                               params.samples)
            rms.append(scale * d["rms"])
            mx.append(scale * d["max"])
        return {"hausdorff_rms_pct": aggregate(rms), "hausdorff_max_pct": aggregate(mx)}


def level_positions(evaluation, i, j):
    return evaluation.level_positions(i, j)
