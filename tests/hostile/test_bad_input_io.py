"""Ordinary I/O errors and unusual outputs of ``rigslim run`` and ``rigslim report``.

Outputs that are folders, in read-only folders, on a full disk (a small tmpfs
where this process may mount one, and always a fault-injecting writer),
symbolic links and device nodes (``/dev/full``, ``/dev/null``), a FIFO, and a
run that fails after its ``write:`` step. The promise: exit 2 with one line
(no traceback), earlier outputs byte-identical, no temporary file left; a
symlink or a device node is written through and never replaced by a regular file.
"""

from __future__ import annotations

import errno
import json
import os
import stat
import subprocess
import threading
import uuid
from pathlib import Path

import pytest
from support.bad_input import DATA, assert_one_line, assert_unchanged, run_cli, run_cli_subprocess, snapshot

from rigslim.io import atomic, read_reduced_npz
from rigslim.io.atomic import TMP_MARK, OutputError, atomic_dir, atomic_path, output_transaction

PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:57"}
steps:
  - select: k-largest
    k: 4
  - solve: k-largest
  - evaluate: [position-rms]
  - write: out/w.npz
"""


@pytest.fixture
def work(tmp_path, capfd):
    """A pipeline beside the example data, and the outputs of an earlier run with k = 3."""
    (tmp_path / "data").symlink_to(DATA, target_is_directory=True)
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text(PIPELINE)
    metrics = tmp_path / "out" / "m.json"
    code, lines = run_cli(["run", "-q", pipeline, "--set", "select.k=3", "--metrics", metrics], capfd)
    assert code == 0, lines
    return pipeline, metrics


def run(capfd, pipeline, *args):
    return run_cli(["run", "-q", pipeline, *args], capfd)


def no_temporaries(*folders):
    for folder in folders:
        left = [p.name for p in Path(folder).iterdir() if TMP_MARK in p.name]
        assert not left, left


# --------------------------------------------------------------------------- folders in the output's place


def test_metrics_path_is_a_folder(work, tmp_path, capfd):
    pipeline, _ = work
    (tmp_path / "m.json").mkdir()
    before = snapshot(tmp_path / "out")
    code, lines = run(capfd, pipeline, "--metrics", tmp_path / "m.json")
    assert_one_line(code, lines, "m.json", "it is a folder", "fix:")
    assert_unchanged(tmp_path / "out", before)
    assert (tmp_path / "m.json").is_dir()


def test_write_path_is_a_folder_after_a_good_write(work, tmp_path, capfd):
    """A run that fails after its first write step leaves that output (and the metrics) as they were."""
    pipeline, metrics = work
    (tmp_path / "out" / "dir.npz").mkdir()
    pipeline.write_text(PIPELINE + "  - write: out/dir.npz\n")
    before = snapshot(tmp_path / "out")
    code, lines = run(capfd, pipeline, "--metrics", metrics)
    assert_one_line(code, lines, "dir.npz", "it is a folder")
    assert_unchanged(tmp_path / "out", before)
    assert read_reduced_npz(tmp_path / "out" / "w.npz").k == 3


def test_parent_is_a_file(work, tmp_path, capfd):
    pipeline, _ = work
    (tmp_path / "afile").write_text("x")
    code, lines = run(capfd, pipeline, "--metrics", tmp_path / "afile" / "m.json")
    assert_one_line(code, lines, "afile", "fix:")
    code, lines = run(capfd, pipeline, "--set", f"write.write={tmp_path / 'afile' / 'w.npz'}")
    assert_one_line(code, lines, "afile", "fix:")


def test_symlink_to_a_folder(work, tmp_path, capfd):
    pipeline, _ = work
    (tmp_path / "d").mkdir()
    (tmp_path / "link.json").symlink_to(tmp_path / "d")
    code, lines = run(capfd, pipeline, "--metrics", tmp_path / "link.json")
    assert_one_line(code, lines, "it is a folder")
    assert (tmp_path / "link.json").is_symlink()


# --------------------------------------------------------------------------- symlinks and device nodes


def test_symlinked_output_is_written_through(work, tmp_path, capfd):
    pipeline, metrics = work
    real = tmp_path / "real"
    real.mkdir()
    os.replace(metrics, real / "m.json")
    os.replace(tmp_path / "out" / "w.npz", real / "w.npz")
    metrics.symlink_to(real / "m.json")
    (tmp_path / "out" / "w.npz").symlink_to(Path("..") / "real" / "w.npz")   # a relative link
    os.chmod(real / "w.npz", 0o640)
    code, lines = run(capfd, pipeline, "--metrics", metrics)
    assert code == 0, lines
    assert metrics.is_symlink() and (tmp_path / "out" / "w.npz").is_symlink()
    assert json.loads((real / "m.json").read_text())["steps"][1]["k"] == 4
    assert read_reduced_npz(real / "w.npz").k == 4
    assert stat.S_IMODE(os.stat(real / "w.npz").st_mode) == 0o640          # the old file's permissions kept
    no_temporaries(real, tmp_path / "out")


def test_dangling_symlink_creates_its_target(work, tmp_path, capfd):
    pipeline, _ = work
    link = tmp_path / "m.json"
    link.symlink_to(tmp_path / "new" / "target.json")
    code, lines = run(capfd, pipeline, "--metrics", link)
    assert code == 0, lines
    assert link.is_symlink() and json.loads((tmp_path / "new" / "target.json").read_text())["steps"]


def test_dev_null_outputs_stay_device_nodes(work, tmp_path, capfd):
    pipeline, _ = work
    before = snapshot(tmp_path / "out")
    code, lines = run(capfd, pipeline, "--metrics", "/dev/null", "--set", "write.write=/dev/null",
                      "--set", "write.writer=npz")
    assert code == 0, lines
    assert stat.S_ISCHR(os.stat("/dev/null").st_mode)
    assert_unchanged(tmp_path / "out", before)


@pytest.mark.skipif(not os.path.exists("/dev/full"), reason="no /dev/full")
@pytest.mark.parametrize("which", ["metrics", "write"])
def test_dev_full_is_one_line_and_stays_a_device(work, tmp_path, capfd, which):
    """As root the old code replaced /dev/full by a regular file and exited 0."""
    pipeline, metrics = work
    args = ["--metrics", "/dev/full"] if which == "metrics" else \
        ["--metrics", metrics, "--set", "write.write=/dev/full", "--set", "write.writer=npz"]
    before = snapshot(tmp_path / "out")
    code, lines = run(capfd, pipeline, *args)
    assert_one_line(code, lines, "/dev/full", "No space left on device", "fix:")
    assert stat.S_ISCHR(os.stat("/dev/full").st_mode)
    assert_unchanged(tmp_path / "out", before)          # the other output was not committed either


def test_fifo_is_written_through(work, tmp_path, capfd):
    pipeline, metrics = work
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    received = []
    reader = threading.Thread(target=lambda: received.append(fifo.read_bytes()), daemon=True)
    reader.start()
    code, lines = run(capfd, pipeline, "--metrics", fifo)
    if reader.is_alive():      # the run never opened the FIFO: release the reader before failing
        os.close(os.open(fifo, os.O_WRONLY | os.O_NONBLOCK))
    reader.join(60)
    assert code == 0, lines
    assert stat.S_ISFIFO(os.lstat(fifo).st_mode)
    assert json.loads(received[0])["steps"][1]["k"] == 4


# --------------------------------------------------------------------------- read-only folders and full disks


def _mount_tmpfs(path: Path, options: str) -> bool:
    path.mkdir(exist_ok=True)
    try:
        done = subprocess.run(["mount", "-t", "tmpfs", "-o", options, "tmpfs", str(path)], capture_output=True,
                              timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return False
    return done.returncode == 0


@pytest.fixture
def tmpfs(tmp_path):
    """mount(path, options): a tmpfs, unmounted afterwards; the test skips where mounting is not allowed."""
    mounted = []

    def mount(name: str, options: str) -> Path:
        path = tmp_path / name
        if not _mount_tmpfs(path, options):
            pytest.skip("cannot mount a tmpfs here (needs root or CAP_SYS_ADMIN); the fault-injecting tests cover it")
        mounted.append(path)
        return path

    yield mount
    for path in reversed(mounted):
        subprocess.run(["umount", "-l", str(path)], capture_output=True, timeout=30)


def test_read_only_folder(work, tmp_path, capfd, tmpfs):
    pipeline, metrics = work
    ro = tmpfs("ro", "size=1m,mode=0755")
    (ro / "m.json").write_bytes(metrics.read_bytes())
    subprocess.run(["mount", "-o", "remount,ro", str(ro)], check=True, capture_output=True, timeout=30)
    before = snapshot(ro)
    code, lines = run(capfd, pipeline, "--metrics", ro / "m.json")
    assert_one_line(code, lines, "m.json", "not writable", "fix:")
    code, lines = run(capfd, pipeline, "--set", f"write.write={ro / 'w.npz'}")
    assert_one_line(code, lines, "w.npz", "Read-only file system", "fix:")
    assert_unchanged(ro, before)


@pytest.mark.skipif(os.geteuid() == 0, reason="root writes into a mode-0555 folder anyway (see the tmpfs test)")
def test_read_only_folder_by_permissions(work, tmp_path, capfd):
    pipeline, _ = work
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        code, lines = run(capfd, pipeline, "--metrics", ro / "m.json")
        assert_one_line(code, lines, "m.json", "fix:")
    finally:
        ro.chmod(0o755)


def test_disk_full_on_a_small_tmpfs(work, tmp_path, capfd, tmpfs):
    """ENOSPC for real: the old 3-weight file fits, the old one plus the new one's temporary file do not."""
    pipeline, metrics = work
    small = tmpfs("small", "size=256k")
    old = (tmp_path / "out" / "w.npz").read_bytes()
    assert 100_000 < len(old) < 200_000
    (small / "w.npz").write_bytes(old)
    before = snapshot(small)
    code, lines = run(capfd, pipeline, "--set", f"write.write={small / 'w.npz'}", "--metrics", small / "m.json")
    assert_one_line(code, lines, "w.npz", "No space left on device", "fix:")
    assert_unchanged(small, before)


@pytest.mark.parametrize("err", [errno.ENOSPC, errno.EDQUOT, errno.EIO])
def test_write_error_injected(work, tmp_path, capfd, monkeypatch, err):
    """A writer whose write fails (the fault-injecting stand-in for a full disk, a quota, a bad disk)."""
    pipeline, metrics = work

    def fail(tmp, target):
        raise OSError(err, os.strerror(err), str(tmp))

    monkeypatch.setattr(atomic, "on_staged", fail)
    before = snapshot(tmp_path / "out")
    code, lines = run(capfd, pipeline, "--metrics", metrics)
    assert_one_line(code, lines, "w.npz", os.strerror(err), "fix:")
    assert_unchanged(tmp_path / "out", before)


def test_subprocess_has_no_traceback(work, tmp_path):
    pipeline, _ = work
    (tmp_path / "m.json").mkdir()
    code, lines = run_cli_subprocess(["run", "-q", pipeline, "--metrics", tmp_path / "m.json"])
    assert_one_line(code, lines, "m.json", "it is a folder")


# --------------------------------------------------------------------------- rigslim report


@pytest.mark.parametrize("output", ["folder", "dev-full", "parent-file", "injected-enospc"])
def test_report_output_errors(work, tmp_path, capfd, monkeypatch, output):
    _, metrics = work
    target = {"folder": tmp_path / "r.html", "dev-full": Path("/dev/full"),
              "parent-file": tmp_path / "afile" / "r.html", "injected-enospc": tmp_path / "out" / "r.html"}[output]
    if output == "folder":
        target.mkdir()
    if output == "parent-file":
        (tmp_path / "afile").write_text("x")
    if output == "dev-full" and not os.path.exists("/dev/full"):
        pytest.skip("no /dev/full")
    if output == "injected-enospc":
        monkeypatch.setattr(atomic, "on_staged", lambda tmp, t: (_ for _ in ()).throw(
            OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(tmp))))
    before = snapshot(tmp_path / "out")
    code, lines = run_cli(["report", "-q", metrics, "-o", target, "--no-renders"], capfd)
    assert_one_line(code, lines, "fix:")
    assert_unchanged(tmp_path / "out", before)


# --------------------------------------------------------------------------- the atomic module itself


def test_transaction_commits_together_or_not_at_all(tmp_path):
    a, b = tmp_path / "a.txt", tmp_path / "b.txt"
    a.write_text("old a")
    with pytest.raises(RuntimeError):
        with output_transaction():
            with atomic_path(a) as tmp:
                tmp.write_text("new a")
            with atomic_path(b) as tmp:
                tmp.write_text("new b")
            assert a.read_text() == "old a" and not b.exists()     # staged, not yet renamed
            raise RuntimeError("a later step fails")
    assert a.read_text() == "old a" and not b.exists()
    no_temporaries(tmp_path)
    with output_transaction():
        with atomic_path(a) as tmp:
            tmp.write_text("new a")
        with atomic_path(b) as tmp:
            tmp.write_text("new b")
    assert a.read_text() == "new a" and b.read_text() == "new b"
    no_temporaries(tmp_path)


def test_atomic_dir_replaces_a_folder_whole(tmp_path):
    folder = tmp_path / "levels"
    folder.mkdir()
    (folder / "old.txt").write_text("old")
    with pytest.raises(OutputError, match="disk went away"):
        with atomic_dir(folder) as tmp:
            with atomic_path(tmp / "new.txt") as f:     # inside a staged folder: written in place
                f.write_text("new")
            raise OSError(errno.EIO, "disk went away")
    assert sorted(p.name for p in folder.iterdir()) == ["old.txt"]
    with atomic_dir(folder) as tmp:
        with atomic_path(tmp / "new.txt") as f:
            f.write_text("new")
    assert sorted(p.name for p in folder.iterdir()) == ["new.txt"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["levels"]
    (tmp_path / "afile").write_text("x")
    with pytest.raises(OutputError):
        with atomic_dir(tmp_path / "afile"):
            pass


def test_long_output_name(tmp_path):
    path = tmp_path / (uuid.uuid4().hex * 7 + ".json")[:250]
    with atomic_path(path) as tmp:
        tmp.write_text("{}")
    assert path.read_text() == "{}"
    no_temporaries(tmp_path)


def test_read_only_old_file_is_replaced_and_keeps_its_mode(tmp_path):
    """The old output's permission bits are given to the new file after it is written, not before."""
    path = tmp_path / "r.json"
    path.write_text("old")
    path.chmod(0o444)
    with atomic_path(path) as tmp:
        tmp.write_text("new")
    assert path.read_text() == "new" and stat.S_IMODE(path.stat().st_mode) == 0o444
    no_temporaries(tmp_path)
