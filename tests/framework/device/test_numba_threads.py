"""rigslim.device.numba_threads: numba gets a new-enough TBB or none, and no threading-layer warning."""

from __future__ import annotations

import os
import subprocess
import sys

from rigslim.device import numba_threads

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
print(numba.threading_layer(), "|", rigslim.device.numba_threads.configure())
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


def test_without_the_wheel_tbb_goes_last(monkeypatch):
    monkeypatch.setattr(numba_threads, "_state", {})
    monkeypatch.setattr(numba_threads, "_wheel_tbb", lambda: None)
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    for name in ("NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"):
        monkeypatch.setenv(name, "")     # recorded, so that teardown restores the variable's absence
        monkeypatch.delenv(name)
    assert numba_threads.configure().startswith("omp")
    assert os.environ["NUMBA_THREADING_LAYER_PRIORITY"] == "omp workqueue tbb"


def test_a_users_choice_is_left_alone(monkeypatch):
    monkeypatch.setattr(numba_threads, "_state", {})
    monkeypatch.delitem(sys.modules, "numba", raising=False)
    monkeypatch.setenv("NUMBA_THREADING_LAYER", "workqueue")
    monkeypatch.setenv("NUMBA_THREADING_LAYER_PRIORITY", "")
    monkeypatch.delenv("NUMBA_THREADING_LAYER_PRIORITY")
    assert numba_threads.configure() == "left alone"
    assert "NUMBA_THREADING_LAYER_PRIORITY" not in os.environ


def test_fallback_priority_is_valid_for_numba():
    """numba accepts the fallback order (it wants a permutation of all three layers) and runs a parallel loop."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("NUMBA_THREADING_LAYER")}
    code = ("import rigslim.device.numba_threads as t, os\n"
            "os.environ['NUMBA_THREADING_LAYER_PRIORITY'] = 'omp workqueue tbb'\n" + PARALLEL_LOOP)
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    assert out.stdout.split("|")[0].strip() in ("omp", "workqueue")
