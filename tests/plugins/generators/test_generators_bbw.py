"""Bounded biharmonic weights (igl.bbw) on a tetrahedral bar with a 2-bone chain inside."""

from __future__ import annotations

import itertools

import numpy as np
import pytest

from rigslim.errors import StepError
from rigslim.plugins.generators.bbw import bounded_biharmonic_weights


def tet_bar(nx=8, ny=2, nz=2, size=(4.0, 1.0, 1.0)):
    """A box split into cubes and each cube into 6 tetrahedra (Freudenthal/Kuhn)."""
    axes = [np.linspace(0, s, n + 1) for s, n in zip(size, (nx, ny, nz), strict=False)]
    V = np.array(list(itertools.product(*axes)))
    shape = (nx + 1, ny + 1, nz + 1)
    T = []
    for i, j, k in itertools.product(range(nx), range(ny), range(nz)):
        corner = np.array([i, j, k])
        for perm in itertools.permutations(range(3)):
            path = [corner.copy()]
            for axis in perm:
                nxt = path[-1].copy()
                nxt[axis] += 1
                path.append(nxt)
            T.append([np.ravel_multi_index(p, shape) for p in path])
    T = np.array(T)
    # positive orientation
    a, b, c, d = (V[T[:, i]] for i in range(4))
    neg = np.einsum("ij,ij->i", np.cross(b - a, c - a), d - a) < 0
    T[neg] = T[neg][:, [1, 0, 2, 3]]
    return V, T


def write_medit(path, V, T):
    lines = ["MeshVersionFormatted 1", "Dimension 3", "Vertices", str(len(V))]
    lines += [f"{x:.17g} {y:.17g} {z:.17g} 0" for x, y, z in V]
    lines += ["Triangles", "0", "Tetrahedra", str(len(T))]
    lines += [" ".join(str(i + 1) for i in t) + " 0" for t in T]
    lines += ["End"]
    path.write_text("\n".join(lines) + "\n")


JOINTS = np.array([[0.5, 0.5, 0.5], [2.0, 0.5, 0.5], [3.5, 0.5, 0.5]])
BONES = np.array([[0, 1], [1, 2]])


def test_bbw_properties():
    V, T = tet_bar()
    report = {}
    W = bounded_biharmonic_weights(V, T, JOINTS, BONES, report=report)
    assert W.shape == (len(V), 2)
    assert W.min() >= 0 and W.max() <= 1
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-12
    on_first = (np.abs(V[:, 1] - 0.5) < 1e-9) & (np.abs(V[:, 2] - 0.5) < 1e-9) & (V[:, 0] > 0.4) & (V[:, 0] < 1.9)
    assert np.allclose(W[on_first, 0], 1.0)
    # each bone dominates its own half of the bar
    assert (W[V[:, 0] < 1.5, 0] > 0.5).all()
    assert (W[V[:, 0] > 2.5, 1] > 0.5).all()
    assert report["constrained_vertices"] > 0


def test_bones_off_the_vertices_are_an_error():
    V, T = tet_bar()
    with pytest.raises(StepError, match="no vertex"):
        bounded_biharmonic_weights(V, T, JOINTS + [0, 0.25, 0.25], BONES)


def test_bbw_pipeline_on_a_medit_mesh(tmp_path):
    from rigslim.runtime.run import run_pipeline

    V, T = tet_bar()
    write_medit(tmp_path / "bar.mesh", V, T)
    (tmp_path / "bar.tgf").write_text("1 0.5 0.5 0.5\n2 2 0.5 0.5\n3 3.5 0.5 0.5\n#\n1 2\n2 3\n#\n")
    (tmp_path / "p.yaml").write_text("inputs:\n  mesh: bar.mesh\n  skeleton: bar.tgf\nsteps:\n  - generate: bbw\n")
    asset = run_pipeline(tmp_path / "p.yaml").asset
    assert asset.weights.shape == (asset.mesh.n_vertices, 2)
    surface = asset.extras["volume"]["surface_vertices"]
    full = bounded_biharmonic_weights(V, T, JOINTS, BONES)
    assert np.abs(asset.weights.toarray() - full[surface]).max() < 1e-8


def test_bbw_needs_a_volume(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("inputs:\n  mesh: data/elephant.obj\n  skeleton: data/elephant.tgf\n"
                          "steps:\n  - generate: bbw\n")
    with pytest.raises(StepError, match="tetrahedral"):
        run_pipeline(path)
