"""The best-fit kernels compile once per process and cache: one specialisation each, the NNLS entry
point called with plain int64 / bool arguments only, no exchange kernel on the default path, and the
elimination without a sort still the reference's with many influences."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from test_selection_best_fit import random_problem

from rigslim.plugins.selection.sparse_fit import sparse_fit, sparse_fit_reference


def test_elimination_over_many_influences_matches_the_reference(rng):
    """Backward elimination tries candidates by increasing bound without a sort; with more than 15
    influences in the fit (past the length where numba's argsort is an insertion sort) it still finds the
    reference's set and error (the reference re-solves every candidate)."""
    V, T, A = random_problem(rng, m=40, n=20, p=12, density=1.0)
    rows = np.repeat(np.arange(40), np.diff(A.indptr))
    first_fit = sparse_fit(V, T, A, 3, "weight")[0]
    assert np.bincount(rows, weights=first_fit > 0, minlength=40).min() > 15   # the elimination starts above 15
    fit, member, errors = sparse_fit(V, T, A, 3, "error")
    _, ref_member, ref_errors = sparse_fit_reference(V, T, A, 3, "error")
    np.testing.assert_allclose(errors, ref_errors, rtol=1e-7, atol=1e-12)
    assert (member == ref_member).mean() > 0.99
    assert np.bincount(rows, weights=member, minlength=40).max() <= 3


#: Run in a fresh process on an empty numba cache (a cached kernel is loaded without compiling, or even
#: typing, what it calls): the default selection first, then every other path; prints each kernel's signatures.
CHILD = """
import json
import numpy as np
from numba import types
from test_selection_best_fit import random_problem
from rigslim.numerics.simplex_nnls import _lawson_hanson
from rigslim.plugins.selection import best_fit as bf, sparse_fit as sf

def sigs():
    out = {name: [str(s) for s in getattr(sf, name).signatures] for name in KERNELS}
    out["_rank_rows"] = [str(s) for s in bf._rank_rows.signatures]
    out["lawson_hanson_literal"] = sum(any(isinstance(t, types.Literal) for t in s) for s in _lawson_hanson.signatures)
    out["lawson_hanson_plain"] = [str(s) for s in _lawson_hanson.signatures
                                  if not any(isinstance(t, types.Literal) for t in s)]
    return out

KERNELS = ("_fit_rows", "_gram", "_eliminate", "_exchange_rows")
rng = np.random.default_rng(0)
V, T, A = random_problem(rng, m=30, n=6, p=4)
sf.sparse_fit(V, T, A, 2, "error")
bf.rank_entries(A, rng.random(A.nnz), 2)
default = sigs()
Tc = T.copy()
Tc[..., :3] = 0.0
Vb, Tb, Ab = random_problem(rng, m=10, n=300, p=2, density=0.02)
for args in ((V, T, A), (V, Tc, A), (Vb, Tb, Ab)):
    for by, swaps in (("weight", 0), ("error", 0), ("error", 2)):
        sf.sparse_fit(*args, 2, by, swaps)
print("SIGS " + json.dumps({"default": default, "all": sigs()}))
"""


@pytest.mark.slow
def test_one_specialisation_per_kernel(tmp_path):
    """On an empty cache: the default selection compiles no exchange kernel; every path together compiles
    each kernel once, and the NNLS entry point once, with plain int64 / bool arguments (no literals)."""
    here = Path(__file__).resolve().parent
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=os.pathsep.join([str(here), str(here.parents[1])]))
    p = subprocess.run([sys.executable, "-c", CHILD], cwd=here, env=env, capture_output=True,
                       text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    got = json.loads(next(ln for ln in p.stdout.splitlines() if ln.startswith("SIGS "))[5:])
    default, every = got["default"], got["all"]
    assert default["_exchange_rows"] == []
    for name in ("_fit_rows", "_gram", "_eliminate", "_rank_rows"):
        assert len(default[name]) == 1, (name, default[name])
    for name in ("_fit_rows", "_gram", "_eliminate", "_exchange_rows"):
        assert len(every[name]) == 1, (name, every[name])
    assert every["lawson_hanson_literal"] == 0
    assert len(every["lawson_hanson_plain"]) == 1
    assert "int64, float64, float64, int64" in every["lawson_hanson_plain"][0]
    assert every["lawson_hanson_plain"][0].endswith("bool)")
