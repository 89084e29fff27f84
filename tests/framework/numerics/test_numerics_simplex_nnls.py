"""The compiled sum-to-one NNLS (Lawson & Hanson) against the batched active-set QP, from a cold and a
warm start, with variables held out; and one compilation of its loops whatever constants a caller passes."""

import numpy as np
from numba import njit

from rigslim.numerics.simplex_nnls import _lawson_hanson
from rigslim.numerics.small_qp import solve_small_qps


def _problem(rng, n, rows=12):
    B = rng.normal(size=(n, rows))
    y = rng.normal(size=rows)
    G = B @ B.T
    return G, B @ y, float(y @ y)


def _exact(G, c, allowed):
    """min x^T G x - 2 c^T x, x >= 0, sum x = 1, x_j = 0 outside ``allowed``: the batched QP on the allowed set."""
    idx = np.flatnonzero(allowed)
    m = len(idx)
    x = solve_small_qps(G[np.ix_(idx, idx)][None], -c[idx][None], np.ones((1, 1, m)), np.ones((1, 1)),
                        nonneg=True, x0=np.full((1, m), 1.0 / m)).x[0]
    out = np.zeros(len(c))
    out[idx] = x
    return out


def _run(G, c, yy, allowed, x, F, nf, settle):
    n = len(c)
    return _lawson_hanson(G, c, yy, allowed, x, F, nf, 1e-13 * G.diagonal().max(), 0.0, 3 * n + 10,
                          np.empty((n + 1, n + 1)), np.empty(n + 1), settle)


def test_cold_start_reaches_the_qp_optimum(rng):
    for _ in range(20):
        n = 7
        G, c, yy = _problem(rng, n)
        x = np.zeros(n)
        F = np.zeros(n + 1, dtype=np.int64)
        j0 = int(np.argmin(G.diagonal() - 2.0 * c))
        x[j0], F[0] = 1.0, j0
        nf, err = _run(G, c, yy, np.ones(n, dtype=bool), x, F, 1, False)
        ref = _exact(G, c, np.ones(n, dtype=bool))
        assert x.min() >= 0.0 and abs(x.sum() - 1.0) < 1e-12
        assert sorted(F[:nf].tolist()) == np.flatnonzero(x > 0).tolist()
        assert abs(err - (x @ G @ x - 2.0 * c @ x + yy)) <= 1e-9 * max(yy, 1.0)
        assert err <= (ref @ G @ ref - 2.0 * c @ ref + yy) + 1e-9 * max(yy, 1.0)


def test_warm_start_with_settle_and_variables_held_out(rng):
    """From the uniform weights on a set (not optimal there: ``settle`` moves to its minimiser first),
    with two variables that may not enter."""
    for _ in range(20):
        n = 8
        G, c, yy = _problem(rng, n, rows=20)
        allowed = np.ones(n, dtype=bool)
        allowed[[1, 5]] = False
        x = np.zeros(n)
        F = np.zeros(n + 1, dtype=np.int64)
        start = [0, 2, 3]
        x[start] = 1.0 / 3.0
        F[:3] = start
        nf, err = _run(G, c, yy, allowed, x, F, 3, True)
        ref = _exact(G, c, allowed)
        assert x[1] == 0.0 and x[5] == 0.0
        assert x.min() >= 0.0 and abs(x.sum() - 1.0) < 1e-12
        assert err <= (ref @ G @ ref - 2.0 * c @ ref + yy) + 1e-9 * max(yy, 1.0)
        np.testing.assert_allclose(x, ref, atol=1e-6)


@njit
def _literal_caller(G, c, yy, allowed, x, F, K, z):
    # constants as a numba caller writes them: Literal[int](1), Literal[bool](False)
    return _lawson_hanson(G, c, yy, allowed, x, F, 1, 1e-13, 0.0, 40, K, z, False)


def test_literal_arguments_give_the_same_fit(rng):
    """A caller passing constants gets its own specialisation of the entry point, with the same result
    as plain int64 / bool arguments (the inner loops see plain types either way)."""
    n = 6
    G, c, yy = _problem(rng, n)
    out = []
    for call in ("literal", "plain"):
        x = np.zeros(n)
        F = np.zeros(n + 1, dtype=np.int64)
        x[0], F[0] = 1.0, 0
        K, z = np.empty((n + 1, n + 1)), np.empty(n + 1)
        allowed = np.ones(n, dtype=bool)
        if call == "literal":
            nf, err = _literal_caller(G, c, yy, allowed, x, F, K, z)
        else:
            nf, err = _lawson_hanson(G, c, yy, allowed, x, F, 1, 1e-13, 0.0, 40, K, z, False)
        out.append((nf, err, x))
    assert out[0][0] == out[1][0] and out[0][1] == out[1][1]
    assert np.array_equal(out[0][2], out[1][2])
