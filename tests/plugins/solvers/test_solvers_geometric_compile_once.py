"""The non-negative geometric kernels compile once per process, with no parallel loop: one specialisation
each, and the sum-to-one NNLS shared with the best-fit selector (one compiled specialisation, no literal
arguments), the default reduction's order (selection, then the solve) on an empty numba cache."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

#: Run in a fresh process on an empty numba cache: best-fit by error, then the geometric fit on its sets,
#: k-largest sets with a ridge, and the whole tube (the threads' path); prints the kernels' signatures.
CHILD = """
import json
import numpy as np
from numba import types
from support.synthetic import tube_asset
from rigslim.numerics.largest_entries import k_largest
from rigslim.numerics.simplex_nnls import _lawson_hanson
from rigslim.plugins.selection.best_fit import best_fit
from rigslim.plugins.solvers import geometric_kernel as gk
from rigslim.plugins.solvers.problem import initial_weights

asset = tube_asset()
asset.influences = best_fit(asset, 2, "error")[0]
after_selection = [str(s) for s in _lawson_hanson.signatures]
gk.geometric_nonnegative(asset, asset.influences, initial_weights(asset.weights, asset.influences), 0.0)
asset.influences = k_largest(asset.weights, 3)
gk.geometric_nonnegative(asset, asset.influences, initial_weights(asset.weights, asset.influences), 1e-3)
big = tube_asset(rings=80, segments=16)
big.influences = k_largest(big.weights, 2)
gk.geometric_nonnegative(big, big.influences, initial_weights(big.weights, big.influences), 1e-3)
print("SIGS " + json.dumps({
    "rows": big.mesh.n_vertices,
    "after_selection": after_selection,
    "lawson_hanson": [str(s) for s in _lawson_hanson.signatures],
    "literal": sum(any(isinstance(t, types.Literal) for t in s) for s in _lawson_hanson.signatures),
    **{name: {"sigs": [str(s) for s in getattr(gk, name).signatures],
              "parallel": bool(getattr(gk, name).targetoptions.get("parallel")),
              "nogil": bool(getattr(gk, name).targetoptions.get("nogil"))}
       for name in ("_fit_rows", "_diagonal_rows", "_basis_row")},
}))
"""


@pytest.mark.slow
def test_geometric_kernels_compile_once_and_share_the_nnls(tmp_path):
    """On an empty cache: each geometric kernel one specialisation, none a parallel loop, the row kernels
    nogil; after the selection, the geometric fit adds no specialisation of the NNLS method."""
    tests = Path(__file__).resolve().parents[2]
    env = dict(os.environ, NUMBA_CACHE_DIR=str(tmp_path), PYTHONPATH=os.pathsep.join([str(tests), str(tests.parent)]))
    p = subprocess.run([sys.executable, "-c", CHILD], cwd=tests, env=env, capture_output=True, text=True, timeout=600)
    assert p.returncode == 0, p.stderr[-2000:]
    got = json.loads(next(ln for ln in p.stdout.splitlines() if ln.startswith("SIGS "))[5:])
    assert got["rows"] >= 512   # over_rows puts the whole tube on threads where numba has 2 or more
    for name in ("_fit_rows", "_diagonal_rows", "_basis_row"):
        assert len(got[name]["sigs"]) == 1, (name, got[name]["sigs"])
        assert not got[name]["parallel"], name
    assert got["_fit_rows"]["nogil"] and got["_diagonal_rows"]["nogil"]
    assert got["literal"] == 0
    assert len(got["after_selection"]) == 1
    assert got["lawson_hanson"] == got["after_selection"]
