"""``rigslim report``: the HTML report of metrics documents (or of a batch summary)."""

from __future__ import annotations


def _cmd_report(args) -> int:
    from pathlib import Path

    from rigslim.io.atomic import refuse_input_as_output

    refuse_input_as_output({"-o": args.output}, args.metrics)        # first: the more precise message
    if Path(args.output).suffix.lower() not in (".html", ".htm"):   # never a page over a .glb or a .json
        from rigslim.errors import InputError

        raise InputError(f"-o {args.output}: the report is an HTML page", field="-o",
                         fix=f"write to {Path(args.output).with_suffix('.html').name}")
    if any(str(p).lower().endswith(".csv") for p in args.metrics):  # a batch's summary.csv: the batch view
        from rigslim.report.batch import cmd_report_batch

        return cmd_report_batch(args)
    from rich.console import Console

    from rigslim.errors import InputError
    from rigslim.io.atomic import check_output, output_transaction, refuse_input_as_output
    from rigslim.report import build_report, load_document, write_report
    from rigslim.runtime.progress import Reporter

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
    refuse_input_as_output({"-o": args.output}, args.metrics)
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
