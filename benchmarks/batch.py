"""``rigslim batch`` speed: 100 asset variants on a 2-worker LocalCluster against a serial loop, and Dask's overhead.

The library: 100 skinned, animated ``.glb`` files, each a variant of bundled
data re-posed (the animation rotated in time, so other frames are the
example and test frames) and re-scaled/re-oriented (a similarity transform
``x -> s R x + c`` applied to the mesh, the joints and every bone transform,
``A' = R A R^T``, ``b' = s R b + c - A' c``): the elephant (6,034 vertices,
24 bones), the Cheb (6,669 vertices, 17 bones, bone heat weights), and the
glTF characters ``RiggedFigure`` (130 vertices, 19 joints) and ``huesitos``
(62, 9; assimp's uniform x100 joint scale divided out). The third glTF
character, ``animation_with_skeleton``, is left out: its joints carry a
non-uniform scale, which a glTF animation of rotations and translations (the
exporter's) cannot hold. Every asset
runs the same template: the 3 largest weights per vertex as influences, their
non-negative Poisson weights ([P10] eq. 5, fitted on 7 example frames), the
three error metrics on 13 test frames, the ``.glb`` written back.

Measured in one run (the machine is shared; run it under the lock):

1. **speed-up**: the 100 assets by a serial loop in this process (the same
   per-asset function ``rigslim batch`` submits, BLAS free to use every core,
   one warm-up asset first) against ``rigslim batch`` on a 2-worker
   LocalCluster (one warm-up asset per worker first; the cluster's start and
   the warm-up are reported apart and in a second ratio), in interleaved
   rounds so that both see the same load;
2. **overhead**: tiny assets (``huesitos`` variants, 62 vertices) in a serial
   loop and as one Dask task each on a warm 1-worker, 1-thread cluster; the
   per-asset difference is the cost of the Dask layer (submission,
   scheduling, transfer of the row, the progress bar).

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/batch.py [--assets 100] [--tiny 100]

Writes docs/results/batch.json and docs/results/batch.md.
"""

from __future__ import annotations

import argparse
import dataclasses
import os
import shutil
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from benchmarks.datasets import DATA, ROOT, machine, write_results  # noqa: E402

TEMPLATE = """\
name: "{name}-k3"
inputs:
  gltf: "{input}"
  fps: 30
poses:
  examples: "0:26:4"
  test: "1:26:2"
steps:
  - select: k-largest
    k: 3
  - solve: poisson
    solver: auto
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: "{name}-k3.glb"
"""

#: The same pipeline with the k-largest solve: single-threaded numpy, where the Poisson solve's numba
#: kernels and BLAS use every core of the serial loop too.
TEMPLATE_K_LARGEST = TEMPLATE.replace("  - solve: poisson\n    solver: auto\n", "  - solve: k-largest\n")

#: family -> number of variants in the 100-asset library
MIX = {"elephant": 30, "cheb": 30, "RiggedFigure": 20, "huesitos": 20}


def _rotation(rng) -> np.ndarray:
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q = q * np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def similarity(mesh, handles, poses, s: float, R: np.ndarray, c: np.ndarray, shift: int):
    """The asset moved by ``x -> s R x + c`` and its animation started ``shift`` frames later (cyclically)."""
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import Poses

    V = s * mesh.V @ R.T + c
    joints = s * np.asarray(handles.joints, float) @ R.T + c
    T = np.roll(poses.T, -shift, axis=0)
    A, b = T[..., :3], T[..., 3]
    A2 = np.einsum("ij,pnjk,lk->pnil", R, A, R)
    b2 = s * np.einsum("ij,pnj->pni", R, b) + c - np.einsum("pnij,j->pni", A2, c)
    return (Mesh(V, mesh.F), dataclasses.replace(handles, joints=joints),
            Poses(np.concatenate([A2, b2[..., None]], axis=-1)))


def _sources():
    """family -> (mesh, handles, weights, poses) of the bundled data."""
    from rigslim.io import read_dmat, read_mesh, read_stacked_animation, read_tgf
    from rigslim.model.weights import validate_weights
    from rigslim.plugin import StepContext
    from rigslim.plugin.host import get_host
    from rigslim.runtime.document import PipelineDoc
    from rigslim.runtime.inputs import read_inputs

    ctx = StepContext(report={}, base_dir=ROOT, progress=lambda it, **k: it, log=lambda *a: None)
    out = {}
    mesh = read_mesh(DATA / "elephant.obj")
    handles = read_tgf(DATA / "elephant.tgf")
    W = validate_weights(read_dmat(DATA / "elephant-weights.dmat"), mesh.n_vertices, n_handles=handles.n)
    out["elephant"] = (mesh, handles, W, read_stacked_animation(DATA / "elephant-anim.dmat", n_handles=handles.n))
    from rigslim.model.asset import Asset

    cheb = Asset(mesh=read_mesh(DATA / "cheburashka.off"), handles=read_tgf(DATA / "cheburashka.tgf"))
    gen = get_host().get("weight-generator", "bone-heat")
    Wc = gen.generate(cheb, gen.parse_params({}), ctx)
    out["cheb"] = (cheb.mesh, cheb.handles, Wc,
                   read_stacked_animation(DATA / "cheburashka-anim.dmat", n_handles=cheb.handles.n))
    from rigslim.model.poses import Poses

    for family, rel in [("RiggedFigure", "RiggedFigure/RiggedFigure.gltf"), ("huesitos", "huesitos.glb")]:
        doc = PipelineDoc(inputs={"gltf": str(DATA / "gltf" / rel), "fps": 30}, steps=[{"select": "k-largest"}])
        a = read_inputs(doc, ROOT, get_host(), ctx, "benchmark")
        # assimp wrote huesitos' joints with a uniform x100 (centimetre) scale: divide it out so the
        # bone transforms are rigid, as a glTF joint animation of rotations and translations needs
        s = float(np.mean(np.cbrt(np.linalg.det(a.poses.T[..., :3]))))
        out[family] = (a.mesh, a.handles, a.weights, Poses(a.poses.T / s))
    return out


def make_library(folder: Path, mix: dict[str, int], seed: int = 15) -> list[Path]:
    """Write the variants as .glb files (``<family>-<i>.glb``); returns their paths in order."""
    from rigslim.io.gltf.write import export_skinned

    folder.mkdir(parents=True, exist_ok=True)
    rng = np.random.default_rng(seed)
    sources = _sources()
    paths = []
    for family, count in mix.items():
        mesh, handles, W, poses = sources[family]
        for i in range(count):
            s = float(np.exp(rng.uniform(np.log(0.2), np.log(5.0))))
            R = _rotation(rng)
            c = rng.uniform(-10, 10, size=3)
            shift = int(rng.integers(0, len(poses)))
            m, h, p = similarity(mesh, handles, poses, s, R, c, shift)
            path = folder / f"{family}-{i:02d}.glb"
            export_skinned(path, m, h, W, p, fps=30.0, name=path.stem)
            paths.append(path)
    return paths


def serial_loop(jobs, template: dict, template_path: Path, out: Path, threads: int | None = None):
    """Run every asset in this process, one after the other; returns (seconds, rows).

    ``threads``: BLAS/numba threads (default: every core, as a plain loop of ``rigslim run`` gets).
    """
    from rigslim.batch.cores import available_cores
    from rigslim.batch.task import run_asset

    t0 = time.perf_counter()
    rows = [run_asset(j.as_dict(), template, str(template_path), str(out), force=True,
                      threads=threads or available_cores()) for j in jobs]
    return time.perf_counter() - t0, rows


def compare(template: dict, template_path: Path, jobs, library, cluster, rounds: int, work: Path):
    """Serial loop and Dask batch over the library in ``rounds`` interleaved rounds; (serial_s, dask_s, rows, rows)."""
    n = len(jobs)
    serial_rows, dask_rows = [None] * n, [None] * n
    serial_s = dask_s = 0.0
    for r in range(rounds):
        idx = list(range(r, n, rounds))
        for which in ("serial", "dask") if r % 2 == 0 else ("dask", "serial"):
            if which == "serial":
                dt, rows = serial_loop([jobs[i] for i in idx], template, template_path, work / "serial")
                serial_s += dt
                for i, row in zip(idx, rows, strict=False):
                    serial_rows[i] = row
            else:
                dt, res = dask_batch(template_path, [library[i] for i in idx], work / "dask",
                                     scheduler=cluster.scheduler_address)
                dask_s += dt
                for i, row in zip(idx, res.rows, strict=False):
                    dask_rows[i] = row
        print(f"{template_path.stem} round {r + 1}/{rounds}: serial {serial_s:.1f} s, Dask {dask_s:.1f} s so far")
    return serial_s, dask_s, serial_rows, dask_rows


def _warm_workers(cluster, job, template: dict, template_path: Path, out: Path) -> None:
    """Run one asset on every worker of ``cluster`` (not timed with the batch)."""
    from distributed import Client

    from rigslim.batch.task import run_asset

    with Client(cluster) as client:
        workers = list(client.scheduler_info()["workers"])
        futures = [client.submit(run_asset, job.as_dict(), template, str(template_path), str(out / str(i)),
                                 force=True, threads=1, workers=[w], pure=False) for i, w in enumerate(workers)]
        client.gather(futures)


def dask_batch(template_path: Path, assets, out: Path, **kw) -> tuple[float, object]:
    from rich.console import Console

    from rigslim.batch.options import BatchOptions
    from rigslim.batch.run import run_batch

    opts = BatchOptions(template=template_path, assets=[str(a) for a in assets], out=out, force=True,
                        dashboard=False, **kw)
    t0 = time.perf_counter()
    result = run_batch(opts, Console(stderr=True, quiet=True))
    return time.perf_counter() - t0, result


def scheduler_throughput(n: int) -> float:
    """Tasks per second the Dask scheduler completes for ``n`` no-op tasks on a warm 2-worker LocalCluster.

    This is the ceiling of the scheduler alone (each asset is one task): the
    scaling plan in docs/batch.md compares it with the task rate a cluster
    of workers asks for.
    """
    from distributed import Client

    from rigslim.batch.run import local_cluster

    with local_cluster(workers=2, threads_per_worker=1, dashboard=False) as (cluster, _), Client(cluster) as client:
        client.gather(client.map(abs, range(-100, 0), pure=False))
        t0 = time.perf_counter()
        client.gather(client.map(abs, range(n), pure=False))
        return n / (time.perf_counter() - t0)


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--assets", type=int, default=100, help="library size (the mix is scaled to it)")
    parser.add_argument("--tiny", type=int, default=100, help="tiny assets for the overhead measurement")
    parser.add_argument("--rounds", type=int, default=4, help="interleaved serial / Dask rounds")
    parser.add_argument("--noop-tasks", type=int, default=5000, help="no-op tasks for the scheduler's rate")
    parser.add_argument("--work", type=Path, help="work folder (default: a temporary folder)")
    parser.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "batch")
    args = parser.parse_args(argv)

    from rigslim.batch.assets import collect_assets, load_template
    from rigslim.batch.run import local_cluster

    work = args.work or Path(tempfile.mkdtemp(prefix="rigslim-batch-bench-"))
    work.mkdir(parents=True, exist_ok=True)
    load_before = os.getloadavg()
    template_path = work / "template.yaml"
    template_path.write_text(TEMPLATE)
    template = load_template(template_path)
    scale = args.assets / sum(MIX.values())
    mix = {k: max(1, round(v * scale)) for k, v in MIX.items()}
    t = time.perf_counter()
    library = make_library(work / "library", mix)
    tiny = make_library(work / "tiny", {"huesitos": args.tiny}, seed=16)
    print(f"library: {len(library)} assets, {len(tiny)} tiny ones, written in {time.perf_counter() - t:.1f} s")
    jobs = collect_assets([str(p) for p in library])
    tiny_jobs = collect_assets([str(p) for p in tiny])

    # Speed-up. The machine is shared, so the serial loop and the batch run in interleaved rounds (a
    # quarter of the library each, every family in each, the order alternating) and see the same load.
    serial_loop(jobs[:1], template, template_path, work / "warm")  # this process's imports and numba caches
    rounds = args.rounds
    start = time.perf_counter()
    with local_cluster(workers=2, threads_per_worker=1, dashboard=False) as (cluster, _):
        started = time.perf_counter() - start
        # the workers' warm-up, like this process's: imports, plugin loading, numba's kernels (compiled when
        # their on-disk cache is stale) -- one asset on each worker, timed apart
        t = time.perf_counter()
        _warm_workers(cluster, jobs[0], template, template_path, work / "warm-dask")
        warm_up = time.perf_counter() - t
        print(f"cluster start {started:.1f} s, worker warm-up {warm_up:.1f} s")
        serial_s, dask_s, serial_rows, dask_rows = compare(template, template_path, jobs, library, cluster, rounds,
                                                           work / "poisson")
        k_template_path = work / "template-k-largest.yaml"
        k_template_path.write_text(TEMPLATE_K_LARGEST)
        k_template = load_template(k_template_path)
        serial_loop(jobs[:1], k_template, k_template_path, work / "warm-k")
        # (2 rounds: each batch pays its client's connection, checks and summary, a second or so)
        k_serial_s, k_dask_s, _, _ = compare(k_template, k_template_path, jobs, library, cluster, 2,
                                             work / "k-largest")
    dask_total = dask_s + started + warm_up
    print(f"serial loop: {serial_s:.1f} s; rigslim batch on 2 workers: {dask_s:.1f} s (speed-up "
          f"{serial_s / dask_s:.2f}x), with cluster start and warm-up {dask_total:.1f} s "
          f"({serial_s / dask_total:.2f}x); k-largest template: {k_serial_s:.1f} s / {k_dask_s:.1f} s "
          f"({k_serial_s / k_dask_s:.2f}x)")
    bad = [r for r in serial_rows + dask_rows if r["status"] != "ok"]
    if bad:
        raise SystemExit(f"{len(bad)} assets failed: {bad[0]['error']}")
    # The serial loop's BLAS and numba use every core, a worker's one: the iterative solves take other
    # rounding paths and stop (tolerance 1e-5) at slightly different weights. Record how far apart they end.
    metric_keys = [k for k in serial_rows[0] if k.endswith(("_mean", "_max")) and isinstance(serial_rows[0][k], float)]
    rel_diff = max(abs(a[k] - b[k]) / max(abs(a[k]), 1e-300) for a, b in zip(serial_rows, dask_rows, strict=False)
                   for k in metric_keys)
    assert rel_diff < 1e-2, f"serial and Dask metrics differ by {rel_diff:.3g} (relative)"

    # Dask overhead on tiny assets: the same work in a serial loop and through a warm 1 x 1 cluster
    # (one BLAS/numba thread in both, as on the worker: the difference is then the Dask layer alone)
    serial_loop(tiny_jobs[:3], template, template_path, work / "tiny-warm", threads=1)
    tiny_serial_s, tiny_rows = serial_loop(tiny_jobs, template, template_path, work / "tiny-serial", threads=1)
    with local_cluster(workers=1, threads_per_worker=1, dashboard=False) as (cluster, _):
        dask_batch(template_path, tiny[:3], work / "tiny-dask-warm", scheduler=cluster.scheduler_address)
        tiny_dask_s, tiny_result = dask_batch(template_path, tiny, work / "tiny-dask",
                                              scheduler=cluster.scheduler_address)
    overhead_ms = 1000 * (tiny_dask_s - tiny_serial_s) / len(tiny)
    # the part of it outside the tasks: submission, scheduling, results, the batch's checks and summary
    gap_ms = 1000 * (tiny_dask_s - sum(r["seconds"] for r in tiny_result.rows)) / len(tiny)
    rate = scheduler_throughput(args.noop_tasks)
    print(f"scheduler: {rate:.0f} no-op tasks/s")
    print(f"tiny assets: serial {tiny_serial_s:.2f} s, Dask {tiny_dask_s:.2f} s -> {overhead_ms:.1f} ms per asset; "
          f"2-worker cluster start {started:.1f} s")

    families = {}
    for r_serial, r_dask in zip(serial_rows, dask_rows, strict=False):
        fam = r_serial["name"].rsplit("-", 1)[0]
        f = families.setdefault(fam, {"assets": 0, "vertices": r_serial["vertices"], "serial_s": [], "dask_s": [],
                                      "peak_mb": []})
        f["assets"] += 1
        f["serial_s"].append(r_serial["seconds"])
        f["dask_s"].append(r_dask["seconds"])
        f["peak_mb"].append(r_dask["peak_memory_mb"])
    fam_rows = {k: {"assets": v["assets"], "vertices": v["vertices"],
                    "serial_mean_s": statistics.mean(v["serial_s"]), "dask_mean_s": statistics.mean(v["dask_s"]),
                    "worker_peak_mb": max(v["peak_mb"])} for k, v in families.items()}
    per_asset_dask = statistics.mean(r["seconds"] for r in dask_rows)
    doc = {"machine": machine(), "load_before": load_before, "assets": len(library), "mix": mix,
           "rounds": rounds, "metrics_max_rel_diff": rel_diff, "serial_s": serial_s,
           "dask_s": dask_s, "worker_warm_up_s": warm_up, "dask_with_start_s": dask_total,
           "speedup": serial_s / dask_s, "speedup_with_start": serial_s / dask_total,
           "k_largest": {"serial_s": k_serial_s, "dask_s": k_dask_s, "speedup": k_serial_s / k_dask_s},
           "cluster_start_s": started, "scheduler_tasks_per_s": rate, "families": fam_rows,
           "per_asset_mean_s": per_asset_dask,
           "tiny": {"assets": len(tiny), "serial_s": tiny_serial_s, "dask_s": tiny_dask_s,
                    "overhead_ms_per_asset": overhead_ms, "outside_tasks_ms_per_asset": gap_ms,
                    "task_mean_s": statistics.mean(r["seconds"] for r in tiny_result.rows)},
           "command": "flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/batch.py"}
    doc["load_after"] = os.getloadavg()
    md = [f"# rigslim batch: {len(library)} assets, LocalCluster (2 workers) vs a serial loop", "",
          f"Machine: {doc['machine']['cpu']}, {doc['machine']['nproc']} cores, Python {doc['machine']['python']}; "
          f"load average (1, 5, 15 min) before {', '.join(f'{x:.2f}' for x in doc['load_before'])}, after "
          f"{', '.join(f'{x:.2f}' for x in doc['load_after'])} "
          "(the machine is shared with other sessions).", "",
          f"Command: `{doc['command']}`", "",
          "| run | wall time | speed-up |", "|---|---:|---:|",
          f"| serial loop (one process, BLAS on all cores; one warm-up asset first) | {serial_s:.1f} s | 1.00x |",
          f"| `rigslim batch` on a 2-worker LocalCluster (one warm-up asset per worker first) | {dask_s:.1f} s "
          f"| {serial_s / dask_s:.2f}x |",
          f"| the same with the cluster's start ({started:.1f} s) and the workers' warm-up ({warm_up:.1f} s) "
          f"| {dask_total:.1f} s | {serial_s / dask_total:.2f}x |",
          f"| k-largest template (single-threaded solve; 2 rounds), serial loop | {k_serial_s:.1f} s | 1.00x |",
          f"| k-largest template, `rigslim batch` on the same 2 workers | {k_dask_s:.1f} s "
          f"| {k_serial_s / k_dask_s:.2f}x |", "",
          f"Both ran in {rounds} interleaved rounds (each a {100 // rounds} % slice of the library with every "
          "family in it, the order alternating), so that both see the same load from other sessions. The "
          f"metrics of every asset agree to {rel_diff:.1e} (relative): the serial loop's BLAS and numba use every "
          "core, a worker's one, so the iterative Poisson solves round differently and stop at their tolerance "
          "at slightly different weights.", "",
          "| family | assets | vertices | mean s / asset, serial | mean s / asset, on a worker | peak RSS of a "
          "worker (MB) |", "|---|---:|---:|---:|---:|---:|"]
    for k, v in fam_rows.items():
        md.append(f"| {k} | {v['assets']} | {v['vertices']:,} | {v['serial_mean_s']:.3f} | {v['dask_mean_s']:.3f} "
                  f"| {v['worker_peak_mb']:.0f} |")
    md += ["", f"Dask overhead, {len(tiny)} tiny assets (huesitos variants, 62 vertices), warm 1-worker 1-thread "
           "cluster against a serial loop of the same function with one BLAS/numba thread:", "",
           "| serial loop | through Dask | overhead per asset |", "|---:|---:|---:|",
           f"| {tiny_serial_s:.2f} s | {tiny_dask_s:.2f} s | {overhead_ms:.1f} ms |", "",
           f"Of that, {gap_ms:.1f} ms per asset is outside the tasks (the batch's wall time less the sum of its "
           "tasks' times: submission, scheduling, results, the batch's checks and summary); the rest is the "
           "same function running slower inside the worker process than in this one.", "",
           f"Scheduler alone: {args.noop_tasks:,} no-op tasks on a warm 2-worker LocalCluster complete at "
           f"{rate:,.0f} tasks/s.", ""]
    write_results(args.out, doc, "\n".join(md) + "\n")
    print("\n".join(md))
    if not args.work:
        shutil.rmtree(work, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
