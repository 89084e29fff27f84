"""The fast paths of rigslim.plugins.decimation.quadrics (shared blended transforms in ``alternate``).

They equal the public formulas.
"""

import numpy as np

from rigslim.plugins.decimation import quadrics as qd


def _random_batch(rng, B=7, K=5, P=4):
    A = rng.normal(size=(B, P, 4, 4))
    Q = A @ np.swapaxes(A, -1, -2) + 0.1 * np.eye(4)
    Tb = np.zeros((B, K, P, 3, 4))
    Tb[..., :3] = np.eye(3) + 0.3 * rng.normal(size=(B, K, P, 3, 3))
    Tb[..., 3] = rng.normal(size=(B, K, P, 3))
    mask = np.ones((B, K), dtype=bool)
    mask[0, 3:] = False
    mask[1, 4:] = False
    a0 = rng.random((B, K)) * mask
    a0 /= a0.sum(axis=1, keepdims=True)
    fallback = rng.normal(size=(B, 3, 3))
    return Q, Tb, a0, mask, fallback


def test_blended_helpers_equal_public_functions():
    rng = np.random.default_rng(3)
    Q, Tb, a0, mask, fallback = _random_batch(rng)
    X = qd._blend(a0, Tb)
    v_ref, s_ref = qd.position_step(Q, Tb, a0, fallback)
    v, s = qd._position_step_blended(Q, X, fallback)
    np.testing.assert_array_equal(v, v_ref)
    np.testing.assert_array_equal(s, s_ref)
    np.testing.assert_array_equal(qd._quartic_error_blended(Q, X, v), qd.quartic_error(Q, Tb, a0, v))
    # and the error is the literal sum over poses of the blended point's quadric error
    E = np.zeros(len(v))
    for j in range(Q.shape[1]):
        M = np.einsum("bk,bkrc->brc", a0, Tb[:, :, j])
        p = np.einsum("brc,bc->br", M[..., :3], v) + M[..., 3]
        ph = np.concatenate([p, np.ones((len(p), 1))], axis=1)
        E += np.einsum("bi,bij,bj->b", ph, Q[:, j], ph)
    np.testing.assert_allclose(qd._quartic_error_blended(Q, X, v), E, rtol=1e-10)


def _alternate_reference(Q, Tb, a0, mask, fallback, iterations, tol, nonnegative):
    """The alternation written with the public steps only (no shared transforms, fresh copies)."""
    v, _ = qd.position_step(Q, Tb, a0, fallback)
    E = qd.quartic_error(Q, Tb, a0, v)
    best_v, best_a, best_E = v, a0.copy(), E
    act = np.arange(len(a0))
    v_act = v
    for _ in range(iterations):
        if act.size == 0:
            break
        a = qd.weight_step(Q[act], Tb[act], v_act, a0=a0[act], mask=mask[act], nonnegative=nonnegative)
        v_act, _ = qd.position_step(Q[act], Tb[act], a, fallback[act])
        E_new = qd.quartic_error(Q[act], Tb[act], a, v_act)
        old = best_E[act]
        better = E_new < old
        gain = (old - E_new) / np.maximum(np.abs(old), 1e-300)
        upd = act[better]
        best_v[upd], best_a[upd], best_E[upd] = v_act[better], a[better], E_new[better]
        keep = gain > tol
        act, v_act = act[keep], v_act[keep]
    return best_v, best_a, best_E


def test_alternate_equals_reference_on_random_edges():
    rng = np.random.default_rng(11)
    for nonnegative in (False, True):
        Q, Tb, a0, mask, fallback = _random_batch(rng, B=9, K=6, P=5)
        v, a, E = qd.alternate(Q, Tb, a0, mask, fallback, iterations=5, tol=1e-4, nonnegative=nonnegative)
        v_r, a_r, E_r = _alternate_reference(Q, Tb, a0, mask, fallback, 5, 1e-4, nonnegative)
        np.testing.assert_allclose(v, v_r, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(a, a_r, rtol=1e-12, atol=1e-12)
        np.testing.assert_allclose(E, E_r, rtol=1e-12, atol=1e-14)
        assert np.all(np.abs(a.sum(axis=1) - 1.0) < 1e-9)
        if nonnegative:
            assert a.min() >= 0.0
