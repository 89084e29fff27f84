"""The one unit of rigslim's position and surface errors.

Every position and Hausdorff error rigslim reports (the ``position-rms`` and ``metro`` metrics, ``rigslim
compare``, ``rigslim reduce``/``lod`` reports, batch summaries and HTML reports) is given twice:

- in world units (``*_m``: metres for glTF, whose unit is the metre; the mesh file's own unit otherwise), and
- in percent of the **reference diagonal** (``*_pct``): the length of the bounding-box diagonal of the
  reference surface, deformed by the input weights into the **first test frame**, in world space,

    D = || max_v x_v(alpha_0) - min_v x_v(alpha_0) ||,   error_pct = 100 * error_m / D.

World space matters: a glTF skin's bind-space mesh can be in any unit (assimp's centimetre-scaled FBX exports
have joints scaling by 0.01), while its posed vertices are in metres; dividing a world-space error by the
bind-space diagonal gave errors 100x too high.
"""

from __future__ import annotations

import numpy as np

__all__ = ["DEFINITION", "diagonal", "reference_diagonal"]

#: The sentence the metrics document and the reports print for ``*_pct``.
DEFINITION = "percent of the world-space bounding-box diagonal of the reference in the first test frame"


def diagonal(X) -> float:
    """Bounding-box diagonal ``|| max_v x_v - min_v x_v ||`` of (m, 3) points (0 for none)."""
    X = np.asarray(X, dtype=np.float64)
    if not len(X):
        return 0.0
    return float(np.linalg.norm(X.max(axis=0) - X.min(axis=0)))


def reference_diagonal(evaluation) -> float:
    """The reference diagonal D of an :class:`rigslim.evaluation.Evaluation` (cached on it).

    Raises
    ------
    StepError
        When the first test frame's deformation has zero or non-finite extent (no percentage exists).
    """
    cache = evaluation._cache
    if "reference_diagonal" not in cache:
        D = diagonal(evaluation.full_positions(0))
        if not (np.isfinite(D) and D > 0):
            from rigslim.errors import StepError

            raise StepError(f"the mesh deformed into the first test frame (frame {evaluation.frames[0]}) has "
                            f"{'zero' if np.isfinite(D) else 'non-finite'} extent: errors in % of its diagonal "
                            "do not exist", field="evaluate", fix="check the mesh and the poses")
        cache["reference_diagonal"] = D
    return cache["reference_diagonal"]
