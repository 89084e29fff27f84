"""Running a batch: the Dask client or local cluster, scheduling and progress."""

from __future__ import annotations

import contextlib
import logging
import os
import time
import uuid
import warnings
from pathlib import Path

from rigslim.batch.cores import available_cores, thread_env
from rigslim.batch.options import BatchOptions, BatchResult
from rigslim.batch.summary import write_summary
from rigslim.errors import InputError


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
    from rigslim.batch.assets import asset_pipeline, check_columns, collect_assets, load_template
    from rigslim.errors import PipelineError, RigslimError
    from rigslim.runtime.document import load_pipeline

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
    from rigslim.batch.task import _clean, base_row, run_asset

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
        self.task = self.progress.add_task("batch", total=total, ok=0, skipped=0, failed=0)

    def __enter__(self):
        self.progress.__enter__()
        return self

    def __exit__(self, *exc):
        return self.progress.__exit__(*exc)

    def advance(self, status: str):
        self.counts[status] = self.counts.get(status, 0) + 1
        self.progress.update(self.task, advance=1, ok=self.counts["ok"], skipped=self.counts["skipped"],
                             failed=self.counts["failed"])
