"""``rigslim run PIPELINE.yaml``: run a pipeline and print its metrics."""

from __future__ import annotations


def _cmd_run(args) -> int:
    from rich.console import Console
    from rich.table import Table

    from rigslim.runtime.run import run_pipeline

    console = Console(stderr=True, quiet=args.quiet)
    result = run_pipeline(args.pipeline, overrides=args.set or [], metrics_path=args.metrics, console=console)
    out = Console()
    for ev in result.evaluations:
        table = Table(title=f"{ev['name']}  ({len(result.document['frames']['test'])} test frames)"
                      if result.document.get("frames") else ev["name"])
        table.add_column("metric")
        table.add_column("mean", justify="right")
        table.add_column("max", justify="right")
        for key, value in ev["metrics"].items():
            if isinstance(value, dict):
                table.add_row(key, f"{value['mean']:.6g}", f"{value['max']:.6g}")
            else:
                table.add_row(key, f"{value:.6g}" if isinstance(value, float) else str(value), "")
        out.print(table)
    steps = Table(title="steps")
    for col in ("stage", "plugin", "seconds"):
        steps.add_column(col, justify="right" if col == "seconds" else "left")
    for s in result.document["steps"]:
        steps.add_row(s["stage"], str(s.get("plugin", "")), f"{s['seconds']:.3f}")
    out.print(steps)
    if args.metrics:
        out.print(f"metrics written to {args.metrics}")
    return 0
