"""``rigslim batch``: one pipeline template over an asset library, on a Dask cluster.

``rigslim batch TEMPLATE.yaml ASSETS... --out DIR`` runs the template once per
asset (:mod:`rigslim.batch.assets` makes each asset's pipeline) as one
``dask.distributed`` task per asset (:func:`rigslim.batch.task.run_asset`):

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

Modules: :mod:`~rigslim.batch.options` (what a batch is asked and returns), :mod:`~rigslim.batch.assets`
(the asset list and each asset's pipeline), :mod:`~rigslim.batch.task` (one asset on a worker),
:mod:`~rigslim.batch.run` (the cluster and the scheduling), :mod:`~rigslim.batch.summary` (the summary
files), :mod:`~rigslim.batch.cores` (cores and thread limits); the command is :mod:`rigslim.commands.batch`.
"""

from rigslim.batch.cores import available_cores, thread_env
from rigslim.batch.options import EXIT_FAILED, EXIT_OK, BatchOptions, BatchResult
from rigslim.batch.run import dask_client, host_threads, local_cluster, prepare, run_batch
from rigslim.batch.summary import HEAD_COLUMNS, STRING_COLUMNS, TAIL_COLUMNS, summary_columns, write_summary

__all__ = ["EXIT_FAILED", "EXIT_OK", "HEAD_COLUMNS", "STRING_COLUMNS", "TAIL_COLUMNS", "BatchOptions", "BatchResult",
           "available_cores", "dask_client", "host_threads", "local_cluster", "prepare", "run_batch", "summary_columns",
           "thread_env", "write_summary"]
