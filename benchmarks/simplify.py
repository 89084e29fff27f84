"""Articulated simplification benchmark: [S09] quartic against Mohr-Gleicher, DeCoro-Rusinkiewicz and static QSlim.

For each model (the elephant, 12k triangles, real animation; the elephant
subdivided twice, ~193k triangles; the armadillo, 86k triangles, 5 handles,
generated poses) and each method, builds the whole hierarchy down to 70
faces (static QSlim: nested pymeshlab runs at every target down to 70),
times it, and measures the Metro distance (two-sided, pymeshlab) between
each simplified level deformed by its own weights and the original mesh
deformed by the input weights, on test poses never used for fitting.

Usage::

    .venv/bin/python benchmarks/simplify.py            # everything (long)
    .venv/bin/python benchmarks/simplify.py --quick    # the 12k elephant only

Writes docs/results/simplify.{json,md,png}.
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import DATA, cpu_model, elephant, write_results  # noqa: E402

METHODS = ["quartic", "mohr-gleicher", "decoro-rusinkiewicz", "static-qslim"]
FRACTIONS = [0.2, 0.1, 0.05, 0.02, 0.01]
OUT = ROOT / "docs" / "results"


def armadillo(n_frames: int = 80, seed: int = 7, amplitude: tuple[float, float] = (20.0, 40.0)):
    """The armadillo with its 5-handle weights and a generated animation.

    Each handle rotates about its weighted centroid, around a fixed random
    axis, by ``A sin(2 pi f t / n + phi)`` with A uniform in ``amplitude``
    degrees (default [20, 40]; the ``armadillo-86k-wide`` dataset uses
    [60, 90]) and one
    or two cycles over the clip; frame t uses the same formula, so example
    frames ``0:80:8`` and test frames ``4:80:8`` are disjoint samples of one
    smooth motion.
    """
    from rigslim.io import read_dmat, read_mesh
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit, Poses
    from rigslim.model.weights import validate_weights

    mesh = read_mesh(DATA / "armadillo.obj")
    W = validate_weights(read_dmat(DATA / "armadillo-weights.dmat"), mesh.n_vertices, normalize=True)
    Wd = W.toarray()
    n = Wd.shape[1]
    centres = (Wd ** 2).T @ mesh.V / (Wd ** 2).sum(axis=0)[:, None]
    rng = np.random.default_rng(seed)
    axes = rng.normal(size=(n, 3))
    axes /= np.linalg.norm(axes, axis=1, keepdims=True)
    amp = np.radians(rng.uniform(*amplitude, n))
    freq = rng.integers(1, 3, n)
    phase = rng.uniform(0, 2 * np.pi, n)
    T = np.zeros((n_frames, n, 3, 4))
    for t in range(n_frames):
        for i in range(n):
            th = amp[i] * np.sin(2 * np.pi * freq[i] * t / n_frames + phase[i])
            k = axes[i]
            Kx = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
            R = np.eye(3) + np.sin(th) * Kx + (1 - np.cos(th)) * Kx @ Kx
            T[t, i, :, :3] = R
            T[t, i, :, 3] = centres[i] - R @ centres[i]
    poses = Poses(T, source="generated armadillo poses")
    split = FrameSplit.from_specs("0:80:8", "4:80:8", n_frames)
    return Asset(mesh=mesh, weights=W, poses=poses, split=split,
                 provenance={"inputs": {"mesh": "armadillo.obj", "poses": "generated"}})


def warm_up(backend: str) -> float:
    """Compile (or load from numba's disk cache) the decimation kernels on a small mesh; returns the seconds.

    The timed runs then measure the simplification, not the one-off compilation.
    """
    import igl
    import scipy.sparse as sp

    from rigslim.model.asset import Asset
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import FrameSplit, Poses
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    V = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], float)
    F = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(V, F, 2)
    W = np.stack([1.0 + V[:, 2], 1.0 - V[:, 2]], axis=1) + 0.1
    W /= W.sum(axis=1, keepdims=True)
    T = np.zeros((4, 2, 3, 4))
    T[:, :, :, :3] = np.eye(3)
    T[:, 1, 0, 3] = np.arange(4) * 0.1
    asset = Asset(mesh=Mesh(V, F), weights=sp.csr_matrix(W), poses=Poses(T),
                  split=FrameSplit.from_specs([0, 2], [1, 3], 4))
    t0 = time.perf_counter()
    for method in ("quartic", "mohr-gleicher", "decoro-rusinkiewicz"):
        plugin = get_host().get("articulated-decimation", method)
        plugin.apply(asset, plugin.parse_params({"min_faces": 40, "backend": backend}), StepContext())
    return time.perf_counter() - t0


def run_method(asset, method: str, min_faces: int, max_bones, test_stride: int, samples: int,
               backend: str = "numba"):
    from rigslim.numerics.surface_distance import metro_distance
    from rigslim.plugin import StepContext
    from rigslim.plugin.evaluation import Evaluation
    from rigslim.plugin.host import get_host

    host = get_host()
    plugin = host.get("articulated-decimation", method)
    raw = {"targets": FRACTIONS + ([min_faces] if method == "static-qslim" else []), "max_bones": max_bones}
    if method != "static-qslim":
        raw["min_faces"] = min_faces
        raw["backend"] = backend
    asset.extras.clear()
    ctx = StepContext()
    t0 = time.perf_counter()
    plugin.apply(asset, plugin.parse_params(raw), ctx)
    seconds = time.perf_counter() - t0
    ev = Evaluation(asset, host)
    frames = list(range(0, len(ev), test_stride))
    scale = 100.0 / asset.mesh.bbox_diagonal
    levels = []
    for i, lv in enumerate(ev.levels):
        rms, mx = [], []
        for j in frames:
            d = metro_distance(ev.level_positions(i, j), lv.mesh.F, ev.full_positions(j), asset.mesh.F, samples)
            rms.append(scale * d["rms"])
            mx.append(scale * d["max"])
        levels.append({"label": lv.label, "faces": lv.n_faces, "vertices": lv.n_vertices,
                       "max_bones": int(lv.weights.influence_counts().max()),
                       "rms_pct_mean": float(np.mean(rms)), "max_pct_mean": float(np.mean(mx)),
                       "max_pct_max": float(np.max(mx))})
    final = ctx.report.get("final_faces", min(lv["faces"] for lv in levels))
    return {"method": method, "seconds": seconds, "final_faces": final, "levels": levels,
            "backend": backend if method != "static-qslim" else None,
            "test_frames": [ev.frames[j] for j in frames]}


def gltfpack_comparison(gltfpack: str, samples: int, ratios=(0.1, 0.02)):
    """gltfpack (meshoptimizer) against quartic and static QSlim at gltfpack's face counts, 4 bones per vertex.

    The elephant is exported as a skinned glTF (4 weights per vertex, the glTF
    norm) and simplified with ``gltfpack -si RATIO -sa -noq`` (aggressive, so
    that it gets near the ratio; no quantisation, so positions stay exact).
    meshoptimizer keeps a subset of the original vertices with their
    attributes, so each output vertex is matched to its original vertex
    (distance checked) and keeps that vertex's 4 weights.
    """
    import subprocess
    import tempfile

    import scipy.sparse as sp
    from scipy.spatial import cKDTree

    from rigslim.io.gltf.document import load_gltf, read_accessor
    from rigslim.io.gltf.write import export_skinned
    from rigslim.model.hierarchy import SimplifiedLevel
    from rigslim.model.mesh import Mesh
    from rigslim.numerics.surface_distance import metro_distance
    from rigslim.plugin import StepContext
    from rigslim.plugin.evaluation import Evaluation
    from rigslim.plugin.host import get_host
    from rigslim.plugins.decimation.articulated import limited_weights
    from rigslim.plugins.decimation.static_qslim import nearest_vertex_weights

    asset = elephant(0)
    W4 = limited_weights(asset.weights, 4)
    tmp = Path(tempfile.mkdtemp())
    export_skinned(tmp / "elephant.glb", asset.mesh, asset.handles, sp.csr_matrix(W4))
    r = subprocess.run([gltfpack, "-h"], capture_output=True, text=True)
    version = ((r.stdout or r.stderr).splitlines() or ["gltfpack"])[0]
    levels = {"gltfpack": []}
    for r in ratios:
        t0 = time.perf_counter()
        subprocess.run([gltfpack, "-i", str(tmp / "elephant.glb"), "-o", str(tmp / "out.glb"), "-si", str(r), "-sa",
                        "-noq"], check=True, capture_output=True)
        secs = time.perf_counter() - t0
        doc = load_gltf(tmp / "out.glb")
        prim = doc.json["meshes"][0]["primitives"][0]
        P = np.asarray(read_accessor(doc, prim["attributes"]["POSITION"]), float)
        F = np.asarray(read_accessor(doc, prim["indices"]), np.int64).reshape(-1, 3)
        dist, nearest = cKDTree(asset.mesh.V).query(P)
        assert dist.max() < 1e-4 * asset.mesh.bbox_diagonal, "gltfpack moved vertices"
        lv = SimplifiedLevel(Mesh(asset.mesh.V[nearest], F),
                             nearest_vertex_weights(asset.mesh.V, W4, asset.mesh.V[nearest]),
                             f"gltfpack-si{r:g}", None, float("nan"), "gltfpack")
        levels["gltfpack"].append((lv, secs))
    faces = [lv.n_faces for lv, _ in levels["gltfpack"]]
    host = get_host()
    for method in ("quartic", "static-qslim"):
        plugin = host.get("articulated-decimation", method)
        asset.extras.clear()
        t0 = time.perf_counter()
        plugin.apply(asset, plugin.parse_params({"targets": faces, "max_bones": 4}), StepContext())
        secs = time.perf_counter() - t0
        levels[method] = [(lv, secs) for lv in asset.levels]
    rows = []
    for method, lvs in levels.items():
        asset.levels = [lv for lv, _ in lvs]
        ev = Evaluation(asset, host)
        scale = 100.0 / asset.mesh.bbox_diagonal
        for i, (lv, secs) in enumerate(lvs):
            d = [metro_distance(ev.level_positions(i, j), lv.mesh.F, ev.full_positions(j), asset.mesh.F, samples)
                 for j in range(len(ev))]
            rows.append({"method": method, "label": lv.label, "faces": lv.n_faces, "seconds": secs,
                         "rms_pct_mean": float(np.mean([scale * x["rms"] for x in d])),
                         "max_pct_mean": float(np.mean([scale * x["max"] for x in d]))})
            print(f"gltfpack comparison {method:14s} {lv.n_faces:6d} faces  rms {rows[-1]['rms_pct_mean']:.4f} "
                  f"max {rows[-1]['max_pct_mean']:.4f}", flush=True)
    return {"gltfpack": version, "dataset": "elephant-12k, 4 bones", "rows": rows}


def at(result, frac, n_faces):
    want = max(1, int(round(frac * n_faces)))
    return min(result["levels"], key=lambda lv: abs(lv["faces"] - want))


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the 12k elephant only")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--out", default=str(OUT))
    ap.add_argument("--gltfpack", metavar="PATH", help="also compare with gltfpack (npm install gltfpack)")
    ap.add_argument("--backend", choices=["numba", "numpy"], default="numba",
                    help="decimation backend of quartic, mohr-gleicher and decoro-rusinkiewicz")
    ap.add_argument("--datasets", nargs="+", metavar="NAME",
                    help="only these datasets (elephant-12k, elephant-12k-4bones, elephant-193k, armadillo-86k, "
                         "armadillo-86k-wide)")
    ap.add_argument("--merge", action="store_true",
                    help="with --gltfpack: add the comparison to the existing simplify.json instead of rerunning")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if args.merge:
        doc = json.loads((out / "simplify.json").read_text())
        doc["gltfpack"] = gltfpack_comparison(args.gltfpack, args.samples)
        finish(doc, out)
        return

    datasets = [("elephant-12k", lambda: elephant(0), None, 1),
                ("elephant-12k-4bones", lambda: elephant(0), 4, 1)]
    if not args.quick:
        datasets += [("elephant-193k", lambda: elephant(2), None, 4),
                     ("armadillo-86k", armadillo, None, 1),
                     ("armadillo-86k-wide", lambda: armadillo(amplitude=(60.0, 90.0)), None, 1)]
    if args.datasets:
        datasets = [d for d in datasets if d[0] in args.datasets]
    import os

    compile_s = warm_up(args.backend)
    print(f"warm-up (numba compilation or cache load): {compile_s:.1f} s", flush=True)

    cpu = cpu_model()
    machine = {"nproc": os.cpu_count(), "cpu": cpu, "python": platform.python_version(),
               "note": "shared 2-core machine; other jobs ran at the same time, so timings are upper bounds"}
    results = []
    for name, load, max_bones, stride in datasets:
        asset = load()
        info = {"dataset": name, "faces": asset.mesh.n_faces, "vertices": asset.mesh.n_vertices,
                "handles": asset.weights.shape[1], "example_poses": len(asset.split.examples),
                "test_poses": len(asset.split.test[::stride]), "max_bones": max_bones, "runs": []}
        for method in METHODS:
            r = run_method(asset, method, 70, max_bones, stride, args.samples, args.backend)
            info["runs"].append(r)
            l10, l2 = at(r, 0.1, info["faces"]), at(r, 0.02, info["faces"])
            print(f"{name:22s} {method:20s} {r['seconds']:8.2f}s  10%: rms {l10['rms_pct_mean']:.4f} "
                  f"max {l10['max_pct_mean']:.4f}   2%: rms {l2['rms_pct_mean']:.4f} max {l2['max_pct_mean']:.4f}",
                  flush=True)
        results.append(info)
    doc = {"machine": machine, "fractions": FRACTIONS, "backend": args.backend, "warm_up_seconds": compile_s,
           "results": results}
    if args.gltfpack:
        doc["gltfpack"] = gltfpack_comparison(args.gltfpack, args.samples)
    finish(doc, out)


def finish(doc, out: Path) -> None:
    md = markdown(doc)
    write_results(out / "simplify", doc, md)
    print(md)
    plot(doc, out / "simplify.png")


def markdown(doc) -> str:
    m = doc["machine"]
    lines = ["# Articulated simplification: results", "",
             f"Machine: {m['cpu']}, nproc {m['nproc']}, Python {m['python']} ({m['note']}).",
             "Written by `benchmarks/simplify.py`. Time: the whole hierarchy down to 70 faces "
             "(static QSlim: nested pymeshlab runs at 20/10/5/2/1% and 70 faces), including the per-pose quadrics"
             + (f"; decimation backend `{doc['backend']}`, measured after a warm-up that compiled or loaded the "
                f"numba kernels ({doc['warm_up_seconds']:.1f} s, not included)." if doc.get("backend") else "."),
             "Errors: two-sided Metro distance (pymeshlab Hausdorff) on test poses never used for fitting, "
             "as % of the rest bounding-box diagonal; RMS and max averaged over the test poses. "
             "Ratio: quartic's RMS / this method's RMS.", ""]
    for d in doc["results"]:
        lines += [f"## {d['dataset']}: {d['faces']:,} faces, {d['handles']} handles, {d['example_poses']} example "
                  f"poses, {d['test_poses']} test poses, max_bones {d['max_bones']}", "",
                  "| method | time (s) | RMS 10% | max 10% | RMS 2% | max 2% "
                  "| quartic/this RMS 10% | quartic/this RMS 2% |",
                  "|---|---|---|---|---|---|---|---|"]
        q = next(r for r in d["runs"] if r["method"] == "quartic")
        q10, q2 = at(q, 0.1, d["faces"]), at(q, 0.02, d["faces"])
        for r in d["runs"]:
            l10, l2 = at(r, 0.1, d["faces"]), at(r, 0.02, d["faces"])
            lines.append(f"| {r['method']} | {r['seconds']:.1f} | {l10['rms_pct_mean']:.4f} | "
                         f"{l10['max_pct_mean']:.3f} | {l2['rms_pct_mean']:.4f} | {l2['max_pct_mean']:.3f} | "
                         f"{q10['rms_pct_mean'] / l10['rms_pct_mean']:.2f} | "
                         f"{q2['rms_pct_mean'] / l2['rms_pct_mean']:.2f} |")
        lines.append("")
    g = doc.get("gltfpack")
    if g:
        lines += [f"## gltfpack ({g['gltfpack']}) on {g['dataset']}", "",
                  "`gltfpack -si R -sa -noq` on a skinned glTF of the elephant (4 weights per vertex); "
                  "quartic and static QSlim (max_bones 4) extracted at gltfpack's face counts; all 64 test poses.", "",
                  "| method | level | faces | time (s) | RMS | max |", "|---|---|---|---|---|---|"]
        for r in g["rows"]:
            lines.append(f"| {r['method']} | {r['label']} | {r['faces']} | {r['seconds']:.2f} | "
                         f"{r['rms_pct_mean']:.4f} | {r['max_pct_mean']:.3f} |")
        lines.append("")
    else:
        lines += ["gltfpack: not run (pass `--gltfpack PATH`).", ""]
    lines += ["![error against face count](simplify.png)", ""]
    return "\n".join(lines)


def plot(doc, path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    res = doc["results"]
    fig, axes = plt.subplots(1, len(res), figsize=(4.5 * len(res), 4), squeeze=False)
    for ax, d in zip(axes[0], res, strict=False):
        for r in d["runs"]:
            lv = sorted(r["levels"], key=lambda x: x["faces"])
            ax.loglog([x["faces"] for x in lv], [x["rms_pct_mean"] for x in lv], "o-", label=r["method"])
        ax.set_title(d["dataset"])
        ax.set_xlabel("faces")
        ax.set_ylabel("test-pose Metro RMS (% bbox diag)")
        ax.grid(True, which="both", alpha=0.3)
    axes[0][0].legend(fontsize=8)
    fig.tight_layout()
    from rigslim.io.atomic import atomic_path

    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=110, format="png")


if __name__ == "__main__":
    main()
