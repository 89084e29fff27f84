"""``rigslim batch``: a pipeline template over an asset library (docs/batch.md)."""

from __future__ import annotations

from pathlib import Path

from rigslim.batch.options import BatchOptions
from rigslim.batch.run import run_batch


def add_parser(sub) -> None:
    """Register ``rigslim batch`` on the CLI's subparsers."""
    p = sub.add_parser("batch", help="run a pipeline template over many assets on Dask (resumable)",
                       description="Run TEMPLATE.yaml once per asset ({input}: the asset's path, {name}: its "
                       "stem) on a Dask cluster; write DIR/<name>/ per asset and DIR/summary.{csv,parquet,json}. "
                       "Exit 0: all ok or skipped; 1: some failed; 2: bad template or arguments.")
    p.add_argument("template", type=Path, metavar="TEMPLATE.yaml", help="pipeline with {input} and {name}")
    p.add_argument("assets", nargs="+", metavar="ASSETS",
                   help="asset files, directories (searched for " + ", ".join(_suffixes()) + ") or manifest "
                   "CSVs (column 'asset', optional 'name', per-asset overrides such as k, clip, select.k)")
    p.add_argument("--out", required=True, type=Path, metavar="DIR", help="output folder (DIR/<name>/ per asset)")
    p.add_argument("--workers", type=int, metavar="N", help="local worker processes (default: the cores)")
    p.add_argument("--threads-per-worker", type=int, default=1, metavar="T",
                   help="assets run at once in each worker (default 1)")
    p.add_argument("--scheduler", metavar="ADDRESS", help="use this Dask scheduler (tcp://HOST:8786 or a "
                   "scheduler file) instead of a local cluster")
    p.add_argument("--memory-limit", metavar="SIZE", help="per local worker, e.g. 4GiB (default: memory / workers)")
    p.add_argument("--retries", type=int, default=2, metavar="R",
                   help="resubmit an asset whose worker died up to R times (default 2)")
    p.add_argument("--timeout", type=float, metavar="S", help="stop an asset after S seconds (status failed)")
    g = p.add_mutually_exclusive_group()
    g.add_argument("--resume", dest="force", action="store_false", default=False,
                   help="skip assets whose record matches (the default)")
    g.add_argument("--force", dest="force", action="store_true", help="rerun every asset")
    p.add_argument("--no-dashboard", action="store_true", help="start the local cluster without the dashboard")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress bar")
    p.set_defaults(func=cmd_batch)


def _suffixes():
    from rigslim.batch.assets import ASSET_SUFFIXES

    return ASSET_SUFFIXES


def cmd_batch(args) -> int:
    from rich.console import Console

    opts = BatchOptions(template=args.template, assets=args.assets, out=args.out, workers=args.workers,
                        threads_per_worker=args.threads_per_worker, scheduler=args.scheduler,
                        memory_limit=args.memory_limit, retries=args.retries, timeout=args.timeout,
                        force=args.force, dashboard=not args.no_dashboard)
    console = Console(stderr=True, quiet=args.quiet)
    result = run_batch(opts, console)
    c = result.counts
    print(f"{len(result.rows)} assets in {result.seconds:.1f} s: {c['ok']} ok, {c['skipped']} skipped, "
          f"{c['failed']} failed; summary written to {opts.out / 'summary.csv'}")
    for r in result.rows:
        if r["status"] == "failed":
            print(f"failed: {r['asset']}: {r['error']}")
    return result.exit_code
