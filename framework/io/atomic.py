"""Outputs that are never damaged: staged temporary files, renamed into place all together.

Every rigslim output goes through :func:`atomic_path` (one file) or
:func:`atomic_dir` (a folder that appears whole). The rules:

- A regular file (or a new path) is written to a temporary file beside it,
  named ``.NAME.rigslim-tmp-PID-XXXXXXXX[SUFFIX]``, flushed (``fsync``) and
  renamed onto it (``rename(2)`` is atomic), so a reader -- or the machine
  after a crash -- sees the old or the new complete file, never a partial
  one. An existing file keeps its permission bits.
- A symbolic link is written through: the file it points to is replaced
  atomically, the link stays.
- A device node, FIFO or socket (``/dev/null``, ``/dev/full``, a pipe) is
  written through: the bytes are staged in the temporary folder and then
  written into the opened node; it is never replaced by a regular file.
- A folder given as a file output, a read-only folder, a full disk
  (``ENOSPC``) or any other ``OSError`` raises :class:`OutputError` (one
  line: the output path, the reason, the fix), the old file stays
  byte-identical and the temporary file is removed -- on every error path,
  ``KeyboardInterrupt`` (SIGINT) included.
- A run killed with SIGKILL cannot clean up; the next write of the same
  output removes the temporary files whose process is gone (see
  :func:`remove_stale`).

Inside :func:`output_transaction` (``rigslim run`` wraps a whole pipeline in
one, ``rigslim report`` its page and renders) nothing is renamed until the
transaction ends: the staged files are committed together (device
write-throughs first, since they can still fail or block on a FIFO, then the
renames, with SIGINT and SIGTERM held back), or all removed if anything
failed before. :func:`staged_view` lets a command read what it staged (to
measure the file it is about to commit), and :func:`scratch_folder` gives a
private folder whose files are written at once (intermediate files that are
read back within the command and never committed).

:func:`refuse_input_as_output` is the one check every command and pipeline
runs before any work: no output may name an input file (the same path after
``./``, ``..`` and symbolic links, or the same inode: a hard link), and no two
outputs may name one file.
"""

from __future__ import annotations

import contextlib
import contextvars
import ctypes
import errno
import os
import re
import secrets
import shutil
import signal
import stat
import tempfile
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path

from rigslim.errors import RigslimError

#: Marker in the name of every temporary output (``.NAME.rigslim-tmp-PID-XXXXXXXX``).
TMP_MARK = ".rigslim-tmp-"
#: A temporary output older than this is stale even when its process id is alive again (reused pid).
STALE_AGE_SECONDS = 24 * 3600
#: Temporary files of rigslim before the marker existed (``.NAME.XXXXXXXX[SUFFIX]``, mkstemp's 8 characters)
#: are removed when older than this.
LEGACY_AGE_SECONDS = 600
#: Test hook: ``on_staged(tmp, target)`` is called when a writer has filled a temporary file, before it is
#: staged or renamed (the fault tests use it to kill a run in the middle of a write). None outside tests.
on_staged = None


class OutputError(RigslimError):
    """An output cannot be written (a folder in its place, no permission, disk full...)."""


_FIXES = {
    errno.ENOSPC: "free space on that device or write the output elsewhere",
    errno.EDQUOT: "free space within your quota or write the output elsewhere",
    errno.EACCES: "choose a folder you can write to, or change its permissions",
    errno.EPERM: "choose a folder you can write to, or change its permissions",
    errno.EROFS: "the file system is read-only: write the output elsewhere",
    errno.EISDIR: "give a file name, not a folder",
    errno.ENOTDIR: "a part of the path is a file, not a folder: fix the path",
    errno.ENAMETOOLONG: "use a shorter file name",
    errno.EXDEV: "write the output on the same file system as its folder",
}


def output_error(exc: OSError, path, what: str = "cannot write output") -> OutputError:
    """The one-line :class:`OutputError` for an ``OSError`` met while writing ``path``."""
    reason = exc.strerror or type(exc).__name__
    return OutputError(f"{what} ({reason})", source=path, field="output",
                       fix=_FIXES.get(exc.errno or 0, "check the path and the free space"))


# --------------------------------------------------------------------------- stale temporary files


def _pid_alive(pid: int) -> bool:
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError):
        return True
    return True


_TMP_RE = re.compile(re.escape(TMP_MARK) + r"(\d+)-[0-9a-f]{8}")
_active: set[str] = set()          # temporary paths of this process that are still in use
_active_lock = threading.Lock()


def _is_stale(entry: Path, now: float) -> bool:
    m = _TMP_RE.search(entry.name)
    try:
        age = now - entry.lstat().st_mtime
    except FileNotFoundError:
        return False
    if m is None:   # a legacy name: only by age
        return age > LEGACY_AGE_SECONDS
    pid = int(m.group(1))
    if pid == os.getpid():
        with _active_lock:
            return str(entry) not in _active   # same pid, not ours: an earlier process with our pid died
    return not _pid_alive(pid) or age > STALE_AGE_SECONDS


def remove_stale(target) -> list[Path]:
    """Remove the temporary files and folders a killed rigslim left for ``target``; return them.

    A temporary output of ``target`` is ``.NAME.rigslim-tmp-PID-XXXXXXXX*`` in
    its folder. It is stale when process PID no longer exists (a run killed
    with SIGKILL, or a crashed machine), or when it is older than
    :data:`STALE_AGE_SECONDS` (the pid was reused since). A run that is still
    writing the same output keeps its files. Temporary files of earlier rigslim
    versions (``.NAME.`` + 8 random characters + the suffix, from
    ``mkstemp``) are removed when older than :data:`LEGACY_AGE_SECONDS`.
    """
    target = Path(target)
    folder = target.parent
    prefix = f".{_short(target.name)}"
    legacy = re.compile(re.escape(f".{target.name}.") + r"[a-z0-9_]{8}(" + re.escape(target.suffix) + r"|\.tmp)?$")
    removed: list[Path] = []
    now = time.time()
    try:
        entries = [e for e in os.scandir(folder) if e.name.startswith(prefix)]
    except OSError:
        return removed
    for e in entries:
        name = e.name
        if not (name.startswith(prefix + TMP_MARK) or legacy.match(name)):
            continue
        p = Path(e.path)
        if not _is_stale(p, now):
            continue
        try:
            if p.is_dir() and not p.is_symlink():
                shutil.rmtree(p)
            else:
                p.unlink()
            removed.append(p)
        except OSError:
            pass
    return removed


# --------------------------------------------------------------------------- staging


def _short(name: str) -> str:
    return name[:120]


def _tmp_name(target: Path, suffix: str) -> str:
    return f".{_short(target.name)}{TMP_MARK}{os.getpid()}-{secrets.token_hex(4)}{suffix}"


@dataclass
class _Staged:
    tmp: Path
    target: Path
    kind: str          # "file" (rename), "through" (copy into a device node / FIFO), "dir" (swap folders)
    mode: int | None = None   # permission bits to give the file before the rename (the old output's)


@dataclass
class _Transaction:
    staged: list[_Staged] = field(default_factory=list)
    dirs: set[str] = field(default_factory=set)

    def add(self, item: _Staged) -> None:
        # a second write of the same output in one run: the last one wins
        for old in [s for s in self.staged if s.target == item.target]:
            self.staged.remove(old)
            _discard(old)
        self.staged.append(item)

    def commit(self) -> None:
        for s in [s for s in self.staged if s.kind == "through"]:   # may block (a FIFO) or fail: interruptible
            _commit_one(s)
        with _sigint_held():
            for s in self.staged:
                if s.kind != "through":
                    _commit_one(s)
            self.staged.clear()

    def abort(self) -> None:
        for s in self.staged:
            _discard(s)
        self.staged.clear()


_current: contextvars.ContextVar[_Transaction | None] = contextvars.ContextVar("rigslim_output_tx", default=None)


@contextlib.contextmanager
def output_transaction():
    """Stage every output written inside; commit them together at the end, or remove them all on error.

    Nested transactions join the outermost one.
    """
    if _current.get() is not None:
        yield _current.get()
        return
    tx = _Transaction()
    token = _current.set(tx)
    try:
        yield tx
        tx.commit()
    except BaseException:
        tx.abort()
        raise
    finally:
        _current.reset(token)


@contextlib.contextmanager
def _sigint_held():
    """Hold SIGINT back while renaming (delivered right after), so Ctrl-C cannot split a commit."""
    main = threading.current_thread() is threading.main_thread()
    if main:
        old = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT, signal.SIGTERM})
    try:
        yield
    finally:
        if main:
            signal.pthread_sigmask(signal.SIG_SETMASK, old)


def _register(tmp: Path) -> None:
    with _active_lock:
        _active.add(str(tmp))


def _unregister(tmp: Path) -> None:
    with _active_lock:
        _active.discard(str(tmp))


def _discard(s: _Staged) -> None:
    with contextlib.suppress(OSError):
        if s.kind == "dir":
            shutil.rmtree(s.tmp, ignore_errors=True)
        else:
            os.unlink(s.tmp)
    _unregister(s.tmp)


def _fsync(path: Path, directory: bool = False) -> None:
    """Flush a file (or a folder's entries) to the disk, so that a crash after the rename finds the new data."""
    try:
        fd = os.open(path, os.O_RDONLY | (getattr(os, "O_DIRECTORY", 0) if directory else 0))
    except PermissionError:   # a write-only file: the rename still happens, unflushed
        return
    try:
        os.fsync(fd)
    except OSError as e:
        if e.errno not in (errno.EINVAL, errno.ENOTSUP, errno.EBADF):   # file systems without fsync: fine
            raise
    finally:
        os.close(fd)


def _commit_one(s: _Staged) -> None:
    try:
        if s.kind == "file":
            if s.mode is not None:
                os.chmod(s.tmp, s.mode)
            _fsync(s.tmp)
            os.replace(s.tmp, s.target)
            with contextlib.suppress(OSError):
                _fsync(s.target.parent, directory=True)
        elif s.kind == "through":
            _write_through(s.tmp, s.target)
            os.unlink(s.tmp)
        else:
            _swap_dirs(s.tmp, s.target)
    except OSError as e:
        _discard(s)
        raise output_error(e, s.target) from None
    _unregister(s.tmp)


def _write_through(tmp: Path, target: Path) -> None:
    fd = os.open(target, os.O_WRONLY | getattr(os, "O_CLOEXEC", 0))
    try:
        with open(tmp, "rb") as src:
            while chunk := src.read(1 << 20):
                view = memoryview(chunk)
                while view:
                    n = os.write(fd, view)
                    view = view[n:]
    finally:
        os.close(fd)


_RENAME_EXCHANGE = 2


def _swap_dirs(tmp: Path, folder: Path) -> None:
    """Put the staged folder ``tmp`` in place of ``folder`` (atomically on Linux: renameat2 EXCHANGE)."""
    if not os.path.lexists(folder):
        os.replace(tmp, folder)
        return
    libc = _libc()
    if libc is not None:
        rc = libc.renameat2(-100, os.fsencode(tmp), -100, os.fsencode(folder), _RENAME_EXCHANGE)  # AT_FDCWD
        if rc == 0:
            shutil.rmtree(tmp, ignore_errors=True)   # now holds the old folder
            return
    old = folder.parent / _tmp_name(folder, ".old")
    os.replace(folder, old)
    os.replace(tmp, folder)
    shutil.rmtree(old, ignore_errors=True)


def _libc():
    try:
        libc = ctypes.CDLL(None, use_errno=True)
        libc.renameat2.argtypes = [ctypes.c_int, ctypes.c_char_p, ctypes.c_int, ctypes.c_char_p, ctypes.c_uint]
        return libc
    except (OSError, AttributeError):
        return None


def _resolve(path: Path) -> tuple[Path, str]:
    """The real output path (a symlink's target) and how to write it: ``"file"`` or ``"through"``."""
    if os.path.islink(path):
        path = Path(os.path.realpath(path))
    try:
        st = os.stat(path)
    except FileNotFoundError:
        return path, "file"
    except OSError as e:
        raise output_error(e, path) from None
    if stat.S_ISDIR(st.st_mode):
        raise OutputError("cannot write output (it is a folder)", source=path, field="output",
                          fix=_FIXES[errno.EISDIR])
    if stat.S_ISREG(st.st_mode):
        return path, "file"
    return path, "through"


def check_output(path) -> None:
    """Raise :class:`OutputError` now if ``path`` can certainly not be written as a file output.

    Used before a long run for outputs known up front (``--metrics``, ``report -o``): a folder in the
    output's place, a parent that is a file, or a read-only or inaccessible folder.
    """
    target, kind = _resolve(Path(path))
    if kind != "file":
        return
    folder = target.parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    if not folder.is_dir():
        raise OutputError("cannot write output (a part of its folder path is a file)", source=target,
                          field="output", fix=_FIXES[errno.ENOTDIR])
    if not os.access(folder, os.W_OK | os.X_OK):
        raise OutputError("cannot write output (its folder is not writable)", source=target, field="output",
                          fix=_FIXES[errno.EACCES])


def _inside_staged_dir(path: Path) -> bool:
    tx = _current.get()
    dirs = set(tx.dirs) if tx is not None else set()
    dirs |= _standalone_dirs | _scratch_dirs
    return any(str(p) in dirs for p in path.parents)


_standalone_dirs: set[str] = set()
_scratch_dirs: set[str] = set()


@contextlib.contextmanager
def scratch_folder(prefix: str = "rigslim-"):
    """A private temporary folder (removed at the end) whose files :func:`atomic_path` writes at once.

    For intermediate files a command reads back itself (one skin's result, the LOD file ``--split`` cuts
    up): they are not outputs, so they are neither staged in the transaction nor committed.
    """
    with tempfile.TemporaryDirectory(prefix=prefix) as tmp:
        names = {tmp, os.path.realpath(tmp)}
        _scratch_dirs.update(names)
        try:
            yield Path(tmp)
        finally:
            _scratch_dirs.difference_update(names)


def _real(path) -> str:
    return os.path.realpath(os.path.abspath(path))


@contextlib.contextmanager
def staged_view(path):
    """Yield a path to read ``path`` as the current transaction will commit it.

    Outside a transaction, or when nothing is staged for ``path``, that is ``path`` itself. Otherwise the
    staged files of ``path``'s folder are linked (or copied) under their final names into a scratch folder,
    so a ``.gltf`` finds its staged ``.bin`` beside it; the folder is removed at the end.
    """
    tx = _current.get()
    target = Path(_real(path))
    item = None if tx is None else next((s for s in tx.staged if _real(s.target) == str(target) and s.kind == "file"),
                                        None)
    if item is None:
        yield Path(path)
        return
    assert tx is not None
    with scratch_folder("rigslim-view-") as folder:
        for s in tx.staged:
            if s.kind == "file" and Path(_real(s.target)).parent == target.parent:
                dst = folder / Path(_real(s.target)).name
                try:
                    os.link(s.tmp, dst)
                except OSError:
                    shutil.copyfile(s.tmp, dst)
        yield folder / target.name


# --------------------------------------------------------------------------- outputs that are inputs


def _identity(path: Path) -> tuple[str, tuple[int, int] | None, bool]:
    """The real path, ``(st_dev, st_ino)`` of an existing file, and whether it is a regular file (or new)."""
    real = _real(path)
    try:
        st = os.stat(real)
    except OSError:
        return real, None, True
    return real, (st.st_dev, st.st_ino), stat.S_ISREG(st.st_mode)


def refuse_input_as_output(outputs, inputs, *, distinct: bool = True) -> None:
    """Raise :class:`OutputError` (one line) if an output is an input file (or, ``distinct``, two outputs
    are one file).

    Parameters
    ----------
    outputs : mapping of str to path-like
        Each output under the name the user gave it (``-o``, ``--report``, ``steps[4].write``); None is skipped.
    inputs : iterable of path-like
        Every file the command or pipeline reads: the inputs, the files they reference (a ``.gltf``'s
        buffers and images) and the pipeline document itself.
    distinct : bool
        Also refuse two outputs naming one file (a pipeline may write one output twice: the last wins).

    Notes
    -----
    Two paths name the same file when their real paths (``./``, ``..`` and symbolic links resolved) are
    equal, or when both exist and have the same ``(st_dev, st_ino)`` (hard links, bind mounts). Device
    nodes and FIFOs (``/dev/null``) may be given as several outputs: they are written through, never replaced.
    """
    ins = []
    for p in inputs:
        if p is not None:
            ins.append((Path(p), *_identity(Path(p))[:2]))
    seen: dict = {}
    for label, out in outputs.items():
        if out is None:
            continue
        real, ident, regular = _identity(Path(out))
        for inp, in_real, in_ident in ins:
            if real == in_real or (ident is not None and ident == in_ident):
                raise OutputError(f"{out} is the input {inp} (same file)", field=label,
                                  fix="write to another path")
        if not (regular and distinct):
            continue
        for key in (real, ident):
            if key is not None and key in seen:
                raise OutputError(f"{out} is also the {seen[key]} output (same file)", field=label,
                                  fix="give each output a path of its own")
        seen[real] = label
        if ident is not None:
            seen[ident] = label


@contextlib.contextmanager
def atomic_path(path, suffix: str | None = None):
    """Yield a temporary path to write ``path``'s new content to; put it in place on success.

    Parameters
    ----------
    path : output path (a new or regular file, a symlink, or a device node / FIFO: see the module docstring)
    suffix : str, optional
        Suffix of the temporary file (``.npz`` for ``numpy.savez``, which appends it otherwise);
        default: the output's own suffix.

    Raises
    ------
    OutputError
        One line, when the output cannot be written; ``path`` is then unchanged and no temporary file is left.
    """
    path = Path(path)
    if _inside_staged_dir(path):   # a file inside a folder that atomic_dir stages: the folder is the unit
        yield path
        return
    target, kind = _resolve(path)
    suffix = suffix if suffix is not None else (target.suffix or ".tmp")
    if kind == "file":
        folder = target.parent
        try:
            folder.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise output_error(e, target, "cannot create the output's folder") from None
        remove_stale(target)
    else:
        folder = Path(tempfile.gettempdir())
        remove_stale(folder / target.name)
    tmp = folder / _tmp_name(target, suffix)
    try:
        mode = stat.S_IMODE(os.stat(target).st_mode) if kind == "file" and target.exists() else 0o666
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as e:
        raise output_error(e, target) from None
    _register(tmp)
    staged = _Staged(tmp, target, kind, mode if mode != 0o666 else None)
    try:
        os.close(fd)
        yield tmp
        if on_staged is not None:
            on_staged(tmp, target)
        tx = _current.get()
        if tx is not None:
            tx.add(staged)
        elif kind == "through":
            _commit_one(staged)
        else:
            with _sigint_held():
                _commit_one(staged)
    except OSError as e:
        _discard(staged)
        raise output_error(e, target) from None
    except BaseException:
        _discard(staged)
        raise


@contextlib.contextmanager
def atomic_dir(folder):
    """Yield a temporary folder to fill; it replaces ``folder`` whole on success (see :func:`atomic_path`).

    Files written inside it through :func:`atomic_path` are written directly
    (the folder is the unit that is staged).
    """
    folder = Path(folder)
    if os.path.islink(folder):
        folder = Path(os.path.realpath(folder))
    if os.path.lexists(folder) and not folder.is_dir():
        raise OutputError("cannot write output folder (a file is in its place)", source=folder, field="output",
                          fix="remove the file or choose another folder name")
    try:
        folder.parent.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise output_error(e, folder, "cannot create the output's folder") from None
    remove_stale(folder)
    tmp = folder.parent / _tmp_name(folder, "")
    try:
        tmp.mkdir()
    except OSError as e:
        raise output_error(e, folder) from None
    _register(tmp)
    staged = _Staged(tmp, folder, "dir")
    tx = _current.get()
    owner = tx.dirs if tx is not None else _standalone_dirs
    owner.add(str(tmp))
    try:
        yield tmp
        if tx is not None:
            tx.add(staged)
        else:
            with _sigint_held():
                _commit_one(staged)
    except OSError as e:
        _discard(staged)
        raise output_error(e, folder) from None
    except BaseException:
        _discard(staged)
        raise
    finally:
        if tx is None:
            owner.discard(str(tmp))
