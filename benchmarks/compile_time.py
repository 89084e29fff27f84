"""Numba compilation on the first call: the default reduction and ``rigslim lod``, on a fresh and a warm cache.

Every measurement runs in a fresh subprocess with ``NUMBA_CACHE_DIR`` pointing to a folder of this run
(empty for a "fresh cache" row), so the numba on-disk cache of the working tree (``__pycache__``) and of
earlier runs plays no part:

a. the first default ``rigslim.reduce_weights`` call on a small input (the tube and two clips of
   ``tools/warm-numba.py``, k = 2: best-fit by error, the non-negative geometric fit, the guard) on an
   empty cache;
b. the same call in a second process on that cache (the kernels are loaded, not compiled);
c. the first ``rigslim lod examples/data/gltf/huesitos.glb --ratios 0.5,0.25`` on an empty cache;
d. the same command in a second process on that cache;
e. ``rigslim lod`` after ``tools/warm-numba.py`` alone on an empty cache (what ``make install`` leaves);
   the warm-up's own seconds are its row;
f. then the README's first command on that cache, ``rigslim run examples/elephant-k4.yaml`` (best-fit,
   geometric, the evaluation's position and normal metrics).

The child processes record numba's ``numba:compile`` events: per compiled function (a dispatcher: one
row per Python function, however many type specialisations), the number of specialisations and the
seconds of its compilation *less* the compilations it triggered inside (callees, numba's own overloads
such as ``np.empty``), so the rows add up to the whole. A caller's own seconds include LLVM's
optimisation of its module with its callees linked in, so a deep call chain is paid at every level.

With ``--baseline REF`` rows a and b are also measured, in the same run, on rigslim as it was at the git
commit REF (its ``framework``, ``plugins`` and ``kernels`` folders, extracted with ``git archive`` into a
temporary folder that comes first on ``PYTHONPATH``): the ratio of a change, side by side.

Writes ``docs/results/compile_time.{json,md}`` and prints the table.

    flock /tmp/rigslim-bench.lock .venv/bin/python benchmarks/compile_time.py --baseline e818b17
    .venv/bin/python benchmarks/compile_time.py --only reduce    # rows a and b only (no file written)
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
if __package__ in (None, ""):
    sys.path.insert(0, str(ROOT))

OUT = ROOT / "docs" / "results" / "compile_time"
GLB = ROOT / "examples" / "data" / "gltf" / "huesitos.glb"
WARM = ROOT / "tools" / "warm-numba.py"
LOD_ARGS = ["lod", str(GLB.relative_to(ROOT)), "--ratios", "0.5,0.25"]
DEMO_ARGS = ["run", "examples/elephant-k4.yaml", "-q"]
TOP = 12  # kernels listed per scenario in the markdown table


# --------------------------------------------------------------------------- child: one measured process

def _record_compiles() -> list:
    """Register a ``numba:compile`` listener; the returned list fills with (name, signature, self seconds)."""
    from numba.core import event

    stack: list = []
    rows: list = []

    class Compiles(event.Listener):
        def on_start(self, ev):
            stack.append([time.perf_counter(), 0.0])

        def on_end(self, ev):
            t0, inner = stack.pop()
            dt = time.perf_counter() - t0
            if stack:
                stack[-1][1] += dt
            f = ev.data["dispatcher"].py_func
            rows.append((f"{f.__module__}.{f.__qualname__}", str(ev.data["args"]), dt - inner))

    event.register("numba:compile", Compiles())
    return rows


def _kernels(rows: list) -> list[dict]:
    """Per compiled function: specialisations and own seconds, largest first."""
    by: dict = {}
    for name, sig, own in rows:
        d = by.setdefault(name, {"kernel": name, "specialisations": 0, "seconds": 0.0, "signatures": []})
        d["specialisations"] += 1
        d["seconds"] += own
        d["signatures"].append(sig)
    out = sorted(by.values(), key=lambda d: -d["seconds"])
    for d in out:
        d["seconds"] = round(d["seconds"], 3)
        if d["specialisations"] == 1:
            del d["signatures"]
    return out


def child(what: str, workdir: str) -> None:
    """Run one scenario in this process and print its JSON line."""
    rows = _record_compiles()
    t0 = time.perf_counter()
    if what == "reduce":
        import runpy

        import rigslim

        warm = runpy.run_path(str(WARM), run_name="warm_numba")
        import numpy as np

        rng = np.random.default_rng(0)
        V, F, W = warm["tube"]()
        clips = [warm["clip"](12, 4, rng), warm["clip"](12, 4, rng)]
        t_import = time.perf_counter() - t0
        t1 = time.perf_counter()
        rigslim.reduce_weights((V, F), W, clips, k=2)
    else:
        from rigslim.commands.cli import main

        t_import = time.perf_counter() - t0
        t1 = time.perf_counter()
        argv = [*DEMO_ARGS, "--metrics", str(Path(workdir) / "demo.json")] if what == "demo" else \
            [*LOD_ARGS, "-o", str(Path(workdir) / "lod.glb")]
        code = main(argv)
        if code not in (0, None):
            raise SystemExit(f"rigslim {argv[0]} exited with {code}")
    seconds = time.perf_counter() - t1
    import rigslim

    print("RESULT " + json.dumps({"seconds": seconds, "import_seconds": t_import, "rigslim": rigslim.__file__,
                                  "compiled_seconds": sum(r[2] for r in rows), "kernels": _kernels(rows)}))


# --------------------------------------------------------------------------- parent: the scenarios

def baseline_tree(ref: str, into: Path) -> Path:
    """rigslim at commit ``ref`` as an importable ``rigslim`` package under ``into`` (framework/ is the package,
    plugins/ and kernels/ its subpackages, as pyproject's package-dir maps them)."""
    import shutil
    import tarfile

    src = into / "src"
    src.mkdir(parents=True)
    archive = into / "tree.tar"
    with archive.open("wb") as f:
        subprocess.run(["git", "archive", ref, "framework", "plugins", "kernels"], cwd=ROOT, stdout=f, check=True)
    with tarfile.open(archive) as t:
        t.extractall(src, filter="data")
    pkg = into / "pkg"
    shutil.copytree(src / "framework", pkg / "rigslim")
    shutil.copytree(src / "plugins", pkg / "rigslim" / "plugins")
    shutil.copytree(src / "kernels", pkg / "rigslim" / "kernels")
    return pkg


def run_child(what: str, cache: Path, workdir: Path, pythonpath: Path | None = None) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    if pythonpath is not None:
        env["PYTHONPATH"] = os.pathsep.join([str(pythonpath), *filter(None, [os.environ.get("PYTHONPATH")])])
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, __file__, "--child", what, "--workdir", str(workdir)], cwd=ROOT, env=env,
                       capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if p.returncode != 0:
        raise SystemExit(f"compile_time: the {what} child failed (exit {p.returncode}):\n{p.stderr[-3000:]}")
    line = next(ln for ln in p.stdout.splitlines() if ln.startswith("RESULT "))
    result = json.loads(line[len("RESULT "):])
    # which rigslim the child imported, checked (the baseline's copy comes first on its PYTHONPATH)
    result["rigslim"] = "working tree" if Path(result["rigslim"]).is_relative_to(ROOT) else "baseline tree"
    return {**result, "process_wall_seconds": wall}


def run_warm(cache: Path) -> dict:
    env = dict(os.environ, NUMBA_CACHE_DIR=str(cache))
    t0 = time.perf_counter()
    p = subprocess.run([sys.executable, str(WARM)], cwd=ROOT, env=env, capture_output=True, text=True)
    if p.returncode != 0:
        raise SystemExit(f"compile_time: tools/warm-numba.py failed (exit {p.returncode}):\n{p.stderr[-3000:]}")
    return {"process_wall_seconds": time.perf_counter() - t0, "stdout": p.stdout.strip()}


def measure(only: str | None, baseline: str | None = None) -> dict:
    scenarios: dict = {}
    with tempfile.TemporaryDirectory(prefix="rigslim-compile-") as tmp:
        tmp = Path(tmp)
        if baseline:
            pkg = baseline_tree(baseline, tmp / "baseline")
            cache = tmp / "cache-baseline"
            cache.mkdir()
            scenarios["a0_reduce_fresh_baseline"] = run_child("reduce", cache, tmp, pkg)
            scenarios["b0_reduce_cached_baseline"] = run_child("reduce", cache, tmp, pkg)
        if only in (None, "reduce"):
            cache = tmp / "cache-reduce"
            cache.mkdir()
            scenarios["a_reduce_fresh"] = run_child("reduce", cache, tmp)
            scenarios["b_reduce_cached"] = run_child("reduce", cache, tmp)
        if only in (None, "lod"):
            cache = tmp / "cache-lod"
            cache.mkdir()
            scenarios["c_lod_fresh"] = run_child("lod", cache, tmp)
            scenarios["d_lod_cached"] = run_child("lod", cache, tmp)
        if only in (None, "install"):
            cache = tmp / "cache-install"
            cache.mkdir()
            scenarios["e_warm_numba"] = run_warm(cache)
            scenarios["e_lod_after_warm_numba"] = run_child("lod", cache, tmp)
            scenarios["f_demo_after_warm_numba"] = run_child("demo", cache, tmp)
    return scenarios


LABELS = {
    "a0_reduce_fresh_baseline": "a. first default `reduce_weights`, fresh cache: baseline",
    "b0_reduce_cached_baseline": "b. the same call, second process (cached): baseline",
    "a_reduce_fresh": "a. first default `reduce_weights`, fresh cache",
    "b_reduce_cached": "b. the same call, second process (cached)",
    "c_lod_fresh": "c. first `rigslim lod huesitos.glb --ratios 0.5,0.25`, fresh cache",
    "d_lod_cached": "d. the same command, second process (cached)",
    "e_warm_numba": "e. `tools/warm-numba.py` (`make install`'s warm-up), fresh cache",
    "e_lod_after_warm_numba": "e. then the first `rigslim lod` (after `make install` alone)",
    "f_demo_after_warm_numba": "f. then the first `rigslim run examples/elephant-k4.yaml` (the README's demo)",
}


def markdown(doc: dict) -> str:
    m = doc["machine"]
    lines = ["# Numba compilation on the first call", "",
             f"Machine: {m['cpu']}, nproc {m['nproc']}, shared with other jobs (one run; load average "
             f"{doc['load_average']} at the start). Python {m['python']}, numba {doc['numba']}. "
             "`benchmarks/compile_time.py`: each row is a fresh process with `NUMBA_CACHE_DIR` set to a folder "
             "of the run (empty for a fresh cache).", "",
             "| scenario | seconds (the call) | compiling | process wall |", "|---|---|---|---|"]
    for key, s in doc["scenarios"].items():
        label = LABELS[key].replace("baseline", f"baseline `{doc.get('baseline')}`")
        call = f"{s['seconds']:.2f}" if "seconds" in s else ""
        comp = f"{s['compiled_seconds']:.2f}" if "compiled_seconds" in s else ""
        lines.append(f"| {label} | {call} | {comp} | {s['process_wall_seconds']:.2f} |")
    lines += ["", "`seconds`: the call alone (imports excluded); `compiling`: the sum of numba's compilation "
              "events in it (their own seconds, nested compilations counted once).", ""]
    sc = doc["scenarios"]
    if "a0_reduce_fresh_baseline" in sc and "a_reduce_fresh" in sc:
        now, then = sc["a_reduce_fresh"]["compiled_seconds"], sc["a0_reduce_fresh_baseline"]["compiled_seconds"]
        lines += [f"First default reduction on a fresh cache, compiling: {now:.1f} s now against {then:.1f} s at "
                  f"`{doc['baseline']}`, measured side by side: {now / then:.2f}x.", ""]
    for key in ("a_reduce_fresh", "a0_reduce_fresh_baseline", "c_lod_fresh"):
        s = doc["scenarios"].get(key)
        if not s:
            continue
        ours = [k for k in s["kernels"] if k["kernel"].startswith("rigslim.")]
        lib = sum(k["seconds"] for k in s["kernels"] if not k["kernel"].startswith("rigslim."))
        lib_n = sum(k["specialisations"] for k in s["kernels"] if not k["kernel"].startswith("rigslim."))
        title = LABELS[key][3:].replace("baseline", f"baseline `{doc.get('baseline')}`")
        lines += [f"## Where {title} compiles",
                  "",
                  f"{len(ours)} rigslim kernels, {sum(k['specialisations'] for k in ours)} specialisations; "
                  f"numba's own overloads (np.empty, dot, sorting, string formatting of error messages...): "
                  f"{lib_n} specialisations, {lib:.2f} s. The {min(TOP, len(ours))} largest rigslim kernels "
                  "(own seconds: less the compilations they trigger, but with LLVM's optimisation of their "
                  "module, callees linked in):", "",
                  "| kernel | specialisations | own seconds |", "|---|---|---|"]
        for k in ours[:TOP]:
            lines.append(f"| `{k['kernel'].removeprefix('rigslim.')}` | {k['specialisations']} | {k['seconds']:.2f} |")
        lines.append("")
    return "\n".join(lines)


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--child", choices=["reduce", "lod", "demo"], help=argparse.SUPPRESS)
    ap.add_argument("--workdir", help=argparse.SUPPRESS)
    ap.add_argument("--only", choices=["reduce", "lod", "install"],
                    help="run one group of rows and print them; docs/results is not written")
    ap.add_argument("--baseline", metavar="REF", help="also rows a and b at this git commit, side by side")
    args = ap.parse_args(argv)
    if args.child:
        child(args.child, args.workdir)
        return
    import numba

    from benchmarks.datasets import machine, write_results

    load = os.getloadavg()[0]
    scenarios = measure(args.only, args.baseline)
    doc = {"benchmark": "compile_time", "machine": machine(), "numba": numba.__version__,
           "load_average": round(load, 2), "baseline": args.baseline, "scenarios": scenarios}
    text = markdown(doc)
    print(text)
    if args.only is None:
        write_results(OUT, doc, text)


if __name__ == "__main__":
    main()
