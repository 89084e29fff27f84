"""Fault tests: SIGKILL, SIGINT and SIGTERM during the solve and during each write of ``rigslim run``.

The pipeline writes reduced weights (.npz), a glTF (.gltf + .bin) and the metrics JSON.

Each test starts from outputs of an earlier run (k = 3), runs the CLI in a
subprocess through tests/support/fault_driver.py, which pauses the run in the
solve or in the middle of one output's write (its temporary file cut to half
its length) and writes a marker file, and then signals it. Afterwards every
output is the old complete file, byte-identical; SIGINT/SIGTERM leave no
temporary file and print one line; after SIGKILL the next run removes the
temporary files the killed one left and writes the new outputs. No timing is
involved: the test waits for the marker.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from support.bad_input import snapshot

from rigslim.io import read_reduced_npz
from rigslim.io.atomic import TMP_MARK

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "examples" / "data"
DRIVER = Path(__file__).resolve().parents[1] / "support" / "fault_driver.py"
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
  - write: out/w.gltf
"""


@pytest.fixture(scope="module")
def old_outputs(tmp_path_factory):
    """The outputs of an earlier run with k = 3 (made once, copied into each test's folder)."""
    folder = tmp_path_factory.mktemp("old")
    (folder / "data").symlink_to(DATA, target_is_directory=True)
    pipeline = folder / "p.yaml"
    pipeline.write_text(PIPELINE)
    proc = driver("none", folder / "unused", pipeline, folder / "out" / "m.json", "--set", "select.k=3")
    assert proc.wait(timeout=300) == 0, proc.stderr.read()
    return folder / "out"


@pytest.fixture
def work(tmp_path, old_outputs):
    """A pipeline beside the example data, and the outputs of an earlier run with k = 3."""
    (tmp_path / "data").symlink_to(DATA, target_is_directory=True)
    pipeline = tmp_path / "p.yaml"
    pipeline.write_text(PIPELINE)
    shutil.copytree(old_outputs, tmp_path / "out")
    return pipeline, tmp_path / "out" / "m.json", snapshot(tmp_path / "out")


def driver(mode, marker, pipeline, metrics, *extra):
    return subprocess.Popen([sys.executable, str(DRIVER), mode, str(marker), "run", "-q", str(pipeline),
                             "--metrics", str(metrics), *extra], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                            text=True, cwd=pipeline.parent)


def wait_for(marker: Path, proc, timeout=300.0):
    end = time.monotonic() + timeout
    while not marker.exists():
        if proc.poll() is not None:
            pytest.fail(f"the run ended ({proc.returncode}) before the fault point: {proc.stderr.read()[-2000:]}")
        if time.monotonic() > end:
            proc.kill()
            pytest.fail("the run never reached the fault point")
        time.sleep(0.02)


def temporaries(folder: Path) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if TMP_MARK in p.name)


#: the solve, then each file the run writes: the weights, the glTF's buffer and JSON, the metrics
PHASES = ["solve", "write:w.npz", "write:w.bin", "write:w.gltf", "write:m.json"]


@pytest.mark.parametrize("phase,sig,status", [(p, signal.SIGINT, 130) for p in PHASES] +
                         [(p, signal.SIGTERM, 143) for p in ("solve", "write:w.npz")])
def test_interrupt_leaves_old_outputs_and_no_temporary(work, tmp_path, phase, sig, status):
    pipeline, metrics, before = work
    marker = tmp_path / "marker"
    proc = driver(phase, marker, pipeline, metrics)
    wait_for(marker, proc)
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=120)
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert proc.returncode == status, err[-2000:]
    assert "Traceback" not in err
    assert len(lines) == 1 and len(lines[0]) <= 300 and lines[0].startswith("rigslim: interrupted"), lines
    assert snapshot(tmp_path / "out") == before          # old outputs byte-identical, nothing else


@pytest.mark.parametrize("phase", PHASES)
def test_sigkill_leaves_old_outputs_and_next_run_cleans_up(work, tmp_path, phase):
    pipeline, metrics, before = work
    out = tmp_path / "out"
    marker = tmp_path / "marker"
    proc = driver(phase, marker, pipeline, metrics)
    wait_for(marker, proc)
    proc.send_signal(signal.SIGKILL)
    proc.communicate(timeout=120)
    assert proc.returncode == -signal.SIGKILL
    after = snapshot(out)
    for name, data in before.items():           # the outputs: the old complete files
        assert after[name] == data, name
    left = temporaries(out)
    if phase.startswith("write:"):              # the write in progress left its (partial) temporary file
        assert any(name.startswith(f".{phase.split(':')[1]}{TMP_MARK}") for name in left), left
    assert sorted(after) == sorted(set(before) | set(left))
    # the next run removes what the killed one left, and writes complete new outputs
    proc = driver("none", tmp_path / "unused", pipeline, metrics)
    _, err = proc.communicate(timeout=300)
    assert proc.returncode == 0, err[-2000:]
    assert temporaries(out) == [] and sorted(p.name for p in out.iterdir()) == ["m.json", "w.bin", "w.gltf", "w.npz"]
    assert read_reduced_npz(out / "w.npz").k == 4
    doc = json.loads(metrics.read_text())
    assert doc["steps"][1]["k"] == 4 and np.isfinite(doc["evaluations"][0]["metrics"]["position_rms_pct"]["mean"])


def test_a_live_runs_temporary_files_are_kept(work, tmp_path):
    """Only files of processes that are gone are stale: a concurrent run's staged file survives."""
    pipeline, metrics, _ = work
    out = tmp_path / "out"
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(120)"])
    try:
        live = out / f".w.npz{TMP_MARK}{sleeper.pid}-0123abcd.npz"
        live.write_bytes(b"partial")
        dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True, text=True)
        stale = out / f".w.npz{TMP_MARK}{int(dead.stdout)}-89abcdef.npz"
        stale.write_bytes(b"partial")
        legacy = out / ".w.npz.u4ygsyh3.npz"          # rigslim's mkstemp names before the marker
        legacy.write_bytes(b"partial")
        old = time.time() - 3600
        os.utime(legacy, (old, old))
        proc = driver("none", tmp_path / "unused", pipeline, metrics)
        _, err = proc.communicate(timeout=300)
        assert proc.returncode == 0, err[-2000:]
        assert live.exists() and not stale.exists() and not legacy.exists()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_interrupt_while_a_fifo_output_waits_for_its_reader(work, tmp_path):
    """Writing into a FIFO blocks until someone reads it; Ctrl-C must still end the run, renaming nothing."""
    pipeline, _, before = work
    fifo = tmp_path / "pipe.json"
    os.mkfifo(fifo)
    marker = tmp_path / "marker"
    proc = driver("through", marker, pipeline, fifo)
    wait_for(marker, proc)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    assert proc.returncode == 130 and "Traceback" not in err, err[-2000:]
    assert snapshot(tmp_path / "out") == before          # w.npz was staged, and removed, not renamed
