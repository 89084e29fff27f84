"""What native libraries (libigl, MKL) print on the process's stderr, kept off rigslim's error line.

libigl's readers print their own diagnosis straight to file descriptor 2
(``Error: readOBJ() face on line 3 has invalid element format``, without a
newline before rigslim's message) or, buffered by C stdio, to descriptor 1
(``Error: bad line`` of the OFF reader, which would appear at exit).
:func:`native_stderr` redirects both descriptors around such a call and
flushes C stdio before restoring them, so the text can go into the one-line
error (or be passed on to stderr when the call succeeds).
"""

from __future__ import annotations

import contextlib
import ctypes
import os
import sys
import tempfile
import threading

_lock = threading.Lock()


def _flush_c_stdio() -> None:
    """``fflush(NULL)``: push C stdio buffers (printf output of native code) to their descriptors."""
    try:
        ctypes.CDLL(None).fflush(None)
    except (OSError, AttributeError):  # no C library to ask: nothing buffered there that we can reach
        pass


class Captured:
    """Text written to descriptors 1 and 2 inside :func:`native_stderr` (at most 64 KiB kept)."""

    text: str = ""

    def replay(self) -> None:
        """Pass the captured text on to stderr (a successful call's warnings are not lost)."""
        if self.text:
            sys.stderr.write(self.text)
            sys.stderr.flush()

    def first_line(self) -> str:
        """The first non-empty line, or ''."""
        return next((line.strip() for line in self.text.splitlines() if line.strip()), "")


@contextlib.contextmanager
def native_stderr():
    """Capture descriptors 1 and 2 for the block; the yielded :class:`Captured` holds the text afterwards.

    The caller puts it into its error message, or calls
    :meth:`Captured.replay` when the native call succeeded.
    """
    out = Captured()
    with _lock:
        try:
            sys.stdout.flush()
            sys.stderr.flush()
            _flush_c_stdio()
            saved = (os.dup(1), os.dup(2))
        except (OSError, ValueError, AttributeError):  # no usable descriptors: nothing to capture
            yield out
            return
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 1)
            os.dup2(tmp.fileno(), 2)
            try:
                yield out
            finally:
                _flush_c_stdio()
                os.dup2(saved[0], 1)
                os.dup2(saved[1], 2)
                os.close(saved[0])
                os.close(saved[1])
                tmp.seek(0)
                out.text = tmp.read(1 << 16).decode("utf-8", errors="replace")
