"""Contact sheets of skinned .glb files posed in three.js: the first file and the others side by side.

Every row is one pose (clip, time) seen from one view; every column one file.
The first file is the reference: its posed bounding sphere frames the camera
of the row, and the same camera renders every other file, so a level of detail
or a peer's output is seen exactly where the original is. With ``--diff`` each
other file also gets a silhouette tile (white both, red only in the reference:
lost, cyan only in the file: added, e.g. webbing) and its label gives the
outline-tolerant silhouette difference ``shape_diff`` (% of the reference's
silhouette area; see tests/support/posed_render.py).

Usage::

    python benchmarks/render_posed.py ORIGINAL.glb LOD-25.glb LOD-10.glb --clip walk --time 0.2,0.6 \\
        --view side --view front --diff -o sheet.png [--labels original,25%,10%] [--size 256] [--json m.json]

``--view`` is ``front``, ``side`` (the suite index's azimuths when the
reference is a suite character, else 0 and 90) or an azimuth in degrees.
Needs Chromium and three.js (``make test-tools``).
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "tests"):          # benchmarks.datasets and support.posed_render when run as a script
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

FONT = Path("/usr/share/fonts/truetype/dejavu/DejaVuSans.ttf")


def _font(size: int):
    from PIL import ImageFont

    try:
        return ImageFont.truetype(str(FONT), size)
    except OSError:
        return ImageFont.load_default()


def _label(tile: np.ndarray, lines: list[str]):
    from PIL import Image, ImageDraw

    img = Image.fromarray(tile)
    d = ImageDraw.Draw(img)
    font = _font(max(10, tile.shape[0] // 20))
    y = 3
    for line in lines:
        d.text((4, y), line, fill=(255, 255, 255), font=font, stroke_width=2, stroke_fill=(0, 0, 0))
        y += font.size + 3 if hasattr(font, "size") else 12
    return np.asarray(img)


def suite_views(path) -> dict:
    """``{"front": azimuth, "side": azimuth}`` of a suite character (by file name), else 0 and 90."""
    from benchmarks.datasets import suite

    stem = Path(path).stem
    for c in suite():
        if stem == c.name or stem.startswith(c.name + "-"):
            return {"front": c.view["front_azimuth"], "side": c.view["side_azimuth"]}
    return {"front": 0.0, "side": 90.0}


def contact_sheet(files, poses, views=("side",), *, labels=None, diff: bool = False, size: int = 256,
                  renderer=None):
    """Render the sheet; return ``(rgb array, rows)`` where rows hold each tile's pose, view and metrics.

    Parameters
    ----------
    files : list of path
        The reference first.
    poses : list of (clip, time)
        ``clip`` a name, an index or None (the first clip).
    views : list of str or float
        ``"front"``, ``"side"`` or an azimuth in degrees.
    renderer : support.posed_render.PosedRenderer, optional
        An open renderer to reuse (else one is started and closed here).
    """
    from support.posed_render import PosedRenderer, View, difference_image, mask_difference

    files = [Path(f) for f in files]
    labels = labels or [f.stem for f in files]
    named = suite_views(files[0])
    own = renderer is None
    r = renderer or PosedRenderer(size=(size, size)).__enter__()
    rows, records = [], []
    try:
        for clip, t in poses:
            for v in views:
                az = named[v] if isinstance(v, str) and v in named else float(v)
                ref = r.render(files[0], clip=clip, time=t, view=View(azimuth=az), size=(size, size))
                tiles = [_label(ref.rgb, [labels[0], f"{ref.faces} faces", f"{ref.clip} t={ref.time:.2f}s"])]
                rec = {"clip": ref.clip, "time": ref.time, "azimuth": az, "files": [{"label": labels[0],
                                                                                    "faces": ref.faces}]}
                for f, lab in zip(files[1:], labels[1:], strict=True):
                    x = r.render(f, clip=clip, time=t, camera=ref.camera, size=(size, size))
                    m = mask_difference(ref.mask, x.mask)
                    rec["files"].append({"label": lab, "faces": x.faces, **m})
                    tiles.append(_label(x.rgb, [lab, f"{x.faces} faces"]))
                    if diff:
                        tiles.append(_label(difference_image(ref.mask, x.mask),
                                            [f"{lab} silhouette", f"shape diff {100 * m['shape_diff']:.1f}%",
                                             f"IoU {m['iou']:.3f}"]))
                rows.append(np.hstack(tiles))
                records.append(rec)
    finally:
        if own:
            r.__exit__(None, None, None)
    width = max(row.shape[1] for row in rows)
    rows = [np.pad(row, ((0, 0), (0, width - row.shape[1]), (0, 0))) for row in rows]
    return np.vstack(rows), records


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("files", nargs="+", type=Path, help="the reference first")
    ap.add_argument("--clip", action="append", default=None,
                    help="clip name or index (repeat for several; default the first clip)")
    ap.add_argument("--time", default="0.5", help="comma-separated times in seconds (clamped to the clip)")
    ap.add_argument("--view", action="append", default=None, help="front, side or an azimuth (repeatable)")
    ap.add_argument("--labels", default=None, help="comma-separated column labels")
    ap.add_argument("--diff", action="store_true", help="add a silhouette difference tile per file")
    ap.add_argument("--size", type=int, default=256, help="tile size in pixels")
    ap.add_argument("--json", type=Path, default=None, help="also write the silhouette metrics here")
    ap.add_argument("-o", "--output", type=Path, required=True)
    args = ap.parse_args(argv)
    for f in args.files:
        if not f.exists():
            print(f"render_posed: {f}: no such file", file=sys.stderr)
            return 2
    if args.output.resolve() in [f.resolve() for f in args.files]:
        print(f"render_posed: {args.output}: the sheet would overwrite an input", file=sys.stderr)
        return 2
    clips = [int(c) if c.isdigit() else c for c in (args.clip or [None])] if args.clip else [None]
    times = [float(t) for t in args.time.split(",")]
    labels = args.labels.split(",") if args.labels else None
    if labels and len(labels) != len(args.files):
        print(f"render_posed: --labels has {len(labels)} names for {len(args.files)} files", file=sys.stderr)
        return 2
    from PIL import Image

    sheet, records = contact_sheet(args.files, [(c, t) for c in clips for t in times], args.view or ["side"],
                                   labels=labels, diff=args.diff, size=args.size)
    args.output.parent.mkdir(parents=True, exist_ok=True)
    Image.fromarray(sheet).save(args.output)
    if args.json:
        args.json.write_text(json.dumps(records, indent=1) + "\n")
    for rec in records:
        cells = "; ".join(f"{f['label']} {f['faces']}f" + (f" shape {100 * f['shape_diff']:.1f}%"
                                                          if "shape_diff" in f else "") for f in rec["files"])
        print(f"{rec['clip']} t={rec['time']:.2f} az={rec['azimuth']:g}: {cells}")
    print(f"wrote {args.output} ({sheet.shape[1]}x{sheet.shape[0]})")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
