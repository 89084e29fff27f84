"""Pictures of far LODs posed: the source, rigslim's level and gltf-transform's at the same face count.

Flat-shaded matplotlib renders (no GPU, no browser) of each file posed by its own skin at one clip time,
front and side, for docs/simplification.md. Usage::

    .venv/bin/python benchmarks/gltf_lod_images.py SOURCE.glb RATIO OUT.png [--gltf-transform PATH] [--clip NAME]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
RIGSLIM = [str(Path(sys.executable).with_name("rigslim"))]


def panel(fig, rows, cols, index, X, F, title, az, lims):
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    Y = np.stack([X[:, 0], -X[:, 2], X[:, 1]], 1)            # glTF y-up -> z-up
    tri = Y[F]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True) + 1e-30
    light = np.array([np.cos(np.radians(az + 30)), np.sin(np.radians(az + 30)), 0.6])
    shade = np.clip(np.abs(n @ (light / np.linalg.norm(light))), 0.15, 1.0)
    ax = fig.add_subplot(rows, cols, index, projection="3d")
    import matplotlib.pyplot as plt

    ax.add_collection3d(Poly3DCollection(tri, facecolors=plt.cm.gray(shade), edgecolors="none"))
    c, r = lims
    ax.set_xlim(c[0] - r, c[0] + r)
    ax.set_ylim(c[1] - r, c[1] + r)
    ax.set_zlim(c[2] - r, c[2] + r)
    ax.view_init(8, az)
    ax.set_axis_off()
    if title:
        ax.set_title(title, fontsize=8)


def main(argv=None):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from rigslim.commands.compare import posed_surfaces
    from rigslim.commands.gltf_common import clip_frames

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("source", type=Path)
    ap.add_argument("ratio", type=float)
    ap.add_argument("out", type=Path)
    ap.add_argument("--gltf-transform", default=str(ROOT / "tools/node/node_modules/.bin/gltf-transform"))
    ap.add_argument("--clip")
    ap.add_argument("--time", type=float, help="clip time (default: 37 %% of the clip)")
    args = ap.parse_args(argv)
    frames, _, _ = clip_frames(args.source, args.clip, 30.0)
    t = args.time if args.time is not None else 0.37 * frames / 30.0
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        gt, welded = tmp / "gt.glb", tmp / "welded.glb"
        subprocess.run([args.gltf_transform, "weld", str(args.source), str(welded)], check=True, capture_output=True)
        subprocess.run([args.gltf_transform, "simplify", str(welded), str(gt), "--ratio", str(args.ratio),
                        "--error", "1"], check=True, capture_output=True)
        P, F, _ = posed_surfaces(gt, clip=args.clip, times=[t])
        rs, rep = tmp / "rs.glb", tmp / "rs.json"
        src_faces = len(posed_surfaces(args.source, clip=args.clip, times=[t])[1])
        subprocess.run(RIGSLIM + ["lod", str(args.source), "-o", str(rs), "--ratios", f"{len(F) / src_faces:.6f}",
                                  "--max-error", "none", "--report", str(rep)] +
                       (["--clip", args.clip] if args.clip else []), check=True, capture_output=True)
        cols = [("source", args.source, 0), ("rigslim", rs, 1), ("gltf-transform", gt, 0)]
        meshes = []
        for name, path, level in cols:
            Pk, Fk, _ = posed_surfaces(path, clip=args.clip, times=[t], level=level)
            meshes.append((f"{name}, {len(Fk)} faces", Pk[0], Fk))
        Y = np.stack([meshes[0][1][:, 0], -meshes[0][1][:, 2], meshes[0][1][:, 1]], 1)
        lims = ((Y.min(0) + Y.max(0)) / 2, (Y.max(0) - Y.min(0)).max() / 2)
        fig = plt.figure(figsize=(7.5, 5))
        for i, (title, X, Fk) in enumerate(meshes):
            panel(fig, 2, 3, i + 1, X, Fk, title, -90, lims)
            panel(fig, 2, 3, i + 4, X, Fk, None, 0, lims)
        plt.subplots_adjust(0, 0, 1, 0.95, 0, 0)
        fig.savefig(args.out, dpi=80)
        print(json.dumps({"out": str(args.out), "time": t, "faces": [len(m[2]) for m in meshes]}))


if __name__ == "__main__":
    main()
