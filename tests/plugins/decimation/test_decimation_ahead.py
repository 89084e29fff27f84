"""Judging ahead in the compiled loop (compiled.py ``speculate``, ``_candidates``): the same collapses for every
width, the work done ahead is used, and the queue pops what it would have popped."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.plugin.host import get_host
from rigslim.plugins.decimation import compiled as cc
from rigslim.plugins.decimation import edge_queue as eq
from rigslim.plugins.decimation.collapse import ahead_width, loop_stats, simplify
from rigslim.plugins.decimation.setup import CLEAN, DIRTY


@pytest.fixture(scope="module")
def elephant_setup(elephant):
    """The quartic plugin's default loop inputs on the elephant (source- and face-side errors on)."""
    plugin = get_host().get("articulated-decimation", "quartic")
    params = plugin.parse_params({"targets": [0.1], "backend": "numba"})
    assert params.source_distance and params.face_distance and params.normalised_error
    Q, W, T, X, model = plugin.setup(elephant, params)
    return elephant, params, W, T, X, model


def run(setup, ahead: int, min_faces: int = 1200):
    asset, params, W, T, X, model = setup
    hier = simplify(asset.mesh.V, asset.mesh.F, W, T, X, model, min_faces=min_faces,
                    keep_boundary=params.keep_boundary, border_collapses=params.border_collapses,
                    min_normal_cos=params.min_normal_cos, backend="numba", normalised=params.normalised_error,
                    source_distance=params.source_distance, face_distance=params.face_distance, ahead=ahead)
    return hier, loop_stats(hier)


def test_every_width_makes_the_same_collapses(elephant_setup):
    """Widths 1 (one edge at a time), 3 and 8 give the same hierarchy, bit for bit, and the wider loops use
    what they judged ahead: most attempts find their guard and error done, most judged errors are used."""
    h1, s1 = run(elephant_setup, 1)
    assert s1["judged_ahead"] == s1["costed_ahead"] == 0
    for width in (3, 8):
        h, s = run(elephant_setup, width)
        np.testing.assert_array_equal(h.collapses, h1.collapses)
        np.testing.assert_array_equal(h.errors, h1.errors)
        np.testing.assert_array_equal(h.n_faces, h1.n_faces)
        np.testing.assert_array_equal(h.V, h1.V)
        for key in ("collapses", "pops", "attempts", "evaluations"):
            assert s[key] == s1[key]
        assert s["ahead_width"] == width
        assert s["judged_ahead"] > 0.4 * s1["measured"]
        assert s["costed_ahead"] > 0
        assert s["measured"] < 1.15 * s1["measured"]          # little judged that no attempt used


def test_the_width_follows_the_threads():
    assert ahead_width(1) == 1
    assert ahead_width(2) == 8
    assert ahead_width(16) == 32


def test_candidates_leave_the_queue_as_it_was():
    """``_candidates`` pops entries to find the next work and queues them again: the same multiset, a valid
    heap, the same pop order. Dirty entries become cost candidates, clean ones guard candidates; stale entries,
    clean ones whose error is in their cost and the edge itself are skipped."""
    rng = np.random.default_rng(5)
    n_edges, m = 40, 30
    ed = cc.LoopEdges(rng.integers(0, m, n_edges), rng.integers(0, m, n_edges), np.zeros(n_edges),
                      np.zeros((n_edges, 3)), np.zeros((n_edges, 2)), np.ones(n_edges, np.int64),
                      np.full(n_edges, CLEAN, np.int8), np.zeros(n_edges, np.int64), np.zeros(1, np.int64),
                      np.zeros(1, np.int64), np.zeros(n_edges), np.full(n_edges, -1, np.int64))
    ed.estate[::4] = DIRTY
    ed.stime[1::8] = 0                  # S in the cost, nothing changed since: no work
    z = np.zeros(2 * m, np.int64)
    mesh = cc.LoopMesh(np.zeros((1, 3), np.int64), z, z, z, np.zeros(2 * m, bool), z, z, z, z.copy())
    cnt = np.zeros(eq.N_COUNTERS, np.int64)
    hc, hs, he = np.zeros(3 * n_edges), np.zeros(3 * n_edges, np.int64), np.zeros(3 * n_edges, np.int64)
    for e in range(n_edges):
        stamp = ed.estamp[e] - (1 if e % 7 == 3 else 0)     # some stale entries
        eq.push(hc, hs, he, cnt, float(rng.integers(0, 5)), stamp, e, ed.estamp, ed.estate)
    qu = cc.LoopQueue(hc, hs, he)
    before = sorted(zip(hc[:cnt[eq.C_HEAP]], hs[:cnt[eq.C_HEAP]], he[:cnt[eq.C_HEAP]], strict=True))
    ah = cc.new_ahead(n_edges, 6, 1, m)
    e0 = int(he[0])
    n = cc._candidates(e0, cc.JUDGE, mesh, ed, qu, cnt, ah)
    after = sorted(zip(hc[:cnt[eq.C_HEAP]], hs[:cnt[eq.C_HEAP]], he[:cnt[eq.C_HEAP]], strict=True))
    assert after == before
    size = cnt[eq.C_HEAP]
    for i in range(1, size):             # the heap property on (cost, stamp, edge)
        p = (i - 1) // 2
        assert (hc[p], hs[p], he[p]) <= (hc[i], hs[i], he[i])
    assert n == 6 and ah.cand[0] == e0 and len(set(ah.cand[:n])) == n
    want, kinds = [e0], [cc.JUDGE]
    for _, st, e in before:
        if len(want) == 6:
            break
        if e == e0 or e in want or st != ed.estamp[e] or (ed.estate[e] == CLEAN and ed.stime[e] == 0):
            continue
        want.append(e)
        kinds.append(cc.EVALUATE if ed.estate[e] == DIRTY else cc.JUDGE)
    assert list(ah.cand[:n]) == want
    assert list(ah.kind[:n]) == kinds
