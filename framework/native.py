"""What native libraries (libigl, MKL) print on the process's stderr, kept off rigslim's error line.

libigl's readers print their own diagnosis (``Error: readOBJ() face on line
3 has invalid element format``) straight to file descriptor 2, without a
newline before rigslim's message. :func:`native_stderr` redirects the
descriptor around such a call, so the text can go into the one-line error
(or be passed on unchanged when the call succeeds).
"""

from __future__ import annotations

import contextlib
import os
import sys
import tempfile
import threading

_lock = threading.Lock()


class Captured:
    """Text written to descriptor 2 inside :func:`native_stderr` (at most 64 KiB kept)."""

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
    """Capture descriptor 2 for the block; the yielded :class:`Captured` holds the text afterwards.

    The caller puts it into its error message, or calls
    :meth:`Captured.replay` when the native call succeeded.
    """
    out = Captured()
    with _lock:
        try:
            sys.stderr.flush()
            saved = os.dup(2)
        except (OSError, ValueError, AttributeError):  # no usable descriptor 2: nothing to capture
            yield out
            return
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 2)
            try:
                yield out
            finally:
                os.dup2(saved, 2)
                os.close(saved)
                tmp.seek(0)
                out.text = tmp.read(1 << 16).decode("utf-8", errors="replace")
