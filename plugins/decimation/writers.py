"""Writers of simplification results: the progressive hierarchy (``.npz``) and the extracted levels.

``hierarchy``: :func:`rigslim.io.hierarchy.write_hierarchy` (read it
back with :func:`rigslim.io.hierarchy.read_hierarchy`).
``levels``: a folder with, per level, ``<label>.obj`` (rest mesh),
``<label>-weights.dmat`` (dense m x n skin weights, as libigl reads them) and
``<label>.npz`` (fixed-k indices/values), plus ``levels.json`` listing them.
Both are chosen by name (``writer: hierarchy`` / ``writer: levels``), since
``.npz`` already means reduced weights.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

import numpy as np

from rigslim.errors import StepError
from rigslim.io.hierarchy import write_hierarchy
from rigslim.plugin import Params, Writer

if TYPE_CHECKING:
    from pathlib import Path

    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext


def write_obj(path, V: np.ndarray, F: np.ndarray) -> None:
    """A plain OBJ (``v`` and 1-based ``f`` lines), written atomically."""
    from rigslim.io.atomic import atomic_path

    with atomic_path(path) as tmp, open(tmp, "w") as fh:
        np.savetxt(fh, V, fmt="v %.9g %.9g %.9g")
        np.savetxt(fh, np.asarray(F, dtype=np.int64) + 1, fmt="f %d %d %d")


def write_levels(folder, levels, binary: bool = True) -> None:
    """Write levels into ``folder``: OBJ + DMAT + NPZ per level and ``levels.json``; the folder appears whole."""
    from rigslim.io import write_dmat, write_reduced_npz
    from rigslim.io.atomic import atomic_dir

    with atomic_dir(folder) as tmp:
        index = []
        for lv in levels:
            write_obj(tmp / f"{lv.label}.obj", lv.mesh.V, lv.mesh.F)
            write_dmat(tmp / f"{lv.label}-weights.dmat", lv.weights.to_sparse().toarray(), binary=binary)
            write_reduced_npz(tmp / f"{lv.label}.npz", lv.weights)
            index.append({"label": lv.label, "method": lv.method, "faces": lv.n_faces, "vertices": lv.n_vertices,
                          "error": None if np.isnan(lv.error) else lv.error,
                          "max_bones": int(lv.weights.influence_counts().max()),
                          "mesh": f"{lv.label}.obj", "weights": f"{lv.label}-weights.dmat",
                          "reduced": f"{lv.label}.npz"})
        (tmp / "levels.json").write_text(json.dumps({"levels": index}, indent=2) + "\n")


class HierarchyWriter(Writer):
    name = "hierarchy"
    summary = "the progressive hierarchy of a decimate step (every collapse) as a compressed .npz"
    suffixes = ()

    def write(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        hier = asset.hierarchy
        if hier is None:
            raise StepError("there is no progressive hierarchy to write", field="write",
                            fix="use a decimate step with quartic, mohr-gleicher or decoro-rusinkiewicz "
                                "(static-qslim records none) before it")
        write_hierarchy(path, hier)


class LevelsWriterParams(Params):
    binary: bool = True
    """Each level's weights as binary DMAT (false: ASCII)."""


class LevelsWriter(Writer[LevelsWriterParams]):
    name = "levels"
    summary = "the simplified levels of a decimate step: OBJ + DMAT weights + fixed-k .npz per level"
    suffixes = ()

    def write(self, path: Path, asset: Asset, params: LevelsWriterParams, ctx: StepContext) -> None:
        levels = asset.levels
        if not levels:
            raise StepError("there are no simplified levels to write", field="write",
                            fix="add a decimate step with 'targets' before it")
        write_levels(path, levels, binary=params.binary)


WRITERS = [HierarchyWriter, LevelsWriter]
