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


class PipelineSteps:
    """A pipeline's inputs read into one asset, and its steps, run one at a time on that asset.

    The set-up of the armadillo benchmarks (this one and ``poisson_speed.py``): the pipeline runner's own
    calls (``load_pipeline``, ``read_inputs``, ``_run_step``), quiet.
    """

    def __init__(self, pipeline: Path = PIPELINE):
        from rich.console import Console

        from rigslim.plugin.host import get_host
        from rigslim.runtime.document import load_pipeline
        from rigslim.runtime.inputs import read_inputs
        from rigslim.runtime.progress import Reporter

        self.pipeline = pipeline
        self.host = get_host()
        doc, steps = load_pipeline(pipeline, host=self.host)
        self.reporter = Reporter(Console(quiet=True))
        self.base = pipeline.parent
        self.asset = read_inputs(doc, self.base, self.host, self.reporter.context(self.base), pipeline)
        self.steps = {s.key: s for s in steps}

    def run(self, key: str, document: dict | None = None):
        """Run the step ``key`` on the asset (its metrics into ``document``); returns the step's context."""
        from rigslim.runtime.run import _run_step

        ctx = self.reporter.context(self.base)
        _run_step(self.steps[key], self.asset, self.host, ctx, self.base, self.pipeline,
                  {"evaluations": []} if document is None else document)
        return ctx


def main() -> None:
    run = PipelineSteps()
    asset = run.asset
    t = time.perf_counter()
    run.run("generate")
    generate_s = time.perf_counter() - t
    run.run("select")
    rows = []
    for label, solver, extra in METHODS:
        step = run.steps["solve"]
        step.plugin, step.params = solver, dict(extra)
        t = time.perf_counter()
        ctx = run.run("solve")
        seconds = time.perf_counter() - t
        document: dict = {"evaluations": []}
        run.run("evaluate", document)
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
