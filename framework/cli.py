"""The ``rigslim`` command line.

``rigslim run PIPELINE.yaml [--metrics FILE.json] [--set STEP.PARAM=VALUE | STEP=PLUGIN]``
runs a pipeline; ``rigslim report METRICS.json [...] -o report.html`` writes an
HTML report of runs; ``rigslim plugins [--json]`` lists loaded plugins. Errors a
user can cause print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import json
import sys

from rigslim.errors import RigslimError

EXIT_USER_ERROR = 2


def _cmd_run(args) -> int:
    from rich.console import Console
    from rich.table import Table

    from rigslim.pipeline import run_pipeline

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


def _cmd_report(args) -> int:
    if any(str(p).lower().endswith(".csv") for p in args.metrics):  # a batch's summary.csv: the batch view
        from rigslim.report.batch import cmd_report_batch

        return cmd_report_batch(args)
    from rich.console import Console

    from rigslim.errors import InputError
    from rigslim.io.atomic import check_output, output_transaction
    from rigslim.progress import Reporter
    from rigslim.report import build_report, load_document, write_report

    frames = None
    if args.frames:
        try:
            frames = [int(f) for f in args.frames.split(",") if f.strip()]
        except ValueError:
            raise InputError(f"--frames '{args.frames}' is not a comma-separated list of frame numbers",
                             field="--frames", fix="write e.g. --frames 12,180") from None
    try:
        width, height = (int(x) for x in args.size.lower().split("x"))
    except ValueError:
        raise InputError(f"--size '{args.size}' is not WIDTHxHEIGHT", field="--size",
                         fix="write e.g. --size 320x270") from None
    check_output(args.output)
    documents = [(load_document(p), p) for p in args.metrics]
    console = Console(stderr=True, quiet=args.quiet)
    reporter = Reporter(console)
    report = build_report(documents, frames=frames, width=width, height=height, backend=args.backend,
                          projection=args.projection, azimuth=args.azimuth, elevation=args.elevation,
                          up_axis=args.up_axis, title=args.title, render=not args.no_renders,
                          progress=reporter.track)
    with output_transaction():  # the page and its PNG files appear together
        written = write_report(args.output, report, args.png_dir)
    for note in report.notes:
        reporter.note(note)
    print(f"report written to {args.output} ({len(report.rows)} evaluations, {len(report.renders)} renders)")
    for p in written:
        print(f"render written to {p}")
    return 0


def _cmd_plugins(args) -> int:
    from rigslim.host import get_host

    infos = sorted(get_host().infos(), key=lambda i: (i.stage, i.name))
    if args.json:
        print(json.dumps([i.as_dict() for i in infos], indent=2))
        return 0
    from rich.console import Console
    from rich.table import Table

    table = Table(title="rigslim plugins")
    for col in ("stage", "name", "package", "version", "summary"):
        table.add_column(col, overflow="fold")
    for i in infos:
        table.add_row(i.stage, i.name, i.package, i.version, i.summary)
    Console().print(table)
    return 0


def build_parser() -> argparse.ArgumentParser:
    import rigslim

    parser = argparse.ArgumentParser(prog="rigslim", description="Reduce skin weights and cage coordinates "
                                     "to k per vertex, and simplify articulated meshes.")
    parser.add_argument("--version", action="version", version=f"rigslim {rigslim.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a YAML pipeline")
    run.add_argument("pipeline", help="pipeline YAML file")
    run.add_argument("--metrics", metavar="FILE.json", help="write the metrics document here")
    run.add_argument("--set", action="append", metavar="STEP.PARAM=VALUE",
                     help="override a step parameter, or with STEP=PLUGIN replace a step's plugin "
                          "(STEP: step name, stage key, plugin or 1-based index)")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    run.add_argument("--allow-external-uris", action="store_true",
                     help="let glTF buffer/image URIs name files outside the glTF's folder (trusted files only)")
    run.set_defaults(func=_cmd_run)
    report = sub.add_parser("report", help="HTML report of metrics JSON files (table, plots, renders)")
    report.add_argument("metrics", nargs="+", metavar="METRICS.json",
                        help="metrics documents of 'rigslim run', or one DIR/summary.csv of 'rigslim batch'")
    report.add_argument("-o", "--output", required=True, metavar="REPORT.html", help="write the report here")
    report.add_argument("--png-dir", metavar="DIR", help="also write the renders as PNG files here")
    report.add_argument("--frames", metavar="F1,F2", help="animation frames to render (default: the worst test frame)")
    report.add_argument("--size", default="320x270", metavar="WxH", help="size of each render (default 320x270)")
    report.add_argument("--backend", choices=["auto", "opengl", "numpy"], default="auto",
                        help="renderer (auto: OpenGL through EGL when available, else numpy)")
    report.add_argument("--projection", choices=["perspective", "orthographic"], default="perspective")
    report.add_argument("--azimuth", type=float, default=30.0, help="view direction around the up axis (degrees)")
    report.add_argument("--elevation", type=float, default=15.0, help="view elevation (degrees)")
    report.add_argument("--up-axis", type=int, choices=[0, 1, 2], default=1, help="world axis pointing up")
    report.add_argument("--title", help="page title")
    report.add_argument("--no-renders", action="store_true", help="table and plots only")
    report.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    report.add_argument("--allow-external-uris", action="store_true",
                        help="let glTF buffer/image URIs name files outside the glTF's folder (trusted files only)")
    report.set_defaults(func=_cmd_report)
    plugins = sub.add_parser("plugins", help="list loaded plugins")
    plugins.add_argument("--json", action="store_true", help="machine-readable output")
    plugins.set_defaults(func=_cmd_plugins)
    from rigslim.gltf_commands import add_commands  # reduce, lod, compare, inspect (docs/gltf.md)

    add_commands(sub)
    from rigslim.batch import add_parser as add_batch_parser

    add_batch_parser(sub)
    return parser


class _Terminated(KeyboardInterrupt):
    """SIGTERM, unwound like Ctrl-C so that staged outputs are removed (docs/pipelines.md, Guarantees)."""


def _terminate(signum, frame):
    raise _Terminated


def main(argv=None) -> int:
    import os
    import signal
    import threading
    import warnings

    parser = build_parser()
    args = parser.parse_args(argv)
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    allow_before = os.environ.get("RIGSLIM_ALLOW_EXTERNAL_URIS")
    if getattr(args, "allow_external_uris", False):  # read by the glTF reader (rigslim.io.gltf)
        os.environ["RIGSLIM_ALLOW_EXTERNAL_URIS"] = "1"
    try:
        # Warnings (numpy's RuntimeWarnings...) are held until the command ends: shown after a success,
        # dropped when a one-line error explains what went wrong.
        with warnings.catch_warnings(record=True) as caught:
            code = args.func(args)
        for w in caught:
            warnings.showwarning(w.message, w.category, w.filename, w.lineno, line=w.line)
        return code
    except RigslimError as e:
        print(f"rigslim: error: {e.one_line()}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt as e:
        print("rigslim: interrupted; every output is either unchanged or complete", file=sys.stderr)
        return 143 if isinstance(e, _Terminated) else 130
    except OSError as e:  # an I/O error no reader or writer turned into a RigslimError: still one line
        where = f"{e.filename}: " if e.filename else ""
        print(f"rigslim: error: {where}{e.strerror or e} (fix: check the path, its permissions and the free space)",
              file=sys.stderr)
        return EXIT_USER_ERROR
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if getattr(args, "allow_external_uris", False):
            if allow_before is None:
                os.environ.pop("RIGSLIM_ALLOW_EXTERNAL_URIS", None)
            else:
                os.environ["RIGSLIM_ALLOW_EXTERNAL_URIS"] = allow_before


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
