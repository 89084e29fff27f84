"""The collapse loop and the articulated decimators on a small skinned tube (fast, no data files)."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.io.hierarchy import read_hierarchy, write_hierarchy
from rigslim.model.asset import Asset
from rigslim.model.mesh import Mesh
from rigslim.model.poses import FrameSplit, Poses
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host


def tube(n_around=16, n_along=24, length=3.0, radius=0.3, n_bones=4, caps=True, seed=0, n_poses=10):
    """A (capped) cylinder along z with n_bones Gaussian skin weights and bending poses.

    Returns an Asset with poses 0..n_poses-1; examples are the even frames, test the odd ones.
    """
    z = np.linspace(0.0, length, n_along + 1)
    t = np.linspace(0, 2 * np.pi, n_around, endpoint=False)
    V = np.array([[radius * np.cos(a), radius * np.sin(a), zz] for zz in z for a in t])
    F = []
    for i in range(n_along):
        for j in range(n_around):
            a, b = i * n_around + j, i * n_around + (j + 1) % n_around
            c, d = a + n_around, b + n_around
            F += [[a, b, d], [a, d, c]]
    if caps:
        c0, c1 = len(V), len(V) + 1
        V = np.vstack([V, [0, 0, 0], [0, 0, length]])
        top = n_along * n_around
        for j in range(n_around):
            F.append([c0, (j + 1) % n_around, j])
            F.append([c1, top + j, top + (j + 1) % n_around])
    mesh = Mesh(V, np.array(F))
    centres = (np.arange(n_bones) + 0.5) * length / n_bones
    W = np.exp(-((V[:, 2:3] - centres[None]) / (0.45 * length / n_bones)) ** 2)
    W /= W.sum(axis=1, keepdims=True)
    rng = np.random.default_rng(seed)
    joints = np.arange(n_bones) * length / n_bones
    T = np.zeros((n_poses, n_bones, 3, 4))
    for p in range(n_poses):
        M = np.eye(4)
        for k in range(n_bones):
            th = 0.0 if p == 0 else rng.uniform(-0.6, 0.6)
            R = np.array([[1, 0, 0], [0, np.cos(th), -np.sin(th)], [0, np.sin(th), np.cos(th)]])
            L = np.eye(4)
            L[:3, :3] = R
            L[:3, 3] = np.array([0, 0, joints[k]]) - R @ np.array([0, 0, joints[k]])
            M = M @ L
            T[p, k] = M[:3]
    poses = Poses(T)
    split = FrameSplit.from_specs(list(range(0, n_poses, 2)), list(range(1, n_poses, 2)), n_poses)
    return Asset(mesh=mesh, weights=sp.csr_matrix(W), poses=poses, split=split)


def decimate(asset, method, **params):
    plugin = get_host().get("articulated-decimation", method)
    asset.extras.clear()
    plugin.apply(asset, plugin.parse_params(params), StepContext())
    return asset.hierarchy, asset.levels


def assert_closed_manifold(mesh: Mesh):
    F = mesh.F
    assert len(np.unique(np.sort(F, axis=1), axis=0)) == len(F), "duplicate faces"
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    _, counts = np.unique(E, axis=0, return_counts=True)
    assert (counts == 2).all(), "an edge is not shared by exactly two faces"
    # consistently oriented: every directed edge once
    D = np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]])
    assert len(np.unique(D, axis=0)) == len(D)
    # Euler characteristic of a sphere
    assert mesh.n_vertices - len(np.unique(E, axis=0)) + len(F) == 2


@pytest.fixture(scope="module")
def asset():
    return tube()


@pytest.fixture(scope="module")
def quartic_run(asset):
    return decimate(asset, "quartic", targets=[0.25, 100], min_faces=70, max_bones=2)


def test_bone_limit_and_partition_of_unity_at_every_level(quartic_run, asset):
    hier, levels = quartic_run
    assert hier.faces_after(hier.n_collapses) <= 72
    counts = (hier.weights.values != 0).sum(axis=1)
    assert counts.max() <= 2                      # every vertex that ever exists, so every level
    assert np.allclose(hier.weights.values.sum(axis=1), 1.0, atol=1e-9)
    for t in np.linspace(0, hier.n_collapses, 7).astype(int):
        lv = hier.prefix(t)
        assert lv.weights.influence_counts().max() <= 2
        assert np.allclose(lv.weights.values.sum(axis=1), 1.0, atol=1e-9)
        assert_closed_manifold(lv.mesh)
        assert lv.n_faces == hier.faces_after(t)


def test_levels_match_targets(quartic_run, asset):
    _, levels = quartic_run
    n = asset.mesh.n_faces
    assert [lv.label for lv in levels] == ["quartic-25pct", "quartic-100f"]
    assert levels[0].n_faces <= round(0.25 * n) and levels[0].n_faces >= round(0.25 * n) - 2
    assert 98 <= levels[1].n_faces <= 100


def test_hierarchy_round_trip_replays_same_meshes(quartic_run, tmp_path):
    hier, _ = quartic_run
    write_hierarchy(tmp_path / "h.npz", hier)
    back = read_hierarchy(tmp_path / "h.npz")
    assert back.method == "quartic" and back.params["max_bones"] == 2
    for t in (0, 10, hier.n_collapses // 2, hier.n_collapses):
        a, b = hier.prefix(t), back.prefix(t)
        assert np.array_equal(a.mesh.F, b.mesh.F)
        assert np.array_equal(a.mesh.V, b.mesh.V)
        assert np.array_equal(a.weights.indices, b.weights.indices)
        assert np.array_equal(a.weights.values, b.weights.values)


def test_collapse_errors_follow_greedy_order(quartic_run):
    hier, _ = quartic_run
    e = hier.errors
    assert (e >= 0).all()
    # lazy queue: a collapse never costs less than what the queue already passed, up to the
    # weight-dependent slack of the lower bound (a few percent of the cost)
    running = np.maximum.accumulate(e)
    assert (e >= 0.9 * running - 1e-12).mean() > 0.97


def test_adaptive_extraction_refines_only_where_the_budget_is_small(quartic_run, asset):
    hier, _ = quartic_run
    m = asset.mesh.n_vertices
    fine = hier.adaptive(np.full(m, -1.0))
    assert fine.n_faces == asset.mesh.n_faces
    coarse = hier.adaptive(np.full(m, np.inf))
    assert coarse.n_faces == hier.faces_after(hier.n_collapses)
    budget = np.where(asset.mesh.V[:, 2] > 1.5, np.inf, -1.0)     # keep the lower half at full detail
    mixed = hier.adaptive(budget)
    assert coarse.n_faces < mixed.n_faces < fine.n_faces
    low = asset.mesh.V[:, 2] < 1.2
    kept = np.isin(np.flatnonzero(low), mixed.vertex_ids)
    assert kept.all()                                               # every lower vertex is still there
    assert_closed_manifold(mixed.mesh)
    err = hier.at_error(np.median(hier.errors))
    assert err.error <= np.median(hier.errors)


def test_error_and_adaptive_targets_from_parameters(asset):
    hier, levels = decimate(asset, "quartic", targets=[200], error_targets=[1e-6],
                            adaptive_targets=[{"center": [0, 0, 0], "radius": 1.2, "error_inside": -1.0,
                                               "error_outside": 1e30, "label": "near-origin"}])
    by = {lv.label: lv for lv in levels}
    assert set(by) == {"quartic-200f", "quartic-err1e-06", "near-origin"}
    assert by["quartic-err1e-06"].error <= 1e-6
    near = by["near-origin"]
    inside = np.flatnonzero(np.linalg.norm(asset.mesh.V, axis=1) <= 1.2)
    assert np.isin(inside, near.vertex_ids).all()
    assert by["quartic-200f"].n_faces < near.n_faces < asset.mesh.n_faces
    assert_closed_manifold(near.mesh)


def _border(F):
    E = np.sort(np.concatenate([F[:, [0, 1]], F[:, [1, 2]], F[:, [2, 0]]]), axis=1)
    u, c = np.unique(E, axis=0, return_counts=True)
    return u[c == 1]


@pytest.mark.parametrize("backend", ["numpy", "numba"])
def test_borders_collapse_only_along_themselves_onto_their_own_points(backend):
    open_tube = tube(n_around=12, n_along=12, caps=False)
    hier, levels = decimate(open_tube, "quartic", targets=[60], max_bones=3, backend=backend)
    border0 = np.unique(_border(open_tube.mesh.F))
    rims0 = [border0[np.isclose(open_tube.mesh.V[border0, 2], z)] for z in (0.0, 3.0)]
    lv = levels[0]
    border = _border(np.asarray(lv.mesh.F))
    assert len(border) >= 6                              # two rims, each still a closed loop of 3 or more edges
    pts = lv.mesh.V[np.unique(border)]
    d = np.linalg.norm(pts[:, None] - open_tube.mesh.V[border0][None], axis=2).min(axis=1)
    assert d.max() < 1e-12                               # every border point is one of the source's
    for rim in rims0:                                    # both rims survive, on their own plane
        z = open_tube.mesh.V[rim[0], 2]
        assert np.isclose(pts[:, 2], z).sum() >= 3
    # interior vertices never land on the border: a level vertex on a rim's plane is a border vertex
    on_plane = np.isclose(lv.mesh.V[:, 2], 0.0) | np.isclose(lv.mesh.V[:, 2], 3.0)
    assert set(np.flatnonzero(on_plane)) == set(np.unique(border).tolist())


def test_fixed_borders_keep_every_border_vertex():
    open_tube = tube(n_around=12, n_along=12, caps=False)
    hier, levels = decimate(open_tube, "quartic", targets=[60], max_bones=3, border_collapses=False)
    boundary = np.unique(_border(open_tube.mesh.F))
    last = hier.prefix(hier.n_collapses)
    # free vertices collapse onto them (a half-edge collapse: the merged vertex is the border vertex, same
    # position and weights), but every border point is still there and no two of them ever merge
    d = np.linalg.norm(open_tube.mesh.V[boundary][:, None] - last.mesh.V[None], axis=2).min(axis=1)
    assert d.max() == 0.0
    assert len(np.unique(_border(np.asarray(last.mesh.F)))) == len(boundary)


@pytest.mark.parametrize("method", ["mohr-gleicher", "decoro-rusinkiewicz"])
def test_baselines_build_valid_hierarchies(asset, method):
    hier, levels = decimate(asset, method, targets=[0.1], min_faces=100, max_bones=2)
    assert hier.method == method
    lv = levels[0]
    assert lv.weights.influence_counts().max() <= 2
    assert np.allclose(lv.weights.values.sum(axis=1), 1.0, atol=1e-9)
    assert_closed_manifold(lv.mesh)
    if method == "mohr-gleicher":   # every vertex is one of the original ones, with its own (limited) weights
        orig = lv.vertex_ids
        V = hier.V[orig]
        d = np.linalg.norm(asset.mesh.V[None] - V[:, None], axis=2).min(axis=1)
        assert d.max() < 1e-12


def test_static_qslim_levels(asset):
    pytest.importorskip("pymeshlab")
    plugin = get_host().get("articulated-decimation", "static-qslim")
    asset.extras.clear()
    plugin.apply(asset, plugin.parse_params({"targets": [0.2, 150], "max_bones": 3}), StepContext())
    assert asset.hierarchy is None
    levels = asset.levels
    assert [lv.n_faces for lv in levels] == [round(0.2 * asset.mesh.n_faces), 150]
    for lv in levels:
        assert lv.weights.influence_counts().max() <= 3
        assert np.allclose(lv.weights.values.sum(axis=1), 1.0)


def test_quartic_beats_baselines_on_test_poses(asset):
    """On a bending tube, the optimised vertices deform closer to the original on unseen poses (Metro RMS)."""
    pytest.importorskip("pymeshlab")
    from rigslim.numerics.blend import linear_blend
    from rigslim.numerics.surface_distance import metro_distance

    def test_error(method):
        _, levels = decimate(asset, method, targets=[120])
        lv = levels[0]
        return np.mean([metro_distance(linear_blend(lv.mesh.V, lv.weights, asset.poses.T[f]), lv.mesh.F,
                                       linear_blend(asset.mesh.V, asset.weights, asset.poses.T[f]), asset.mesh.F,
                                       samples=5000)["rms"] for f in asset.split.test])

    q = test_error("quartic")
    assert q < test_error("mohr-gleicher")
    assert q < test_error("decoro-rusinkiewicz")


def test_missing_inputs_are_step_errors():
    from rigslim.errors import StepError

    a = tube(n_along=4)
    a.poses = None
    plugin = get_host().get("articulated-decimation", "quartic")
    with pytest.raises(StepError):
        plugin.apply(a, plugin.parse_params({"targets": [0.5]}), StepContext())
    from pydantic import ValidationError

    for bad in ([-1], [0], [float("nan")], [float("inf")]):         # refused with the parameters, before any work
        with pytest.raises(ValidationError, match="targets"):
            plugin.parse_params({"targets": bad})


def test_endpoint_candidates_never_cost_more_than_mohr_gleicher(asset):
    """With endpoint candidates, every edge's quartic cost is at most Mohr-Gleicher's on the same quadrics."""
    from rigslim.plugins.decimation.collapse import SimplifyState
    from rigslim.plugins.decimation.models import MohrGleicherModel, QuarticModel
    from rigslim.plugins.decimation.quadrics import per_pose_quadrics

    T = asset.example_poses().T
    Q, X = per_pose_quadrics(asset.mesh.V, asset.mesh.F, asset.weights, T)
    st = SimplifyState(asset.mesh.V, asset.mesh.F, asset.weights.toarray(), T, X)
    E = asset.mesh.edges
    _, _, eq = QuarticModel(Q, endpoints=True).costs(st, E[:, 0], E[:, 1])
    _, _, em = MohrGleicherModel(Q).costs(st, E[:, 0], E[:, 1])
    _, _, ep = QuarticModel(Q).costs(st, E[:, 0], E[:, 1])
    assert (eq <= em * (1 + 1e-12) + 1e-15).all()
    assert (eq <= ep * (1 + 1e-12) + 1e-15).all()
    assert (ep < em).mean() > 0.5            # the alternation alone already beats keeping an endpoint mostly


def test_quartic_weights_are_nonnegative_by_default_for_skinning_input(quartic_run, asset):
    hier, _ = quartic_run
    assert (hier.weights.values >= 0).all()           # every vertex of every level
    free, _ = decimate(asset, "quartic", targets=[100], min_faces=100, max_bones=2, nonnegative=False)
    assert np.allclose(free.weights.values.sum(axis=1), 1.0, atol=1e-9)
