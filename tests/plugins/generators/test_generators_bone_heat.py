"""Bone heat weights: non-negative, partition of unity, each bone dominant near itself,
the linear system against a dense solve, visibility, and the pipeline step."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.errors import StepError
from rigslim.model.mesh import Mesh
from rigslim.plugins.generators.bone_heat import bone_heat_weights, nearest_visible_bones, point_segment_distances


@pytest.fixture(scope="module")
def capsule():
    """An elongated closed surface along x with a 3-bone chain inside."""
    import igl

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1.0]])
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(V, F, 3)
    V = V / np.linalg.norm(V, axis=1, keepdims=True) * [3.0, 0.6, 0.6]
    joints = np.array([[-2.4, 0, 0], [-0.8, 0, 0], [0.8, 0, 0], [2.4, 0, 0]])
    bones = np.array([[0, 1], [1, 2], [2, 3]])
    return Mesh(V, F), joints, bones


@pytest.fixture(scope="module")
def cheb(data_dir):
    from rigslim.io import read_mesh, read_tgf

    return read_mesh(data_dir / "cheburashka.off"), read_tgf(data_dir / "cheburashka.tgf")


def test_point_segment_distances():
    A = np.array([[0, 0, 0.0]])
    B = np.array([[2, 0, 0.0]])
    d, Q = point_segment_distances(np.array([[1, 1, 0], [-1, 0, 0], [3, 0, 1.0]]), A, B)
    assert np.allclose(d[:, 0], [1, 1, np.sqrt(2)])
    assert np.allclose(Q[:, 0], [[1, 0, 0], [0, 0, 0], [2, 0, 0]])


def test_properties_on_the_cheb(cheb):
    mesh, skel = cheb
    report = {}
    W = bone_heat_weights(mesh, skel.joints, skel.bones, report=report)
    assert W.shape == (mesh.n_vertices, 17)
    assert W.min() >= 0
    assert np.abs(W.sum(axis=1) - 1).max() < 1e-12
    # dense: bone heat spreads every bone over the whole connected surface
    assert (W > 1e-8).sum(axis=1).mean() > 12
    # each bone's weight is largest near that bone
    P, d = nearest_visible_bones(mesh.V, mesh.F, skel.joints[skel.bones[:, 0]], skel.joints[skel.bones[:, 1]])
    nearest = P.argmax(axis=1)
    for i in range(17):
        assert nearest[W[:, i].argmax()] == i
    seen = np.isfinite(d)
    assert (W.argmax(axis=1)[seen] == nearest[seen]).mean() > 0.85
    assert report["vertices_seeing_no_bone"] < 0.05 * mesh.n_vertices


def test_system_matches_a_dense_solve(capsule):
    mesh, joints, bones = capsule
    report = {}
    W = bone_heat_weights(mesh, joints, bones, heat=1.0, report=report)
    P, d = nearest_visible_bones(mesh.V, mesh.F, joints[bones[:, 0]], joints[bones[:, 1]])
    H = np.where(np.isfinite(d), 1.0 / d**2, 0.0)
    M = mesh.massmatrix.diagonal()
    K = -mesh.cotmatrix.toarray() + np.diag(M * H)
    dense = np.linalg.solve(K, (M * H)[:, None] * P)
    # the report counts exactly the round-off negatives the dense solve has, before they are clipped
    assert report["clipped_negatives"] == int((dense < -1e-10).sum())
    dense = np.clip(dense, 0, None)
    dense /= dense.sum(axis=1, keepdims=True)
    assert np.abs(W - dense).max() < 1e-10
    # the chain: the first bone dominates the -x end, the last the +x end
    assert W[np.argmin(mesh.V[:, 0]), 0] > 0.9
    assert W[np.argmax(mesh.V[:, 0]), 2] > 0.9
    assert W.min() >= 0


def test_visibility_blocks_bones_behind_the_surface():
    """Two arms with a gap: a vertex must not pick the other arm's bone, nearer through empty space."""
    import igl

    # two boxes (arms) side by side with a gap between them, as one mesh
    box_V = np.array([[x, y, z] for x in (0, 1) for y in (0, 1) for z in (0, 1)], dtype=float)
    box_F = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                      [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    Va = box_V * [0.4, 4, 0.4]
    Vb = box_V * [0.4, 4, 0.4] + [0.6, 0, 0]
    V = np.vstack([Va, Vb])
    F = np.vstack([box_F, box_F + 8])
    V, F = igl.upsample(V, F, 2)
    # arm a's bone hugs its outer side (0.35 from the inner face x = 0.4); arm b's bone is 0.25 away
    # from that face, but behind arm b's wall at x = 0.6
    # (slanted in z so that no test ray runs exactly along a mesh edge)
    A = np.array([[0.05, 0.3, 0.13], [0.65, 0.3, 0.13]])
    B = np.array([[0.05, 3.7, 0.29], [0.65, 3.7, 0.29]])
    inner_a = np.flatnonzero(np.isclose(V[:, 0], 0.4) & (V[:, 1] > 0.5) & (V[:, 1] < 3.5))
    assert len(inner_a)
    P, d = nearest_visible_bones(V, F, A, B)
    assert (P[inner_a, 0] == 1).all()
    assert (d[inner_a] > 0.35).all()
    P2, d2 = nearest_visible_bones(V, F, A, B, visibility=False)
    assert (P2[inner_a, 1] == 1).all()
    assert (d2[inner_a] < d[inner_a]).all()


def test_bone_heat_step_needs_a_skeleton(write_pipeline, tmp_path):
    from rigslim.runtime.run import run_pipeline

    (tmp_path / "tet.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 0 1\nf 1 3 2\nf 1 2 4\nf 1 4 3\nf 2 3 4\n")
    path = write_pipeline("""
inputs:
  mesh: data/cheburashka.off
  cage: tet.obj
steps:
  - generate: bone-heat
""")
    with pytest.raises(StepError, match="skeleton"):
        run_pipeline(path)


def test_cheb_pipeline_runs(write_pipeline):
    from rigslim.runtime.run import run_pipeline

    path = write_pipeline("""
inputs:
  mesh: data/cheburashka.off
  skeleton: data/cheburashka.tgf
  animation: data/cheburashka-anim.dmat
poses: {examples: "0:40:6", test: "1:40:8"}
steps:
  - generate: bone-heat
  - select: k-largest
    k: 5
  - solve: k-largest
  - evaluate: [position-rms, max-influences]
""")
    result = run_pipeline(path)
    metrics = result.document["evaluations"][0]["metrics"]
    assert metrics["input_max_influences"] == 17
    assert metrics["max_influences"] == 5
    assert 0 < metrics["position_rms_pct"]["mean"] < 2.0
    gen = result.document["steps"][1]
    assert gen["plugin"] == "bone-heat"
    # the step's report is the generator's own, for the same mesh and skeleton
    from rigslim.io import read_mesh, read_tgf

    skel = read_tgf(path.parent / "data" / "cheburashka.tgf")
    direct = {}
    bone_heat_weights(read_mesh(path.parent / "data" / "cheburashka.off"), skel.joints, skel.bones, report=direct)
    assert gen["report"]["clipped_negatives"] == direct["clipped_negatives"]
    assert gen["report"]["vertices_seeing_no_bone"] == direct["vertices_seeing_no_bone"]
