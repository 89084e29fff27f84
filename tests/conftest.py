"""Shared fixtures: the bundled example data, small meshes, quiet pipeline runs."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
EXAMPLES = ROOT / "examples"
DATA = EXAMPLES / "data"


@pytest.fixture(scope="session")
def data_dir() -> Path:
    return DATA


@pytest.fixture(scope="session")
def elephant():
    """The elephant asset: mesh, skeleton, weights, all 457 poses and the issue's split."""
    from rigslim.io import read_dmat, read_mesh, read_stacked_animation, read_tgf
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit
    from rigslim.model.weights import validate_weights

    mesh = read_mesh(DATA / "elephant.obj")
    handles = read_tgf(DATA / "elephant.tgf")
    weights = validate_weights(read_dmat(DATA / "elephant-weights.dmat"), mesh.n_vertices, n_handles=handles.n)
    poses = read_stacked_animation(DATA / "elephant-anim.dmat", n_handles=handles.n)
    split = FrameSplit.from_specs("0:457:45", "5:457:7", len(poses))
    return Asset(mesh=mesh, handles=handles, weights=weights, poses=poses, split=split)


@pytest.fixture
def rng():
    return np.random.default_rng(0)


@pytest.fixture
def write_pipeline(tmp_path):
    """Write a pipeline YAML (text) into tmp_path with the example data folder beside it."""
    def write(text: str, name: str = "pipeline.yaml") -> Path:
        link = tmp_path / "data"
        if not link.exists():
            link.symlink_to(DATA, target_is_directory=True)
        path = tmp_path / name
        path.write_text(text)
        return path

    return write
