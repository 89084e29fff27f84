"""The LOD benchmark's peers: gltfpack (meshoptimizer) and glTF-Transform's ``simplify``, run at a ratio.

Both are npm packages pinned by ``tools/setup-testmodels.sh`` into tools/node/:

- **gltfpack** 1.3: ``gltfpack -i IN -o OUT -si R -sa -noq`` (simplify to ratio
  R of the triangles, ``-sa`` aggressive: ignore the error limit and topology
  restrictions so that R is reached; ``-noq`` no quantisation, so that
  rigslim's reader and ``rigslim compare`` read the result as they read the
  input). ``aggressive=False`` drops ``-sa`` (gltfpack then stops at its
  error bound, ``-se``, default 1 %);
- **glTF-Transform** 4.5: ``gltf-transform weld IN W`` then
  ``gltf-transform simplify W OUT --ratio R --error E`` (meshoptimizer's
  simplifier too; ``--error`` is a fraction of the mesh radius, default here
  1 = unbounded, so that R is reached; welding first lets it collapse across
  split vertices, as its documentation advises).

Each call returns a :class:`PeerResult`: output path, wall seconds of the
tool's process(es), the faces of the written file, the commands. The faces
a peer reaches differ from ``R * faces`` (each stops where its own rules
allow); :func:`at_faces` searches the ratio so that a peer lands within a
tolerance of a given face count, for comparisons at equal face counts.

Example
-------
>>> from benchmarks.peers import available, gltfpack, gltf_transform
>>> r = gltfpack("in.glb", "out.glb", 0.25)          # doctest: +SKIP
>>> r.faces, r.seconds                                 # doctest: +SKIP
"""

from __future__ import annotations

import json
import shutil
import struct
import subprocess
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NODE = ROOT / "tools" / "node" / "node_modules"
GLTFPACK = NODE / "gltfpack" / "cli.js"
GLTF_TRANSFORM = NODE / "@gltf-transform" / "cli" / "bin" / "cli.js"


class PeerError(RuntimeError):
    """A peer is not installed, or it failed (the message has its stderr's last lines)."""


@dataclass
class PeerResult:
    """One peer run: ``path`` written, ``seconds`` of wall time, ``faces`` in it, ``commands`` run."""

    tool: str
    ratio: float
    path: Path
    seconds: float
    faces: int
    commands: list = field(default_factory=list)


def _node(script: Path) -> list[str]:
    node = shutil.which("node")
    if node is None:
        raise PeerError("node is not on PATH (apt-get install nodejs)")
    if not script.exists():
        raise PeerError(f"{script} is missing: run tools/setup-testmodels.sh")
    return [node, str(script)]


def available() -> dict:
    """``{"gltfpack": bool, "gltf-transform": bool}``: which peers are installed."""
    return {"gltfpack": GLTFPACK.exists() and shutil.which("node") is not None,
            "gltf-transform": GLTF_TRANSFORM.exists() and shutil.which("node") is not None}


def versions() -> dict:
    """Installed versions, read from the npm packages' package.json (None when missing)."""
    out = {}
    for name, pkg in (("gltfpack", NODE / "gltfpack" / "package.json"),
                      ("gltf-transform", NODE / "@gltf-transform" / "cli" / "package.json")):
        out[name] = json.loads(pkg.read_text())["version"] if pkg.exists() else None
    return out


def _run(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    secs = time.perf_counter() - t0
    if p.returncode != 0:
        tail = "\n".join((p.stderr or p.stdout).strip().splitlines()[-5:])
        raise PeerError(f"{Path(cmd[1]).parent.name}: exit {p.returncode}: {' '.join(cmd[2:])}\n{tail}")
    return secs


def count_faces(path) -> int:
    """Triangles in a .glb: index count / 3 (or vertex count / 3) summed over every mesh primitive."""
    raw = Path(path).read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + n])
    total = 0
    for mesh in doc.get("meshes", []):
        for p in mesh["primitives"]:
            if p.get("mode", 4) != 4:
                continue
            acc = p["indices"] if "indices" in p else p["attributes"]["POSITION"]
            total += doc["accessors"][acc]["count"] // 3
    return total


def gltfpack(src, dst, ratio: float, *, aggressive: bool = True, error: float | None = None,
             extra: tuple = ()) -> PeerResult:
    """``gltfpack -i SRC -o DST -si RATIO [-sa] [-se ERROR] -noq``."""
    cmd = _node(GLTFPACK) + ["-i", str(src), "-o", str(dst), "-si", f"{ratio:g}", "-noq"]
    if aggressive:
        cmd.append("-sa")
    if error is not None:
        cmd += ["-se", f"{error:g}"]
    cmd += list(extra)
    secs = _run(cmd)
    return PeerResult("gltfpack", ratio, Path(dst), secs, count_faces(dst), [cmd])


def gltf_transform(src, dst, ratio: float, *, error: float = 1.0, weld: bool = True,
                   lock_border: bool = False) -> PeerResult:
    """``gltf-transform weld`` then ``simplify --ratio RATIO --error ERROR`` (``--lock-border`` optional)."""
    dst = Path(dst)
    base = _node(GLTF_TRANSFORM)
    cmds, secs = [], 0.0
    with tempfile.TemporaryDirectory(prefix="rigslim-peer-") as tmp:
        source = Path(src)
        if weld:
            welded = Path(tmp) / "welded.glb"
            cmds.append(base + ["weld", str(source), str(welded)])
            secs += _run(cmds[-1])
            source = welded
        cmd = base + ["simplify", str(source), str(dst), "--ratio", f"{ratio:g}", "--error", f"{error:g}"]
        if lock_border:
            cmd += ["--lock-border", "true"]
        cmds.append(cmd)
        secs += _run(cmd)
    return PeerResult("gltf-transform", ratio, dst, secs, count_faces(dst), cmds)


PEERS = {"gltfpack": gltfpack, "gltf-transform": gltf_transform}


def run_peers(src, folder, ratio: float, tools=("gltfpack", "gltf-transform")) -> dict:
    """Every installed peer at ``ratio``: ``{tool: PeerResult}``, files ``folder/STEM-TOOL-RATIO.glb``."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    have = available()
    out = {}
    for tool in tools:
        if have.get(tool):
            out[tool] = PEERS[tool](src, folder / f"{Path(src).stem}-{tool}-{ratio:g}.glb", ratio)
    return out


def at_faces(tool: str, src, dst, faces: int, *, tolerance: float = 0.03, steps: int = 8, **kwargs) -> PeerResult:
    """Run ``tool`` with the ratio that lands within ``tolerance`` of ``faces`` (bisection on the ratio).

    Returns the closest result found after at most ``steps`` runs (check
    ``abs(r.faces - faces) <= tolerance * faces`` when it matters).
    """
    total = count_faces(src)
    lo, hi = 0.0, 1.0
    ratio = min(1.0, faces / max(total, 1))
    best = None
    for _ in range(steps):
        r = PEERS[tool](src, dst, ratio, **kwargs)
        if best is None or abs(r.faces - faces) < abs(best.faces - faces):
            best = r
            shutil.copy(dst, Path(dst).with_suffix(".best.glb"))
        if abs(r.faces - faces) <= tolerance * faces:
            break
        if r.faces > faces:
            hi = ratio
        else:
            lo = ratio
        ratio = (lo + hi) / 2
    best_file = Path(dst).with_suffix(".best.glb")
    if best_file.exists():
        shutil.move(best_file, dst)
    best.path = Path(dst)
    return best
