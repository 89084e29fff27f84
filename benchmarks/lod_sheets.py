"""Contact sheets of every suite character's far levels: ``rigslim lod`` beside gltf-transform and gltfpack.

For each character of the suite (benchmarks.datasets.suite; with ``--index``, of another index such as the
sweep's, ``tools/suite/sweep.py --out FOLDER`` then ``--index FOLDER/index.json``) and each ratio:

1. ``rigslim lod CHAR.glb -o OUT.glb --ratios R1,R2 --split`` (defaults otherwise, as a new user runs it);
2. the peers (benchmarks/peers.py) at rigslim's face count of that level
   (ratio searched so that each lands within 3 %; gltfpack ``-si R -sa -noq``,
   gltf-transform ``weld`` + ``simplify --ratio R --error 1``);
3. one sheet per level (benchmarks/render_posed.py): rows are the index's test
   poses seen from the character's side and front, columns the original and
   the three levels, each level with its silhouette difference tile
   (red: lost, cyan: added) and ``shape_diff`` (% of the original's silhouette).

Writes ``OUT/CHAR-R.png``, ``OUT/CHAR-R.json`` and ``OUT/summary.md`` (worst
``shape_diff`` per character, level and tool).

Usage::

    python benchmarks/lod_sheets.py [--out DIR] [--ratios 0.25,0.1] [--only NAME ...] [--size 220] [--keep DIR]
        [--index FOLDER/index.json]
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
for _p in (ROOT, ROOT / "tests"):
    if str(_p) not in sys.path:
        sys.path.insert(0, str(_p))

from benchmarks.datasets import index_characters, suite  # noqa: E402
from benchmarks.peers import PeerError, at_faces, available, count_faces  # noqa: E402
from benchmarks.render_posed import contact_sheet  # noqa: E402

RIGSLIM = [sys.executable, "-m", "rigslim.cli"]


def rigslim_level(path: Path, tmp: Path, ratio: float) -> Path:
    """``rigslim lod IN -o OUT --ratios R --split``: the level's file (one run per ratio, so that a level that
    stops short of its target, or merges with another, still gives the file that command writes; where it writes
    no level at all, the source, which is what the user then shows)."""
    out = tmp / f"{path.stem}-rigslim-{ratio:g}.glb"
    done = sorted(tmp.glob(f"{out.stem}-*.glb"), key=count_faces)
    if done:
        return done[0]
    p = subprocess.run([*_rigslim(), "lod", str(path), "-o", str(out), "--ratios", f"{ratio:g}", "--split"],
                       capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"rigslim lod {path.name} --ratios {ratio:g}: {p.stderr.strip()[-400:]}")
    sys.stderr.write("".join(f"  {line}\n" for line in p.stderr.strip().splitlines()))
    written = sorted(tmp.glob(f"{out.stem}-*.glb"), key=count_faces)
    return written[0] if written else path      # no level (the bound before the first collapse): the source


def _rigslim() -> list[str]:
    exe = Path(sys.executable).with_name("rigslim")
    return [str(exe)] if exe.exists() else RIGSLIM


def level_ratio(ratio: float, faces: int, floor: int = 0) -> float:
    """``ratio``, raised so that the level keeps at least ``floor`` faces (at most 0.5): a 10 % level of a
    700-face wolf is 70 faces, which no game ships; its far level is a few hundred faces."""
    if floor and faces * ratio < floor:
        return round(min(0.5, floor / faces), 2)
    return ratio


def sheets_for(c, out: Path, tmp: Path, ratios: list[float], size: int, renderer, floor: int = 0) -> list[dict]:
    rows = []
    for ratio in sorted({level_ratio(r, c.faces, floor) for r in ratios}, reverse=True):
        try:
            level = rigslim_level(c.path, tmp, ratio)
        except RuntimeError as e:
            print(f"  {e}", file=sys.stderr)
            rows.append({"character": c.name, "ratio": ratio, "faces": c.faces, "sheet": "", "worst": {},
                         "error": str(e)})
            continue
        faces = count_faces(level)
        files, labels = [c.path, level], ["original", "rigslim lod"]
        for tool in ("gltf-transform", "gltfpack"):
            if not available()[tool]:
                continue
            dst = tmp / f"{c.name}-{tool}-{ratio:g}.glb"
            if dst.exists():
                files.append(dst)
                labels.append(tool)
                continue
            try:
                r = at_faces(tool, c.path, dst, faces)
            except PeerError as e:
                print(f"  {tool} failed: {e}", file=sys.stderr)
                continue
            files.append(r.path)
            labels.append(tool)
        poses = [(t["clip"], t["time"]) for t in c.test_renders]
        from PIL import Image

        sheet, records = contact_sheet(files, poses, ["side", "front"], labels=labels, diff=True, size=size,
                                       renderer=renderer)
        stem = out / f"{c.name}-{round(100 * ratio)}"
        Image.fromarray(sheet).save(stem.with_suffix(".png"))
        worst = {}
        for rec in records:
            for f in rec["files"][1:]:
                w = worst.setdefault(f["label"], {"faces": f["faces"], "shape_diff": 0.0, "iou": 1.0})
                w["shape_diff"] = max(w["shape_diff"], f["shape_diff"])
                w["iou"] = min(w["iou"], f["iou"])
        rows.append({"character": c.name, "ratio": ratio, "faces": c.faces, "sheet": str(stem.with_suffix(".png")),
                     "worst": worst})
        stem.with_suffix(".json").write_text(json.dumps({"row": rows[-1], "records": records}, indent=1) + "\n")
        cells = ", ".join(f"{k} {v['faces']}f {100 * v['shape_diff']:.1f}%" for k, v in worst.items())
        print(f"{c.name} {ratio:g}: {cells}", flush=True)
    return rows


def summary(rows: list[dict]) -> str:
    tools = ["rigslim lod", "gltf-transform", "gltfpack"]
    lines = ["| character | level | " + " | ".join(f"{t} faces / worst shape diff / min IoU" for t in tools)
             + " | sheet |", "|---|---|" + "---|" * len(tools) + "---|"]
    for r in rows:
        if r.get("error"):
            lines.append(f"| {r['character']} ({r['faces']}) | {100 * r['ratio']:g} % | rigslim lod failed: "
                         f"{r['error'][-120:]} | | | |")
            continue
        cells = []
        for t in tools:
            w = r["worst"].get(t)
            cells.append(f"{w['faces']} / {100 * w['shape_diff']:.1f} % / {w['iou']:.3f}" if w else "-")
        lines.append(f"| {r['character']} ({r['faces']}) | {100 * r['ratio']:g} % | " + " | ".join(cells)
                     + f" | {Path(r['sheet']).name} |")
    return "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=Path("out/lod-sheets"))
    ap.add_argument("--ratios", default="0.25,0.1")
    ap.add_argument("--only", nargs="*", default=None)
    ap.add_argument("--size", type=int, default=220)
    ap.add_argument("--floor", type=int, default=0,
                    help="raise a ratio so that the level keeps at least this many faces (e.g. 250)")
    ap.add_argument("--keep", type=Path, default=None,
                    help="keep the level files here and reuse those already there (re-render without re-running)")
    ap.add_argument("--index", type=Path, default=None,
                    help="characters of this index (tools/suite/sweep.py's FOLDER/index.json) instead of the suite")
    args = ap.parse_args(argv)
    from support.posed_render import PosedRenderer

    def characters(names=None):
        return suite(names) if args.index is None else index_characters(args.index, names)

    args.out.mkdir(parents=True, exist_ok=True)
    ratios = [float(r) for r in args.ratios.split(",")]
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigslim-sheets-") as tmp, \
            PosedRenderer(size=(args.size, args.size)) as renderer:
        for c in characters(args.only):
            work = (args.keep or Path(tmp)) / c.name
            work.mkdir(parents=True, exist_ok=True)
            rows.extend(sheets_for(c, args.out, work, ratios, args.size, renderer, args.floor))
    # the summary covers every sheet in the folder (earlier runs with --only included), in suite order
    order = {c.name: i for i, c in enumerate(characters())}
    done = {(r["character"], r["ratio"]): r for r in rows}
    for f in args.out.glob("*.json"):
        doc = json.loads(f.read_text())
        if isinstance(doc, dict) and "row" in doc:
            done.setdefault((doc["row"]["character"], doc["row"]["ratio"]), doc["row"])
    rows = sorted(done.values(), key=lambda r: (order.get(r["character"], 99), -r["ratio"]))
    (args.out / "summary.md").write_text(summary(rows))
    print(summary(rows))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
