"""rigslim.numba_threads: numba gets a new-enough TBB or none, and no threading-layer warning."""

from __future__ import annotations

import os
import subprocess
import sys

from rigslim import numba_threads

PARALLEL_LOOP = """
import warnings
warnings.simplefilter("error")          # any NumbaWarning (TBB too old) fails the run
import rigslim, numba, numpy as np
from numba import njit, prange

@njit(parallel=True)
def total(a):
    s = 0.0
    for i in prange(a.size):
        s += a[i]
    return s

assert total(np.ones(1000)) == 1000.0
print(numba.threading_layer(), "|", rigslim.numba_threads.configure())
"""


def test_parallel_loop_without_warning():
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    out = subprocess.run([sys.executable, "-c", PARALLEL_LOOP], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    layer, how = (s.strip() for s in out.stdout.strip().splitlines()[-1].split("|"))
    if how.startswith("tbb ("):      # the tbb wheel was loaded: numba must actually use it
        assert layer == "tbb"
    else:
        assert layer in ("omp", "workqueue")


def test_without_the_wheel_tbb_is_taken_out_of_the_search(monkeypatch):
    monkeypatch.setattr(numba_threads, "_state", {})
    monkeypatch.setattr(numba_threads, "_wheel_tbb", lambda: None)
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    monkeypatch.delenv("NUMBA_THREADING_LAYER", raising=False)
    monkeypatch.delenv("NUMBA_THREADING_LAYER_PRIORITY", raising=False)
    assert numba_threads.configure().startswith("omp")
    assert os.environ["NUMBA_THREADING_LAYER_PRIORITY"] == "omp workqueue"


def test_a_users_choice_is_left_alone(monkeypatch):
    monkeypatch.setattr(numba_threads, "_state", {})
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "workqueue")
    monkeypatch.delenv("NUMBA_THREADING_LAYER_PRIORITY", raising=False)
    assert numba_threads.configure() == "left alone"
    assert "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ
