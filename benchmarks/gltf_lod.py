"""glTF LOD benchmark: ``rigslim lod`` against gltfpack in the same run, measured with ``rigslim compare``.

For every skinned character in examples/data/gltf/ (and the elephant
exported to glTF with its 4 largest weights, ~12k triangles):

- ``rigslim lod IN -o OUT --ratios 0.5,0.25`` (quartic, 4 bones, seams and
  material boundaries locked), run as a command-line process and timed;
- ``gltfpack -i IN -o OUT -si R -noq`` for R = 0.5 and 0.25 (meshoptimizer's
  simplifier; ``-noq`` keeps positions unquantised, so only simplification
  is measured);
- ``rigslim compare IN CANDIDATE --frames TEST [--level L] --json``: the
  two-sided Hausdorff distance of each result posed by its own skin against
  the input posed by its own, on the test frames ``lod`` did not fit to
  (frames halfway between its example frames), RMS as % of the input's
  world-space diagonal and in world units.

Usage::

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/gltf_lod.py [--gltfpack PATH]

gltfpack defaults to tools/node/node_modules/gltfpack/cli.js (tools/setup-testmodels.sh).
Writes docs/results/gltf_lod.{json,md}.
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

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import DATA, machine, write_results  # noqa: E402

GLTF = ROOT / "examples" / "data" / "gltf"
OUT = ROOT / "docs" / "results"
RATIOS = (0.5, 0.25)
REPEATS = 3
RIGSLIM = ([str(Path(sys.executable).with_name("rigslim"))] if Path(sys.executable).with_name("rigslim").exists()
           else [sys.executable, "-m", "rigslim.commands.cli"])


def characters() -> list[Path]:
    return sorted(list(GLTF.glob("*.gl*")) + list(GLTF.glob("*/*.gltf")))


def export_elephant(folder: Path) -> Path:
    """The libigl elephant (12,000 faces... see DATA.md) as a skinned .glb with its 4 largest weights per vertex."""
    out = folder / "elephant-k4.glb"
    yml = folder / "elephant-k4.yaml"
    yml.write_text(f"""
inputs:
  mesh: {DATA / 'elephant.obj'}
  skeleton: {DATA / 'elephant.tgf'}
  weights: {DATA / 'elephant-weights.dmat'}
  animation: {DATA / 'elephant-anim.dmat'}
steps:
  - select: k-largest
    k: 4
  - solve: k-largest
  - write: {out}
    fps: 30
""")
    subprocess.run(RIGSLIM + ["run", str(yml), "-q"], check=True, capture_output=True)
    return out


def run(cmd: list[str]) -> tuple[float, str]:
    t0 = time.perf_counter()
    p = subprocess.run(cmd, capture_output=True, text=True)
    secs = time.perf_counter() - t0
    if p.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} failed: {p.stderr.strip()[-800:]}")
    return secs, p.stdout


def compare(ref: Path, cand: Path, frames: str, level: int, samples: int) -> dict:
    _, out = run(RIGSLIM + ["compare", str(ref), str(cand), "--frames", frames, "--level", str(level), "--json",
                            "--samples", str(samples)])
    return json.loads(out)


def bench(path: Path, tmp: Path, gltfpack: list[str] | None, samples: int) -> dict:
    from rigslim.commands.gltf_common import _poses, clip_frames

    frames, clip, duration = clip_frames(path, None, 30.0)
    test = _poses(frames)["test"]
    stem = path.stem
    out = tmp / f"{stem}-rigslim.glb"
    report = tmp / f"{stem}-report.json"
    times, command_times = [], []
    for _ in range(REPEATS):          # the machine is shared: the minimum of a few runs is the fairest figure
        secs, _ = run(RIGSLIM + ["lod", str(path), "-o", str(out), "--ratios", ",".join(map(str, RATIOS)),
                                 "--report", str(report)])
        times.append(secs)
        command_times.append(json.loads(report.read_text())["seconds"])
    rep = json.loads(report.read_text())
    row = {"character": str(path.relative_to(ROOT)) if path.is_relative_to(ROOT) else path.name,
           "input_faces": rep["input_faces"], "frames": frames, "test_frames": test,
           "example_poses": len(range(*[int(x) for x in rep["pipeline"]["poses"]["examples"].split(":")]))
           if frames > 1 else 1, "locked_seam_vertices": rep["locked_seam_vertices"],
           "rigslim_process_seconds": min(times), "rigslim_process_seconds_all": times,
           "rigslim_command_seconds": min(command_times), "rigslim_command_seconds_all": command_times,
           "levels": []}
    for level, (ratio, _lv) in enumerate(zip(RATIOS, rep["levels"], strict=False), 1):
        r = compare(path, out, test, level, samples)
        entry = {"ratio": ratio, "rigslim": {"faces": r["faces"], "rms_pct": r["hausdorff_rms_pct"],
                                             "max_pct": r["hausdorff_max_pct"], "rms_m": r["hausdorff_rms_m"]}}
        if gltfpack:
            for key, flags in (("gltfpack", []), ("gltfpack_sa", ["-sa"])):
                gp = tmp / f"{stem}-{key}-{ratio:g}.glb"
                gsecs, _ = run(gltfpack + ["-i", str(path), "-o", str(gp), "-si", str(ratio), "-noq"] + flags)
                g = compare(path, gp, test, 0, samples)
                entry[key] = {"faces": g["faces"], "rms_pct": g["hausdorff_rms_pct"], "max_pct": g["hausdorff_max_pct"],
                              "rms_m": g["hausdorff_rms_m"], "seconds": gsecs,
                              "rms_ratio": (r["hausdorff_rms_pct"] / g["hausdorff_rms_pct"]
                                            if g["hausdorff_rms_pct"] > 0 else float("inf"))}
            # no gltfpack result at rigslim's face count: also take rigslim at gltfpack -sa's count
            rf, ga = r["faces"], entry["gltfpack_sa"]
            if all(abs(entry[k]["faces"] - rf) > 0.05 * max(rf, 1) for k in ("gltfpack", "gltfpack_sa")) \
                    and ga["faces"] < row["input_faces"]:
                extra = tmp / f"{stem}-rigslim-at-{ga['faces']}.glb"
                ratio = f"{ga['faces'] / row['input_faces']:.6f}"
                run(RIGSLIM + ["lod", str(path), "-o", str(extra), "--ratios", ratio])
                e = compare(path, extra, test, 1, samples)
                entry["rigslim_at_gltfpack_sa"] = {"faces": e["faces"], "rms_pct": e["hausdorff_rms_pct"],
                                                   "max_pct": e["hausdorff_max_pct"],
                                                   "rms_ratio": (e["hausdorff_rms_pct"] / ga["rms_pct"]
                                                                 if ga["rms_pct"] > 0 else float("inf"))}
        row["levels"].append(entry)
        print(f"{row['character']:48s} {ratio:4g}: rigslim {r['faces']:6d} faces RMS {r['hausdorff_rms_pct']:.4f} %"
              + "".join(f" | {k} {entry[k]['faces']:6d} faces RMS {entry[k]['rms_pct']:.4f} % ratio "
                        f"{entry[k]['rms_ratio']:.2f}" for k in ("gltfpack", "gltfpack_sa") if k in entry), flush=True)
    return row


def markdown(doc: dict) -> str:
    m = doc["machine"]
    lines = ["# glTF levels of detail: `rigslim lod` against gltfpack", "",
             f"Machine: {m['cpu']}, nproc {m['nproc']}, Python {m['python']} (shared 2-core machine; other jobs "
             "ran at the same time, so timings are upper bounds). Written by `benchmarks/gltf_lod.py`.", "",
             f"gltfpack: {doc['gltfpack'] or 'not run'} (`-si R -noq`). rigslim: `rigslim lod IN -o OUT --ratios "
             "0.5,0.25` (quartic [S09], at most 4 bones per vertex, UV seams and material boundaries collapsed only "
             "along themselves). "
             "Errors: `rigslim compare` (two-sided Hausdorff, pymeshlab, "
             f"{doc['samples']} samples per direction and frame) on the test frames, RMS averaged over them, as % of "
             "the input's world-space bounding-box diagonal; ratio = rigslim RMS / gltfpack RMS (target <= 0.5). "
             "Face counts differ where seam corners stop rigslim early or gltfpack stops at its error limit.", "",
             "Two gltfpack runs per ratio: `-si R -noq` as the issue states (gltfpack stops at its error limit, "
             "so it may keep more faces) and `-si R -sa -noq` (aggressive: ignores the limit, reaches R). The target "
             "is judged against the gltfpack result with the same face count as rigslim's (within 5 %), when one has "
             "it; otherwise rigslim is run again at gltfpack -sa's face count (shown in brackets: faces and RMS) and "
             "judged there; `n/a` where no comparison at equal faces exists (neither tool simplified).", "",
             "| character | faces | target | rigslim faces | rigslim RMS % | gltfpack faces | gltfpack RMS % | "
             "gltfpack -sa faces | gltfpack -sa RMS % | ratio (equal faces) | <= 0.5 |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for row in doc["results"]:
        for lv in row["levels"]:
            g, ga = lv.get("gltfpack"), lv.get("gltfpack_sa")
            rf = lv["rigslim"]["faces"]
            same = [x for x in (g, ga) if x and abs(x["faces"] - rf) <= 0.05 * max(rf, 1)]
            ratio = min((x["rms_ratio"] for x in same), default=None)
            extra = lv.get("rigslim_at_gltfpack_sa")
            if ratio is None and extra and abs(extra["faces"] - ga["faces"]) <= 0.05 * max(ga["faces"], 1):
                ratio = extra["rms_ratio"]
                rf = f"{rf} ({extra['faces']}: {extra['rms_pct']:.4f})"
            lv["rms_ratio_equal_faces"] = ratio
            met = "n/a" if ratio is None else ("yes" if ratio <= 0.5 else "no")
            if lv["rigslim"]["faces"] >= row["input_faces"] and (not g or g["faces"] >= row["input_faces"]):
                met = "n/a (neither simplified)"
            cells = [f"{x['faces']} | {x['rms_pct']:.4f}" if x else " | " for x in (g, ga)]
            lines.append(f"| {row['character']} | {row['input_faces']} | {lv['ratio']:g} | {rf} | "
                         f"{lv['rigslim']['rms_pct']:.4f} | {cells[0]} | {cells[1]} | "
                         f"{'' if ratio is None else f'{ratio:.2f}'} | {met} |")
    lines += ["", "## Time of `rigslim lod`", "",
              "Process: the whole `rigslim lod` command line (Python start-up, imports, numba's cached kernels, "
              "reading, decimation, writing). Command: the pipeline run inside it (`seconds` of `--report`). "
              f"Fastest of {REPEATS} runs (all runs in brackets; the machine is shared, so the spread is load).", "",
              "| character | faces | example poses | process (s) | command (s) |", "|---|---|---|---|---|"]
    for row in doc["results"]:
        allp = ", ".join(f"{x:.2f}" for x in row["rigslim_process_seconds_all"])
        allc = ", ".join(f"{x:.2f}" for x in row["rigslim_command_seconds_all"])
        lines.append(f"| {row['character']} | {row['input_faces']} | {row['example_poses']} | "
                     f"{row['rigslim_process_seconds']:.2f} ({allp}) | {row['rigslim_command_seconds']:.2f} ({allc}) |")
    lines.append("")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--gltfpack", default=str(ROOT / "tools/node/node_modules/gltfpack/cli.js"),
                    help="gltfpack: a binary, or the npm package's cli.js (run with node)")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--out", default=str(OUT))
    args = ap.parse_args(argv)
    gltfpack = None
    version = None
    if args.gltfpack and Path(args.gltfpack).exists():
        gltfpack = (["node", args.gltfpack] if args.gltfpack.endswith(".js") else [args.gltfpack])
        p = subprocess.run(gltfpack + ["-h"], capture_output=True, text=True)
        version = ((p.stdout or p.stderr).splitlines() or ["gltfpack"])[0]
    results = []
    with tempfile.TemporaryDirectory(prefix="rigslim-gltf-lod-") as tmp:
        tmp = Path(tmp)
        # warm-up: numba compiles (or loads its cache) once, outside the timed runs
        run(RIGSLIM + ["lod", str(GLTF / "huesitos.glb"), "-o", str(tmp / "warm.glb")])
        paths = characters() + [export_elephant(tmp)]
        for path in paths:
            results.append(bench(path, tmp, gltfpack, args.samples))
    doc = {"machine": machine() | {"load": os.getloadavg()[0]}, "gltfpack": version, "samples": args.samples,
           "ratios": list(RATIOS), "results": results}
    md = markdown(doc)
    write_results(Path(args.out) / "gltf_lod", doc, md)
    print(md)


if __name__ == "__main__":
    main()
