"""The k largest entries per row: the padded-table sort gives the sets of the (row, -value, column) lexsort."""

import numpy as np
import pytest
import scipy.sparse as sp

from rigslim.numerics import largest_entries
from rigslim.numerics.largest_entries import k_largest


def lexsort_sets(A: sp.csr_matrix, k: int, key=None):
    """The reference: one lexsort of every stored entry by (row, -value, column), the first k of each row."""
    A = sp.csr_matrix(A)
    A.sort_indices()
    m = A.shape[0]
    counts = np.diff(A.indptr)
    rows = np.repeat(np.arange(m), counts)
    vals = A.data if key is None else key(A.data)
    order = np.lexsort((A.indices, -vals, rows))
    rank = np.arange(len(order)) - np.repeat(A.indptr[:-1], counts)
    keep = rank < k
    indices = np.zeros((m, k), dtype=np.int32)
    valid = np.zeros((m, k), dtype=bool)
    indices[rows[order[keep]], rank[keep]] = A.indices[order[keep]]
    valid[rows[order[keep]], rank[keep]] = True
    return indices, valid


@pytest.mark.parametrize("seed", range(40))
def test_padded_sort_matches_the_lexsort_with_ties_padding_and_signs(seed):
    rng = np.random.default_rng(seed)
    m, n = int(rng.integers(1, 40)), int(rng.integers(1, 30))
    A = sp.random(m, n, density=rng.uniform(0.3, 1.0), random_state=seed, format="csr")
    A.data = np.round(A.data * 3) / 3 - (0.4 if seed % 3 == 0 else 0.0)      # many ties, some negative
    for k in (1, 2, n, n + 2):
        for key in (None, np.abs):
            sets = k_largest(A, k, key=key)
            indices, valid = lexsort_sets(A, k, key)
            assert (sets.valid == valid).all() and (sets.indices == indices).all()


def test_the_padded_path_is_taken_for_even_rows_and_ties_keep_the_lower_handle(monkeypatch):
    """Three equal weights: the two lower handles are kept, in index order (:func:`k_largest`'s rule)."""
    calls = []
    padded = largest_entries._k_largest_padded
    monkeypatch.setattr(largest_entries, "_k_largest_padded", lambda *a: calls.append(1) or padded(*a))
    A = sp.csr_matrix(np.array([[0.0, 1 / 3, 1 / 3, 1 / 3], [0.5, 0.25, 0.0, 0.25]]))
    sets = k_largest(A, 2)
    assert calls == [1]
    assert sets.indices.tolist() == [[1, 2], [0, 1]] and sets.valid.all()


def test_uneven_rows_and_nan_take_the_lexsort():
    """One long row among short ones (the padded table would be far larger than the entries) and NaN."""
    A = sp.lil_matrix((50, 60))
    A[0, :] = np.linspace(1.0, 2.0, 60)
    for r in range(1, 50):
        A[r, r % 60] = 1.0
    A = sp.csr_matrix(A)
    sets = k_largest(A, 3)
    assert sets.indices[0].tolist() == [59, 58, 57] and sets.valid[1].tolist() == [True, False, False]
    B = sp.csr_matrix(np.array([[np.nan, 0.5, 0.2]]))
    indices, valid = lexsort_sets(B, 2)
    sets = k_largest(B, 2)
    assert (sets.indices == indices).all() and (sets.valid == valid).all()
