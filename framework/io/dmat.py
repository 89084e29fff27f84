"""libigl's DMAT matrix format, ASCII and binary.

The first line is ``cols rows``. If it is ``0 0``, a second ASCII line
``cols rows`` follows, then the values as little-endian float64 in
column-major order; otherwise the values follow as ASCII, column-major.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.io.atomic import atomic_path


def _header(line: bytes, path, which: str) -> tuple[int, int]:
    try:
        cols, rows = (int(t) for t in line.split())
    except ValueError:
        raise InputError(f"{which} line {line[:40]!r} is not 'cols rows'", source=path, field="header",
                         fix="give a DMAT file (first line: number of columns and rows)") from None
    if cols < 0 or rows < 0:
        raise InputError("negative matrix size", source=path, field="header", fix="repair the file")
    return cols, rows


def read_dmat(path) -> np.ndarray:
    """Read a DMAT file.

    Returns
    -------
    (rows, cols) float64 array
    """
    path = Path(path)
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", source=path, field="path",
                         fix="check the path") from None
    first, _, rest = data.partition(b"\n")
    cols, rows = _header(first, path, "first")
    if cols == 0 and rows == 0 and rest:
        second, _, payload = rest.partition(b"\n")
        cols, rows = _header(second, path, "second")
        need = 8 * cols * rows
        if len(payload) < need:
            raise InputError(f"binary payload holds {len(payload)} bytes, {need} expected for "
                             f"{rows} x {cols}", source=path, field="values", fix="the file is truncated; re-export it")
        values = np.frombuffer(payload[:need], dtype="<f8")
    else:
        try:
            values = np.array(rest.split(), dtype=np.float64)
        except ValueError:
            raise InputError("non-numeric value in the ASCII body", source=path, field="values",
                             fix="repair or re-export the file") from None
        if values.size != cols * rows:
            raise InputError(f"{values.size} values for a {rows} x {cols} matrix", source=path,
                             field="values", fix="the file is truncated or its header is wrong")
    return values.reshape(cols, rows).T.copy()


def write_dmat(path, M, binary: bool = True) -> None:
    """Write a 2D array as DMAT (binary by default), atomically."""
    M = np.atleast_2d(np.asarray(M, dtype=np.float64))
    rows, cols = M.shape
    with atomic_path(path) as tmp, open(tmp, "wb") as f:
        if binary:
            f.write(b"0 0\n")
            f.write(f"{cols} {rows}\n".encode())
            f.write(np.ascontiguousarray(M.T).astype("<f8").tobytes())
        else:
            f.write(f"{cols} {rows}\n".encode())
            np.savetxt(f, M.T.reshape(-1, 1), fmt="%.17g")
