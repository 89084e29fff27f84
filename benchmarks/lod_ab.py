"""``rigslim lod`` of the working tree against another checkout (a git revision), on real characters.

A change to the collapse costs alters every level of every character; this measures whether it helps where it
was meant to without costing elsewhere. Per character (the suite's and hold-out's, ``--group``, or those of a
sweep index, ``--index``) and per checkout:

- ``rigslim lod IN -o OUT --ratios 0.5,0.25,0.1 --max-error none --report R.json`` (no error bound: both
  checkouts reach the same face counts), the other checkout run through its own sources
  (``--base FOLDER``, e.g. ``git worktree add /tmp/base HEAD``; this environment's packages);
- each level measured by ``rigslim compare IN OUT --level L`` on the held-out frames of every clip of the
  working tree's report (:func:`benchmarks.gltf_lod.held_out_frames`, at most :data:`MAX_CLIPS` clips,
  evenly spread; :func:`benchmarks.gltf_lod.compare`): two-sided Hausdorff RMS / max, % of the world
  diagonal. Levels more than 3 % apart in faces are not compared.

The summary: per level, the geometric mean over characters of each figure's ratio (working tree / base), its
range, and how many characters got better or worse by more than 3 %.

Usage::

    git worktree add /tmp/base HEAD
    .venv/bin/python benchmarks/lod_ab.py --base /tmp/base [--index FOLDER/index.json | --group all]
        [--only NAME ...] [--name lod_ab]

Writes docs/results/NAME.{json,md}.
"""

from __future__ import annotations

import argparse
import json
import math
import subprocess
import sys
import tempfile
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from benchmarks.datasets import index_characters, machine, suite, write_results  # noqa: E402
from benchmarks.gltf_lod import RIGSLIM, compare, held_out_frames, run  # noqa: E402

RATIOS = (0.5, 0.25, 0.1)
#: Clips measured per character at most (evenly spread over its clips: re_player_all has 62).
MAX_CLIPS = 8
#: Runs the command-line interface from another checkout's sources (the editable install's finder remapped).
_BASE_CLI = """import sys
import __editable___rigslim_0_1_0_finder as finder
root = sys.argv.pop(1)
finder.MAPPING.update({"rigslim": root + "/framework", "rigslim.kernels": root + "/kernels",
                       "rigslim.plugins": root + "/plugins"})
from rigslim.commands.cli import main
sys.exit(main(sys.argv[1:]))
"""


def levels_for(path: Path, tmp: Path, base: Path, samples: int) -> dict:
    """``{"head": [...], "base": [...]}``: each checkout's levels of one character, measured."""
    runs = {"head": RIGSLIM, "base": [sys.executable, "-c", _BASE_CLI, str(base)]}
    test = None
    out = {}
    for name, cli in runs.items():
        dst, report = tmp / f"{path.stem}-{name}.glb", tmp / f"{path.stem}-{name}.json"
        run(cli + ["lod", str(path), "-o", str(dst), "--ratios", ",".join(map(str, RATIOS)), "--max-error", "none",
                    "--report", str(report)])
        rep = json.loads(report.read_text())
        if test is None:
            test = held_out_frames(rep)
            test = test[::-(-len(test) // MAX_CLIPS)]
        out[name] = [compare(path, dst, test, level, samples) for level in range(1, len(rep["levels"]) + 1)]
    return out


def _geo(xs: list[float]) -> float:
    return math.exp(sum(map(math.log, xs)) / len(xs)) if xs else float("nan")


def summary(results: dict) -> tuple[list[dict], str]:
    rows = []
    lines = ["| level | characters | RMS head / base: geometric mean (min - max) | better / worse by > 3 % "
             "| max head / base: geometric mean (min - max) | better / worse by > 3 % |", "|---|---|---|---|---|---|"]
    for i, ratio in enumerate(RATIOS):
        ratios: dict[str, list[float]] = {"rms_pct": [], "max_pct": []}
        for per in results.values():
            a, b = per["base"], per["head"]
            if i >= len(a) or i >= len(b) or abs(a[i]["faces"] - b[i]["faces"]) > 0.03 * a[i]["faces"]:
                continue
            for key, xs in ratios.items():
                if a[i][key] > 0 and b[i][key] > 0:
                    xs.append(b[i][key] / a[i][key])
        if not ratios["rms_pct"]:
            continue
        row = {"ratio": ratio, "n": len(ratios["rms_pct"])}
        cells = []
        for key, xs in ratios.items():
            row[key] = {"geo": _geo(xs), "min": min(xs), "max": max(xs), "better": sum(x < 0.97 for x in xs),
                        "worse": sum(x > 1.03 for x in xs)}
            r = row[key]
            cells.append(f"{r['geo']:.3f} ({r['min']:.2f} - {r['max']:.2f}) | {r['better']} / {r['worse']}")
        rows.append(row)
        lines.append(f"| {100 * ratio:g} % | {row['n']} | " + " | ".join(cells) + " |")
    return rows, "\n".join(lines) + "\n"


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--base", type=Path, required=True, help="the other checkout (git worktree add FOLDER REV)")
    ap.add_argument("--index", type=Path, help="a character index (tools/suite/sweep.py --out FOLDER writes one)")
    ap.add_argument("--group", default="all", choices=("suite", "holdout", "all"), help="without --index")
    ap.add_argument("--only", nargs="*", help="only these characters (by name)")
    ap.add_argument("--samples", type=int, default=20000)
    ap.add_argument("--name", default="lod_ab", help="the results' file stem in docs/results")
    args = ap.parse_args(argv)
    if not (args.base / "plugins" / "decimation").is_dir():
        ap.error(f"--base {args.base}: not a rigslim checkout (no plugins/decimation)")
    chars = index_characters(args.index, args.only) if args.index else suite(args.only, group=args.group)
    results: dict = {}
    with tempfile.TemporaryDirectory(prefix="rigslim-ab-") as t:
        for c in chars:
            try:
                results[c.name] = levels_for(c.path, Path(t), args.base, args.samples)
            except RuntimeError as e:
                print(f"{c.name}: {e}", file=sys.stderr)
                continue
            cells = "; ".join(f"{k}: " + ", ".join(f"{r['faces']}f {r['rms_pct']:.4f}/{r['max_pct']:.3f}" for r in v)
                              for k, v in results[c.name].items())
            print(f"{c.name}: {cells}", flush=True)
    rows, table = summary(results)
    rev = subprocess.run(["git", "-C", str(args.base), "rev-parse", "--short", "HEAD"], capture_output=True,
                         text=True).stdout.strip()
    md = (f"# `rigslim lod`: the working tree against {rev or args.base}\n\nMachine: {machine()}. Written by "
          f"`benchmarks/lod_ab.py` ({len(results)} characters, "
          f"{'index ' + args.index.name if args.index else 'group ' + args.group}; levels "
          f"{', '.join(map(str, RATIOS))} with `--max-error none`; errors on held-out frames of every clip, "
          "two-sided Hausdorff, % of the world diagonal).\n\n" + table)
    print(md)
    write_results(ROOT / "docs" / "results" / args.name, {"machine": machine(), "base": rev, "ratios": RATIOS,
                                                          "summary": rows, "characters": results}, md)
    return 0


if __name__ == "__main__":
    sys.exit(main())
