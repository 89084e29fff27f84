"""Writer plugins for reduced weights."""

from __future__ import annotations

from typing import TYPE_CHECKING

from rigslim.errors import StepError
from rigslim.io import write_dmat, write_reduced_npz
from rigslim.plugin import Params, Writer

if TYPE_CHECKING:
    from pathlib import Path

    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext


def _reduced(asset):
    asset.require("reduced", step="write")
    return asset.reduced


class NPZWriter(Writer):
    name = "npz"
    summary = "reduced weights as fixed-k indices (int32) and values in a compressed .npz"
    suffixes = (".npz",)

    def write(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        write_reduced_npz(path, _reduced(asset))


class DMATWriterParams(Params):
    binary: bool = True
    """Binary DMAT (false: ASCII)."""


class DMATWriter(Writer[DMATWriterParams]):
    name = "dmat"
    summary = "reduced weights as a dense m x n DMAT (binary or ASCII), as libigl reads them"
    suffixes = (".dmat",)

    def write(self, path: Path, asset: Asset, params: DMATWriterParams, ctx: StepContext) -> None:
        reduced = _reduced(asset)
        if reduced.n_vertices * reduced.n_handles > 2e8:
            raise StepError("the dense matrix would exceed 200M entries", field="write",
                            fix="write an .npz instead")
        write_dmat(path, reduced.to_sparse().toarray(), binary=params.binary)


WRITERS = [NPZWriter, DMATWriter]
