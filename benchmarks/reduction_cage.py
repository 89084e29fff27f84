"""Reduction quality on the paper's cage setup: the armadillo, mean value coordinates of a 110-vertex cage, 110 -> 8.

Runs ``examples/armadillo-k8.yaml`` once per method through the pipeline
(same inputs, same example/test split: 6 example poses, 24 test poses),
prints a table and writes ``docs/results/reduction_cage.{json,md}``.
The coordinates are computed once and reused (they do not depend on the method).

    .venv/bin/python benchmarks/reduction_cage.py
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

from benchmarks.datasets import machine, write_results  # noqa: E402

OUT = ROOT / "docs" / "results"
PIPELINE = ROOT / "examples" / "armadillo-k8.yaml"
#: (label, solver, extra parameters). MVC can be negative, so non-negativity is off (the default for such input).
METHODS = [
    ("k-largest", "k-largest", {}),
    ("geometric", "geometric", {}),
    ("smooth", "smooth", {}),
    ("poisson", "poisson", {}),
    ("poisson+lambda 0.1", "poisson", {"position_weight": 0.1}),
    ("poisson+lambda 1", "poisson", {"position_weight": 1.0}),
]


def main() -> None:
    from rich.console import Console

    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import load_pipeline
    from rigslim.runtime.inputs import read_inputs
    from rigslim.runtime.progress import Reporter
    from rigslim.runtime.run import _run_step

    host = get_host()
    doc, steps = load_pipeline(PIPELINE, host=host)
    reporter = Reporter(Console(quiet=True))
    base = PIPELINE.parent
    asset = read_inputs(doc, base, host, reporter.context(base), PIPELINE)
    by_key = {s.key: s for s in steps}
    t = time.perf_counter()
    _run_step(by_key["generate"], asset, host, reporter.context(base), base, PIPELINE, {"evaluations": []})
    generate_s = time.perf_counter() - t
    _run_step(by_key["select"], asset, host, reporter.context(base), base, PIPELINE, {"evaluations": []})
    rows = []
    for label, solver, extra in METHODS:
        step = by_key["solve"]
        step.plugin, step.params = solver, dict(extra)
        ctx = reporter.context(base)
        t = time.perf_counter()
        _run_step(step, asset, host, ctx, base, PIPELINE, {"evaluations": []})
        seconds = time.perf_counter() - t
        document = {"evaluations": []}
        _run_step(by_key["evaluate"], asset, host, reporter.context(base), base, PIPELINE, document)
        m = document["evaluations"][0]["metrics"]
        rows.append({"method": label, "solver": solver, "params": extra, "seconds": seconds,
                     "position_rms_pct": m["position_rms_pct"]["mean"],
                     "position_max_pct": m["position_rms_pct"]["max"],
                     "normal_rms_rad": m["normal_rms_rad"]["mean"], "normal_max_rad": m["normal_rms_rad"]["max"],
                     "max_influences": m["max_influences"], "solver_report": {
                         k: v for k, v in ctx.report.items() if isinstance(v, (int, float, str, bool))}})
        print(f"{label:22s} {seconds:7.2f}s  position {rows[-1]['position_rms_pct']:.4f}%  "
              f"normal {rows[-1]['normal_rms_rad']:.4f} rad", flush=True)
    result = {"machine": machine(), "pipeline": str(PIPELINE.relative_to(ROOT)), "k": 8,
              "vertices": asset.mesh.n_vertices, "handles": asset.handles.n,
              "examples": asset.split.examples, "test": asset.split.test,
              "generate_seconds": generate_s, "rows": rows}
    mach = result["machine"]
    lines = ["# Reduction quality on a cage: armadillo, mean value coordinates, 110 -> 8", "",
             f"Machine: {mach['cpu']}, nproc {mach['nproc']}. Pipeline `{result['pipeline']}`: "
             f"{result['vertices']:,} vertices, {result['handles']}-vertex cage, mean value coordinates "
             f"({generate_s:.1f} s), k-largest influence sets of 8; example frames {result['examples']}, "
             f"{len(result['test'])} test frames (never used for fitting). MVC can be negative, so no "
             "non-negativity (the default for such input). Errors: means over the test frames "
             "(maxima in parentheses).", "",
             "| method | solve (s) | position RMS (% diag) | normal RMS (rad) |", "|---|---|---|---|"]
    for r in rows:
        lines.append(f"| {r['method']} | {r['seconds']:.2f} | "
                     f"{r['position_rms_pct']:.4f} ({r['position_max_pct']:.4f}) "
                     f"| {r['normal_rms_rad']:.4f} ({r['normal_max_rad']:.4f}) |")
    write_results(OUT / "reduction_cage", result, "\n".join(lines) + "\n")
    print("\n".join(lines))


if __name__ == "__main__":
    main()
