"""Deformation throughput: numpy, OpenCL and OpenGL, full weights against k = 8 and k = 4.

The elephant midpoint-subdivided ``levels`` times (3: ~386k vertices, ~772k
triangles; the paper's model had 702,538 polygons) with its skin weights
interpolated (up to 24 per vertex), reduced to k = 8 and k = 4 by k-largest
(the throughput does not depend on how the values were fitted). Each back end
deforms the same test poses with positions only and with positions + normals
(blended-matrix: the elephant is skinned to a skeleton).

Timings per frame, median over the poses after one warm-up frame:

- ``device_ms``: OpenCL profiling event of the kernel launch; GL timer query
  (``GL_TIME_ELAPSED``) on hardware GL, wall time of draw + ``glFinish`` on
  llvmpipe (whose query does not cover the vertex shading, see
  ``rigslim.plugins.deformers.opengl_deformer``); wall time for numpy;
- ``frame_ms``: wall time of the whole frame: upload of the transforms,
  kernel, read-back of positions (and normals) into numpy arrays.

``fps`` is ``1000 / device_ms``; the effective bandwidth is
``bytes_per_frame / device_ms``, counting every input read once (rest
positions, weights and indices, handle records, rest normals) and every
output written once (positions, normals).

``--quick`` (under 3 minutes on the 2-core CPU machine) times every CPU
back end, the compiled ``cpu`` deformer (fixed and compact layouts), OpenCL
on the CPU device (PoCL) and OpenGL on llvmpipe when present, at k = 8 and
k = 4 with and without normals, against numpy with the full weights
(positions), together with the machine's copy bandwidth and the recomputed
normals of the full deformation, all in one run; see :func:`run_quick`.

Usage::

    .venv/bin/python -m benchmarks.deform_throughput                # full size, writes docs/results/deform.{json,md}
    .venv/bin/python -m benchmarks.deform_throughput --quick --json docs/results/deform-cpu.json   # + .md
    .venv/bin/python -m benchmarks.deform_throughput --levels 1 --frames 3 --out /tmp/deform
    python3 benchmarks/deform_throughput.py --device gpu             # on a machine with a GPU
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import statistics
import subprocess
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):          # run as a script: python3 benchmarks/deform_throughput.py
    import sys

    sys.path.insert(0, str(ROOT))

from benchmarks.datasets import cpu_model, write_results  # noqa: E402

#: [P10] section 5, 702,538-polygon model, 137-vertex cage: CPU full weights 1.2 fps,
#: CPU 8 weights 13.9 fps, GeForce GTX 280 8 weights 142.9 fps.
PAPER = {"cpu_full_fps": 1.2, "cpu_k8_fps": 13.9, "gtx280_k8_fps": 142.9}


def gpu_names() -> list[str]:
    try:
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=10)
        return [x.strip() for x in out.stdout.splitlines() if x.strip()] if out.returncode == 0 else []
    except (OSError, subprocess.SubprocessError):
        return []


def time_bound(bound, poses, normals: bool) -> dict:
    """Median device and frame time of one bound deformer over the poses (one warm-up frame first)."""
    device, frame = [], []
    bound.deform(poses[0], normals=normals)
    for T in poses:
        t = time.perf_counter()
        bound.deform(T, normals=normals)
        frame.append(time.perf_counter() - t)
        device.append(bound.last_seconds)
    device_s = statistics.median(device)
    frame_s = statistics.median(frame)
    moved = bound.bytes_per_frame(normals)
    return {"device_ms": 1e3 * device_s, "frame_ms": 1e3 * frame_s, "fps": 1.0 / device_s,
            "fps_frame": 1.0 / frame_s, "bytes_per_frame": moved, "gb_per_s": moved / device_s / 1e9}


def run(levels: int, frames: int, backends: list[str], ks: list[int | None], device: str | None = None,
        log=print) -> dict:
    from benchmarks.datasets import elephant
    from rigslim.model.weights import influence_counts
    from rigslim.numerics.largest_entries import k_largest
    from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
    from rigslim.plugins.solvers.renormalised import renormalised_weights

    load_start = os.getloadavg()[0]
    t = time.perf_counter()
    asset = elephant(levels=levels)
    mesh, W = asset.mesh, asset.weights
    log(f"elephant subdivided {levels}x: {mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles, "
        f"{W.nnz:,} weights (max {int(influence_counts(W).max())} per vertex) [{time.perf_counter() - t:.1f} s]")
    test = asset.split.test
    step = max(1, len(test) // frames)
    poses = asset.poses.T[test[::step][:frames]]
    weight_sets = {}
    for k in ks:
        weight_sets["full" if k is None else f"k={k}"] = W if k is None else renormalised_weights(W, k_largest(W, k))

    deformers = {"numpy": NumpyDeformer()}
    devices = {"numpy": f"{cpu_model()} ({os.cpu_count()} logical CPUs), numpy {np.__version__}"}
    params = {"numpy": {}}
    if "cpu" in backends:
        from rigslim.plugins.deformers.cpu_deformer import CPUDeformer

        deformers["cpu"] = CPUDeformer()
        devices["cpu"] = f"{cpu_model()} ({os.cpu_count()} logical CPUs), numba"
        params["cpu"] = {}
    if "opencl" in backends:
        from rigslim.device.opencl import OpenCLUnavailable, get_runtime
        from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer

        try:
            devices["opencl"] = get_runtime(device).name
            deformers["opencl"] = OpenCLDeformer()
            params["opencl"] = {} if device is None else {"device": device}
        except OpenCLUnavailable as e:
            log(f"opencl skipped: {e}")
    if "opengl" in backends:
        from rigslim.device.egl import EGLUnavailable, shared_context
        from rigslim.plugins.deformers.opengl_deformer import OpenGLDeformer

        try:
            ctx = shared_context()
            devices["opengl"] = f"{ctx.renderer}, {ctx.version} (EGL {ctx.platform})"
            deformers["opengl"] = OpenGLDeformer()
            params["opengl"] = {}
        except EGLUnavailable as e:
            log(f"opengl skipped: {e}")
    deformers = {b: d for b, d in deformers.items() if b in backends}

    rows = []
    for label, weights in weight_sets.items():
        for backend, deformer in deformers.items():
            raw = dict(params[backend])
            if backend == "opencl":
                raw["layout"] = "csr" if label == "full" else "fixed"
            bound = deformer.bind(mesh, weights, deformer.parse_params(raw), handles=asset.handles)
            for normals in (False, True):
                r = time_bound(bound, poses, normals)
                r.update({"backend": backend, "weights": label, "normals": normals,
                          "layout": getattr(bound, "layout", "sparse" if label == "full" else "fixed")})
                rows.append(r)
                log(f"{backend:7s} {label:5s} {'pos+nrm' if normals else 'pos':7s} {r['layout']:6s} "
                    f"device {r['device_ms']:9.2f} ms  frame {r['frame_ms']:9.2f} ms  {r['fps']:8.1f} fps  "
                    f"{r['gb_per_s']:6.2f} GB/s")
            bound.close()
            if backend == "opencl" and label != "full":      # the compact 16-bit layout too
                bound = deformer.bind(mesh, weights, deformer.parse_params({**raw, "layout": "compact"}),
                                      handles=asset.handles)
                for normals in (False, True):
                    r = time_bound(bound, poses, normals)
                    r.update({"backend": backend, "weights": label, "normals": normals, "layout": "compact"})
                    rows.append(r)
                    log(f"{backend:7s} {label:5s} {'pos+nrm' if normals else 'pos':7s} compact "
                        f"device {r['device_ms']:9.2f} ms  frame {r['frame_ms']:9.2f} ms  {r['fps']:8.1f} fps  "
                        f"{r['gb_per_s']:6.2f} GB/s")
                bound.close()

    def fps(backend, weights, normals=False, layout=None):
        for r in rows:
            if r["backend"] == backend and r["weights"] == weights and r["normals"] == normals and \
                    (layout is None or r["layout"] == layout):
                return r["fps"]
        return None

    load_end = os.getloadavg()[0]
    numpy_full = fps("numpy", "full")
    ratios = {}
    for backend in deformers:
        for label in weight_sets:
            for normals in (False, True):
                f = fps(backend, label, normals, layout="fixed" if backend == "opencl" and label != "full" else None)
                if f and numpy_full:
                    ratios[f"{backend} {label}{' +normals' if normals else ''}"] = f / numpy_full
    return {
        "benchmark": "deform_throughput",
        "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
        "machine": {"cpu": cpu_model(), "nproc": os.cpu_count(), "platform": platform.platform(),
                    "gpus": gpu_names()},
        "devices": devices,
        "mesh": {"levels": levels, "vertices": mesh.n_vertices, "triangles": mesh.n_faces,
                 "handles": asset.handles.n, "weights_nnz": int(W.nnz),
                 "max_weights_per_vertex": int(influence_counts(W).max())},
        "frames": [int(f) for f in test[::step][:frames]],
        "rows": rows,
        "speedup_over_numpy_full": ratios,
        "load_average": [load_start, load_end],
        "paper": PAPER,
    }


def markdown(doc: dict) -> str:
    m, mach = doc["mesh"], doc["machine"]
    lines = [
        "# Deformation throughput",
        "",
        f"Measured {doc['date_utc']} UTC by `benchmarks/deform_throughput.py` on {mach['cpu']} "
        f"({mach['nproc']} logical CPUs, shared with other jobs), {mach['platform']}.",
        "",
        f"Mesh: the elephant subdivided {m['levels']}x, {m['vertices']:,} vertices, {m['triangles']:,} triangles, "
        f"{m['handles']} bones, {m['weights_nnz']:,} interpolated weights (up to {m['max_weights_per_vertex']} "
        f"per vertex); k = 8 and k = 4 by k-largest. {len(doc['frames'])} test poses, median per frame after a "
        f"warm-up frame. Normals: blended-matrix (the inverse transpose of sum_l w_l R_l) in the same pass.",
        "",
        "Devices:",
        "",
    ]
    for b, d in doc["devices"].items():
        lines.append(f"- {b}: {d}")
    gpus = mach["gpus"]
    lines += ["", ("GPU: " + ", ".join(gpus)) if gpus else
              "**No GPU machine was available for this run**: the GPU rows of the issue (OpenCL and OpenGL on "
              "the NVIDIA machine, the H100 target of 20,000 deformations/s) are not measured.", "",
              "`device ms`: OpenCL profiling event of the kernel; for OpenGL on llvmpipe the wall time of draw + "
              "glFinish (llvmpipe's GL_TIME_ELAPSED query reads ~50 ns: it does not cover vertex shading); numpy: "
              "wall time. `frame ms`: the whole frame, upload + kernel + read-back into numpy. fps = 1000 / device "
              "ms. GB/s = bytes a frame must move (inputs read once, outputs written once) / device time.", "",
              "| backend | weights | layout | normals | device ms | frame ms | fps | bytes/frame | GB/s |",
              "|---|---|---|---|---:|---:|---:|---:|---:|"]
    for r in doc["rows"]:
        lines.append(f"| {r['backend']} | {r['weights']} | {r['layout']} | {'yes' if r['normals'] else 'no'} | "
                     f"{r['device_ms']:.2f} | {r['frame_ms']:.2f} | {r['fps']:.1f} | {r['bytes_per_frame']:,} | "
                     f"{r['gb_per_s']:.2f} |")
    lines += ["", "Speed-up over full-weight numpy (positions only) in the same run (device time):", "",
              "| configuration | x numpy full |", "|---|---:|"]
    for k, v in doc["speedup_over_numpy_full"].items():
        lines.append(f"| {k} | {v:.1f} |")
    ratio = doc["speedup_over_numpy_full"].get("opencl k=8")
    load = doc.get("load_average")
    lines += ["", "## Targets", ""]
    if ratio is not None:
        lines.append(f"- k = 8 through OpenCL at least 10x the full-weight numpy deformation (same run): "
                     f"**{ratio:.1f}x, {'met' if ratio >= 10 else 'missed'}**.")
    lines.append("- H100, k = 8 with normals, at least 20,000 deformations/s and half the copy bandwidth: "
                 + ("see the GPU rows." if gpus else "**not measured (no GPU machine in this session)**."))
    if load:
        lines.append(f"- 1-minute load average at start / end of the run: {load[0]:.2f} / {load[1]:.2f} "
                     f"on {mach['nproc']} CPUs (other jobs share the machine; timings are noisy).")
    p = doc["paper"]
    lines += ["", f"For context, [P10] section 5 (702,538 polygons, 137-vertex cage, 2010 hardware): CPU full "
              f"weights {p['cpu_full_fps']} fps, CPU 8 weights {p['cpu_k8_fps']} fps, GeForce GTX 280 8 weights "
              f"{p['gtx280_k8_fps']} fps.", ""]
    return "\n".join(lines)


#: Keys of every ``--quick`` row (the issue's schema; tests check them).
QUICK_ROW_KEYS = ("backend", "weights", "layout", "normals", "device_ms", "frame_ms", "gbps")


def copy_bandwidth(nbytes: int = 512 << 20, repeats: int = 5) -> dict:
    """Copy bandwidth in GB/s (bytes read + bytes written per second), best of ``repeats``.

    Two probes over the same ``nbytes`` buffers: ``numpy.copyto`` (one thread) and a
    numba ``prange`` copy over all cores (the threads the cpu deformer uses).
    ``copy_gbps`` is the higher of the two, the bar the kernels are held to.
    """
    from rigslim.plugins.deformers.cpu_kernels import copy_rows

    rows = max(1, nbytes // 64)
    src = np.ones((rows, 16), dtype=np.float32)
    dst = np.empty_like(src)
    copy_rows(src[:8], dst[:8])          # compile outside the timing
    out = {}
    for name, fn in (("numpy_copyto", lambda: np.copyto(dst, src)), ("numba_parallel", lambda: copy_rows(src, dst))):
        best = float("inf")
        for _ in range(repeats):
            t = time.perf_counter()
            fn()
            best = min(best, time.perf_counter() - t)
        out[name] = 2 * src.nbytes / best / 1e9
    out["bytes"] = int(src.nbytes)
    out["copy_gbps"] = max(out["numpy_copyto"], out["numba_parallel"])
    return out


def time_frames(frame, bound, poses, normals: bool) -> tuple[float, float]:
    """Median (device_ms, frame_ms) over the poses after one warm-up frame; ``frame(T, normals)`` is one frame."""
    frame(poses[0], normals)
    device, wall = [], []
    for T in poses:
        t = time.perf_counter()
        frame(T, normals)
        wall.append(time.perf_counter() - t)
        device.append(bound.last_seconds)
    return 1e3 * statistics.median(device), 1e3 * statistics.median(wall)


def run_quick(levels: int = 3, frames: int = 8, ks=(8, 4), copy_mib: int = 512, log=print) -> dict:
    """Every CPU back end on the same mesh and poses in one run, with the copy bandwidth.

    A frame is what a caller runs per pose with the outputs already allocated:
    numpy ``deform(T)`` (the float64 reference, full weights, positions);
    ``launch(T, normals)`` of the cpu deformer (handle table + one kernel call),
    of OpenCL (upload, kernel, read-back into preallocated host arrays) and of
    OpenGL (upload, draw, read-back). ``device_ms`` is the kernel's own time
    (``last_seconds``), ``frame_ms`` the wall time of the frame, and
    ``gbps = bytes_per_frame / frame_ms`` with every input read once and every
    output written once (``bytes_per_frame`` of each bound deformer).
    """
    from benchmarks.datasets import elephant
    from rigslim.model.weights import influence_counts
    from rigslim.numerics.area_weighted_normals import operator_for
    from rigslim.numerics.largest_entries import k_largest
    from rigslim.plugins.deformers.cpu_deformer import CPUDeformer
    from rigslim.plugins.deformers.numpy_deformer import NumpyDeformer
    from rigslim.plugins.solvers.renormalised import renormalised_weights

    started = time.perf_counter()
    load_start = os.getloadavg()[0]
    asset = elephant(levels=levels)
    mesh, W = asset.mesh, asset.weights
    test = asset.split.test
    step = max(1, len(test) // frames)
    chosen = test[::step][:frames]
    poses = asset.poses.T[chosen]
    log(f"elephant subdivided {levels}x: {mesh.n_vertices:,} vertices, {mesh.n_faces:,} triangles, {W.nnz:,} weights "
        f"(max {int(influence_counts(W).max())} per vertex), {len(poses)} poses "
        f"[{time.perf_counter() - started:.1f} s]")
    copy = copy_bandwidth(copy_mib << 20)
    log(f"copy bandwidth: numpy copyto {copy['numpy_copyto']:.1f} GB/s, numba parallel {copy['numba_parallel']:.1f} "
        f"GB/s (read + write)")
    rows, devices = [], {"numpy": f"{cpu_model()}, numpy {np.__version__}", "cpu": "numba, all cores"}

    def add(backend, weights, layout, normals, device_ms, frame_ms, moved):
        row = {"backend": backend, "weights": weights, "layout": layout, "normals": bool(normals),
               "device_ms": device_ms, "frame_ms": frame_ms, "gbps": moved / (frame_ms * 1e-3) / 1e9}
        rows.append(row)
        log(f"{backend:7s} {str(weights):5s} {layout:7s} {'pos+nrm' if normals else 'pos':7s} "
            f"device {device_ms:8.2f} ms  frame {frame_ms:8.2f} ms  {row['gbps']:6.2f} GB/s")

    ref = NumpyDeformer().bind(mesh, W, NumpyDeformer.Params(normals="none"))
    device_ms, frame_ms = time_frames(lambda T, n: ref.deform(T), ref, poses, False)
    add("numpy", "full", "sparse", False, device_ms, frame_ms, ref.bytes_per_frame(False))
    numpy_full_ms = frame_ms

    # recomputed (area-weighted) normals of the full deformation: the reference of the normal metrics
    full_positions = ref.deform(poses[0])
    op = operator_for(mesh.F, mesh.n_vertices)
    out = np.empty((mesh.n_vertices, 3))
    op(full_positions, out=out)
    times = []
    for T in poses:
        P = ref.deform(T)
        t = time.perf_counter()
        op(P, out=out)
        times.append(time.perf_counter() - t)
    recomputed_ms = 1e3 * statistics.median(times)
    log(f"recomputed normals (face->vertex operator): {recomputed_ms:.2f} ms = {recomputed_ms / numpy_full_ms:.2f}x "
        f"numpy full positions")

    backends = {"cpu": CPUDeformer()}
    try:
        from rigslim.device.opencl import OpenCLUnavailable, get_runtime
        from rigslim.plugins.deformers.opencl_deformer import OpenCLDeformer

        rt = get_runtime("cpu")
        devices["opencl"] = rt.name
        backends["opencl"] = OpenCLDeformer()
    except (ImportError, OpenCLUnavailable, Exception) as e:  # noqa: BLE001 - any missing driver skips the rows
        log(f"opencl (CPU device) skipped: {e}")
    try:
        from rigslim.device.egl import shared_context
        from rigslim.plugins.deformers.opengl_deformer import OpenGLDeformer

        ctx = shared_context()
        if ctx.is_software:
            devices["opengl"] = f"{ctx.renderer}, {ctx.version}"
            backends["opengl"] = OpenGLDeformer()
        else:
            log(f"opengl skipped: {ctx.renderer} is not a CPU renderer")
    except Exception as e:  # noqa: BLE001
        log(f"opengl skipped: {e}")

    # Back end by back end (every k of one before the next): PoCL's and llvmpipe's worker threads stay busy
    # for a while after their last frame, and would otherwise eat into the next back end's cores.
    reduced_by_k = {k: renormalised_weights(W, k_largest(W, k)) for k in ks}
    for backend, deformer in backends.items():
        for k in ks:
            reduced = reduced_by_k[k]
            for layout in ("fixed", "compact"):
                raw = {"layout": layout, **{"opencl": {"device": "cpu"}, "cpu": {"engine": "numba"}}.get(backend, {})}
                bound = deformer.bind(mesh, reduced, deformer.parse_params(raw), handles=asset.handles)

                def frame(T, normals, bound=bound):
                    bound.launch(T, normals, read=True)

                for normals in (False, True):
                    device_ms, frame_ms = time_frames(frame, bound, poses, normals)
                    add(backend, int(k), layout, normals, device_ms, frame_ms, bound.bytes_per_frame(normals))
                bound.close()

    def best(backend, k, normals):
        cands = [r for r in rows if r["backend"] == backend and r["weights"] == k and r["normals"] == normals]
        return min(cands, key=lambda r: r["frame_ms"]) if cands else None

    targets = {}
    for k in ks:
        r = best("cpu", k, True)
        if r is not None:
            targets[f"cpu k={k} normals"] = {"layout": r["layout"], "frame_ms": r["frame_ms"],
                                             "x_numpy_full": numpy_full_ms / r["frame_ms"],
                                             "fraction_of_copy": r["gbps"] / copy["copy_gbps"]}
    return {
        "benchmark": "deform_throughput --quick",
        "date_utc": time.strftime("%Y-%m-%d %H:%M:%S", time.gmtime()),
        "machine": {"cpu": cpu_model(), "nproc": os.cpu_count(), "platform": platform.platform()},
        "devices": devices,
        "mesh": {"levels": levels, "vertices": mesh.n_vertices, "triangles": mesh.n_faces,
                 "handles": asset.handles.n, "weights_nnz": int(W.nnz)},
        "frames": [int(f) for f in chosen],
        "copy_gbps": copy["copy_gbps"],
        "copy": copy,
        "rows": rows,
        "recomputed_normals": {"ms": recomputed_ms, "x_numpy_full_positions": recomputed_ms / numpy_full_ms},
        "targets": targets,
        "load_average": [load_start, os.getloadavg()[0]],
        "seconds": time.perf_counter() - started,
    }


def quick_markdown(doc: dict) -> str:
    m, mach, c = doc["mesh"], doc["machine"], doc["copy"]
    lines = [
        "# Deformation throughput on the CPU (`--quick`)",
        "",
        f"Measured {doc['date_utc']} UTC by `benchmarks/deform_throughput.py --quick` on {mach['cpu']} "
        f"({mach['nproc']} logical CPUs, shared with other jobs), {mach['platform']}; "
        f"{doc['seconds']:.0f} s in all.",
        "",
        f"Mesh: the elephant subdivided {m['levels']}x, {m['vertices']:,} vertices, {m['triangles']:,} triangles, "
        f"{m['handles']} bones, {m['weights_nnz']:,} weights; k-largest reductions. {len(doc['frames'])} test poses, "
        f"median frame after a warm-up frame. Normals: blended-matrix, in the same pass.",
        "",
        "Devices: " + "; ".join(f"{b}: {d}" for b, d in doc["devices"].items()) + ".",
        "",
        f"Copy bandwidth in the same run (read + write of {c['bytes'] / 2**20:.0f} MiB): numpy copyto "
        f"{c['numpy_copyto']:.1f} GB/s, numba parallel copy {c['numba_parallel']:.1f} GB/s; "
        f"**copy_gbps = {doc['copy_gbps']:.1f} GB/s**.",
        "",
        "`frame ms`: wall time of one frame into preallocated outputs (numpy: `deform(T)`, float64, allocating); "
        "`device ms`: the kernel alone; GB/s = bytes a frame must move (inputs read once, outputs written once) / "
        "frame time.",
        "",
        "| backend | weights | layout | normals | device ms | frame ms | GB/s | % of copy | x numpy full |",
        "|---|---|---|---|---:|---:|---:|---:|---:|",
    ]
    base = next(r["frame_ms"] for r in doc["rows"] if r["backend"] == "numpy" and r["weights"] == "full")
    for r in doc["rows"]:
        lines.append(f"| {r['backend']} | {r['weights']} | {r['layout']} | {'yes' if r['normals'] else 'no'} | "
                     f"{r['device_ms']:.2f} | {r['frame_ms']:.2f} | {r['gbps']:.2f} | "
                     f"{100 * r['gbps'] / doc['copy_gbps']:.1f} | {base / r['frame_ms']:.1f} |")
    rn = doc["recomputed_normals"]
    lines += ["", f"Recomputed area-weighted normals of the full deformation (face->vertex operator): "
              f"{rn['ms']:.2f} ms, {rn['x_numpy_full_positions']:.2f}x the numpy full positions frame.", "",
              "## Targets", ""]
    for name, t in doc["targets"].items():
        lines.append(f"- {name} ({t['layout']}): {t['frame_ms']:.2f} ms, **{t['x_numpy_full']:.1f}x** numpy full "
                     f"(target 10x: {'met' if t['x_numpy_full'] >= 10 else 'not met'}), "
                     f"**{100 * t['fraction_of_copy']:.0f}%** of copy bandwidth "
                     f"(target 50%: {'met' if t['fraction_of_copy'] >= 0.5 else 'not met'}).")
    lines.append(f"- recomputed normals <= 2x numpy positions: {rn['x_numpy_full_positions']:.2f}x, "
                 f"{'met' if rn['x_numpy_full_positions'] <= 2 else 'not met'}.")
    load = doc["load_average"]
    lines += [f"- 1-minute load average at start / end: {load[0]:.2f} / {load[1]:.2f} on {mach['nproc']} CPUs.", ""]
    return "\n".join(lines)


def write(doc: dict, out: Path) -> None:
    write_results(out, doc, markdown(doc))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--levels", type=int, default=3, help="subdivision levels of the elephant (3: ~772k triangles)")
    ap.add_argument("--frames", type=int, default=8, help="test poses timed per configuration")
    ap.add_argument("--backends", default="numpy,opencl,opengl")
    ap.add_argument("--k", default="full,8,4", help="weight sets: full and/or k values")
    ap.add_argument("--out", type=Path, default=ROOT / "docs" / "results" / "deform",
                    help="output path without suffix (.json and .md are written)")
    ap.add_argument("--device", default=None, help="OpenCL device spec: auto, gpu, cpu, or part of a name")
    ap.add_argument("--markdown-only", action="store_true",
                    help="rewrite OUT.md from an existing OUT.json without timing anything")
    ap.add_argument("--quick", action="store_true",
                    help="every CPU back end at k = 8 and 4 against numpy full weights, with the copy bandwidth "
                         "(under 3 minutes on 2 cores); prints the table, writes --json FILE and FILE's .md")
    ap.add_argument("--json", type=Path, default=None, help="--quick: where to write the JSON (and .md beside it)")
    ap.add_argument("--copy-mib", type=int, default=512, help="--quick: buffer size of the copy-bandwidth probe")
    args = ap.parse_args(argv)
    if args.quick:
        ks = [int(x) for x in args.k.split(",") if x.strip() != "full"] if args.k != "full,8,4" else [8, 4]
        doc = run_quick(args.levels, args.frames, ks, copy_mib=args.copy_mib)
        text = quick_markdown(doc)
        if args.json is not None:
            write_results(args.json.with_suffix(""), doc, text)
        print()
        print(text)
        return 0
    if args.markdown_only:
        doc = json.loads(Path(args.out).with_suffix(".json").read_text())
        write(doc, args.out)
        print(markdown(doc))
        return 0
    ks = [None if x.strip() == "full" else int(x) for x in args.k.split(",")]
    doc = run(args.levels, args.frames, [b.strip() for b in args.backends.split(",")], ks, device=args.device)
    write(doc, args.out)
    print()
    print(markdown(doc))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
