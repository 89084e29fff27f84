"""Opening USD stages, and the conventions between USD's matrices and rigslim's.

USD multiplies row vectors by matrices (``p' = p M``, translation in the last
row, ``GfMatrix4d``); rigslim, like the papers, multiplies columns
(``v' = T v``, translation in the last column). So a USD matrix ``M`` is
rigslim's ``M^T`` and products reverse: USD's ``A * B`` (apply A, then B)
is rigslim's ``B^T A^T``. :func:`to_columns` and :func:`to_rows` convert
stacks of 4x4 matrices.

``usd-core`` is an optional dependency (``pip install 'rigslim[usd]'``);
:func:`pxr_modules` imports it on first use and turns its absence into one
line.
"""

from __future__ import annotations

import contextlib
import os
import resource
from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.io.usd import USD_SUFFIXES


def pxr_modules():
    """``(Usd, UsdGeom, UsdSkel, Sdf, Gf, Vt)`` from ``usd-core``, or one line saying how to install it."""
    try:
        from pxr import Gf, Sdf, Usd, UsdGeom, UsdSkel, Vt
    except ImportError as e:
        raise InputError(f"USD support needs the usd-core package ({e})", field="usd",
                         fix="pip install 'rigslim[usd]' (or pip install usd-core)") from None
    return Usd, UsdGeom, UsdSkel, Sdf, Gf, Vt


def to_columns(M) -> np.ndarray:
    """(n, 4, 4) float64 column-vector matrices from USD row-vector ``GfMatrix4d`` (array or sequence)."""
    A = np.array(M, dtype=np.float64).reshape(-1, 4, 4)
    return np.ascontiguousarray(A.transpose(0, 2, 1))


def to_rows(T: np.ndarray):
    """A ``VtMatrix4dArray`` from (n, 4, 4) column-vector matrices."""
    _, _, _, _, Gf, Vt = pxr_modules()
    T = np.asarray(T, dtype=np.float64).reshape(-1, 4, 4)
    return Vt.Matrix4dArray([Gf.Matrix4d(*[float(x) for x in m.T.ravel()]) for m in T])


def matrix_rows(T: np.ndarray):
    """One ``GfMatrix4d`` from a 4x4 column-vector matrix."""
    _, _, _, _, Gf, _ = pxr_modules()
    return Gf.Matrix4d(*[float(x) for x in np.asarray(T, dtype=np.float64).T.ravel()])


@contextlib.contextmanager
def diagnostics():
    """Collect USD's warnings and errors (which it would print to stderr) while the block runs.

    Yields a list that holds ``"text"`` of every diagnostic issued inside the block once it ends.
    """
    from pxr import UsdUtils

    found: list[str] = []
    delegate = UsdUtils.CoalescingDiagnosticDelegate()
    try:
        yield found
    finally:
        for item in delegate.TakeUncoalescedDiagnostics():
            found.append(" ".join(str(item.commentary).split()))
        del delegate


#: Address space a USD read may add to the process (bytes): at least this, or 100x the file's size.
#: ``RIGSLIM_USD_MEMORY`` (bytes) overrides it.
MEMORY_BUDGET = 4 << 30


def _address_space() -> int:
    """This process's current virtual memory size in bytes (0 where /proc is unavailable)."""
    try:
        with open("/proc/self/status") as f:
            for line in f:
                if line.startswith("VmSize:"):
                    return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


@contextlib.contextmanager
def memory_budget(path):
    """Cap the address space while USD reads ``path``, so that a corrupt crate file asking for terabytes fails.

    USD's crate reader allocates what a file's counts say; a damaged ``.usdc``
    can make it allocate (and zero) more memory than the machine has. Inside
    the block the soft ``RLIMIT_AS`` is the current size plus
    ``max(MEMORY_BUDGET, 100 x file size)`` (never above an existing limit);
    USD then fails the read with an error, which :func:`open_stage` and the
    reader turn into one line. The previous limit is restored afterwards.
    """
    try:
        size = os.stat(path).st_size
    except OSError:
        size = 0
    budget = int(os.environ.get("RIGSLIM_USD_MEMORY", "0") or 0) or max(MEMORY_BUDGET, 100 * size)
    current = _address_space()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    cap = current + budget if current else resource.RLIM_INFINITY
    if hard != resource.RLIM_INFINITY:
        cap = min(cap, hard)
    if soft != resource.RLIM_INFINITY:
        cap = min(cap, soft)
    try:
        resource.setrlimit(resource.RLIMIT_AS, (cap, hard))
    except (ValueError, OSError):
        cap = None
    try:
        yield
    except MemoryError:
        raise InputError(f"reading it needs more than {budget / 2**30:.1f} GiB (a corrupt file?)", source=path,
                         field="layer", fix="re-export the file; set RIGSLIM_USD_MEMORY=BYTES if it is real") from None
    finally:
        if cap is not None:
            resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


def open_stage(path):
    """Open a USD stage read-only, with every payload loaded.

    Parameters
    ----------
    path : path-like
        ``.usd``, ``.usda``, ``.usdc`` or ``.usdz``.

    Returns
    -------
    pxr.Usd.Stage

    Raises
    ------
    InputError
        One line when the file is missing, not a USD layer, or fails to compose.
    """
    Usd = pxr_modules()[0]
    from pxr import Tf

    path = Path(path)
    if path.suffix.lower() not in USD_SUFFIXES:
        raise InputError(f"'{path.suffix or path.name}' is not a USD file", source=path, field="path",
                         fix="give a .usd, .usda, .usdc or .usdz file")
    if not path.is_file():
        raise InputError("file not found", source=path, field="path", fix="check the path")
    with memory_budget(path), diagnostics() as found:
        try:
            stage = Usd.Stage.Open(str(path), Usd.Stage.LoadAll)
        except Tf.ErrorException as e:
            stage, found = None, found + [tf_message(e)]
    if stage is None:
        why = found[0] if found else "USD could not open it"
        raise InputError(f"not a readable USD layer ({why})", source=path, field="layer",
                         fix="re-export the file; check it with usdchecker")
    return stage


def tf_message(error) -> str:
    """The text of a ``Tf.ErrorException`` without USD's C++ locations (its first quoted commentary)."""
    import re

    text = " ".join(str(error).split())
    found = re.findall(r"\.(?:cpp|h) : '(.*?)'(?= Error in |$)", text)
    return found[0] if found else text


def time_codes_per_second(stage) -> float:
    """The stage's ``timeCodesPerSecond`` (USD's default 24 when unauthored)."""
    tcps = float(stage.GetTimeCodesPerSecond())
    return tcps if np.isfinite(tcps) and tcps > 0 else 24.0
