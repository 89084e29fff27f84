"""Reader plugins: one per (role, format)."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

from rigslim.errors import InputError
from rigslim.io import read_dmat, read_medit_surface, read_mesh, read_stacked_animation, read_tgf
from rigslim.io.meshfile import MESH_SUFFIXES
from rigslim.model.handles import Handles
from rigslim.model.weights import validate_weights
from rigslim.plugin import Params, Reader

if TYPE_CHECKING:
    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext


class MeshReader(Reader):
    name = "mesh"
    summary = "triangle mesh from OBJ/OFF/PLY/STL (libigl), or the surface of a MEDIT .mesh"
    role = "mesh"
    suffixes = MESH_SUFFIXES

    def read(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        if path.suffix.lower() == ".mesh":
            V, F, volume = read_medit_surface(path)
            from rigslim.model.mesh import Mesh

            asset.mesh = Mesh(V, F, source=str(path))
            asset.extras["volume"] = volume
        else:
            asset.mesh = read_mesh(path)


class TGFReader(Reader):
    name = "tgf"
    summary = "skeleton from libigl's TGF (joints, then parent-child bones); one handle per bone"
    role = "skeleton"
    suffixes = (".tgf",)

    def read(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        asset.handles = read_tgf(path)


class CageReader(Reader):
    name = "cage"
    summary = "closed triangle cage (OBJ/OFF/PLY); one handle per cage vertex"
    role = "cage"
    suffixes = (".obj", ".off", ".ply", ".stl")

    def read(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        asset.handles = Handles.from_cage(read_mesh(path), source=str(path))


class DMATWeightsReaderParams(Params):
    normalize: bool = False
    """Divide each row by its sum (false: rows must already sum to 1)."""


class DMATWeightsReader(Reader[DMATWeightsReaderParams]):
    name = "dmat-weights"
    summary = "input weights, m x n DMAT (ASCII or binary); rows must sum to 1 unless normalize"
    role = "weights"
    suffixes = (".dmat",)
    after = ("mesh", "skeleton", "cage")

    def read(self, path: Path, asset: Asset, params: DMATWeightsReaderParams, ctx: StepContext) -> None:
        if asset.mesh is None:
            raise InputError("weights are given but no mesh", source=path, field="inputs.mesh",
                             fix="add 'mesh:' under inputs")
        n = asset.handles.n if asset.handles is not None else None
        asset.weights = validate_weights(read_dmat(path), asset.mesh.n_vertices, n_handles=n,
                                         normalize=params.normalize, source=str(path))


class StackedAnimationReader(Reader):
    name = "dmat-animation"
    summary = "libigl's stacked LBS animation: (12 x bones) x frames DMAT of transposed 3x4 transforms"
    role = "animation"
    suffixes = (".dmat",)
    after = ("mesh", "skeleton", "cage", "weights")

    def read(self, path: Path, asset: Asset, params: Params, ctx: StepContext) -> None:
        n = asset.handles.n if asset.handles is not None else None
        if n is None and asset.weights is not None:
            n = asset.weights.shape[1]
        asset.poses = read_stacked_animation(path, n_handles=n)


READERS = [MeshReader, TGFReader, CageReader, DMATWeightsReader, StackedAnimationReader]
