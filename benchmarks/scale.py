"""Scale benchmark (issue 21 item 7): peak memory and wall time of the glTF commands on big skinned meshes.

The meshes are generated here: a tube of ``rings x segments`` quads (two triangles each) along x, bound to two
bones (a smooth 2-influence blend around the middle) and bent by a 1 s clip of 31 keys; ``--triangles`` sets the
size (default 2.6M for ``reduce`` and ``compare``, 1M for ``lod``). Each command runs as its own process
(``rigslim reduce|lod|compare``), and its peak resident set size is the kernel's ``ru_maxrss`` of that child
(``os.wait4``), so the Python interpreter, numpy temporaries and native libraries all count.

Targets (issue 21): ``reduce`` of 2.6M triangles < 4 GB; ``lod`` of 1M triangles < 8 GB; ``compare`` of
2.6M triangles < 60 s.

Usage::

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/scale.py [--quick] [--only reduce,lod,compare]

``--quick`` runs 10x smaller meshes (a smoke test of the script). Writes docs/results/scale.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402

RIGSLIM = ([str(Path(sys.executable).with_name("rigslim"))] if Path(sys.executable).with_name("rigslim").exists()
           else [sys.executable, "-m", "rigslim.cli"])
TARGETS = {"reduce": ("peak_gb", 4.0), "lod": ("peak_gb", 8.0), "compare": ("seconds", 60.0)}


def tube(triangles: int, hard: bool = False):
    """(V, F, W) of a 2-bone tube with about ``triangles`` triangles: rings along x in [0, 2], segments around;
    ``hard``: one influence per vertex (bone 1 past x = 1), what ``rigslim reduce -k 1`` makes of the smooth
    blend."""
    quads = triangles // 2
    segments = max(8, int(np.sqrt(quads / 2)))
    rings = max(2, quads // segments + 1)
    x = np.linspace(0.0, 2.0, rings)
    a = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    V = np.empty((rings * segments, 3))
    V[:, 0] = np.repeat(x, segments)
    V[:, 1] = 0.2 * np.tile(np.cos(a), rings)
    V[:, 2] = 0.2 * np.tile(np.sin(a), rings)
    r = np.arange(rings - 1)[:, None] * segments
    s = np.arange(segments)[None, :]
    p00 = (r + s).ravel()
    p01 = (r + (s + 1) % segments).ravel()
    p10, p11 = p00 + segments, p01 + segments
    F = np.concatenate([np.stack([p00, p01, p11], 1), np.stack([p00, p11, p10], 1)]).astype(np.int64)
    t = np.clip((V[:, 0] - 0.8) / 0.4, 0.0, 1.0)
    w1 = t * t * (3 - 2 * t)                       # smoothstep blend of bone 1 over x in [0.8, 1.2]
    if hard:
        w1 = (V[:, 0] > 1.0).astype(float)
    W = np.stack([1 - w1, w1], 1)
    return V, F, W


def write_tube(path: Path, triangles: int, hard: bool = False) -> dict:
    """The tube (:func:`tube`) as a skinned .glb (rigslim's exporter), bent by bone 1 about z over 31 frames."""
    import scipy.sparse as sp

    from rigslim.io.gltf.write import export_skinned
    from rigslim.io.transforms import trs_matrix
    from rigslim.model.handles import Handles
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import Poses

    V, F, W = tube(triangles, hard)
    rows = np.repeat(np.arange(len(V)), 2)
    A = sp.csr_matrix((W.ravel(), (rows, np.tile([0, 1], len(V)))), shape=(len(V), 2))
    A.eliminate_zeros()
    handles = Handles("skeleton", ["root", "tip"], joints=np.array([[0.0, 0, 0], [1.0, 0, 0], [2.0, 0, 0]]),
                      bones=np.array([[0, 1], [1, 2]]), parents=np.array([-1, 0]))
    frames = 31
    ang = 0.9 * np.sin(np.linspace(0, 2 * np.pi, frames))
    T = np.tile(np.eye(4)[:3], (frames, 2, 1, 1))
    for f, g in enumerate(ang):
        q = np.array([0.0, 0.0, np.sin(g / 2), np.cos(g / 2)])
        pivot = np.array([1.0, 0, 0])
        M = trs_matrix(pivot, q, np.ones(3)) @ trs_matrix(-pivot, np.array([0, 0, 0, 1.0]), np.ones(3))
        T[f, 1] = M[:3]
    export_skinned(path, Mesh(V, F), handles, A, Poses(T, np.arange(frames)), fps=30.0, quantize="ubyte")
    return {"vertices": int(len(V)), "triangles": int(len(F)), "bytes": path.stat().st_size}


def _compare_summary(stdout: str) -> dict | None:
    """The Hausdorff and vertex figures of ``rigslim compare --json``'s output (``None`` if it is cut short)."""
    try:
        res = json.loads(stdout.strip().splitlines()[-1])
    except (ValueError, IndexError):
        return None
    keys = ("frames", "hausdorff_frames", "hausdorff_frame_cap", "samples", "hausdorff_max_m", "hausdorff_rms_m",
            "hausdorff_max_bound_m", "position_max_m", "position_rms_m")
    return {k: res[k] for k in keys if k in res}


def run_one(cmd: list[str], timeout: float) -> dict:
    """Run ``cmd`` through a fresh helper process whose RUSAGE_CHILDREN figures are that command's alone: wall
    time, CPU time (user + system, every thread), peak RSS (GB), exit status, the output's tail and the load
    average at the start (1 min; on a shared machine wall time is about CPU time x max(1, load / cores))."""
    helper = ("import json, os, subprocess, sys, time, resource\n"
              "t0 = time.perf_counter()\n"
              "p = subprocess.run(json.loads(sys.argv[1]), capture_output=True, text=True,\n"
              "                   timeout=float(sys.argv[2]))\n"
              "ru = resource.getrusage(resource.RUSAGE_CHILDREN)\n"
              "print(json.dumps({'rc': p.returncode, 'seconds': time.perf_counter() - t0,\n"
              "                  'cpu_s': ru.ru_utime + ru.ru_stime,\n"
              "                  'peak_gb': ru.ru_maxrss * 1024 / 1e9, 'stdout': p.stdout[-4000:],\n"
              "                  'stderr': p.stderr[-600:]}))\n")
    load = os.getloadavg()[0]
    t0 = time.perf_counter()
    try:
        p = subprocess.run([sys.executable, "-c", helper, json.dumps(cmd), str(timeout)], capture_output=True,
                           text=True, timeout=timeout + 60)
    except subprocess.TimeoutExpired:
        return {"status": "timeout", "seconds": time.perf_counter() - t0, "peak_gb": None, "load_start": load}
    if p.returncode != 0:
        return {"status": "timeout" if "TimeoutExpired" in p.stderr else "error", "peak_gb": None,
                "seconds": time.perf_counter() - t0, "tail": p.stderr[-600:], "load_start": load}
    r = json.loads(p.stdout)
    return {"status": "ok" if r["rc"] == 0 else f"exit {r['rc']}", "seconds": r["seconds"], "cpu_s": r["cpu_s"],
            "peak_gb": r["peak_gb"], "stdout": r["stdout"], "tail": r["stderr"], "load_start": load}


def markdown(doc: dict) -> str:
    """docs/results/scale.md from the results document."""
    md = ["# Scale: the glTF commands on big skinned meshes", "",
          "Generated by `benchmarks/scale.py` (a 2-bone tube; each command a process of its own, peak RSS = the "
          "child's ru_maxrss, CPU = its user + system time, every thread). `--only` re-runs some commands and keeps "
          "the other rows; the load average (1 min, 2 cores) is the one at each command's start (`end`: at the end "
          "of an earlier whole run): with the machine shared, wall time is about CPU time x max(1, load / cores).",
          "", f"Machine: {doc['machine']}.", "",
          "| command | triangles | vertices | status | wall s | CPU s | load | peak GB | target | met |",
          "|---|---|---|---|---|---|---|---|---|---|"]
    for r in doc["rows"]:
        cpu = "" if r.get("cpu_s") is None else f"{r['cpu_s']:.1f}"
        load = (f"{r['load_start']:.1f}" if r.get("load_start") is not None
                else f"{r['load_end']:.1f} (end)" if r.get("load_end") is not None else "")
        md.append(f"| {r['command']} | {r['triangles']:,} | {r['vertices']:,} | {r['status']} | {r['seconds']:.1f} | "
                  f"{cpu} | {load} | {r['peak_gb'] if r['peak_gb'] is None else round(r['peak_gb'], 2)} | "
                  f"{r['target']} | {'yes' if r['met'] else 'no'} |")
    for r in doc["rows"]:
        c = r.get("compare")
        if c:
            bound = (f"; vertex to vertex on every frame: max {c['position_max_m']:.4g} m (the bound on every "
                     f"frame's Hausdorff max), RMS {c['position_rms_m']:.4g} m" if "position_max_m" in c else "")
            md += ["", f"compare (the tube against a one-influence copy, same topology): Hausdorff on "
                   f"{len(c['hausdorff_frames'])} of {len(c['frames'])} frames "
                   f"({', '.join(map(str, c['hausdorff_frames']))}; cap {c['hausdorff_frame_cap']}, every vertex "
                   f"and {c['samples']} face samples per direction), max {c['hausdorff_max_m']:.4g} m, RMS "
                   f"{c['hausdorff_rms_m']:.4g} m{bound}."]
    return "\n".join(md) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="10x smaller meshes")
    ap.add_argument("--only", default="reduce,lod,compare")
    ap.add_argument("--timeout", type=float, default=3600.0)
    args = ap.parse_args()
    div = 10 if args.quick else 1
    only = args.only.split(",")
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigslim-scale-") as tmp:
        tmp = Path(tmp)
        big = tmp / "tube-2.6M.glb"
        mid = tmp / "tube-1M.glb"
        sizes = {}
        if {"reduce", "compare"} & set(only):
            sizes["big"] = write_tube(big, 2_600_000 // div)
        if "lod" in only:
            sizes["mid"] = write_tube(mid, 1_000_000 // div)
        jobs = {
            "reduce": (big, RIGSLIM + ["reduce", str(big), "-o", str(tmp / "reduced.glb"), "-k", "1"]),
            "lod": (mid, RIGSLIM + ["lod", str(mid), "-o", str(tmp / "lod.glb"), "--ratios", "0.5,0.25"]),
            "compare": (big, RIGSLIM + ["compare", str(big), str(tmp / "reduced.glb"), "--json"]),
        }
        for name in ("reduce", "lod", "compare"):
            if name not in only:
                continue
            src, cmd = jobs[name]
            if name == "compare" and not (tmp / "reduced.glb").exists():   # --only compare: no reduce output
                write_tube(tmp / "reduced.glb", 2_600_000 // div, hard=True)
            print(f"{name}: {' '.join(cmd[len(RIGSLIM):])}", flush=True)
            r = run_one(cmd, args.timeout)
            key, limit = TARGETS[name]
            size = sizes["mid" if name == "lod" else "big"]
            row = {"command": name, **size, **r, "target": f"{key} < {limit:g}" + ("" if div == 1 else " (full size)"),
                   "met": bool(r["status"] == "ok" and r.get(key) is not None and r[key] < limit),
                   "date": time.strftime("%Y-%m-%d %H:%M UTC", time.gmtime())}
            if name == "compare" and r["status"] == "ok":
                row["compare"] = _compare_summary(r["stdout"])
            rows.append(row)
            print(f"  {r['status']}: {r['seconds']:.1f} s wall, {r.get('cpu_s', float('nan')):.1f} s CPU, "
                  f"load {r['load_start']:.1f} at the start, peak {r['peak_gb'] or float('nan'):.2f} GB "
                  f"({size['triangles']:,} triangles); target {row['target']}: "
                  f"{'met' if row['met'] else 'missed'}", flush=True)
            if r["status"] != "ok":
                print("  " + (r.get("tail") or "")[-400:].replace("\n", "\n  "), flush=True)
    stem = ROOT / "docs" / "results" / "scale"
    if not args.quick and stem.with_suffix(".json").exists():     # keep the rows of the commands not run now
        before = json.loads(stem.with_suffix(".json").read_text())
        kept = [r for r in before.get("rows", []) if r["command"] not in only]
        for r in kept:          # rows of a run before CPU and load were kept per row: that run's load at its end
            if "load_start" not in r and "load_end" not in r and before.get("loadavg"):
                r["load_end"] = before["loadavg"][0]
        rows = sorted(kept + rows, key=lambda r: ("reduce", "lod", "compare").index(r["command"]))
    doc = {"machine": machine(), "quick": args.quick, "loadavg": os.getloadavg(), "rows": rows}
    md = markdown(doc)
    if not args.quick:
        write_results(stem, doc, md)
    else:
        print(md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
