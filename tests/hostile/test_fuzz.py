"""Fuzzing the readers of untrusted files (hypothesis, derandomized, about a minute in all).

Inputs are mutations of the bundled data: pipelines from examples/,
the .glb/.gltf characters (truncated, bytes flipped, JSON fields replaced by
hostile values such as -1, 2**31, "10", true, null, huge strings), DMAT,
TGF, OBJ, OFF, PLY and MEDIT files (with their Laplacian) and a metrics JSON. The property: every input either reads
or raises rigslim's own error with a one-line message of at most
:data:`rigslim.errors.MAX_LINE` characters.

Each case runs in a worker process under ``RLIMIT_AS`` = 2 GiB with a
per-case timeout, so a hang or a memory blow-up fails the test (the worker
is restarted after one) instead of stalling the machine.
"""

from __future__ import annotations

import json
import os
import pickle
import select
import struct
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from rigslim.errors import MAX_LINE

ROOT = Path(__file__).resolve().parents[2]
DATA = ROOT / "examples" / "data"
WORKER = Path(__file__).with_name("_fuzz_worker.py")
#: Seconds one case may take in the worker (a bound for hangs, not a speed target).
CASE_TIMEOUT = 30.0
MEMORY_LIMIT = 2 << 30

#: ``RIGSLIM_FUZZ_SCALE=20`` multiplies every test's examples for a longer exploratory run;
#: ``RIGSLIM_FUZZ_RANDOM=1`` draws new cases instead of CI's fixed (derandomized) sequence.
SCALE = float(os.environ.get("RIGSLIM_FUZZ_SCALE", "1"))
FUZZ = settings(max_examples=100, deadline=None, derandomize=not os.environ.get("RIGSLIM_FUZZ_RANDOM"),
                database=None, print_blob=True,
                suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large,
                                       HealthCheck.function_scoped_fixture])


def examples(n: int) -> settings:
    """The suite's settings with ``n`` examples (times RIGSLIM_FUZZ_SCALE)."""
    return settings(FUZZ, max_examples=max(1, int(n * SCALE)))


class Worker:
    """A long-lived reader process; restarted when a case kills it or runs past the timeout."""

    def __init__(self):
        self.proc = None

    def start(self):
        env = dict(os.environ, RIGSLIM_FUZZ_RLIMIT_AS=str(MEMORY_LIMIT), OMP_NUM_THREADS="1",
                   OPENBLAS_NUM_THREADS="1", MKL_NUM_THREADS="1", NUMBA_NUM_THREADS="1",
                   PYTHONPATH=os.pathsep.join([str(ROOT), os.environ.get("PYTHONPATH", "")]))
        self.proc = subprocess.Popen([sys.executable, str(WORKER)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                     stderr=subprocess.DEVNULL, env=env)
        ready = self._receive(120.0)
        assert ready == ("ready", None), ready

    def stop(self):
        if self.proc is not None:
            self.proc.kill()
            self.proc.wait()
            self.proc = None

    def _receive(self, timeout):
        out = self.proc.stdout
        ready, _, _ = select.select([out], [], [], timeout)
        if not ready:
            return None
        head = out.read(4)
        if len(head) < 4:
            return ("died", f"worker exited with status {self.proc.wait()}")
        (n,) = struct.unpack("<I", head)
        return pickle.loads(out.read(n))

    def run(self, kind: str, suffix: str, payload: bytes):
        if self.proc is None or self.proc.poll() is not None:
            self.start()
        data = pickle.dumps((kind, suffix, payload))
        self.proc.stdin.write(struct.pack("<I", len(data)) + data)
        self.proc.stdin.flush()
        answer = self._receive(CASE_TIMEOUT)
        if answer is None:
            self.stop()
            return ("timeout", f"no answer within {CASE_TIMEOUT} s")
        if answer[0] == "died":
            self.stop()
        return answer


@pytest.fixture(scope="module")
def worker():
    w = Worker()
    yield w
    w.stop()


def check(worker: Worker, kind: str, suffix: str, payload: bytes):
    """The property: the reader succeeds or raises a RigslimError with one short line."""
    status, detail = worker.run(kind, suffix, payload)
    if status not in ("ok", "error"):
        import hashlib
        import tempfile

        keep = Path(os.environ.get("RIGSLIM_FUZZ_FAILURES", Path(tempfile.gettempdir()) / "rigslim-fuzz-failures"))
        keep.mkdir(parents=True, exist_ok=True)
        saved = keep / f"{kind}-{hashlib.sha1(payload).hexdigest()[:12]}{suffix}"
        saved.write_bytes(payload)
        pytest.fail(f"{kind} case ({len(payload)} bytes, saved as {saved}) gave {status}:\n{detail}")
    if status == "error":
        assert "\n" not in detail and len(detail) <= MAX_LINE, f"not one short line: {detail[:600]!r}"


# --------------------------------------------------------------------------- mutation strategies

HOSTILE = [-1, 0, 1, 2 ** 31, 2 ** 32 + 1, 2 ** 63, -2 ** 63, 10 ** 30, "10", "", "x" * 5000, True, False, None,
           [], {}, [[[[[[]]]]]], 1e308, -1e308, 2.5, [0] * 50, {"a": {"b": {"c": []}}}, "data:;base64,@@",
           "../../etc/passwd", "/dev/zero", 5126, "MAT4", "CUBICSPLINE"]


def _paths(obj, prefix=()):
    """Every (path) into a JSON value, containers included."""
    yield prefix
    if isinstance(obj, dict):
        for k, v in obj.items():
            yield from _paths(v, prefix + (k,))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            yield from _paths(v, prefix + (i,))


def _mutate_json(doc, path, action, value):
    doc = json.loads(json.dumps(doc))
    if not path:
        return value if action == "replace" else doc
    parent = doc
    for p in path[:-1]:
        parent = parent[p]
    key = path[-1]
    if action == "delete":
        del parent[key]
    elif action == "duplicate" and isinstance(parent, list):
        parent.insert(key, parent[key])
    else:
        parent[key] = value
    return doc


@st.composite
def json_mutations(draw, doc, rounds=3):
    """1..rounds field mutations of a JSON document."""
    for _ in range(draw(st.integers(1, rounds))):
        paths = list(_paths(doc))
        path = paths[draw(st.integers(0, len(paths) - 1))]
        action = draw(st.sampled_from(["replace", "replace", "replace", "delete", "duplicate"]))
        doc = _mutate_json(doc, path, action, draw(st.sampled_from(HOSTILE)))
    return doc


@st.composite
def byte_mutations(draw, data: bytes):
    """Truncation, flipped bytes, inserted or deleted spans."""
    data = bytearray(data)
    for _ in range(draw(st.integers(1, 4))):
        op = draw(st.sampled_from(["truncate", "flip", "flip", "insert", "delete"]))
        at = draw(st.integers(0, max(len(data) - 1, 0)))
        if op == "truncate":
            del data[at:]
        elif op == "flip" and data:
            data[at] = draw(st.integers(0, 255))
        elif op == "insert":
            data[at:at] = draw(st.binary(min_size=1, max_size=64))
        elif op == "delete":
            del data[at:at + draw(st.integers(1, 64))]
    return bytes(data)


def _glb_parts(path: Path):
    data = path.read_bytes()
    jlen = struct.unpack_from("<I", data, 12)[0]
    doc = json.loads(data[20:20 + jlen])
    return doc, data[20 + jlen:]


def _glb(doc, rest: bytes) -> bytes:
    js = json.dumps(doc).encode()
    js += b" " * (-len(js) % 4)
    body = struct.pack("<II", len(js), 0x4E4F534A) + js + rest
    return struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body


# --------------------------------------------------------------------------- the readers

GLB = {name: _glb_parts(DATA / "gltf" / name) for name in ("huesitos.glb", "animation_with_skeleton.glb")}
GLTF = json.loads((DATA / "gltf" / "simple_skin.gltf").read_text())
PIPELINES = sorted((ROOT / "examples").glob("*.yaml"))


def test_worker_reads_the_untouched_files(worker):
    """The seeds themselves read (so mutations are measured against working inputs)."""
    for name in GLB:
        assert worker.run("gltf", ".glb", (DATA / "gltf" / name).read_bytes())[0] == "ok"
    assert worker.run("gltf", ".gltf", json.dumps(GLTF).encode())[0] == "ok"
    assert worker.run("tgf", ".tgf", (DATA / "cheburashka.tgf").read_bytes())[0] == "ok"
    assert worker.run("obj", ".obj", (DATA / "armadillo-cage.obj").read_bytes())[0] == "ok"
    assert worker.run("obj", ".off", OFF)[0] == "ok"
    assert worker.run("obj", ".mesh", MEDIT)[0] == "ok"
    assert worker.run("obj", ".ply", PLY[False])[0] == "ok" and worker.run("obj", ".ply", PLY[True])[0] == "ok"
    assert worker.run("dmat", ".dmat", (DATA / "cheburashka-anim.dmat").read_bytes())[0] == "ok"
    for p in PIPELINES:
        assert worker.run("yaml", ".yaml", p.read_bytes())[0] == "ok", p


@examples(250)
@given(data=st.data())
def test_gltf_json_fields(worker, data):
    name = data.draw(st.sampled_from(sorted(GLB) + ["simple_skin.gltf"]))
    if name.endswith(".glb"):
        doc, rest = GLB[name]
        check(worker, "gltf", ".glb", _glb(data.draw(json_mutations(doc)), rest))
    else:
        check(worker, "gltf", ".gltf", json.dumps(data.draw(json_mutations(GLTF))).encode())


@examples(150)
@given(data=st.data())
def test_gltf_bytes(worker, data):
    name = data.draw(st.sampled_from(["huesitos.glb", "simple_skin.gltf"]))
    check(worker, "gltf", Path(name).suffix, data.draw(byte_mutations((DATA / "gltf" / name).read_bytes())))


HUGE = [2 ** 31, 2 ** 32 - 1, 2 ** 40, 10 ** 9]


@examples(60)
@given(data=st.data())
def test_gltf_huge_counts(worker, data):
    doc, rest = GLB["huesitos.glb"]
    doc = json.loads(json.dumps(doc))
    section = data.draw(st.sampled_from(["accessors", "bufferViews", "buffers"]))
    i = data.draw(st.integers(0, len(doc[section]) - 1))
    key = {"accessors": "count", "bufferViews": "byteLength", "buffers": "byteLength"}[section]
    doc[section][i][key] = data.draw(st.sampled_from(HUGE))
    if section == "accessors" and data.draw(st.booleans()):
        doc[section][i].pop("bufferView", None)
    check(worker, "gltf", ".glb", _glb(doc, rest))


YAML_SNIPPETS = ["&a [*a]", "*undefined", "!!python/object/apply:os.system [ls]", "{", "[" * 200, "true", "1e9999",
                 "- - - -", "k: 1\nk: 2", "\t", "'unterminated", "? complex\n: key", "!!binary AAAA", "null", "~",
                 "steps: []", "- evaluate: {position-rms: [1, 2]}", "- select: k-largest\n  k: true"]


@st.composite
def yaml_mutations(draw):
    lines = PIPELINES[draw(st.integers(0, len(PIPELINES) - 1))].read_text().splitlines()
    for _ in range(draw(st.integers(1, 3))):
        at = draw(st.integers(0, len(lines)))
        op = draw(st.sampled_from(["insert", "replace", "delete", "duplicate"]))
        if op == "insert":
            lines.insert(at, draw(st.sampled_from(YAML_SNIPPETS)))
        elif lines and at < len(lines):
            if op == "replace":
                head = lines[at].split(":")[0]
                lines[at] = f"{head}: {draw(st.sampled_from(YAML_SNIPPETS))}"
            elif op == "delete":
                del lines[at]
            else:
                lines.insert(at, lines[at])
    return "\n".join(lines).encode()


@examples(300)
@given(data=st.data())
def test_yaml_pipelines(worker, data):
    if data.draw(st.booleans()):
        payload = data.draw(yaml_mutations())
    else:
        payload = data.draw(byte_mutations(PIPELINES[data.draw(st.integers(0, len(PIPELINES) - 1))].read_bytes()))
    check(worker, "yaml", ".yaml", payload)


def _small_dmat(binary: bool) -> bytes:
    """A 24 x 3 DMAT (two stacked bone transforms), binary or ASCII."""
    import tempfile

    import numpy as np

    from rigslim.io.dmat import write_dmat

    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "seed.dmat"
        write_dmat(out, np.arange(24 * 3, dtype=float).reshape(24, 3) / 7.0, binary=binary)
        return out.read_bytes()


@examples(200)
@given(data=st.data())
def test_dmat(worker, data):
    binary = data.draw(st.booleans())
    seed = _small_dmat(binary)
    if data.draw(st.booleans()):  # a header that promises more (or less) than the body holds
        rows = data.draw(st.sampled_from([0, 1, 12, 2 ** 31, 2 ** 62, -3]))
        lines = seed.split(b"\n", 2)
        at = 1 if binary else 0
        lines[at] = f"3 {rows}".encode()
        seed = b"\n".join(lines)
    check(worker, "dmat", ".dmat", data.draw(byte_mutations(seed)))


@examples(200)
@given(data=st.data())
def test_tgf(worker, data):
    seed = (DATA / "cheburashka.tgf").read_bytes()
    if data.draw(st.booleans()):
        lines = seed.decode().splitlines()
        bones = [i for i, line in enumerate(lines) if len(line.split()) == 2 or (len(line.split()) > 2 and
                                                                                   "." not in line)]
        if bones:
            i = data.draw(st.sampled_from(bones))
            a = data.draw(st.integers(-2, 20))
            b = data.draw(st.integers(-2, 20))
            lines[i] = f"{a} {b}"
        seed = "\n".join(lines).encode()
    check(worker, "tgf", ".tgf", data.draw(byte_mutations(seed)))


def _off_seed() -> bytes:
    """The armadillo cage (110 vertices) as OFF text."""
    lines = (DATA / "armadillo-cage.obj").read_text().splitlines()
    V = [line.split()[1:4] for line in lines if line.startswith("v ")]
    F = [[str(int(t.split("/")[0]) - 1) for t in line.split()[1:]] for line in lines if line.startswith("f ")]
    return ("OFF\n" + f"{len(V)} {len(F)} 0\n" + "".join(" ".join(v) + "\n" for v in V)
            + "".join(f"{len(f)} " + " ".join(f) + "\n" for f in F)).encode()


OFF = _off_seed()


@examples(150)
@given(data=st.data())
def test_obj(worker, data):
    check(worker, "obj", ".obj", data.draw(byte_mutations((DATA / "armadillo-cage.obj").read_bytes())))


@examples(150)
@given(data=st.data())
def test_off(worker, data):
    check(worker, "obj", ".off", data.draw(byte_mutations(OFF)))


def _ply_seeds() -> dict[bool, bytes]:
    """The armadillo cage as ASCII and binary PLY."""
    import tempfile

    import igl

    V, F = igl.read_triangle_mesh(str(DATA / "armadillo-cage.obj"))
    seeds = {}
    with tempfile.TemporaryDirectory() as tmp:
        for binary in (False, True):
            out = Path(tmp) / f"seed{int(binary)}.ply"
            igl.write_triangle_mesh(str(out), V, F, igl.FileEncoding.Binary if binary else igl.FileEncoding.Ascii)
            seeds[binary] = out.read_bytes()
    return seeds


PLY = _ply_seeds()
MEDIT = b"""MeshVersionFormatted 1
Dimension 3
Vertices
5
0 0 0 0
1 0 0 0
0 1 0 0
0 0 1 0
1 1 1 0
Tetrahedra
2
1 2 3 4 0
2 3 4 5 0
End
"""


@examples(100)
@given(data=st.data())
def test_medit(worker, data):
    check(worker, "obj", ".mesh", data.draw(byte_mutations(MEDIT)))


@examples(150)
@given(data=st.data())
def test_ply(worker, data):
    check(worker, "obj", ".ply", data.draw(byte_mutations(PLY[data.draw(st.booleans())])))


REPORT = {"name": "fuzz", "steps": [{"stage": "read", "plugin": "inputs", "seconds": 0.1},
                                    {"stage": "select", "plugin": "k-largest", "k": 2, "seconds": 0.0},
                                    {"stage": "solve", "plugin": "poisson", "k": 2, "seconds": 1.5},
                                    {"stage": "evaluate", "plugin": "metrics", "seconds": 0.2}],
          "frames": {"examples": [0, 2], "test": [1, 3]},
          "evaluations": [{"name": "poisson-k2", "step": 3,
                           "metrics": {"position_rms_pct": {"mean": 1.5, "max": 2.0, "per_frame": [1.0, 2.0]},
                                       "max_influences": 2, "mean_influences": 1.9},
                           "influence_histogram": {"input": [0, 3, 7], "reduced": [0, 1, 9]}}]}


@examples(300)
@given(data=st.data())
def test_report_json(worker, data):
    if data.draw(st.booleans()):
        payload = json.dumps(data.draw(json_mutations(REPORT))).encode()
    else:
        payload = data.draw(byte_mutations(json.dumps(REPORT).encode()))
    check(worker, "report", ".json", payload)
