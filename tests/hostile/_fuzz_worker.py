"""Worker process of tests/hostile/test_fuzz.py: reads cases from stdin, runs one reader per case.

Runs under ``RLIMIT_AS`` (the parent passes the limit), single-threaded
numeric libraries, and answers each case with ``("ok", None)``,
``("error", one_line)`` for a :class:`rigslim.errors.RigslimError`, or
``("crash", traceback)`` for anything else (MemoryError included). Frames
are a 4-byte little-endian length followed by a pickle.
"""

from __future__ import annotations

import os
import pickle
import resource
import struct
import sys
import tempfile
import traceback
from pathlib import Path


def _limit():
    limit = int(os.environ.get("RIGSLIM_FUZZ_RLIMIT_AS", str(2 << 30)))
    resource.setrlimit(resource.RLIMIT_AS, (limit, limit))


def _read(stream):
    head = stream.read(4)
    if len(head) < 4:
        return None
    (n,) = struct.unpack("<I", head)
    return pickle.loads(stream.read(n))


def _write(stream, obj):
    data = pickle.dumps(obj)
    stream.write(struct.pack("<I", len(data)) + data)
    stream.flush()


def run_case(kind: str, suffix: str, payload: bytes, folder: Path):
    """Run the reader ``kind`` on ``payload`` written as a file with ``suffix``."""
    path = folder / f"case{suffix}"
    path.write_bytes(payload)
    if kind == "yaml":
        from rigslim.runtime.document import load_pipeline

        load_pipeline(path)
    elif kind == "gltf":
        from rigslim.io.gltf.skin import read_gltf_skin

        skin = read_gltf_skin(path, weld=True)
        skin.mesh.edges  # noqa: B018 - the derived data a pipeline builds first
    elif kind == "usd":
        from rigslim.io.usd.read import read_usd_skin

        skin = read_usd_skin(path)
        skin.mesh.edges  # noqa: B018
    elif kind == "dmat":
        from rigslim.io.animation import stacked_to_transforms
        from rigslim.io.dmat import read_dmat

        stacked_to_transforms(read_dmat(path), source=path)
    elif kind == "tgf":
        from rigslim.io.tgf import read_tgf

        read_tgf(path)
    elif kind == "obj":
        from rigslim.io.meshfile import read_mesh

        mesh = read_mesh(path)
        if mesh.n_vertices <= 20_000:
            mesh.cotmatrix  # noqa: B018 - the Laplacian every solver builds
            mesh.massmatrix  # noqa: B018
    elif kind == "report":
        from rigslim.report import load_document, summarize

        summarize(load_document(path), str(path))
    else:
        raise ValueError(f"unknown case kind {kind!r}")


def main() -> int:
    _limit()
    from rigslim.errors import RigslimError
    from rigslim.plugin.host import get_host

    get_host()  # load the plugins once
    stdin, stdout = sys.stdin.buffer, sys.stdout.buffer
    sys.stdout = sys.stderr  # nothing but frames on the pipe
    with tempfile.TemporaryDirectory(prefix="rigslim-fuzz-") as tmp:
        folder = Path(tmp)
        _write(stdout, ("ready", None))
        while True:
            case = _read(stdin)
            if case is None:
                return 0
            try:
                run_case(*case, folder)
                answer = ("ok", None)
            except RigslimError as e:
                answer = ("error", str(e))
            except BaseException:  # noqa: BLE001 - every other exception is a finding
                answer = ("crash", traceback.format_exc(limit=12)[-4000:])
            _write(stdout, answer)


if __name__ == "__main__":
    sys.exit(main())
