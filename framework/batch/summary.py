"""The batch summary: one row per asset, written as summary.csv, summary.json and summary.parquet."""

from __future__ import annotations

import csv
from pathlib import Path

from rigslim.batch.options import BatchOptions, BatchResult
from rigslim.io.jsonsafe import dumps_strict

#: Columns every summary has, in this order; metric columns follow, then :data:`TAIL_COLUMNS`.
HEAD_COLUMNS = ["asset", "name", "status", "error", "seconds", "peak_memory_mb", "vertices", "faces", "joints",
                "input_influences", "output_influences"]


TAIL_COLUMNS = ["worker", "threads", "attempts"]


STRING_COLUMNS = {"asset", "name", "status", "error", "worker"}


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
        Path(tmp).write_text(dumps_strict(doc, indent=2, default=str) + "\n")
    return paths
