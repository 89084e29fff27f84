"""Levels fitted on every clip against levels fitted on the first clip only, measured on every clip.

``rigslim lod`` fits its collapses to example frames of every clip (since 2026-12-05); before, it fitted the
first clip only, so a limb that only a later clip moves was simplified as if it never moved. Per suite
character with two or more clips and per ratio R (0.25, 0.1; ``--max-error none``, so that both levels have
the same face count):

- *every clip*: ``rigslim lod IN -o A --ratios R --max-error none --report A.json`` (the default);
- *first clip*: the same with ``--clip FIRST`` (what ``lod`` did before);
- each level measured by ``rigslim compare IN LEVEL --clip C --frames F --level 1 --json`` on every clip C,
  on the frames F that are held out by both fits (the every-clip report's ``clips.test`` less the first-clip
  fit's example frames; at most 6 per clip, evenly): two-sided Hausdorff RMS averaged over the frames / max
  over them, % of the input's world diagonal.

The summary per character: the mean over clips of the RMS ratio (every / first), and the worst clip's RMS of
each (the level a player sees in every clip is as good as its worst clip).

Usage::

    .venv/bin/python benchmarks/lod_clips.py [--suite examples/data/gltf/suite] [--only NAME ...]

Writes docs/results/lod_clips.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402

RIGSLIM = [str(Path(sys.executable).with_name("rigslim"))]
RATIOS = (0.25, 0.1)
FRAMES_PER_CLIP = 6


def rigslim(args: list[str]) -> str:
    p = subprocess.run(RIGSLIM + args, capture_output=True, text=True)
    if p.returncode != 0:
        raise RuntimeError(f"rigslim {' '.join(args)} failed: {p.stderr.strip()[-600:]}")
    return p.stdout


def level(src: Path, out: Path, ratio: float, clip: str | None) -> dict:
    """One level at ``ratio`` (no error bound) and its report."""
    report = out.with_suffix(".json")
    rigslim(["lod", str(src), "-o", str(out), "--ratios", f"{ratio:g}", "--max-error", "none", "--report",
             str(report), *(["--clip", clip] if clip else [])])
    return json.loads(report.read_text())


def measure(src: Path, cand: Path, clip: str, frames: list[int]) -> dict:
    r = json.loads(rigslim(["compare", str(src), str(cand), "--clip", clip, "--frames", ",".join(map(str, frames)),
                            "--level", "1", "--json"]))
    return {"faces": r["faces"], "rms_pct": r["hausdorff_rms_pct"], "max_pct": r["hausdorff_max_pct"]}


def bench(src: Path, tmp: Path) -> list[dict]:
    rows = []
    for ratio in RATIOS:
        every = level(src, tmp / f"{src.stem}-every-{ratio:g}.glb", ratio, None)
        clips = every["clips"]["test"]
        first_name = every["clips"]["examples"][0]["clip"]
        first = level(src, tmp / f"{src.stem}-first-{ratio:g}.glb", ratio, first_name)
        fitted_first = set(first["clips"]["examples"][0]["frames"])
        row = {"character": src.stem, "ratio": ratio, "first_clip": first_name,
               "faces": {"every": every["levels"][0]["faces"], "first": first["levels"][0]["faces"]}, "clips": []}
        for c in clips:
            frames = [f for f in c["frames"] if c["clip"] != first_name or f not in fitted_first]
            frames = frames[::-(-len(frames) // FRAMES_PER_CLIP)] if frames else []
            if not frames:
                continue
            e = measure(src, tmp / f"{src.stem}-every-{ratio:g}.glb", c["clip"], frames)
            f = measure(src, tmp / f"{src.stem}-first-{ratio:g}.glb", c["clip"], frames)
            row["clips"].append({"clip": c["clip"], "frames": frames, "every": e, "first": f})
            print(f"{src.stem:14s} {ratio:4g} {c['clip']:14s} first {f['faces']}f {f['rms_pct']:.4f} / "
                  f"{f['max_pct']:.3f}   every {e['faces']}f {e['rms_pct']:.4f} / {e['max_pct']:.3f}", flush=True)
        rs = [c["every"]["rms_pct"] / c["first"]["rms_pct"] for c in row["clips"] if c["first"]["rms_pct"] > 0]
        row["mean_rms_ratio"] = sum(rs) / len(rs) if rs else None
        for side in ("every", "first"):
            worst = max(row["clips"], key=lambda c, s=side: c[s]["rms_pct"])
            row[f"worst_{side}"] = {"clip": worst["clip"], "rms_pct": worst[side]["rms_pct"],
                                    "max_pct": max(c[side]["max_pct"] for c in row["clips"])}
        rows.append(row)
    return rows


def markdown(doc: dict) -> str:
    lines = ["# `rigslim lod` fitted on every clip against the first clip only", "",
             f"Machine: {doc['machine']}. Written by `benchmarks/lod_clips.py` (module docstring: what is "
             "measured). Per level (no error bound, equal face counts): the two-sided Hausdorff RMS / max "
             "(% of the world diagonal) on each clip's frames that neither fit used, fitted on the first clip "
             "only (`--clip FIRST`, what `lod` did before) and on every clip (the default).", "",
             "| character | R | faces (first / every where they differ) | clip | first clip only | every clip | "
             "RMS ratio |",
             "|---|---|---|---|---|---|---|"]
    for row in doc["rows"]:
        for c in row["clips"]:
            f, e = c["first"], c["every"]
            ratio = e["rms_pct"] / f["rms_pct"] if f["rms_pct"] > 0 else float("nan")
            mark = " (fitted)" if c["clip"] == row["first_clip"] else ""
            faces = f"{e['faces']}" if e["faces"] == f["faces"] else f"{f['faces']} / {e['faces']}"
            lines.append(f"| {row['character']} | {row['ratio']:g} | {faces} | {c['clip']}{mark} | "
                         f"{f['rms_pct']:.4f} / {f['max_pct']:.3f} | {e['rms_pct']:.4f} / {e['max_pct']:.3f} | "
                         f"{ratio:.2f} |")
    lines += ["", "Per character and level: the mean over clips of the RMS ratio (every / first), and the worst "
              "clip's RMS with the largest max over the clips, for each fit.", "",
              "| character | R | mean RMS ratio | worst clip, first clip only | worst clip, every clip |",
              "|---|---|---|---|---|"]
    for row in doc["rows"]:
        wf, we = row["worst_first"], row["worst_every"]
        lines.append(f"| {row['character']} | {row['ratio']:g} | {row['mean_rms_ratio']:.2f} | {wf['clip']}: "
                     f"{wf['rms_pct']:.4f} / {wf['max_pct']:.3f} | {we['clip']}: {we['rms_pct']:.4f} / "
                     f"{we['max_pct']:.3f} |")
    rs = [r["mean_rms_ratio"] for r in doc["rows"] if r["mean_rms_ratio"] is not None]
    better = sum(r["worst_every"]["rms_pct"] <= r["worst_first"]["rms_pct"] for r in doc["rows"])
    lower_max = sum(r["worst_every"]["max_pct"] <= r["worst_first"]["max_pct"] for r in doc["rows"])
    lines += ["", f"Mean of the per-level mean RMS ratios: {sum(rs) / len(rs):.3f} over {len(rs)} levels; the worst "
              f"clip's RMS is no worse fitted on every clip at {better} of {len(doc['rows'])} levels, the largest "
              f"max over the clips at {lower_max} of {len(doc['rows'])}.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--suite", type=Path, default=ROOT / "examples" / "data" / "gltf" / "suite")
    ap.add_argument("--only", nargs="*")
    ap.add_argument("--name", default="lod_clips")
    ap.add_argument("--from-json", type=Path, help="rewrite the Markdown of a written JSON document")
    args = ap.parse_args(argv)
    if args.from_json:
        doc = json.loads(args.from_json.read_text())
        write_results(ROOT / "docs" / "results" / args.name, doc, markdown(doc))
        return 0
    from rigslim.io.gltf.document import load_gltf

    files = sorted(p for p in args.suite.glob("*.glb") if not args.only or p.stem in args.only)
    files = [p for p in files if len(load_gltf(p).json.get("animations", [])) >= 2]
    rows = []
    with tempfile.TemporaryDirectory(prefix="rigslim-lod-clips-") as tmp:
        for src in files:
            rows += bench(src, Path(tmp))
    m = machine()
    doc = {"machine": f"{m['cpu']}, nproc {m['nproc']}, Python {m['python']}",
           "ratios": list(RATIOS), "frames_per_clip": FRAMES_PER_CLIP, "rows": rows}
    write_results(ROOT / "docs" / "results" / args.name, doc, markdown(doc))
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
