"""Parts removed whole (plugins/decimation/prune.py): parts, removal distances against a brute force, the lazy
greedy against an eager one, the overshoot put back, and the decimate step reaching a target no collapse can."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.model.hierarchy import SimplifiedLevel
from rigslim.model.mesh import Mesh
from rigslim.model.weights import ReducedWeights
from rigslim.plugin import StepContext
from rigslim.plugin.host import get_host
from rigslim.plugins.decimation.collapse import point_triangle_distances2
from rigslim.plugins.decimation.prune import (
    PruneStep,
    face_parts,
    kept_back,
    prune_sequence,
    pruned_level,
    removal_distance,
)

TETRA = np.array([[0, 2, 1], [0, 1, 3], [1, 2, 3], [0, 3, 2]], np.int64)


def tetra(centre, size):
    """A closed tetrahedron around ``centre``: its 4 corners."""
    c = np.array([[1.0, 1, 1], [1, -1, -1], [-1, 1, -1], [-1, -1, 1]])
    return np.asarray(centre, float) + size * c


def parts_mesh(centres, sizes):
    """Tetrahedra, one per centre: (V, F, part of every face)."""
    V = np.concatenate([tetra(c, s) for c, s in zip(centres, sizes, strict=True)])
    F = np.concatenate([TETRA + 4 * i for i in range(len(centres))])
    return V, F, np.repeat(np.arange(len(centres)), 4)


def rigid_level(V, F, n_handles=1) -> SimplifiedLevel:
    w = ReducedWeights(np.zeros((len(V), 1), np.int32), np.ones((len(V), 1)), n_handles)
    return SimplifiedLevel(Mesh(V, F), w, "lv", np.arange(len(V)) + 100, 0.5, "quartic")


def poses(P):
    """P rigid translations of the one bone."""
    T = np.zeros((P, 1, 3, 4))
    T[:, 0, :, :3] = np.eye(3)
    T[:, 0, :, 3] = np.arange(P)[:, None] * np.array([0.3, -0.2, 0.1])
    return T


def test_face_parts_label_each_connected_part():
    V, F, part = parts_mesh([[0, 0, 0], [5, 0, 0], [10, 0, 0]], [1, 1, 1])
    F = np.concatenate([F, [[0, 20, 21]]])            # a stray face sharing vertex 0 joins part 0
    n, got = face_parts(F)
    assert n == 3
    assert (got[:4] == got[0]).all() and got[-1] == got[0]
    assert len({got[0], got[4], got[8]}) == 3


def test_removal_distance_is_the_area_weighted_rms_over_poses_and_face_points():
    """Against a brute force: per pose, each face of the part at its corners, edge midpoints and centroid, each
    point weighted by a seventh of its face's rest area, squared distance to the rest, averaged."""
    V, F, part = parts_mesh([[0, 0, 0], [3, 0.5, 0], [0, 4, 1]], [1.0, 0.2, 0.5])
    V[4] += [0.1, 0.0, 0.05]                               # faces of different areas
    T = poses(3)
    X = np.stack([V @ T[j, 0, :, :3].T + T[j, 0, :, 3] for j in range(3)])
    rest, mine = F[part != 1], F[part == 1]
    got = removal_distance(X, V, mine, rest)
    bary = [(1, 0, 0), (0, 1, 0), (0, 0, 1), (0.5, 0.5, 0), (0, 0.5, 0.5), (0.5, 0, 0.5), (1 / 3, 1 / 3, 1 / 3)]
    num = den = 0.0
    for j in range(3):
        A, B, C = X[j][rest[:, 0]], X[j][rest[:, 1]], X[j][rest[:, 2]]
        for f in mine:
            area = 0.5 * np.linalg.norm(np.cross(V[f[1]] - V[f[0]], V[f[2]] - V[f[0]]))
            for b in bary:
                q = b[0] * X[j][f[0]] + b[1] * X[j][f[1]] + b[2] * X[j][f[2]]
                num += area / 7 * point_triangle_distances2(np.repeat(q[None], len(rest), 0), A, B, C).min()
                den += area / 7
    assert got == pytest.approx(np.sqrt(num / den), rel=1e-12)


def test_an_enclosed_part_is_measured_over_its_faces_not_its_corners():
    """A flat plate whose four corners touch four posts: at its corners it lies on them, over its faces it
    does not, so it is not the first part to go."""
    plate = np.array([[0.0, 0, 0], [4, 0, 0], [4, 4, 0], [0, 4, 0]])
    Fp = np.array([[0, 1, 2], [0, 2, 3]], np.int64)
    Vt, Ft, _ = parts_mesh(plate + [0, 0, 0.3], np.full(4, 0.2))
    V, F = np.concatenate([plate, Vt]), np.concatenate([Fp, Ft + 4])
    level, T = rigid_level(V, F), poses(2)
    X = np.stack([V @ T[j, 0, :, :3].T + T[j, 0, :, 3] for j in range(2)])
    at_corners = [np.sqrt(np.mean([point_triangle_distances2(np.repeat(X[j][v][None], 16, 0), *(X[j][F[2:, c]]
                                   for c in range(3))).min() for j in range(2) for v in range(4)]))]
    assert at_corners[0] < removal_distance(X, V, F[2:6], np.concatenate([F[:2], F[6:]]))   # corners alone: first
    steps, _ = prune_sequence(level, T, len(F) - 1, None)
    assert set(steps[0].faces.tolist()) != {0, 1}          # over its faces the plate is far from the posts


def eager_sequence(level, T, min_faces):
    """Every remaining part measured against the current rest at every step (its own hierarchy); the one of
    least added squared error, rest area times squared distance, goes."""
    V, F = level.mesh.V, np.asarray(level.mesh.F)
    X = np.stack([V @ T[j, 0, :, :3].T + T[j, 0, :, 3] for j in range(len(T))])
    n, part = face_parts(F)
    tri = V[F]
    area = np.bincount(part, 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1))
    alive = set(range(n))
    order, left = [], len(F)
    while left > min_faces and len(alive) > 1:
        d = {p: removal_distance(X, V, F[part == p], F[np.isin(part, list(alive - {p}))]) for p in alive}
        p = min(sorted(d), key=lambda q: area[q] * d[q] ** 2)
        alive.remove(p)
        left -= int((part == p).sum())
        order.append((p, d[p]))
    return order, part


def test_the_lazy_greedy_removes_what_an_eager_one_does():
    """Random clusters of tetrahedra around a large one: the queue by last cost gives the eager greedy's
    sequence and distances (removing a part only moves the rest's surface away)."""
    rng = np.random.default_rng(4)
    centres = np.concatenate([[[0, 0, 0]], rng.normal(scale=3.0, size=(14, 3))])
    sizes = np.concatenate([[2.5], rng.uniform(0.05, 0.6, 14)])
    V, F, part = parts_mesh(centres, sizes)
    level, T = rigid_level(V, F), poses(4)
    steps, why = prune_sequence(level, T, 12, None)
    want, labels = eager_sequence(level, T, 12)
    assert why is None and steps[-1].faces_left <= 12
    got = [int(labels[s.faces[0]]) for s in steps]
    assert got == [p for p, _ in want]
    np.testing.assert_allclose([s.distance for s in steps], [d for _, d in want], rtol=1e-12)
    assert [s.faces_left for s in steps] == list(range(len(F) - 4, len(F) - 4 * len(steps) - 1, -4))


def test_a_large_part_measured_against_the_rest_gives_the_brute_force_distances():
    """The studded ball's ball has most of the faces: it is measured against a hierarchy of the other live parts
    (``LARGE_SHARE``), the studs against the shared one. Removing every part but one (the ball stays), the
    sequence and its distances are the eager brute force's; every part's first distance, the ball's among them,
    is the brute force's, and the ball's again once a stud is gone."""
    from rigslim.plugins.decimation.prune import LARGE_MIN_FACES, _PartDistances

    V, F, n_ball = studded_ball(6)
    level, T = rigid_level(V, F), poses(3)
    n, part = face_parts(F)
    X = np.stack([V @ T[j, 0, :, :3].T + T[j, 0, :, 3] for j in range(len(T))])
    measure = _PartDistances(X, V, F, part, n)
    assert n_ball >= LARGE_MIN_FACES and measure.large.sum() == 1 and measure.large[part[0]]   # the ball alone
    brute = [removal_distance(X, V, F[part == p], F[part != p]) for p in range(n)]
    np.testing.assert_allclose(measure.start(), brute, rtol=1e-12)
    measure.alive[part[-1]] = False                                    # the far stud gone: the ball measured again
    assert measure.distance(part[0]) == pytest.approx(
        removal_distance(X, V, F[part == part[0]], F[(part != part[0]) & (part != part[-1])]), rel=1e-12)
    steps, why = prune_sequence(level, T, 1, None)
    want, labels = eager_sequence(level, T, 1)
    assert why == "no collapse" and len(steps) == n - 1 and part[0] not in {part[s.faces[0]] for s in steps}
    assert [int(labels[s.faces[0]]) for s in steps] == [p for p, _ in want]
    np.testing.assert_allclose([s.distance for s in steps], [d for _, d in want], rtol=1e-12)


def test_the_bound_and_the_last_part_stop_the_removals():
    V, F, _ = parts_mesh([[0, 0, 0], [3, 0, 0], [0, 30, 0]], [1.0, 0.3, 0.3])
    level, T = rigid_level(V, F), poses(2)
    steps, why = prune_sequence(level, T, 1, 5.0)          # the far part (about 29 away) passes the bound
    assert why == "max_error" and len(steps) == 1 and steps[0].distance < 5.0
    steps, why = prune_sequence(level, T, 1, None)
    assert why == "no collapse" and len(steps) == 2         # one part is always left
    assert prune_sequence(level, T, 12, None) == ([], None)  # the target is already met


def test_kept_back_puts_back_what_fits_in_the_overshoot_farthest_first():
    f = [np.arange(k) for k in (3, 4, 18, 3, 28)]
    steps = [PruneStep(x, 0, d) for x, d in zip(f, (0.1, 0.2, 0.3, 0.4, 0.5), strict=True)]
    kept = kept_back(steps, 8)          # the 28-face removal overshot by 8: the 3 (0.4) and then the 4 (0.2) fit
    assert [s.distance for s in kept] == [0.1, 0.3, 0.5]
    assert kept_back(steps, 2) == steps


def test_pruned_level_keeps_the_other_faces_vertices_and_weights():
    V, F, part = parts_mesh([[0, 0, 0], [3, 0, 0], [6, 0, 0]], [1.0, 0.3, 0.3])
    level = rigid_level(V, F)
    lv = pruned_level(level, [PruneStep(np.flatnonzero(part == 1), 8, 0.1)], "x")
    assert lv.n_faces == 8 and lv.n_vertices == 8 and lv.label == "x" and lv.error == level.error
    np.testing.assert_array_equal(lv.vertex_ids, np.r_[100:104, 108:112])
    np.testing.assert_array_equal(lv.mesh.V, np.concatenate([V[:4], V[8:]]))
    assert lv.weights.n_vertices == 8


def studded_ball(n_studs: int = 12):
    """A ball (a convex hull of 164 points, radius 3) with small tetrahedra studded on its surface and one far
    above it: the studs cannot collapse below 4 faces each."""
    from scipy.spatial import ConvexHull

    rng = np.random.default_rng(2)
    ball = rng.normal(size=(164, 3))
    ball = 3.0 * ball / np.linalg.norm(ball, axis=1, keepdims=True)
    hull = ConvexHull(ball)
    Fb = hull.simplices.astype(np.int64)
    outward = np.einsum("ij,ij->i", np.cross(ball[Fb[:, 1]] - ball[Fb[:, 0]], ball[Fb[:, 2]] - ball[Fb[:, 0]]),
                        ball[Fb[:, 0]])
    Fb[outward < 0] = Fb[outward < 0][:, ::-1]
    studs = rng.normal(size=(n_studs, 3))
    studs = 3.05 * studs / np.linalg.norm(studs, axis=1, keepdims=True)
    Vt, Ft, _ = parts_mesh(np.concatenate([studs, [[0.0, 0.0, 9.0]]]), np.full(n_studs + 1, 0.12))
    return np.concatenate([ball, Vt]), np.concatenate([Fb, Ft + len(ball)]), len(Fb)


def decimated(target, **params):
    from test_decimation_source_error import rigid_asset

    V, F, n_ball = studded_ball()
    asset = rigid_asset(V, F)
    plugin = get_host().get("articulated-decimation", "quartic")
    said: list[str] = []
    ctx = StepContext(log=said.append)
    plugin.apply(asset, plugin.parse_params({"targets": [target], **params}), ctx)
    return asset, ctx, said


def test_the_step_reaches_a_target_no_collapse_can_by_removing_the_nearest_parts():
    """The ball collapses to a few faces but the 13 studs stay at 4 faces each: the target of 30 faces is met
    by removing studs (the ones on the ball first, the far one last: it is never needed), the ball stays, and
    the level says so."""
    asset, ctx, said = decimated(30, max_error="none")
    t = ctx.report["targets"][0]
    lv = asset.levels[0]
    assert t["stopped"] is None and t["parts_removed"] > 0 and lv.n_faces == t["faces"] <= 30
    assert lv.label == t["label"] == "quartic-30f"
    far = np.flatnonzero(lv.mesh.V[:, 2] > 8.0)
    assert len(far) == 4                       # the far stud is kept: the studs on the ball cost far less
    assert t["removal_distance"] < 1.5         # the coarse ball lies within about 0.6 of its studs; the far one 6
    assert any(f"{t['parts_removed']} parts removed whole" in line for line in said)


def test_no_part_goes_past_the_bound_or_with_prune_parts_off():
    asset, ctx, _ = decimated(30, max_error="0.01m")
    t = ctx.report["targets"][0]
    assert t["faces"] > 30 and t["stopped"] in ("max_error", "no collapse")
    assert t["removal_distance"] <= 0.01
    asset, ctx, _ = decimated(30, max_error="none", prune_parts=False)
    t = ctx.report["targets"][0]
    assert t["stopped"] == "no collapse" and t["parts_removed"] == 0 and t["faces"] > 30
