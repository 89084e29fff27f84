"""The ``.npz`` file of reduced weights.

Keys: ``indices`` (m, k) int32, ``values`` (m, k) float64, ``n_handles``
(scalar), and ``format`` = ``"rigslim.reduced-weights/1"``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.io.atomic import atomic_path
from rigslim.model.weights import ReducedWeights

FORMAT = "rigslim.reduced-weights/1"


def write_reduced_npz(path, reduced: ReducedWeights, **metadata) -> None:
    """Write reduced weights (and optional metadata arrays/strings) atomically."""
    with atomic_path(path, suffix=".npz") as tmp:
        with open(tmp, "wb") as f:
            np.savez_compressed(f, format=FORMAT, indices=reduced.indices, values=reduced.values,
                                n_handles=reduced.n_handles, **metadata)


def read_reduced_npz(path) -> ReducedWeights:
    """Read reduced weights written by :func:`write_reduced_npz`."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            if str(z.get("format", "")) != FORMAT:
                raise InputError(f"not a {FORMAT} file", source=path, field="format",
                                 fix="give an .npz written by rigslim")
            return ReducedWeights(z["indices"], z["values"], int(z["n_handles"]))
    except (OSError, ValueError, KeyError) as e:
        raise InputError(f"cannot read it ({e})", source=path, field="contents",
                         fix="give an .npz written by rigslim") from None
