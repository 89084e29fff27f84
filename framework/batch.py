"""``rigslim batch``: one pipeline template over an asset library, on a Dask cluster.

``rigslim batch TEMPLATE.yaml ASSETS... --out DIR`` runs the template once per
asset (:mod:`rigslim.batch_assets` makes each asset's pipeline) as one
``dask.distributed`` task per asset (:func:`rigslim.batch_task.run_asset`):

- without ``--scheduler`` on a :class:`distributed.LocalCluster` of
  ``--workers`` processes with ``--threads-per-worker`` threads each, whose
  BLAS/OpenMP/numba pools get ``cores // (workers x threads)`` threads, so the
  machine is never oversubscribed;
- with ``--scheduler ADDRESS`` on an existing cluster (``dask scheduler`` /
  ``dask worker``, dask-jobqueue on SLURM/PBS, ...); each task then limits its
  pools to ``cores // (Dask threads on its host)``.

Assets already done (record matching input hash, pipeline and version) are
``skipped``; a bad asset is ``failed`` with the one-line error ``rigslim
run`` prints, and the batch goes on; an asset whose worker died (killed, out
of memory) is submitted again up to ``--retries`` times. The results go to
``DIR/summary.csv``, ``DIR/summary.parquet`` and ``DIR/summary.json``; the exit
status is 0 when every asset is ok or skipped, 1 when any failed, 2 for a bad
template or bad arguments. See docs/batch.md.
"""

from __future__ import annotations

import contextlib
import csv
import json
import logging
import os
import time
import uuid
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from rigslim.errors import InputError

#: Columns every summary has, in this order; metric columns follow, then :data:`TAIL_COLUMNS`.
HEAD_COLUMNS = ["asset", "name", "status", "error", "seconds", "peak_memory_mb", "vertices", "faces", "joints",
                "input_influences", "output_influences"]
TAIL_COLUMNS = ["worker", "threads", "attempts"]
STRING_COLUMNS = {"asset", "name", "status", "error", "worker"}

EXIT_OK, EXIT_FAILED = 0, 1


def available_cores() -> int:
    """CPU cores this process may run on (the affinity mask, else ``os.cpu_count()``)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def thread_env(n: int) -> dict[str, str]:
    """Environment that caps a worker process's BLAS, OpenMP and numba pools at ``n`` threads.

    It replaces Dask's default pre-spawn environment, which also sets ``MALLOC_TRIM_THRESHOLD_=65536``:
    with it glibc maps and unmaps every large numpy temporary afresh, and a Poisson reduction of a
    6k-vertex character took 1.5x the CPU time (measured); rigslim's workers keep glibc's default.
    """
    n = str(max(1, int(n)))
    return {"OMP_NUM_THREADS": n, "OPENBLAS_NUM_THREADS": n, "MKL_NUM_THREADS": n, "BLIS_NUM_THREADS": n,
            "VECLIB_MAXIMUM_THREADS": n, "NUMEXPR_NUM_THREADS": n, "NUMBA_NUM_THREADS": n}


@dataclass
class BatchOptions:
    """What ``rigslim batch`` was asked to do (see :func:`add_parser` for each option)."""

    template: Path
    assets: list[str]
    out: Path
    workers: int | None = None
    threads_per_worker: int = 1
    scheduler: str | None = None
    memory_limit: str | None = None
    retries: int = 2
    timeout: float | None = None
    force: bool = False
    dashboard: bool = True


@dataclass
class BatchResult:
    rows: list[dict]
    seconds: float
    dashboard: str | None = None
    cluster: dict = field(default_factory=dict)

    @property
    def counts(self) -> dict[str, int]:
        c = {"ok": 0, "skipped": 0, "failed": 0}
        for r in self.rows:
            c[r["status"]] = c.get(r["status"], 0) + 1
        return c

    @property
    def exit_code(self) -> int:
        return EXIT_FAILED if self.counts["failed"] else EXIT_OK


def _check_options(opts: BatchOptions) -> None:
    if opts.workers is not None and opts.workers < 1:
        raise InputError(f"--workers {opts.workers} is not a positive count", field="--workers", fix="give 1 or more")
    if opts.threads_per_worker < 1:
        raise InputError(f"--threads-per-worker {opts.threads_per_worker} is not a positive count",
                         field="--threads-per-worker", fix="give 1 or more")
    if opts.retries < 0:
        raise InputError(f"--retries {opts.retries} is negative", field="--retries", fix="give 0 or more")
    if opts.timeout is not None and not opts.timeout > 0:
        raise InputError(f"--timeout {opts.timeout} is not a positive number of seconds", field="--timeout",
                         fix="give e.g. --timeout 600")
    if opts.scheduler and (opts.workers is not None or opts.memory_limit):
        raise InputError("--workers and --memory-limit size a local cluster; with --scheduler the cluster "
                         "has its own workers", field="--scheduler",
                         fix="size the workers where they are started (dask worker --nworkers/--memory-limit)")
    if opts.memory_limit:
        from dask.utils import parse_bytes

        try:
            parse_bytes(opts.memory_limit)
        except (ValueError, TypeError):
            raise InputError(f"--memory-limit '{opts.memory_limit}' is not a size", field="--memory-limit",
                             fix="write e.g. --memory-limit 4GiB") from None
    if opts.out.exists() and not opts.out.is_dir():
        raise InputError("--out names a file, not a folder", source=opts.out, field="--out",
                         fix="give a folder (it is created if missing)")


def prepare(opts: BatchOptions):
    """Check the arguments and the template; list the assets. Raises a RigslimError (exit 2) on bad input."""
    from rigslim.batch_assets import asset_pipeline, check_columns, collect_assets, load_template
    from rigslim.errors import PipelineError, RigslimError
    from rigslim.pipeline import load_pipeline

    _check_options(opts)
    template = load_template(opts.template)
    jobs = collect_assets(opts.assets)
    check_columns(template, jobs)
    # The template itself must be a valid pipeline: check it with the first asset put in (no overrides).
    import tempfile

    import yaml

    probe = asset_pipeline(template, opts.template, type(jobs[0])(jobs[0].path, jobs[0].name))
    with tempfile.TemporaryDirectory(prefix="rigslim-batch-") as tmp:
        path = Path(tmp) / "template.yaml"
        path.write_text(yaml.safe_dump(probe, sort_keys=False))
        try:
            load_pipeline(path)
        except RigslimError as e:
            raise PipelineError(e.problem, source=opts.template, field=e.field, fix=e.fix) from None
    opts.out.mkdir(parents=True, exist_ok=True)
    return template, jobs


@contextlib.contextmanager
def dask_client(opts: BatchOptions):
    """A :class:`distributed.Client` on a new LocalCluster, or on ``opts.scheduler``."""
    from distributed import Client

    if opts.scheduler:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            try:
                if Path(opts.scheduler).is_file():  # a scheduler file (dask scheduler --scheduler-file)
                    client = Client(scheduler_file=opts.scheduler, timeout="30s")
                else:
                    client = Client(opts.scheduler, timeout="30s")
            except (OSError, TimeoutError) as e:
                raise InputError(f"cannot reach the Dask scheduler ({e})", source=opts.scheduler,
                                 field="--scheduler", fix="start one with 'dask scheduler' or give its address "
                                 "as tcp://HOST:8786") from None
        with client:
            yield client, {"kind": "scheduler", "address": opts.scheduler}
        return
    with local_cluster(opts.workers, opts.threads_per_worker, opts.memory_limit, opts.dashboard) as (cluster, info):
        with Client(cluster) as client:
            yield client, info


@contextlib.contextmanager
def local_cluster(workers: int | None = None, threads_per_worker: int = 1, memory_limit: str | None = None,
                  dashboard: bool = True):
    """A :class:`distributed.LocalCluster` of worker processes set up for ``rigslim batch``.

    Each worker process gets ``cores // (workers x threads_per_worker)``
    BLAS/OpenMP/numba threads (environment variables set before it starts);
    the scheduler reports a task whose worker died at once (the batch
    resubmits it, ``--retries``) and gives each worker only as many tasks as
    it has threads. Yields ``(cluster, info)``.
    """
    import dask
    from distributed import LocalCluster

    cores = available_cores()
    workers = workers or cores
    blas = max(1, cores // (workers * threads_per_worker))
    env = thread_env(blas)
    # Dask's nanny writes pre-spawn-environ into *this* process's environment before it spawns a worker
    # (BLAS reads its variables when the worker imports numpy, so they must be there before): keep numba's
    # out of it (numba re-reads NUMBA_NUM_THREADS here and refuses a change once its threads run; the
    # worker gets it through ``env``, set in the worker before it starts), and put ours back afterwards.
    pre_spawn = {k: v for k, v in env.items() if not k.startswith("NUMBA_")}
    saved = {k: os.environ.get(k) for k in [*pre_spawn, "PYTHONHASHSEED"]}
    config = {
        # --retries is applied by the batch (one resubmission per worker death), so the
        # scheduler must report a task whose worker died at once instead of retrying it itself,
        "distributed.scheduler.allowed-failures": 0,
        # and hand each worker only as many tasks as it has threads (none queued on a worker that may die).
        "distributed.scheduler.worker-saturation": 1.0,
        "distributed.nanny.pre-spawn-environ": pre_spawn,
    }
    address = ":8787" if dashboard and _has_bokeh() else None
    cluster = None
    try:
        with dask.config.set(config), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cluster = LocalCluster(n_workers=workers, threads_per_worker=threads_per_worker, processes=True,
                                   memory_limit=memory_limit or "auto", dashboard_address=address,
                                   silence_logs=logging.ERROR, env=env)
        yield cluster, {"kind": "local", "workers": workers, "threads_per_worker": threads_per_worker,
                        "blas_threads": blas, "cores": cores, "memory_limit": memory_limit or "auto"}
    finally:
        if cluster is not None:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cluster.close()
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v


def _has_bokeh() -> bool:
    try:
        import bokeh  # noqa: F401
        return True
    except ImportError:
        return False


def host_threads(client) -> dict[str, int]:
    """Dask threads per host of the cluster (the tasks divide their host's cores by this)."""
    counts: dict[str, int] = {}
    for info in client.scheduler_info(n_workers=-1)["workers"].values():
        host = info.get("host") or ""
        counts[host] = counts.get(host, 0) + int(info.get("nthreads") or 1)
    return counts


def _died_reason(job, attempts: int, exc, opts: BatchOptions) -> str:
    marker = opts.out / job.name / ".timeout"
    if marker.is_file():
        with contextlib.suppress(OSError):
            return " ".join(marker.read_text().split())
    mem = f" {opts.memory_limit}" if opts.memory_limit else ""
    return (f"the worker running it died {attempts} time(s) (killed, or past its memory limit{mem}); "
            f"gave up after --retries {opts.retries}")


def run_batch(opts: BatchOptions, console=None) -> BatchResult:
    """Run every asset on Dask; write DIR/summary.{csv,parquet,json}; return the rows."""
    from distributed import as_completed
    from rich.console import Console

    import rigslim
    from rigslim.batch_task import _clean, base_row, run_asset

    console = console or Console(stderr=True)
    template, jobs = prepare(opts)
    t0 = time.perf_counter()
    rows: dict[str, dict] = {}
    token = uuid.uuid4().hex[:8]
    with dask_client(opts) as (client, cluster):
        dashboard = client.dashboard_link if (opts.dashboard and _dashboard_running(client)) else None
        if dashboard:
            console.print(f"Dask dashboard: {dashboard}")
        threads = host_threads(client)
        by_key = {}

        def submit(job, attempt):
            key = f"rigslim-batch-{token}-{job.name}-{attempt}"
            fut = client.submit(run_asset, job.as_dict(), template, str(opts.template.resolve()), str(opts.out),
                                force=opts.force, timeout=opts.timeout, threads=threads, attempt=attempt,
                                version=rigslim.__version__, key=key, pure=False, retries=0)
            by_key[key] = (job, attempt)
            return fut

        futures = [submit(j, 1) for j in jobs]
        with _Progress(console, len(jobs)) as progress:
            done = as_completed(futures, with_results=False)
            for fut in done:
                job, attempt = by_key.pop(fut.key)
                if fut.status == "finished":
                    row = fut.result()
                else:
                    exc = fut.exception()
                    from distributed import KilledWorker

                    if isinstance(exc, KilledWorker) and attempt <= opts.retries and \
                            not (opts.out / job.name / ".timeout").is_file():
                        done.add(submit(job, attempt + 1))
                        fut.release()
                        continue
                    row = base_row(job.as_dict())
                    row["worker"] = ""
                    row["attempts"] = attempt
                    if isinstance(exc, KilledWorker):
                        row["error"] = _died_reason(job, attempt, exc, opts)
                        _clean(opts.out / job.name)  # what the killed attempt staged must not stay
                    else:
                        row["error"] = " ".join(f"{type(exc).__name__}: {exc}".split())
                fut.release()
                rows[job.name] = row
                progress.advance(row["status"])
    ordered = [rows[j.name] for j in jobs]
    result = BatchResult(ordered, time.perf_counter() - t0, dashboard, cluster)
    write_summary(opts, result)
    return result


def _dashboard_running(client) -> bool:
    try:
        return bool(client.scheduler_info().get("services", {}).get("dashboard"))
    except Exception:  # noqa: BLE001 - the link is a convenience
        return False


class _Progress:
    """A live bar on stderr: done of total, ok / skipped / failed counts, elapsed and remaining time."""

    def __init__(self, console, total: int):
        from rich.progress import (
            BarColumn,
            MofNCompleteColumn,
            Progress,
            TextColumn,
            TimeElapsedColumn,
            TimeRemainingColumn,
        )

        self.counts = {"ok": 0, "skipped": 0, "failed": 0}
        self.progress = Progress(TextColumn("batch"), BarColumn(), MofNCompleteColumn(),
                                 TextColumn("[green]{task.fields[ok]} ok[/] [cyan]{task.fields[skipped]} skipped[/] "
                                            "[red]{task.fields[failed]} failed[/]"),
                                 TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                                 console=console, disable=console.quiet)
        self.task = self.progress.add_task("batch", total=total, **self.counts)

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc):
        return self.progress.__exit__(*exc)

    def advance(self, status: str):
        self.counts[status] = self.counts.get(status, 0) + 1
        self.progress.update(self.task, advance=1, **self.counts)


# --- the summary --------------------------------------------------------------------------------

def summary_columns(rows: list[dict]) -> list[str]:
    """Fixed columns, then every metric column in order of first appearance, then worker and attempts."""
    cols = list(HEAD_COLUMNS)
    for r in rows:
        for k in r:
            if k not in cols and k not in TAIL_COLUMNS:
                cols.append(k)
    return cols + TAIL_COLUMNS


def _arrow_table(rows: list[dict], columns: list[str]):
    import pyarrow as pa

    arrays, fields = [], []
    for c in columns:
        values = [r.get(c) for r in rows]
        present = [v for v in values if v is not None and v != ""]
        if c in STRING_COLUMNS:
            typ = pa.string()
            values = [None if v is None else str(v) for v in values]
        elif present and all(isinstance(v, int) and not isinstance(v, bool) for v in present):
            typ = pa.int64()
        else:
            typ = pa.float64()
            values = [None if v is None or v == "" else float(v) for v in values]
        arrays.append(pa.array(values, type=typ))
        fields.append(pa.field(c, typ))
    return pa.Table.from_arrays(arrays, schema=pa.schema(fields))


def write_summary(opts: BatchOptions, result: BatchResult) -> dict[str, Path]:
    """DIR/summary.csv, summary.parquet (pyarrow) and summary.json, each written atomically."""
    import pyarrow.parquet as pq

    import rigslim
    from rigslim.io.atomic import atomic_path

    columns = summary_columns(result.rows)
    paths = {k: opts.out / f"summary.{k}" for k in ("csv", "parquet", "json")}
    with atomic_path(paths["csv"]) as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.DictWriter(fh, fieldnames=columns, restval="", extrasaction="ignore")
            w.writeheader()
            for r in result.rows:
                w.writerow({k: ("" if v is None else v) for k, v in r.items()})
    with atomic_path(paths["parquet"]) as tmp:
        pq.write_table(_arrow_table(result.rows, columns), tmp)
    doc = {"rigslim_version": rigslim.__version__, "template": str(Path(opts.template).resolve()),
           "out": str(Path(opts.out).resolve()), "seconds": result.seconds, "counts": result.counts,
           "cluster": result.cluster, "dashboard": result.dashboard, "columns": columns,
           "rows": [{c: r.get(c) for c in columns} for r in result.rows]}
    with atomic_path(paths["json"]) as tmp:
        Path(tmp).write_text(json.dumps(doc, indent=2, default=str) + "\n")
    return paths


# --- the command --------------------------------------------------------------------------------

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
    from rigslim.batch_assets import ASSET_SUFFIXES

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
