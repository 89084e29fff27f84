"""Progressive hierarchies (:class:`~rigslim.model.hierarchy.ProgressiveHierarchy`) as compressed ``.npz`` files.

The file holds ``format`` (:data:`~rigslim.model.hierarchy.FORMAT`), the rest mesh ``V``/``F``, the
fixed-width weights (``weight_indices``, ``weight_values``, ``n_handles``), the collapse sequence
(``collapses``, ``errors``, ``n_faces``), the ``method`` and its ``params`` as JSON.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.io.atomic import atomic_path
from rigslim.model.hierarchy import FORMAT, ProgressiveHierarchy
from rigslim.model.weights import ReducedWeights


def write_hierarchy(path, hierarchy: ProgressiveHierarchy) -> None:
    """Write ``hierarchy`` to a compressed ``.npz`` atomically (read it back with :func:`read_hierarchy`)."""
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as fh:
            np.savez_compressed(fh, format=np.array(FORMAT), V=hierarchy.V, F=hierarchy.F,
                                weight_indices=hierarchy.weights.indices, weight_values=hierarchy.weights.values,
                                n_handles=np.array(hierarchy.weights.n_handles), collapses=hierarchy.collapses,
                                errors=hierarchy.errors, n_faces=hierarchy.n_faces, method=np.array(hierarchy.method),
                                params=np.array(json.dumps(hierarchy.params, default=str)))


def read_hierarchy(path) -> ProgressiveHierarchy:
    """Read a hierarchy written by :func:`write_hierarchy`."""
    path = Path(path)
    try:
        z = np.load(path, allow_pickle=False)
    except (OSError, ValueError) as e:
        raise InputError(f"cannot read hierarchy ({e})", source=path, field="file",
                         fix="give a .npz written by the 'hierarchy' writer") from None
    with z:
        if "format" not in z or str(z["format"]) != FORMAT:
            raise InputError("not a rigslim progressive hierarchy", source=path, field="format",
                             fix="give a .npz written by the 'hierarchy' writer")
        w = ReducedWeights(z["weight_indices"], z["weight_values"], int(z["n_handles"]))
        return ProgressiveHierarchy(z["V"], w, z["F"], z["collapses"], z["errors"], z["n_faces"],
                                    str(z["method"]), json.loads(str(z["params"])))
