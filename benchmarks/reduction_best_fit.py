"""best-fit influence sets against k-largest sets and Dem Bones (the tables of docs/results/reduction_quality_best_fit).

Parts (``--parts``, default all but ``386k``):

- ``elephant``: k = 4, every selector x solver row, Dem Bones' weight solve
  (py-dem-bones, ``bench`` extra; ``computeWeights`` with the true bone
  transforms held fixed, nnz = 4) in the same run; times of select, solve and
  Dem Bones side by side (each the best of ``--repeat`` runs, after a warm-up
  that compiles the numba kernels);
- ``ks``: the elephant at k = 2, 3, 5, 6, 8: best-fit + geometric against Dem Bones;
- ``cheb``: the Cheb, bone-heat weights, 17 -> 5 (``examples/cheburashka-k5.yaml``);
- ``armadillo``: mean value coordinates of a 110-vertex cage, 110 -> 8
  (``examples/armadillo-k8.yaml``), Poisson with ``position_weight: auto``;
- ``386k``: the elephant subdivided three times (386,050 vertices), best-fit +
  geometric against Dem Bones, times only plus errors on every 4th test frame.

Errors are measured on test frames never used for fitting (elephant: examples
``0:457:45``, test ``5:457:7`` minus 180, 64 frames): position RMS over vertices
(% of the bounding-box diagonal) and normal RMS angle (rad, area-weighted normals
recomputed on both deformations), per frame, averaged over frames; p99 is the
99th percentile of the per-vertex normal angle, averaged over frames.

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/reduction_best_fit.py
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from benchmarks.datasets import elephant, machine, write_results  # noqa: E402
from benchmarks.reduction_speed import dem_bones_weights  # noqa: E402

OUT = ROOT / "docs" / "results"


def errors(asset, reduced, frames=None):
    """Mean over frames of position RMS (% diag), normal RMS (rad) and the normal angle's p99 (rad)."""
    from rigslim.numerics.blend import linear_blend, per_vertex_normals
    from rigslim.numerics.normal_error import normal_angles

    frames = asset.split.test if frames is None else frames
    V, F = asset.mesh.V, asset.mesh.F
    T = asset.poses.select(frames).T
    pos, nrm, p99 = [], [], []
    for j in range(len(T)):
        full = linear_blend(V, asset.weights, T[j])
        red = linear_blend(V, reduced, T[j])
        pos.append(100.0 * np.sqrt(np.mean(np.sum((full - red) ** 2, axis=1))) / asset.mesh.bbox_diagonal)
        theta = normal_angles(per_vertex_normals(red, F), per_vertex_normals(full, F))
        nrm.append(np.sqrt(np.mean(theta ** 2)))
        p99.append(np.percentile(theta, 99))
    return float(np.mean(pos)), float(np.mean(nrm)), float(np.mean(p99))


def timed(fn, repeat):
    """(result of the last call, best seconds over ``repeat`` calls)."""
    best = np.inf
    for _ in range(repeat):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return out, best


def select(asset, selector, k, repeat, **params):
    from rigslim.numerics.largest_entries import k_largest
    from rigslim.plugins.selection.best_fit import best_fit

    if selector == "k-largest":
        return timed(lambda: (k_largest(asset.weights, k), {}), repeat)
    return timed(lambda: best_fit(asset, k, **params), repeat)


def solve(asset, method, repeat, **params):
    from rigslim.plugin import StepContext
    from rigslim.plugins.solvers.methods import GeometricSolver, PoissonSolver, SmoothSolver
    from rigslim.plugins.solvers.renormalised import renormalised_weights

    if method == "k-largest":
        return timed(lambda: (renormalised_weights(asset.weights, asset.influences), {}), repeat)
    plugin = {"geometric": GeometricSolver, "smooth": SmoothSolver, "poisson": PoissonSolver}[method]()

    def run():
        ctx = StepContext()
        red = plugin.solve(asset, plugin.parse_params(params), ctx)
        return red, ctx.report
    return timed(run, repeat)


def dem_bones(asset, k, repeat):
    best, W = np.inf, None
    for _ in range(repeat):
        W, secs = dem_bones_weights(asset, k)
        best = min(best, secs)
    return W, best


def row(label, asset, reduced, sel_s, solve_s, report=None):
    p, n, n99 = errors(asset, reduced)
    r = {"method": label, "position_pct": p, "normal_rad": n, "normal_p99_rad": n99, "select_s": sel_s,
         "solve_s": solve_s, "total_s": (sel_s or 0.0) + (solve_s or 0.0)}
    if report and "position_weight_auto" in report:
        r["position_weight"] = report["position_weight"]
        r["folds"] = report["position_weight_auto"].get("fold_count")
        r["held_out"] = [{kk: g[kk] for kk in ("position_weight", "position_rms_pct", "normal_rms_rad", "score")}
                         for g in report["position_weight_auto"]["grid"]]
    print(f"  {label:<44} pos {p:.4f}  nrm {n:.4f}  p99 {n99:.4f}  select {sel_s or 0:.3f}s  "
          f"solve {solve_s or 0:.3f}s" + (f"  lambda {r['position_weight']:g}" if "position_weight" in r else ""),
          flush=True)
    return r


ELEPHANT_ROWS = [
    # (label, selector, selector params, solver, solver params)
    ("k-largest", "k-largest", {}, "k-largest", {}),
    ("geometric on k-largest", "k-largest", {}, "geometric", {}),
    ("poisson on k-largest", "k-largest", {}, "poisson", {}),
    ("best-fit by weight + geometric", "best-fit", {"by": "weight"}, "geometric", {}),
    ("best-fit by error + geometric", "best-fit", {"by": "error"}, "geometric", {}),
    ("best-fit by error, 2 swaps + geometric", "best-fit", {"by": "error", "swaps": 2}, "geometric", {}),
    ("best-fit by weight, one-ring vote 0.5 + geometric", "best-fit", {"by": "weight", "coherence": 0.5},
     "geometric", {}),
    ("best-fit by weight, one-ring vote 1 + geometric", "best-fit", {"by": "weight", "coherence": 1.0},
     "geometric", {}),
    ("best-fit by error + smooth", "best-fit", {"by": "error"}, "smooth", {}),
    ("best-fit by error + poisson", "best-fit", {"by": "error"}, "poisson", {}),
    ("best-fit by error + poisson, lambda auto", "best-fit", {"by": "error"}, "poisson", {"position_weight": "auto"}),
    ("poisson on k-largest, lambda auto", "k-largest", {}, "poisson", {"position_weight": "auto"}),
]


def part_elephant(repeat):
    asset = elephant(0)
    k = 4
    rows = []
    print(f"elephant k = {k}", flush=True)
    for label, selector, sparams, solver, params in ELEPHANT_ROWS:
        slow = solver != "geometric" and solver != "k-largest"
        (sets, _), sel_s = select(asset, selector, k, repeat, **sparams)
        asset.influences = sets
        (red, rep), solve_s = solve(asset, solver, 1 if slow else repeat, **params)
        rows.append(row(label, asset, red, sel_s, solve_s, rep))
    W, secs = dem_bones(asset, k, repeat)
    rows.append(row(f"Dem Bones computeWeights (nnz = {k})", asset, W, None, secs))
    return {"k": k, "vertices": asset.mesh.n_vertices, "rows": rows}


def part_ks(repeat):
    asset = elephant(0)
    out = []
    for k in (2, 3, 4, 5, 6, 8):
        print(f"elephant k = {k}", flush=True)
        rows = []
        for label, by in (("best-fit by error + geometric", "error"), ("best-fit by weight + geometric", "weight")):
            (sets, _), sel_s = select(asset, "best-fit", k, repeat, by=by)
            asset.influences = sets
            (red, _), solve_s = solve(asset, "geometric", repeat)
            rows.append(row(label, asset, red, sel_s, solve_s))
        W, secs = dem_bones(asset, k, repeat)
        rows.append(row("Dem Bones computeWeights", asset, W, None, secs))
        out.append({"k": k, "rows": rows})
    return out


def pipeline_asset(yaml_name):
    from rich.console import Console

    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs
    from rigslim.runtime.progress import Reporter
    from rigslim.runtime.run import _run_step

    path = ROOT / "examples" / yaml_name
    host = get_host()
    doc, steps = load_pipeline(path, host=host)
    reporter = Reporter(Console(quiet=True))
    asset = read_inputs(doc, path.parent, host, reporter.context(path.parent), path)
    gen = next(s for s in steps if s.key == "generate")
    t = time.perf_counter()
    _run_step(gen, asset, host, reporter.context(path.parent), path.parent, path, {"evaluations": []})
    k = next(s for s in steps if s.key == "select").params["k"]
    return asset, k, time.perf_counter() - t


def part_pipeline(yaml_name, rows_spec, repeat, dem=False):
    asset, k, gen_s = pipeline_asset(yaml_name)
    print(f"{yaml_name}: {asset.mesh.n_vertices} vertices, {asset.handles.n} handles, k = {k}", flush=True)
    rows = []
    for label, selector, sparams, solver, params in rows_spec:
        slow = solver not in ("geometric", "k-largest")
        (sets, _), sel_s = select(asset, selector, k, 1 if slow else repeat, **sparams)
        asset.influences = sets
        (red, rep), solve_s = solve(asset, solver, 1 if slow else repeat, **params)
        rows.append(row(label, asset, red, sel_s, solve_s, rep))
    if dem:
        W, secs = dem_bones(asset, k, repeat)
        rows.append(row(f"Dem Bones computeWeights (nnz = {k})", asset, W, None, secs))
    return {"pipeline": f"examples/{yaml_name}", "k": k, "vertices": asset.mesh.n_vertices,
            "handles": asset.handles.n, "generate_s": gen_s, "examples": asset.split.examples,
            "test_frames": len(asset.split.test), "rows": rows}


CHEB_ROWS = [
    ("k-largest", "k-largest", {}, "k-largest", {}),
    ("geometric on k-largest", "k-largest", {}, "geometric", {}),
    ("poisson on k-largest, lambda auto", "k-largest", {}, "poisson", {"position_weight": "auto"}),
    ("best-fit by weight + geometric", "best-fit", {"by": "weight"}, "geometric", {}),
    ("best-fit by error + geometric", "best-fit", {"by": "error"}, "geometric", {}),
    ("best-fit by error + poisson, lambda auto", "best-fit", {"by": "error"}, "poisson", {"position_weight": "auto"}),
]
ARMADILLO_ROWS = [
    ("k-largest", "k-largest", {}, "k-largest", {}),
    ("geometric on k-largest", "k-largest", {}, "geometric", {}),
    ("best-fit by weight + geometric", "best-fit", {"by": "weight"}, "geometric", {}),
    ("best-fit by error + geometric", "best-fit", {"by": "error"}, "geometric", {}),
    ("best-fit by error + poisson, lambda auto", "best-fit", {"by": "error"}, "poisson",
     {"position_weight": "auto", "position_weight_grid": [0.01, 0.1, 1.0]}),
]


def part_386k(repeat):
    from benchmarks.reduction_speed import TEST_STRIDE

    asset = elephant(3)
    k = 4
    print(f"elephant {asset.mesh.n_vertices} vertices, k = {k}", flush=True)
    frames = asset.split.test[::TEST_STRIDE[3]]
    out = []
    for label, by in (("best-fit by weight + geometric", "weight"), ("best-fit by error + geometric", "error")):
        (sets, _), sel_s = select(asset, "best-fit", k, repeat, by=by)
        asset.influences = sets
        (red, _), solve_s = solve(asset, "geometric", repeat)
        p, n, n99 = errors(asset, red, frames)
        out.append({"method": label, "select_s": sel_s, "solve_s": solve_s, "total_s": sel_s + solve_s,
                    "position_pct": p, "normal_rad": n, "normal_p99_rad": n99})
        print(f"  {label:<44} select {sel_s:.2f}s solve {solve_s:.2f}s pos {p:.4f} nrm {n:.4f}", flush=True)
    W, secs = dem_bones(asset, k, 1)
    p, n, n99 = errors(asset, W, frames)
    out.append({"method": "Dem Bones computeWeights", "total_s": secs, "position_pct": p, "normal_rad": n,
                "normal_p99_rad": n99})
    print(f"  Dem Bones {secs:.2f}s pos {p:.4f} nrm {n:.4f}", flush=True)
    return {"vertices": asset.mesh.n_vertices, "k": k, "test_frames": len(frames), "rows": out}


def fmt(x, d=4):
    return "" if x is None else f"{x:.{d}f}"


def table(rows, times=True):
    head = "| method | position RMS (% diag) | normal RMS (rad) | normal p99 (rad) |"
    head += " select (s) | solve (s) | total (s) |" if times else ""
    lines = [head, "|" + "---|" * (head.count("|") - 1)]
    for r in rows:
        line = f"| {r['method']} | {fmt(r['position_pct'])} | {fmt(r['normal_rad'])} | {fmt(r.get('normal_p99_rad'))} |"
        if times:
            line += f" {fmt(r.get('select_s'), 3)} | {fmt(r.get('solve_s'), 3)} | {fmt(r.get('total_s'), 3)} |"
        if "position_weight" in r:
            line = line.replace(f"| {r['method']} |", f"| {r['method']} (chose {r['position_weight']:g}) |", 1)
        lines.append(line)
    return lines


def markdown(doc):
    m = doc["machine"]
    out = ["# Reduction quality with best-fit influence sets", "",
           f"Machine: {m['cpu']}, nproc {m['nproc']}, Python {m['python']}. "
           "`flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/reduction_best_fit.py "
           f"--parts PART` wrote this, one run per part ({', '.join(doc['parts'])}). "
           "Errors on test frames never used for fitting, means "
           "over frames; normal p99: the 99th percentile of the per-vertex normal angle, mean over frames. "
           "Times: best of the repeats (Poisson rows: one run), after a warm-up; `total` is select + solve. "
           "All skeleton rows non-negative (the default).", ""]
    if "elephant" in doc:
        e = doc["elephant"]
        out += [f"## Elephant, k = {e['k']} ({e['vertices']:,} vertices, 24 bones, 11 example poses, 64 test frames)",
                ""] + table(e["rows"]) + [""]
    if "ks" in doc:
        out += ["## Elephant, k = 2 ... 8, against Dem Bones", "",
                "| k | method | position RMS (% diag) | normal RMS (rad) | normal p99 (rad) | total (s) |",
                "|---|---|---|---|---|---|"]
        for blk in doc["ks"]:
            for r in blk["rows"]:
                out.append(f"| {blk['k']} | {r['method']} | {fmt(r['position_pct'])} | {fmt(r['normal_rad'])} | "
                           f"{fmt(r['normal_p99_rad'])} | {fmt(r['total_s'], 3)} |")
        out.append("")
    for key, title in (("cheb", "Cheb, bone heat, 17 -> 5"),
                       ("armadillo", "Armadillo, mean value coordinates, 110 -> 8")):
        if key in doc:
            c = doc[key]
            out += [f"## {title} (`{c['pipeline']}`: {c['vertices']:,} vertices, {c['handles']} handles, "
                    f"example frames {c['examples']}, {c['test_frames']} test frames)", ""] + table(c["rows"]) + [""]
            for r in c["rows"]:
                if "held_out" in r:
                    cv = f"{r['folds']}-fold cross-validated" if r.get("folds") else "held-out"
                    out.append(f"- {r['method']}: {cv} " + "; ".join(
                        f"lambda {g['position_weight']:g}: {g['position_rms_pct']:.4f} % / "
                        f"{g['normal_rms_rad']:.4f} rad"
                        f" (score {g['score']:.3f})" for g in r["held_out"]))
            out.append("")
    if "386k" in doc:
        b = doc["386k"]
        out += [f"## Elephant subdivided, {b['vertices']:,} vertices, k = {b['k']} "
                f"(errors on {b['test_frames']} test frames)", ""] + table(b["rows"]) + [""]
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="*", default=["elephant", "ks", "cheb", "armadillo"],
                    choices=["elephant", "ks", "cheb", "armadillo", "386k"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stem", default=str(OUT / "reduction_quality_best_fit"))
    args = ap.parse_args()
    # warm-up: compile the numba kernels outside the timings
    warm = elephant(0)
    from rigslim.plugins.selection.best_fit import best_fit

    for by in ("weight", "error"):
        warm.influences = best_fit(warm, 4, by, swaps=1)[0]
    solve(warm, "geometric", 1)
    doc = {"machine": machine(), "parts": args.parts}
    previous = Path(args.stem).with_suffix(".json")
    if previous.exists():  # keep the parts this run does not redo
        import json

        old = json.loads(previous.read_text())
        doc = {**{k: v for k, v in old.items() if k not in args.parts}, "machine": machine(),
               "parts": sorted(set(old.get("parts", [])) | set(args.parts))}
    if "elephant" in args.parts:
        doc["elephant"] = part_elephant(args.repeat)
    if "ks" in args.parts:
        doc["ks"] = part_ks(args.repeat)
    if "cheb" in args.parts:
        doc["cheb"] = part_pipeline("cheburashka-k5.yaml", CHEB_ROWS, args.repeat)
    if "armadillo" in args.parts:
        doc["armadillo"] = part_pipeline("armadillo-k8.yaml", ARMADILLO_ROWS, args.repeat)
    if "386k" in args.parts:
        doc["386k"] = part_386k(1)
    text = markdown(doc)
    write_results(args.stem, doc, text)
    print(text)


if __name__ == "__main__":
    main()
