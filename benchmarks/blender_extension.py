"""The Blender extension on the bundled characters: held-out error against Blender's Limit Total, LODs, renders.

    .venv/bin/python benchmarks/blender_extension.py [--k 2] [--characters tube,huesitos,...] [--suite]

Needs .venv-blender (tools/setup-blender.sh). For every character it builds the extension zip, then
runs tests/support/blender_driver.py in Blender (the bpy module): the zip installed as a user
extension, Limit Influences run with rigslim's default reduction and with ``best-fit`` selection,
the error of both and of Blender's own Limit Total + Normalize All measured by posing the meshes
with Blender's depsgraph at held-out frames, then Generate Skinned LODs. Writes
docs/results/blender_extension.json and .md, and, with benchmarks/blender_render.py, the Workbench
renders docs/images/blender-limit-NAME.png and docs/images/blender-lods-NAME.png. Quality figures
only (errors, faces); the times in the JSON are the worker's wall clock on a shared machine.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
GLTF = ROOT / "examples" / "data" / "gltf"
CHARACTERS = {"tube": None, "huesitos": GLTF / "huesitos.glb",
              "animation_with_skeleton": GLTF / "animation_with_skeleton.glb",
              "RiggedFigure": GLTF / "RiggedFigure" / "RiggedFigure.gltf"}
RENDERED = ("tube", "animation_with_skeleton")
#: name -> (fitted actions, held-out actions) for characters whose suite entry holds clips out
CLIPS: dict[str, tuple[list[str], list[str]]] = {}


def blender(script: Path, zip_path: Path, *args: str) -> None:
    with tempfile.TemporaryDirectory() as user:
        env = {k: v for k, v in os.environ.items() if k not in ("RIGSLIM_PYTHON", "PYTHONPATH")}
        env["BLENDER_USER_RESOURCES"] = user
        proc = subprocess.run([str(BLENDER_PY), str(script), "--zip", str(zip_path), "--rigslim-python",
                               sys.executable, *args], capture_output=True, text=True, env=env)
    if proc.returncode != 0:
        raise SystemExit(f"{script.name} {' '.join(args)} failed:\n{proc.stdout[-2000:]}\n{proc.stderr[-2000:]}")


def driver(zip_path: Path, name: str, k: int, select: str, lods: bool) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        out = Path(tmp) / "r.json"
        args = ["--out", str(out), "--k", str(k), "--select", select, "--max-bones", "4", "--no-keep-better"]
        if name in CLIPS:
            args += ["--actions", ", ".join(CLIPS[name][0]), "--test-actions", ", ".join(CLIPS[name][1])]
        if CHARACTERS[name] is not None:
            args += ["--gltf", str(CHARACTERS[name])]
        if not lods:
            args.append("--skip-lods")
        blender(ROOT / "tests" / "support" / "blender_driver.py", zip_path, *args)
        return json.loads(out.read_text())


def sheet(paths: list[Path], target: Path, labels: list[str]) -> None:
    from PIL import Image, ImageDraw

    ims = [Image.open(p).convert("RGB") for p in paths]
    w, h = ims[0].size
    out = Image.new("RGB", (w * len(ims), h + 28), "white")
    draw = ImageDraw.Draw(out)
    for i, (im, label) in enumerate(zip(ims, labels, strict=True)):
        out.paste(im, (i * w, 28))
        draw.text((i * w + 8, 8), label, fill=(0, 0, 0))
    target.parent.mkdir(parents=True, exist_ok=True)
    out.save(target, optimize=True)


def renders(zip_path: Path, name: str, k: int) -> dict:
    with tempfile.TemporaryDirectory() as tmp:
        args = ["--out", tmp, "--k", str(k), "--max-bones", "4"]
        if CHARACTERS[name] is not None:
            args += ["--gltf", str(CHARACTERS[name])]
        blender(ROOT / "benchmarks" / "blender_render.py", zip_path, *args)
        fig = json.loads((Path(tmp) / "figures.json").read_text())
        e = fig["errors_at_frame"]
        scale = fig["colour_scale_pct"]
        sheet([Path(tmp) / f"{n}.png" for n in ("input", "limit_total", "rigslim", "rigslim_best_fit")],
              ROOT / "docs" / "images" / f"blender-limit-{name}.png",
              ["input weights", f"Limit Total k={k}: {e['limit_total']['rms_pct']:.3g} % RMS",
               f"rigslim default: {e['rigslim']['rms_pct']:.3g} % RMS",
               f"rigslim best-fit: {e['rigslim_best_fit']['rms_pct']:.3g} % RMS"])
        levels = fig["levels"]
        sheet([Path(tmp) / f"lod{i}.png" for i in range(len(levels))], ROOT / "docs" / "images" /
              f"blender-lods-{name}.png", [f"{lv['name']}: {lv['triangles']} triangles" for lv in levels])
        fig["colour_scale_pct"] = scale
        return fig


def ratio(theirs: float, ours: float) -> str:
    """Limit Total's error over rigslim's ("-" when both are zero: nothing to limit)."""
    if theirs == 0 and ours == 0:
        return "-"
    return f"{theirs / ours:.3g}x" if ours > 0 else "inf"


def markdown(rows: list[dict], figures: dict, k: int) -> str:
    out = [f"# Blender extension: Limit Influences and Generate Skinned LODs (k = {k})", "",
           f"Written by `benchmarks/blender_extension.py` (Blender {rows[0]['blender']} as the bpy module, "
           f"{platform.processor() or platform.machine()}, Python {platform.python_version()}). "
           "Errors are measured by Blender: the meshes posed by the depsgraph at held-out frames (every 4th "
           "sampled frame, never fitted), RMS vertex distance per frame as % of the rest bounding-box diagonal, "
           "mean over frames; max is the largest vertex distance.", "",
           "| character | vertices | input max influences | held-out frames | Limit Total RMS % (max %) | "
           "rigslim default | RMS % (max %) | ratio | best-fit RMS % (max %) | ratio |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|"]
    if any(r.get("clips") for r in rows):
        out[2] = out[2].replace("held-out frames (every 4th sampled frame, never fitted)",
                                "every frame of the held-out clips (never fitted; the others' frames are fitted)")
        out.insert(3, "\nClips (fitted / held out): " + "; ".join(
            f"{r['name']}: {', '.join(r['clips'][0])} / {', '.join(r['clips'][1])}" for r in rows if r.get("clips"))
            + ". Raw fits (keep-Limit-Total fallback off).")
    for r in rows:
        d, b = r["default"], r["best_fit"]
        out.append(f"| {r['name']} | {r['vertices']} | {d['input_max_influences']} | {d['measured_frames']} | "
                   f"{d['limit_total_rms_pct']:.4g} ({d['limit_total_max_pct']:.3g}) | {d['select']} + {d['solve']} | "
                   f"{d['rms_pct']:.4g} ({d['max_pct']:.3g}) | {ratio(d['limit_total_rms_pct'], d['rms_pct'])}"
                   f" | {b['rms_pct']:.4g} ({b['max_pct']:.3g}) | "
                   f"{ratio(b['limit_total_rms_pct'], b['rms_pct'])} |")
    out += ["", "Generate Skinned LODs (ratios 0.5, 0.25, bone limit 4; faces are triangles):", "",
            "| character | source triangles | LOD1 | LOD2 | LODs valid (groups <= 4, sums 1, materials, UVs) |",
            "|---|---:|---:|---:|---|"]
    for r in rows:
        lods = r["lods"]
        ok = all(lv["valid"] and lv["max_groups"] <= 4 and lv["max_sum_error"] < 1e-5 and lv["groups_are_bones"]
                 and lv["materials"] == r["materials"] and lv["uv_finite"] for lv in lods)
        cells = [str(lv["faces"]) for lv in lods] + [""] * (2 - len(lods))
        out.append(f"| {r['name']} | {r['triangles']} | {' | '.join(cells[:2])} | {'yes' if ok else 'NO'} |")
    if figures:
        out += ["", "Renders (docs/images/blender-*.png), at the held-out frame where Limit Total errs most:", ""]
        for name, fig in figures.items():
            out.append(f"- {name}: {fig['action']} frame {fig['frame']}, colour scale 0 to "
                       f"{fig['colour_scale_pct']:.3g} % of the diagonal")
    return "\n".join(out) + "\n"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--k", type=int, default=2)
    ap.add_argument("--characters", default=",".join(CHARACTERS))
    ap.add_argument("--no-renders", action="store_true")
    ap.add_argument("--suite", action="store_true", help="also every character of examples/data/gltf/suite/suite.json")
    ap.add_argument("--suite-dir", default=str(GLTF / "suite"), help="folder of suite.json (default: %(default)s)")
    ap.add_argument("--output", default="blender_extension", help="name of the docs/results files")
    ap.add_argument("--clip-split", action="store_true",
                    help="suite characters with held-out clips: fit on the fit clips, measure on the held-out ones")
    ap.add_argument("--renders-only", action="store_true",
                    help="keep the figures of docs/results/OUTPUT.json, render the named characters again")
    args = ap.parse_args()
    names = [n for n in args.characters.split(",") if n]
    if args.suite:
        suite = json.loads((Path(args.suite_dir) / "suite.json").read_text())
        for ch in suite["characters"]:
            CHARACTERS[ch["name"]] = Path(args.suite_dir) / Path(ch["file"]).name
            if args.clip_split and ch.get("holdout_clips"):
                CLIPS[ch["name"]] = (list(ch["fit_clips"]), list(ch["holdout_clips"]))
            elif args.clip_split:
                continue
            names.append(ch["name"])
    if not BLENDER_PY.exists():
        print(f"{BLENDER_PY} missing: run tools/setup-blender.sh", file=sys.stderr)
        return 2
    dist = Path(tempfile.mkdtemp())
    subprocess.run([sys.executable, str(ROOT / "integrations/blender/build.py"), "--output", str(dist)], check=True,
                   capture_output=True)
    zip_path = next(dist.glob("rigslim-*.zip"))
    rows, figures = [], {}
    results = ROOT / "docs" / "results"
    if args.renders_only:
        old = json.loads((results / f"{args.output}.json").read_text())
        rows, figures = old["rows"], old["figures"]
        for name in names:
            figures[name] = renders(zip_path, name, old["k"])
        names = []
    for name in names:
        full = driver(zip_path, name, args.k, "", True)
        best = driver(zip_path, name, args.k, "best-fit", False)
        rows.append({"name": name, "clips": CLIPS.get(name), "blender": full["blender"], "object": full["object"],
                     "vertices": full["groups"]["vertices"], "triangles": full["source_triangles"],
                     "materials": full["source_materials"], "default": full["limit"], "best_fit": best["limit"],
                     "independent_default": full["independent"], "lods": full["lods"],
                     "lod_record": full["lod_record"]})
        d = full["limit"]
        print(f"{name:24s} Limit Total {d['limit_total_rms_pct']:.4g} %  rigslim {d['rms_pct']:.4g} %  "
              f"best-fit {best['limit']['rms_pct']:.4g} %  LODs {[lv['faces'] for lv in full['lods']]}", flush=True)
        if name in RENDERED and not args.no_renders:
            figures[name] = renders(zip_path, name, args.k)
    results.mkdir(parents=True, exist_ok=True)
    (results / f"{args.output}.json").write_text(json.dumps({"k": args.k, "rows": rows, "figures": figures},
                                                               indent=1))
    (results / f"{args.output}.md").write_text(markdown(rows, figures, args.k))
    print((results / f"{args.output}.md").read_text())
    return 0


if __name__ == "__main__":
    sys.exit(main())
