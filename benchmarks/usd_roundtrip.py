"""USD / UsdSkel round trip: glTF -> USD -> posed points, reduced and LOD outputs, against UsdSkel's own skinning.

Characters: every skinned glTF in examples/data/gltf/, assimp's animated test
characters converted to .glb (``BCN_Epileptic.X``, ``Testwuson.X``, when
assimp-testmodels is installed), the libigl elephant exported to glTF with its
4 largest weights, and every ``.glb``/``.gltf`` under ``--suite DIR``.

Per character:

1. read the glTF (``read_gltf_skin``, welded) and export it to UsdSkel
   (``build_stage`` + ``save_stage``, ``.usdc``); read the ``.usdc`` back
   (``read_usd_skin``);
2. pose every frame three ways: rigslim's linear blend of the glTF reading,
   rigslim's of the USD reading, and UsdSkel's ``SkinningQuery.ComputeSkinnedPoints``;
   report the largest difference over all vertices and frames as a fraction of
   the posed bounding-box diagonal (``gltf_vs_usd``, ``usd_vs_usdskel``);
3. reduce to k = 2 (k-largest; 1 for two-joint skins) and to levels at 50 % and 25 % of the faces
   (quartic [S09], 2 bones per vertex) in one pipeline on the USD input,
   write ``.usdc`` (``LOD`` variant set); read every level back and pose it by
   UsdSkel and by rigslim (``level_vs_usdskel``, largest over levels);
4. run the USD validators (``check_usd``: every ``UsdValidation`` validator in
   every LOD variant) on the exported and on the reduced/LOD file.

Times (export, read, write with levels; fastest of 3, under the bench lock)
and file sizes are reported beside each. Writes docs/results/usd_roundtrip.{json,md}.

Usage::

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/usd_roundtrip.py [--suite DIR] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402
from benchmarks.gltf_lod import assimp_characters, characters, export_elephant  # noqa: E402

OUT = ROOT / "docs" / "results" / "usd_roundtrip"


def fastest(fn, repeat: int = 3):
    best, value = float("inf"), None
    for _ in range(repeat):
        t0 = time.perf_counter()
        value = fn()
        best = min(best, time.perf_counter() - t0)
    return best, value


def diag(P: np.ndarray) -> float:
    P = P.reshape(-1, 3)
    return float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))


def relative_error(a_frames, b_frames) -> float:
    return max(float(np.abs(a - b).max()) / max(diag(a), 1e-12) for a, b in zip(a_frames, b_frames, strict=True))


def lod_pipeline(src: Path, out: Path, frames: int, joints: int) -> str:
    step = max(2, frames // 12)
    k = max(1, min(2, joints - 1))
    return f"""\
name: usd-roundtrip
inputs:
  usd: {src}
poses:
  examples: "0:{frames}:{step}"
  test: "{max(1, step // 2)}:{frames}:{step}"
steps:
  - select: k-largest
    k: {k}
  - solve: k-largest
  - decimate: quartic
    targets: [0.5, 0.25]
    max_bones: {k}
  - write: {out}
"""


def bench(gltf: Path, tmp: Path) -> dict:
    from rigslim.io.gltf.skin import read_gltf_skin
    from rigslim.io.usd.check import check_usd
    from rigslim.io.usd.export import bind_transforms, build_stage
    from rigslim.io.usd.read import read_usd_skin
    from rigslim.io.usd.skinning import usdskel_points
    from rigslim.io.usd.write import save_stage, write_usd
    from rigslim.numerics.blend import linear_blend
    from rigslim.runtime.run import run_pipeline

    g = read_gltf_skin(gltf, weld=True)
    usd = tmp / f"{gltf.stem}.usdc"
    t_export, _ = fastest(lambda: save_stage(build_stage(g.mesh, g.handles, g.weights, g.poses, fps=g.fps,
                                                         bind=bind_transforms(g.handles, g), name=gltf.stem), usd))
    t_read, u = fastest(lambda: read_usd_skin(usd, fps=g.fps))
    ref = usdskel_points(u)
    gl = [linear_blend(g.mesh.V, g.weights, T) for T in g.poses.T]
    us = [linear_blend(u.mesh.V, u.weights, T) for T in u.poses.T]
    row = {"character": gltf.name, "vertices": u.mesh.n_vertices, "faces": u.mesh.n_faces, "joints": u.handles.n,
           "frames": len(u.poses), "gltf_vs_usd": relative_error(gl, us), "usd_vs_usdskel": relative_error(us, ref),
           "export_s": t_export, "read_s": t_read, "usdc_bytes": usd.stat().st_size,
           "gltf_bytes": sum(p.stat().st_size for p in gltf.parent.glob(gltf.stem + "*")),
           "export_check": check_usd(usd)}
    yml = tmp / f"{gltf.stem}-lod.yaml"
    out = tmp / f"{gltf.stem}-lod.usdc"
    yml.write_text(lod_pipeline(usd, out, len(u.poses), u.handles.n))
    result = run_pipeline(yml)
    a = result.asset
    t_write, _ = fastest(lambda: write_usd(out, a.extras["usd"], a.reduced, levels=a.levels, hierarchy=a.hierarchy))
    level_err, faces = [], []
    for i in range(len(result.asset.levels) + 1):
        lv = read_usd_skin(out, lod=i, fps=g.fps)
        faces.append(lv.mesh.n_faces)
        r = usdskel_points(lv)
        level_err.append(relative_error([linear_blend(lv.mesh.V, lv.weights, T) for T in lv.poses.T], r))
    row.update({"lod_faces": faces, "level_vs_usdskel": max(level_err), "write_lod_s": t_write,
                "lod_usdc_bytes": out.stat().st_size, "lod_check": check_usd(out)})
    return row


def markdown(doc: dict) -> str:
    lines = ["# USD / UsdSkel round trip", "",
             f"Measured {doc['date']} on {doc['machine']['cpu']} ({doc['machine']['nproc']} cores, load "
             f"{doc['load']:.1f}: times are loaded-machine times); usd-core {doc['usd_core']}."
             " `benchmarks/usd_roundtrip.py`.", "",
             "Errors: largest posed-point difference over every vertex and frame, as a fraction of the posed "
             "bounding-box diagonal. `gltf_vs_usd`: rigslim posing the glTF vs rigslim posing its USD export; "
             "`usd_vs_usdskel`: rigslim vs UsdSkel's ComputeSkinnedPoints on the same file; `levels`: the same "
             "on every LOD variant of the k = 2, 50 %/25 % output. `valid`: USD validators (every LOD variant).", "",
             "| character | verts | faces | joints | frames | gltf_vs_usd | usd_vs_usdskel | levels (faces) | "
             "levels vs UsdSkel | valid | export s | read s | write+LOD s | .usdc KiB |",
             "|---|---:|---:|---:|---:|---:|---:|---|---:|---|---:|---:|---:|---:|"]
    for r in doc["characters"]:
        valid = "yes" if not r["export_check"] and not r["lod_check"] else "NO"
        lines.append(f"| {r['character']} | {r['vertices']} | {r['faces']} | {r['joints']} | {r['frames']} | "
                     f"{r['gltf_vs_usd']:.2e} | {r['usd_vs_usdskel']:.2e} | {' / '.join(map(str, r['lod_faces']))} | "
                     f"{r['level_vs_usdskel']:.2e} | {valid} | {r['export_s']:.3f} | {r['read_s']:.3f} | "
                     f"{r['write_lod_s']:.3f} | {r['usdc_bytes'] / 1024:.0f} |")
    return "\n".join(lines) + "\n"


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--suite", type=Path)
    parser.add_argument("--only", nargs="*")
    args = parser.parse_args(argv)
    from pxr import Usd

    rows = []
    with tempfile.TemporaryDirectory(prefix="rigslim-usd-bench-") as t:
        tmp = Path(t)
        paths = characters(args.suite) + assimp_characters(tmp) + [export_elephant(tmp)]
        for p in paths:
            if args.only and p.stem not in args.only and p.name not in args.only:
                continue
            try:
                row = bench(p, tmp)
            except Exception as e:  # noqa: BLE001 - an unskinned file, or one rigslim refuses: say so, go on
                print(f"{p.name}: skipped ({type(e).__name__}: {e})", file=sys.stderr)
                continue
            rows.append(row)
            print(f"{row['character']}: gltf_vs_usd {row['gltf_vs_usd']:.2e}, usd_vs_usdskel "
                  f"{row['usd_vs_usdskel']:.2e}, levels {row['level_vs_usdskel']:.2e}, faces {row['lod_faces']}, "
                  f"checks {len(row['export_check']) + len(row['lod_check'])}", file=sys.stderr)
    doc = {"date": time.strftime("%Y-%m-%d"), "machine": machine(), "load": os.getloadavg()[0],
           "usd_core": ".".join(map(str, Usd.GetVersion()[1:])), "characters": rows}
    text = markdown(doc)
    print(text)
    write_results(OUT, doc, text)


if __name__ == "__main__":
    main()
