"""Weight generators: time and accuracy of cage coordinates and skinning weights.

- mean value coordinates of the armadillo (43,243 vertices) in its 110-vertex
  cage, numpy against OpenCL (PoCL on this CPU, or any GPU there is);
- an automatic 100-vertex cage for the Cheb, and harmonic coordinates of the
  Cheb in it (regular grid, conjugate gradients);
- bone heat weights of the Cheb for its 17-bone skeleton;
- bounded biharmonic weights of the tetrahedral hand (if the shared data is there);
- quality on test poses never used for fitting: the examples (Cheb 17 -> 5,
  armadillo 110 -> 8 with MVC and with harmonic coordinates, the Cheb's
  skinned automatic cage 100 -> 8) reduced with k-largest.

Run from the repository root::

    .venv/bin/python -m benchmarks.coordinates

writes ``docs/results/coordinates.json`` and ``docs/results/coordinates.md``.
"""

from __future__ import annotations

import argparse
import json
import time
from pathlib import Path

import numpy as np

from benchmarks.datasets import machine, write_results

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
SHARED = ROOT.parent / "shared" / "data"

#: [P10] Table 1: models, vertex counts, deformation, max and optimised weights per vertex.
PAPER = [("Buddha", 427_616, "MVC", 45, 12), ("Bunny", 35_947, "MVC", 47, 8), ("Armadillo", 15_002, "MVC", 110, 8),
         ("Horse", 48_485, "MVC", 51, 8), ("Armadillo", 15_002, "HC", 110, 8), ("Horse", 48_485, "HC", 51, 8),
         ("Cheb", 6_669, "SD", 17, 5), ("Human", 120_226, "SD", 17, 5)]



def timed(fn, *args, **kwargs):
    t = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t


def bench_mvc(log) -> list[dict]:
    from rigslim.io import read_mesh
    from rigslim.plugins.generators.mean_value import mean_value_coordinates, mean_value_coordinates_opencl

    mesh = read_mesh(DATA / "armadillo.obj")
    cage = read_mesh(DATA / "armadillo-cage.obj")
    size = f"{mesh.n_vertices:,} x {cage.n_vertices} ({cage.n_faces} faces)"
    rows = []
    log("MVC armadillo, numpy ...")
    Wn, tn = timed(mean_value_coordinates, mesh.V, cage.V, cage.F)
    lin_n = float(np.abs(Wn @ cage.V - mesh.V).max() / mesh.bbox_diagonal)
    rows.append({"task": "mean value coordinates", "model": "armadillo", "size": size, "backend": "numpy",
                 "seconds": tn, "check": f"linear precision {lin_n:.1e} (x diag)",
                 "linear_precision_rel": lin_n, "negative_fraction": float((Wn < 0).mean())})
    try:
        from rigslim.device.opencl import get_runtime

        for spec in ("cpu", "gpu"):
            try:
                rt = get_runtime(spec)
            except Exception:
                continue
            log(f"MVC armadillo, OpenCL on {rt.name} ...")
            _, tb = timed(mean_value_coordinates_opencl, mesh.V[:64], cage.V, cage.F, device=spec)  # build + warm-up
            Wc, tc = timed(mean_value_coordinates_opencl, mesh.V, cage.V, cage.F, device=spec)
            diff = float(np.abs(Wc - Wn).max())
            rows.append({"task": "mean value coordinates", "model": "armadillo", "size": size,
                         "backend": f"opencl ({rt.name})", "seconds": tc, "warmup_seconds": tb,
                         "check": f"max |W_cl - W_np| {diff:.1e}", "max_abs_diff_vs_numpy": diff,
                         "speedup_vs_numpy": tn / tc})
    except ImportError:
        log("pyopencl missing: OpenCL rows skipped")
    return rows


def bench_cheb(log) -> list[dict]:
    from rigslim.io import read_mesh, read_tgf
    from rigslim.plugins.generators.bone_heat import bone_heat_weights
    from rigslim.plugins.generators.cage import build_cage, enclosure
    from rigslim.plugins.generators.harmonic import harmonic_coordinates

    mesh = read_mesh(DATA / "cheburashka.off")
    skel = read_tgf(DATA / "cheburashka.tgf")
    rows = []
    log("cage for the Cheb ...")
    cage, tc = timed(build_cage, mesh, 100)
    enc = enclosure(cage, mesh.V)
    rows.append({"task": "automatic cage (build_cage)", "model": "Cheb", "size": f"{mesh.n_vertices:,} vertices",
                 "backend": "igl", "seconds": tc,
                 "check": f"{cage.n_vertices} cage vertices, min winding {enc.winding.min():.4f}, "
                          f"min clearance {enc.clearance.min() / mesh.bbox_diagonal:.4f} diag",
                 "cage_vertices": cage.n_vertices, "min_winding": float(enc.winding.min())})
    for res in (32, 64):
        log(f"harmonic coordinates of the Cheb, grid {res} ...")
        rep = {}
        W, th = timed(harmonic_coordinates, mesh.V, cage.V, cage.F, resolution=res, report=rep)
        lin = float(np.abs(W @ cage.V - mesh.V).max())
        rows.append({"task": "harmonic coordinates", "model": "Cheb",
                     "size": f"{mesh.n_vertices:,} x {cage.n_vertices}, grid {res} ({rep['unknowns']:,} unknowns)",
                     "backend": f"numpy/scipy CG ({rep['iterations']} it.)", "seconds": th,
                     "check": f"min {W.min():.1e}, linear precision {lin / rep['spacing']:.2f} h",
                     "linear_precision_in_h": lin / rep["spacing"], "min_weight": float(W.min()), **rep})
    log("bone heat of the Cheb ...")
    rep = {}
    W, tb = timed(bone_heat_weights, mesh, skel.joints, skel.bones, report=rep)
    rows.append({"task": "bone heat weights", "model": "Cheb", "size": f"{mesh.n_vertices:,} x {skel.n} bones",
                 "backend": "igl + scipy LU", "seconds": tb,
                 "check": f"min {W.min():.1e}, {((W > 1e-8).sum(1) == skel.n).mean():.0%} of vertices use all "
                          f"{skel.n} bones, {rep['vertices_seeing_no_bone']} see no bone",
                 **rep})
    return rows


def bench_hand(log) -> list[dict]:
    hand = SHARED / "hand.mesh"
    if not hand.exists():
        log("hand.mesh not found: bbw row skipped")
        return []
    from rigslim.io import read_medit_surface, read_tgf
    from rigslim.plugins.generators.bbw import bounded_biharmonic_weights

    _, _, vol = read_medit_surface(hand)
    skel = read_tgf(SHARED / "hand.tgf")
    log("bbw of the hand ...")
    rep = {}
    W, t = timed(bounded_biharmonic_weights, vol["V"], vol["T"], skel.joints, skel.bones, report=rep)
    return [{"task": "bounded biharmonic weights", "model": "hand",
             "size": f"{len(vol['V']):,} tet vertices, {len(vol['T']):,} tets x {skel.n} bones",
             "backend": "igl.bbw (8 active-set it.)", "seconds": t,
             "check": f"min {W.min():.1e}, rows sum to 1 within {np.abs(W.sum(1) - 1).max():.0e}", **rep}]


def bench_quality(log) -> list[dict]:
    from rigslim.runtime.run import run_pipeline

    rows = []
    for name in ("cheburashka-k5", "armadillo-k8", "armadillo-harmonic-k8", "cheburashka-cage-k8"):
        log(f"pipeline examples/{name}.yaml ...")
        res, t = timed(run_pipeline, ROOT / "examples" / f"{name}.yaml")
        doc = res.document
        m = doc["evaluations"][0]["metrics"]
        gens = [s for s in doc["steps"] if s["stage"] == "generate"]
        rows.append({"pipeline": f"examples/{name}.yaml", "generator": " + ".join(g["plugin"] for g in gens),
                     "generate_seconds": sum(g["seconds"] for g in gens), "input_influences": m["input_max_influences"],
                     "k": m["max_influences"], "examples": len(doc["frames"]["examples"]),
                     "test": len(doc["frames"]["test"]), "position_rms_pct": m["position_rms_pct"]["mean"],
                     "position_rms_pct_max": m["position_rms_pct"]["max"],
                     "normal_rms_rad": m["normal_rms_rad"]["mean"], "total_seconds": t})
    return rows


def markdown(doc: dict) -> str:
    lines = ["# Weight generators: timings", "",
             f"Machine: {doc['machine']['cpu']}, {doc['machine']['nproc']} CPU cores (shared), "
             f"Python {doc['machine']['python']}. One run each, wall-clock seconds.", "",
             "| task | model | size | backend | seconds | check |", "|---|---|---|---|---:|---|"]
    for r in doc["timings"]:
        check = r["check"].replace("|", "\\|")
        lines.append(f"| {r['task']} | {r['model']} | {r['size']} | {r['backend']} | {r['seconds']:.2f} | {check} |")
    cl = [r for r in doc["timings"] if r.get("speedup_vs_numpy")]
    if cl:
        lines += [""] + [f"OpenCL ({r['backend']}) / numpy MVC speed ratio: {r['speedup_vs_numpy']:.2f}x" for r in cl]
    lines += ["", "## Quality on test poses (k-largest reduction of the generated weights)", "",
              "| pipeline | generator (seconds) | weights per vertex | example / test poses "
              "| position RMS % of diag (mean / max) | normal RMS rad (mean) |", "|---|---|---|---|---|---|"]
    for q in doc["quality"]:
        lines.append(f"| {q['pipeline']} | {q['generator']} ({q['generate_seconds']:.1f}) | "
                     f"{q['input_influences']} -> {q['k']} | "
                     f"{q['examples']} / {q['test']} | {q['position_rms_pct']:.3f} / {q['position_rms_pct_max']:.3f} "
                     f"| {q['normal_rms_rad']:.4f} |")
    lines += ["", "## The paper's models, for context ([P10] Table 1)", "",
              "| model | vertices | deformation | weights per vertex |", "|---|---:|---|---|"]
    for name, verts, kind, full, k in PAPER:
        lines.append(f"| {name} | {verts:,} | {kind} | {full} -> {k} |")
    lines += ["", "Ours: the armadillo at full resolution (43,243 vertices, the paper used 15,002) with a "
              "110-vertex cage; the Cheb at the paper's 6,669 vertices with 17 bones.", ""]
    return "\n".join(lines)


def write(doc: dict, out: Path) -> None:
    write_results(out, doc, markdown(doc))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "coordinates",
                    help="output path without suffix (.json and .md are written)")
    ap.add_argument("--skip", default="", help="comma list of parts to skip: mvc,cheb,hand,quality")
    ap.add_argument("--markdown-only", action="store_true", help="rewrite the .md from the existing .json")
    args = ap.parse_args(argv)
    if args.markdown_only:
        doc = json.loads(args.out.with_suffix(".json").read_text())
        write(doc, args.out)
        print(markdown(doc))
        return 0
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}

    def log(msg):
        print(msg, flush=True)

    timings = []
    if "mvc" not in skip:
        timings += bench_mvc(log)
    if "cheb" not in skip:
        timings += bench_cheb(log)
    if "hand" not in skip:
        timings += bench_hand(log)
    quality = bench_quality(log) if "quality" not in skip else []
    doc = {"machine": machine(),
           "timings": timings, "quality": quality,
           "paper": [dict(zip(("model", "vertices", "deformation", "max_weights", "optimized_weights"), p,
                              strict=False))
                     for p in PAPER]}
    write(doc, args.out)
    print()
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
