"""One asset of a batch, as a Dask worker runs it: resume check, pipeline run, record.

:func:`run_asset` is the task ``rigslim batch`` submits per asset; it is a
plain function (the benchmark's serial loop calls it directly) and returns the
asset's summary row. The asset's folder ``DIR/<name>/`` holds

- ``pipeline.yaml``: the asset's pipeline (``rigslim run`` reruns it as is);
- the outputs its write steps produce (written atomically by the writers);
- ``metrics.json``: the metrics document of ``rigslim run --metrics``;
- ``record.json``, written last and atomically: the input files' sha256, the
  pipeline's sha256 (after templating and overrides), the rigslim version,
  every output file with its size, and the summary row.

An asset is *done* when ``record.json`` exists, its key matches the current
input, pipeline and version, and every recorded output exists with its
recorded size. A worker killed mid-asset leaves no record (and the writers'
atomic renames leave no half-written file under an output's name), so the
asset reruns. Before it does, the record and hidden leftovers of interrupted
atomic writes (``.NAME.*`` temporaries) in the folder are removed.
"""

from __future__ import annotations

import contextlib
import ctypes
import json
import os
import threading
import time
import traceback
from pathlib import Path

RECORD = "record.json"
METRICS = "metrics.json"
PIPELINE = "pipeline.yaml"
ERROR_LOG = "error.log"
#: Files of the asset folder that are the batch's bookkeeping, not pipeline outputs.
BOOKKEEPING = (RECORD, PIPELINE, ERROR_LOG)


class AssetTimeout(BaseException):
    """Raised inside the task's thread when the asset ran past ``--timeout`` (a BaseException, so that no
    ``except Exception`` in a plugin swallows it)."""


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


# --- per-worker thread limits -------------------------------------------------------------------

_blas_limit: int | None = None
_blas_lock = threading.Lock()


def limit_threads(n: int) -> None:
    """Limit BLAS/OpenMP (threadpoolctl, process-wide) and numba (this thread) to ``n`` threads.

    ``rigslim batch`` passes ``n = max(1, cores // (Dask threads on this host))``
    so that workers x threads-per-worker x n never exceeds the cores.
    """
    global _blas_limit
    n = max(1, int(n))
    with _blas_lock:
        if _blas_limit != n:
            try:
                from threadpoolctl import threadpool_limits

                threadpool_limits(limits=n)
            except ImportError:  # pragma: no cover - threadpoolctl is in the batch extra
                pass
            _blas_limit = n
    try:
        import numba

        # numba.config sets its attributes at import (from the environment); its stubs do not declare them
        numba.set_num_threads(min(n, numba.config.NUMBA_NUM_THREADS))  # type: ignore[attr-defined]
    except Exception:  # pragma: no cover - numba is a core dependency; a failure here must not fail the asset
        pass


# --- peak memory ---------------------------------------------------------------------------------

class PeakRSS:
    """Largest resident set size of this process while the block runs (sampled every 20 ms).

    With one Dask thread per worker (the default) that is the asset's own peak;
    with several it is the worker process's peak while the asset ran.
    """

    def __init__(self, interval: float = 0.02):
        import psutil

        self._proc = psutil.Process()
        self.interval = interval
        self.peak = 0
        self._stop = threading.Event()

    def _sample(self):
        while not self._stop.wait(self.interval):
            self.peak = max(self.peak, self._proc.memory_info().rss)

    def __enter__(self):
        self.peak = self._proc.memory_info().rss
        self._thread = threading.Thread(target=self._sample, daemon=True)
        self._thread.start()
        return self

    def __exit__(self, *exc):
        self._stop.set()
        self._thread.join()
        self.peak = max(self.peak, self._proc.memory_info().rss)
        return False


# --- per-asset timeout ---------------------------------------------------------------------------

class Deadline:
    """Raise :class:`AssetTimeout` in the calling thread after ``seconds``.

    The exception is delivered between Python bytecodes
    (``PyThreadState_SetAsyncExc``), so it stops the pipeline at its next
    Python-level statement; a single long call into compiled code finishes
    first. If the thread is still running ``grace`` seconds after the
    deadline and this runs inside a Dask worker, the worker process is killed
    (after writing ``.timeout`` into the asset folder, so the batch reports the
    reason): the nanny restarts it and the batch marks the asset failed.
    """

    def __init__(self, seconds: float | None, marker: Path | None = None, grace: float = 30.0):
        self.seconds = seconds
        self.marker = marker
        self.grace = grace
        self._lock = threading.Lock()
        self._done = False
        self.fired = False

    def _fire(self):
        with self._lock:
            if self._done:
                return
            self.fired = True
            ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid), ctypes.py_object(AssetTimeout))
        if self._stopped.wait(self.grace):
            return
        with self._lock:
            if self._done:
                return
        if _in_dask_worker():
            if self.marker is not None:
                with contextlib.suppress(OSError):
                    self.marker.write_text(f"timed out after {self.seconds:g} s (stuck in compiled code)\n")
            os.kill(os.getpid(), 9)

    def __enter__(self):
        if self.seconds is None:
            return self
        self._tid = threading.get_ident()
        self._stopped = threading.Event()
        self._timer = threading.Timer(self.seconds, self._fire)
        self._timer.daemon = True
        self._timer.start()
        return self

    def __exit__(self, *exc):
        if self.seconds is None:
            return False
        with self._lock:
            self._done = True
            self._timer.cancel()
            self._stopped.set()
            if self.fired:  # clear an exception that is set but not yet raised
                ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(self._tid), None)
        return False


def threads_for_task(host_threads: dict[str, int] | int | None) -> int | None:
    """BLAS/numba threads for a task: this host's cores divided by the Dask threads on this host.

    ``host_threads`` maps a worker host to the Dask threads of all workers on
    it (:func:`rigslim.batch.run.host_threads`); an int is used as is.
    """
    if host_threads is None or isinstance(host_threads, int):
        return host_threads
    from rigslim.batch.cores import available_cores

    try:
        from distributed import get_worker

        worker = get_worker()
        dask_threads = host_threads.get(worker.ip) or worker.state.nthreads
    except (ImportError, ValueError):
        return None
    return max(1, available_cores() // max(1, dask_threads))


def _in_dask_worker() -> bool:
    try:
        from distributed import get_worker

        get_worker()
        return True
    except (ImportError, ValueError):
        return False


def _worker_name() -> str:
    try:
        from distributed import get_worker

        return str(get_worker().address)
    except (ImportError, ValueError):
        return f"pid {os.getpid()}"


# --- the record ----------------------------------------------------------------------------------

def _outputs(folder: Path) -> dict[str, int]:
    """Relative path -> size of every pipeline output in the asset folder (bookkeeping and hidden files aside)."""
    out = {}
    for p in sorted(folder.rglob("*")):
        rel = p.relative_to(folder)
        if p.is_file() and not any(part.startswith(".") for part in rel.parts) and str(rel) not in BOOKKEEPING:
            out[str(rel)] = p.stat().st_size
    return out


def read_record(folder: Path) -> dict | None:
    try:
        return json.loads((folder / RECORD).read_text())
    except (OSError, ValueError):
        return None


def is_done(record: dict | None, key: dict, folder: Path) -> bool:
    """The record matches ``key`` and every recorded output (and the metrics) is there, at its size."""
    if not record or record.get("key") != key:
        return False
    outputs = record.get("outputs") or {}
    if METRICS not in outputs:
        return False
    for rel, size in outputs.items():
        p = folder / rel
        if not p.is_file() or p.stat().st_size != size:
            return False
    return True


def _clean(folder: Path) -> None:
    """Remove the record, the error log and hidden leftovers of interrupted atomic writes."""
    if not folder.is_dir():
        return
    for name in (RECORD, ERROR_LOG, ".timeout"):
        with contextlib.suppress(FileNotFoundError):
            (folder / name).unlink()
    for p in sorted(folder.rglob(".*"), reverse=True):
        if p.is_file():
            with contextlib.suppress(FileNotFoundError):
                p.unlink()


def _write_json(path: Path, data: dict) -> None:
    from rigslim.io.atomic import atomic_path
    from rigslim.io.jsonsafe import dumps_strict

    with atomic_path(path) as tmp:
        Path(tmp).write_text(dumps_strict(data, indent=2, default=str) + "\n")


# --- the summary row -----------------------------------------------------------------------------

def summary_metrics(document: dict) -> dict:
    """A metrics document's evaluations as the summary row's metric values, ``{column: value}``.

    The last evaluation's metrics become ``<metric>_mean`` / ``<metric>_max``
    (or ``<metric>`` for a single number): ``position_rms_pct_mean``,
    ``normal_rms_rad_max``, ``hausdorff_max_pct@10%_mean`` (one pair per
    simplified level) ...; earlier evaluations get the prefix ``step<N>.``.
    """
    from rigslim.runtime.metrics_document import flat_metrics

    cols = {}
    evaluations = document.get("evaluations") or []
    for i, ev in enumerate(evaluations):
        prefix = "" if i == len(evaluations) - 1 else f"step{ev.get('step')}."
        for key, value in flat_metrics(ev).items():
            if isinstance(value, dict):
                for stat in ("mean", "max"):
                    if isinstance(value.get(stat), (int, float)):
                        cols[f"{prefix}{key}_{stat}"] = float(value[stat])
            elif isinstance(value, (int, float)) and not isinstance(value, bool):
                cols[f"{prefix}{key}"] = value
    return cols


def _influences(asset) -> tuple[int | None, int | None]:
    from rigslim.model.weights import influence_counts

    before = int(influence_counts(asset.weights).max()) if asset.weights is not None and \
        asset.weights.shape[0] else None
    after = None
    if asset.reduced is not None:
        after = int(asset.reduced.influence_counts().max())
    levels = asset.levels
    if levels:
        counts = [int(lv.weights.influence_counts().max()) for lv in levels if lv.weights is not None]
        after = max(counts + ([after] if after is not None else [])) if counts else after
    return before, after


def base_row(job: dict) -> dict:
    return {"asset": job["path"], "name": job["name"], "status": "failed", "error": "", "seconds": 0.0,
            "peak_memory_mb": None, "vertices": None, "faces": None, "joints": None,
            "input_influences": None, "output_influences": None, "worker": _worker_name(), "attempts": 1}


def run_asset(job: dict, template: dict, template_path: str, out_dir: str, *, force: bool = False,
              timeout: float | None = None, threads: int | None = None, attempt: int = 1,
              version: str | None = None) -> dict:
    """Run one asset (or find it done) and return its summary row.

    Parameters
    ----------
    job : :meth:`AssetJob.as_dict`
    template, template_path : the template document and its file
    out_dir : the batch's ``--out`` folder
    force : rerun even if the record says the asset is done
    timeout : seconds before the asset is stopped (:class:`Deadline`)
    threads : BLAS/numba threads for this task (:func:`limit_threads`)
    attempt : 1 for the first try; retries after a worker died count up

    Returns
    -------
    dict
        The row: ``status`` is ``ok``, ``skipped`` or ``failed`` (``error``
        holds the one line ``rigslim run`` prints), plus sizes, metrics and
        the worker's address. Never raises for a bad asset.
    """
    t0 = time.perf_counter()
    try:
        return _run_asset(job, template, template_path, out_dir, force, timeout, threads, attempt, version, t0)
    except Exception as e:  # noqa: BLE001 - a bug must fail this asset, not the batch
        row = base_row(job)
        row.update(attempts=attempt, error=_error_line(e), seconds=time.perf_counter() - t0)
        return row


def _run_asset(job, template, template_path, out_dir, force, timeout, threads, attempt, version, t0) -> dict:
    import rigslim
    from rigslim.batch.assets import AssetJob, asset_pipeline, input_hash, pipeline_hash

    n_threads = threads_for_task(threads)
    if n_threads:
        limit_threads(n_threads)
    row_threads = n_threads
    version = version or rigslim.__version__
    row = base_row(job)
    row["attempts"] = attempt
    row["threads"] = row_threads
    asset_job = AssetJob.from_dict(job)
    folder = Path(out_dir) / asset_job.name
    try:
        if not asset_job.path.is_file():
            raise _user_error("asset file not found", asset_job.path, asset_job.source)
        doc = asset_pipeline(template, Path(template_path), asset_job)
        key = {"input_sha256": input_hash(asset_job.path), "pipeline_sha256": pipeline_hash(doc),
               "rigslim_version": version}
    except Exception as e:  # noqa: BLE001 - every failure of one asset becomes its row
        row["error"] = _error_line(e)
        row["seconds"] = time.perf_counter() - t0
        return row
    record = read_record(folder)
    if not force and record is not None and is_done(record, key, folder):
        previous = dict(record.get("row") or {})
        # the row of the run that made the outputs (its seconds, attempts, memory), marked as skipped
        previous.update({"status": "skipped", "error": "", "worker": row["worker"], "asset": job["path"],
                         "name": asset_job.name})
        return previous
    folder.mkdir(parents=True, exist_ok=True)
    _clean(folder)
    with PeakRSS() as mem:
        row.update(_run(doc, folder, timeout))
    row["peak_memory_mb"] = mem.peak / 2**20
    row["seconds"] = time.perf_counter() - t0
    if row["status"] == "ok":
        row_copy = {k: v for k, v in row.items() if k != "worker"}
        _write_json(folder / RECORD, {"key": key, "outputs": _outputs(folder), "row": row_copy,
                                      "finished": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime())})
    return row


def _user_error(problem, path, source):
    from rigslim.errors import InputError

    return InputError(problem, source=path, field="asset", fix=f"check the asset named by {source}")


def _error_line(e: BaseException) -> str:
    """The line ``rigslim run`` prints for a user error; type and message for anything else."""
    from rigslim.errors import RigslimError

    if isinstance(e, RigslimError):
        return f"rigslim: error: {e.one_line()}"
    if isinstance(e, AssetTimeout):
        return _one_line(str(e))
    return _one_line(f"{type(e).__name__}: {e}") or type(e).__name__


def _run(doc: dict, folder: Path, timeout: float | None) -> dict:
    """Write the asset's pipeline.yaml and run it like ``rigslim run pipeline.yaml --metrics metrics.json``."""
    import yaml
    from rich.console import Console

    from rigslim.io.atomic import atomic_path
    from rigslim.runtime.run import run_pipeline

    pipeline = folder / PIPELINE
    with atomic_path(pipeline) as tmp:
        Path(tmp).write_text(yaml.safe_dump(doc, sort_keys=False))
    deadline = Deadline(timeout, folder / ".timeout")
    out: dict = {}
    try:
        with deadline:
            result = run_pipeline(pipeline, metrics_path=folder / METRICS, console=Console(quiet=True))
    except AssetTimeout:
        out.update(status="failed", error=f"timed out after {timeout:g} s (--timeout)")
        return out
    except BaseException as e:  # noqa: BLE001 - a bad asset must not stop the batch
        if isinstance(e, (KeyboardInterrupt, SystemExit)):
            raise
        out.update(status="failed", error=_error_line(e))
        with contextlib.suppress(OSError):
            (folder / ERROR_LOG).write_text(traceback.format_exc())
        return out
    document = result.document
    before, after = _influences(result.asset)
    out.update(status="ok", error="",
               vertices=(document.get("mesh") or {}).get("vertices"),
               faces=(document.get("mesh") or {}).get("faces"),
               joints=(document.get("handles") or {}).get("count"),
               input_influences=before, output_influences=after, **summary_metrics(document))
    return out
