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


# --- the default of rigslim reduce on every character of the suite (part "suite") ---------------------------

SUITE_KS = (2, 3, 4)
#: Test frames per clip at most (evenly subsampled), so that the part stays within minutes on 2 cores.
MAX_TEST_FRAMES = 16
#: A normal p95 at or below this (rad) is 0: fewer than 5 % of the vertices turn at all (arccos of a unit dot
#: product resolves nothing below sqrt(2 eps) ~ 1.5e-8 rad; the ties measured are 5e-9 to 2e-8).
P95_ZERO = 1e-6


def clip_asset(path, fit_clips, test_clips, count=24):
    """A glTF character read as ``rigslim reduce`` reads it, with examples from ``fit_clips`` and test frames
    on ``test_clips`` (held-out frames of a fit clip, every frame of another), poses: {examples: {clips}}."""
    from rich.console import Console

    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs
    from rigslim.runtime.progress import Reporter

    raw = {"inputs": {"gltf": {"path": str(path), "fps": 30.0}},
           "poses": {"examples": {"clips": fit_clips, "count": count}, "test": {"clips": test_clips}},
           "steps": [{"select": "k-largest", "k": 1}]}
    host = get_host()
    source = Path(path).parent / "<benchmark>"
    doc, _ = load_pipeline(source, [], host, raw=raw)
    return read_inputs(doc, Path(path).parent, host, Reporter(Console(quiet=True)).context(Path(path).parent),
                       source)


def default_reduce(asset, k):
    """``rigslim reduce``'s default steps (best-fit by error, geometric with its guard); (weights, report, s)."""
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    host = get_host()
    t0 = time.perf_counter()
    sel = host.get("influence-selection", "best-fit")
    sel.apply(asset, sel.parse_params({"k": k, "by": "error"}), StepContext())
    sol = host.get("weight-solver", "geometric")
    ctx = StepContext()
    sol.apply(asset, sol.parse_params({}), ctx)
    return asset.reduced, ctx.report, time.perf_counter() - t0


def frame_errors(asset, reduced, frames):
    """Per frame: position RMS (% of the rest diagonal) and the 95th percentile of the normal angle (rad,
    area-weighted vertex normals recomputed on both deformations; vertices whose normal vanishes left out)."""
    from rigslim.numerics.blend import linear_blend, per_vertex_normals

    V, F = asset.mesh.V, asset.mesh.F
    T = asset.poses.select(list(frames)).T
    pos, p95 = [], []
    for j in range(len(T)):
        full = linear_blend(V, asset.weights, T[j])
        red = linear_blend(V, reduced, T[j])
        pos.append(100.0 * np.sqrt(np.mean(np.sum((full - red) ** 2, axis=1))) / asset.mesh.bbox_diagonal)
        a, b = per_vertex_normals(red, F), per_vertex_normals(full, F)
        na, nb = np.linalg.norm(a, axis=1), np.linalg.norm(b, axis=1)
        ok = (na > 1e-12) & (nb > 1e-12)
        cos = np.einsum("vc,vc->v", a[ok], b[ok]) / (na[ok] * nb[ok])
        p95.append(float(np.percentile(np.arccos(np.clip(cos, -1.0, 1.0)), 95)) if ok.any() else 0.0)
    return np.asarray(pos), np.asarray(p95)


def clip_test_frames(asset):
    """``{clip: stack frames}``: each test clip's frames that the errors are measured on (at most
    ``MAX_TEST_FRAMES``, evenly)."""
    out = {}
    for part in asset.split.clips["test"]:
        seg = next(s for s in asset.split.segments if s["clip"] == part["clip"])
        frames = [seg["start"] + f for f in part["frames"]]
        if len(frames) > MAX_TEST_FRAMES:
            frames = [frames[i] for i in np.linspace(0, len(frames) - 1, MAX_TEST_FRAMES).round().astype(int)]
        out[part["clip"]] = frames
    return out


def yardstick_weights(asset, k):
    """The default's selection and solve (best-fit by error + geometric, clips balanced; no guard) fitted on
    the very frames the errors are measured on, every test frame of every clip: what one weight set reaches
    with these bone transforms when it sees the test motion, the yardstick for the Dem Bones ratio."""
    import copy
    import dataclasses

    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host

    a = copy.copy(asset)
    frames = sorted({f for fr in clip_test_frames(asset).values() for f in fr})
    a.split = dataclasses.replace(asset.split, examples=frames, validation=[])
    host = get_host()
    sel = host.get("influence-selection", "best-fit")
    sel.apply(a, sel.parse_params({"k": k, "by": "error"}), StepContext())
    sol = host.get("weight-solver", "geometric")
    sol.apply(a, sol.parse_params({"guard": "off"}), StepContext())
    return a.reduced


def per_clip_rows(asset, methods):
    """For each test clip: frames, and per method the position RMS (pooled over its frames) and mean normal p95."""
    rows = []
    for clip, frames in clip_test_frames(asset).items():
        r = {"clip": clip, "frames": len(frames)}
        for name, W in methods.items():
            pos, p95 = frame_errors(asset, W, frames)
            r[name] = {"position_pct": float(np.sqrt(np.mean(pos ** 2))), "normal_p95_rad": float(np.mean(p95))}
        rows.append(r)
    return rows


def character_block(name, asset, k, fit_clips, held_clips):
    """One character at one k: the default, k-largest and Dem Bones, per test clip."""
    from rigslim.plugins.solvers.safeguards import k_largest_weights

    passes = int(np.diff(asset.weights.indptr).max()) <= k
    default, rep, secs = default_reduce(asset, k)
    methods = {"default": default, "k_largest": k_largest_weights(asset.weights, k)}
    W, dem_s = dem_bones_weights(asset, k)
    methods["dem_bones"] = W
    if not passes:
        methods["yardstick"] = yardstick_weights(asset, k)
    rows = per_clip_rows(asset, methods)
    blk = {"character": name, "k": k, "vertices": asset.mesh.n_vertices, "joints": asset.handles.n,
           "max_influences": int(np.diff(asset.weights.indptr).max()), "pass_through": passes,
           "fit_clips": fit_clips, "held_out_clips": held_clips, "examples": len(asset.split.examples),
           "validation_frames": rep.get("validation_frames", 0), "fallback_vertices": rep.get("fallback_vertices", 0),
           "default_s": secs, "dem_bones_s": dem_s, "clips": rows}
    line = "  ".join(f"{r['clip'][:12]:>12} {r['default']['position_pct']:.4f}/{r['k_largest']['position_pct']:.4f}/"
                     f"{r['dem_bones']['position_pct']:.4f}" for r in rows)
    print(f"  {name:<18} k={k} fell back {blk['fallback_vertices']:>4}  {secs:.2f}s vs {dem_s:.2f}s  {line}",
          flush=True)
    return blk


def elephant_default():
    """The elephant (one clip) as the default sees it: examples 0:457:45, validation 22:457:45 (the guard),
    test 5:457:7 minus 180 and minus validation frames."""
    import dataclasses

    from rigslim.model.poses import FrameSplit

    asset = elephant(0)
    val = list(range(22, 457, 45))
    test = [f for f in asset.split.test if f not in set(val)]
    asset = dataclasses.replace(asset, split=FrameSplit(asset.split.examples, test, [], validation=val,
                                                        clips={"test": [{"clip": "elephant", "frames": test}]},
                                                        segments=[{"clip": "elephant", "start": 0, "frames": 457}]))
    return asset


def part_suite(repeat):
    """The elephant and every suite character at k = 2, 3, 4, in two configurations: ``all`` (the one-liner:
    examples from every clip, tested on held-out frames of every clip) and, for characters with held-out
    clips, ``split`` (examples from the suite's fit clips; tested on their held-out frames and on every
    frame of the held-out clips, which neither the fit nor the guard saw)."""
    from benchmarks.datasets import suite
    from rigslim.plugins.solvers.safeguards import k_largest_weights

    out = []
    asset = elephant_default()
    for k in SUITE_KS:
        blk = character_block("elephant", asset, k, ["elephant"], [])
        blk["config"] = "all"
        if k == 4:     # the elephant target: errors on every test frame, times best of `repeat`
            red, best = None, np.inf
            for _ in range(repeat):
                red, _, secs = default_reduce(asset, k)
                best = min(best, secs)
            p, n, _ = errors(asset, red)
            dem = min(dem_bones_weights(asset, k)[1] for _ in range(repeat))
            W, _ = dem_bones_weights(asset, k)
            pd, nd, _ = errors(asset, W)
            pk, nk, _ = errors(asset, k_largest_weights(asset.weights, k))
            blk["target"] = {"position_pct": p, "normal_rad": n, "seconds": best, "dem_bones_position_pct": pd,
                             "dem_bones_normal_rad": nd, "dem_bones_s": dem, "k_largest_position_pct": pk,
                             "k_largest_normal_rad": nk, "test_frames": len(asset.split.test)}
            print(f"  elephant k=4 target: {p:.4f} % / {n:.4f} rad in {best:.3f}s; Dem Bones {pd:.4f} / {nd:.4f} "
                  f"in {dem:.3f}s; k-largest {pk:.4f} / {nk:.4f}", flush=True)
        out.append(blk)
    for c in suite():
        configs = [("all", "all", "all")]
        if c.holdout_clips:
            configs.append(("split", c.fit_clips, c.fit_clips + c.holdout_clips))
        for config, fit, test in configs:
            asset = clip_asset(c.path, fit, test)
            fit_names = [s["clip"] for s in asset.split.segments
                         if any(e["clip"] == s["clip"] for e in asset.split.clips["examples"])]
            held = [s["clip"] for s in asset.split.segments if s["clip"] not in fit_names]
            for k in SUITE_KS:
                blk = character_block(c.name, asset, k, fit_names, held)
                blk["config"] = config
                out.append(blk)
    return {"ks": list(SUITE_KS), "max_test_frames": MAX_TEST_FRAMES, "blocks": out,
            "summary": {cfg: suite_summary([b for b in out if b["config"] == cfg]) for cfg in ("all", "split")}}


def suite_summary(blocks):
    """Per k: the default's position RMS over k-largest's and Dem Bones', per clip (clips where k-largest is
    exact, i.e. pass-through, left out of the ratios), and the normal p95 comparisons."""
    out = []
    for k in sorted({b["k"] for b in blocks}):
        kl, db, yd, worse, n_better, n_clips, p95, db_max = [], [], [], [], 0, 0, [], None
        for b in (b for b in blocks if b["k"] == k):
            for r in b["clips"]:
                d, q, e = (r[m]["position_pct"] for m in ("default", "k_largest", "dem_bones"))
                n_clips += 1
                if q <= 1e-12:
                    continue
                kl.append(d / q)
                db.append(d / e if e > 0 else np.nan)
                if "yardstick" in r:
                    yd.append(r["yardstick"]["position_pct"] / e if e > 0 else np.nan)
                if e > 0 and d / e >= np.nanmax(db):
                    db_max = {"character": b["character"], "clip": r["clip"], "default": d, "dem_bones": e}
                if d > q:
                    worse.append({"character": b["character"], "clip": r["clip"], "default": d, "k_largest": q})
                p95.append((r["default"]["normal_p95_rad"], r["k_largest"]["normal_p95_rad"],
                            r["dem_bones"]["normal_p95_rad"]))
                n_better += d < q
        if not kl:      # every clip passes through (k >= every vertex's influence count): nothing to compare
            out.append({"k": k, "clips": n_clips, "ratio_clips": 0})
            continue
        p95 = np.asarray(p95)
        zero = p95.max(axis=1) <= P95_ZERO
        out.append({"k": k, "clips": n_clips, "ratio_clips": len(kl),
                    "vs_k_largest_mean": float(np.mean(kl)), "vs_k_largest_max": float(np.max(kl)),
                    "vs_dem_bones_mean": float(np.nanmean(db)), "vs_dem_bones_max": float(np.nanmax(db)),
                    "vs_dem_bones_max_clip": db_max,
                    "yardstick_vs_dem_bones_mean": float(np.nanmean(yd)) if yd else None,
                    "clips_above_k_largest": worse,
                    # of the clips where some method turns normals (p95 above round-off); on the others fewer
                    # than 5 % of the vertices turn at all with any of the three, so no p95 is below another
                    "normal_p95_below_both": int((~zero & (p95[:, 0] < p95[:, 1]) & (p95[:, 0] < p95[:, 2])).sum()),
                    "normal_p95_all_zero": int(zero.sum()),
                    "normal_p95_default_mean": float(p95[:, 0].mean()),
                    "normal_p95_k_largest_mean": float(p95[:, 1].mean()),
                    "normal_p95_dem_bones_mean": float(p95[:, 2].mean())})
    return out


def suite_markdown(doc):
    s = doc["suite"]
    m = doc["machine"]
    out = ["## The default of `rigslim reduce` on the elephant and the real-character suite", "",
           f"Machine: {m['cpu']}, nproc {m['nproc']}. `flock /tmp/rigslim-bench.lock .venv/bin/python "
           "benchmarks/reduction_best_fit.py --parts suite` wrote this section.", "",
           "`rigslim reduce`'s default (best-fit by error + geometric, with the guard against k-largest on "
           "validation frames) against k-largest (the k largest weights renormalised) and Dem Bones' weight "
           "solve (`computeWeights`, true bone transforms fixed, nnz = k), all fitted to the same example poses. "
           "Two configurations: *all clips* as `rigslim reduce` runs (24 example frames sampled evenly "
           "from every clip; the frames between examples alternately validation frames, for the guard, and test "
           "frames), and, "
           "for characters with held-out clips, *fit / held-out clips* (examples and validation from the "
           "suite's fit clips only; tested on their held-out frames and on every frame of the held-out clips, "
           f"which neither the fit nor the guard saw). At most {s['max_test_frames']} test frames per clip, "
           "evenly; position RMS in % of the rest "
           "bounding-box diagonal, pooled over the clip's frames; normal p95: the 95th percentile of the "
           "per-vertex normal angle (rad), mean over frames. The elephant (one clip): examples 0:457:45, "
           "validation 22:457:45, test 5:457:7 minus those.", "",
           "*Yardstick*: the default's selection and solve fitted on the very frames the errors are measured on "
           "(every test frame of every clip, clips balanced, no guard), so what one weight set can reach with these "
           "bone transforms when it sees the test motion. It is not a bound clip by clip: one weight set trades the "
           "clips against each other (in the held-out configuration it gives re_drone's four quiet clips 0.0048 % "
           "where the default, which never saw the sword attack, gives 0.0001 %), but its mean ratio to Dem Bones "
           "shows what fitting the example poses better could gain.", "",
           "| configuration, k | clips | default / k-largest, mean (max) | clips above k-largest | "
           "default / Dem Bones, mean (max) | yardstick / Dem Bones, mean "
           "| normal p95 default / k-largest / Dem Bones (mean) | clips with normal p95 below both |",
           "|---|---|---|---|---|---|---|---|"]
    for cfg, title in (("all", "all clips fitted (the one-liner)"),
                       ("split", "fit clips / held-out clips (multi-clip characters)")):
        out += summary_rows(s["summary"][cfg], title)
    for cfg in ("all", "split"):
        for r in s["summary"][cfg]:
            w = r.get("vs_dem_bones_max_clip")
            if w:
                out.append(f"- {cfg}, k = {r['k']}: the largest default / Dem Bones ratio is {w['character']} "
                           f"{w['clip']} ({w['default']:.4f} % vs {w['dem_bones']:.4f} %).")
    out += ["", "Clips where k-largest is already exact (every vertex has at most k influences: the weights pass "
            "through) are counted in `clips` but not in the ratios.", ""]
    return out + suite_detail(s)


def summary_rows(summary, title):
    out = []
    for r in summary:
        if not r["ratio_clips"]:
            out.append(f"| {title}, k = {r['k']} | 0 of {r['clips']} | every clip passes through | | | | | |")
            continue
        above = ", ".join(f"{w['character']} {w['clip']} ({w['default']:.4f} vs {w['k_largest']:.4f})"
                          for w in r["clips_above_k_largest"]) or "none"
        out.append(f"| {title}, k = {r['k']} | {r['ratio_clips']} of {r['clips']} | {r['vs_k_largest_mean']:.3f} "
                   f"({r['vs_k_largest_max']:.3f}) | {above} | {r['vs_dem_bones_mean']:.3f} "
                   f"({r['vs_dem_bones_max']:.3f}) | {fmt(r.get('yardstick_vs_dem_bones_mean'), 3)} | "
                   f"{r['normal_p95_default_mean']:.4f} / "
                   f"{r['normal_p95_k_largest_mean']:.4f} / {r['normal_p95_dem_bones_mean']:.4f} | "
                   f"{r['normal_p95_below_both']} of {r['ratio_clips'] - r.get('normal_p95_all_zero', 0)}"
                   f"{_zero_ties(r)} |")
    return out


def _zero_ties(r) -> str:
    """The clips where no method's p95 can be below another's: all three are 0."""
    n = r.get("normal_p95_all_zero", 0)
    return f" (and {n} where it is 0 for all three)" if n else ""


def suite_detail(s):
    out = []
    t = next((b["target"] for b in s["blocks"] if "target" in b), None)
    if t:
        out += [f"Elephant, k = 4, all {t['test_frames']} test frames: the default {t['position_pct']:.4f} % / "
                f"{t['normal_rad']:.4f} rad in {t['seconds']:.3f} s (select + solve + guard); Dem Bones "
                f"{t['dem_bones_position_pct']:.4f} % / {t['dem_bones_normal_rad']:.4f} rad in "
                f"{t['dem_bones_s']:.3f} s; k-largest {t['k_largest_position_pct']:.4f} % / "
                f"{t['k_largest_normal_rad']:.4f} rad.", ""]
    out += ["Per clip (position RMS, % of the rest diagonal; `fell back`: vertices the guard gave k-largest's "
            "weights; times of the default's select + solve + guard and of Dem Bones' `computeWeights`):", "",
            "| character, configuration | k | vertices | joints | clip | frames | default | k-largest | Dem Bones | "
            "normal p95 default / k-largest / Dem Bones | fell back | default (s) | Dem Bones (s) |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    for b in s["blocks"]:
        for i, r in enumerate(b["clips"]):
            held = " (held out)" if r["clip"] in b["held_out_clips"] else ""
            head = (f"| {b['character']}, {b['config']}{' (pass-through)' if b['pass_through'] else ''} | {b['k']} | "
                    f"{b['vertices']} | {b['joints']} |") if i == 0 else "| | | | |"
            tail = (f" {b['fallback_vertices']} | {b['default_s']:.3f} | {b['dem_bones_s']:.3f} |" if i == 0
                    else " | | |")
            out.append(f"{head} {r['clip']}{held} | {r['frames']} | {r['default']['position_pct']:.4f} | "
                       f"{r['k_largest']['position_pct']:.4f} | {r['dem_bones']['position_pct']:.4f} | "
                       f"{r['default']['normal_p95_rad']:.4f} / {r['k_largest']['normal_p95_rad']:.4f} / "
                       f"{r['dem_bones']['normal_p95_rad']:.4f} |{tail}")
    return out + [""]


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
    if "suite" in doc:
        out += suite_markdown(doc)
    if "386k" in doc:
        b = doc["386k"]
        out += [f"## Elephant subdivided, {b['vertices']:,} vertices, k = {b['k']} "
                f"(errors on {b['test_frames']} test frames)", ""] + table(b["rows"]) + [""]
    return "\n".join(out) + "\n"


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--parts", nargs="*", default=["elephant", "ks", "cheb", "armadillo"],
                    choices=["elephant", "ks", "cheb", "armadillo", "386k", "suite"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--stem", default=str(OUT / "reduction_quality_best_fit"))
    ap.add_argument("--from-json", action="store_true",
                    help="measure nothing: recompute the suite summary from the stored blocks, rewrite the Markdown")
    args = ap.parse_args()
    if args.from_json:
        import json

        doc = json.loads(Path(args.stem).with_suffix(".json").read_text())
        if "suite" in doc:
            blocks = doc["suite"]["blocks"]
            doc["suite"]["summary"] = {cfg: suite_summary([b for b in blocks if b["config"] == cfg])
                                       for cfg in ("all", "split")}
        write_results(args.stem, doc, markdown(doc))
        return
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
    if "suite" in args.parts:
        doc["suite"] = part_suite(args.repeat)
    text = markdown(doc)
    write_results(args.stem, doc, text)
    print(text)


if __name__ == "__main__":
    main()
