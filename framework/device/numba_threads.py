"""numba's threading layer: the ``tbb`` wheel's TBB, else OpenMP -- never a too-old system TBB.

numba prefers its TBB threading layer and looks for ``libtbb.so.12`` through
the dynamic loader. The ``tbb`` wheel (a rigslim dependency) installs a recent
one (interface 12200) into ``<prefix>/lib``, where the loader does not look,
while an older system TBB (e.g. 2021.5, interface 12050 < numba's minimum
12060) is found first and makes numba warn "The TBB threading layer requires
TBB version 2021 update 6 or later" at the first parallel loop.

:func:`configure` (run when :mod:`rigslim` is imported, before numba) loads
the wheel's ``libtbb.so.12`` globally, so numba's version check and its
``tbbpool`` extension both get it. Without that wheel (or on other systems) it
moves TBB behind the layers that always load (``NUMBA_THREADING_LAYER_PRIORITY=
"omp workqueue tbb"``; numba wants all three named). A layer the user chose (``NUMBA_THREADING_LAYER`` or
``NUMBA_THREADING_LAYER_PRIORITY``) is left alone.
"""

from __future__ import annotations

import ctypes
import os
import sys
from pathlib import Path

#: numba's minimum TBB interface version (TBB 2021 update 6).
MIN_TBB_INTERFACE = 12060
_state: dict = {}


def _wheel_tbb() -> Path | None:
    path = Path(sys.prefix) / "lib" / "libtbb.so.12"
    return path if path.exists() else None


def configure() -> str:
    """Make numba's TBB layer use a new-enough TBB, or skip TBB; return what was done (once per process)."""
    if "done" in _state:
        return _state["done"]
    result = "left alone"
    if sys.platform.startswith("linux") and "numba" not in sys.modules and not (
            os.environ.get("NUMBA_THREADING_LAYER") or os.environ.get("NUMBA_THREADING_LAYER_PRIORITY")):
        result = "tbb"
        lib = _wheel_tbb()
        try:
            if lib is None:
                raise OSError("no tbb wheel")
            handle = ctypes.CDLL(str(lib), mode=ctypes.RTLD_GLOBAL)
            version = handle.TBB_runtime_interface_version
            version.restype = ctypes.c_int
            if version() < MIN_TBB_INTERFACE:
                raise OSError("tbb wheel too old")
            result = f"tbb ({lib}, interface {version()})"
        except (OSError, AttributeError):
            os.environ["NUMBA_THREADING_LAYER_PRIORITY"] = "omp workqueue tbb"   # workqueue always loads
            result = "omp or workqueue (no usable tbb wheel)"
    _state["done"] = result
    return result
