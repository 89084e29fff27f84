"""``rigslim batch`` on a real Dask cluster (no mocks).

One LocalCluster of 2 worker processes is started for the module (the same
set-up ``rigslim batch`` makes, :func:`rigslim.batch.run.local_cluster`) and the
batches reach it with ``--scheduler``; one test starts the command's own
local cluster. The assets are the bundled small glTF characters (62 to 130
vertices) so that every batch takes seconds.
"""

from __future__ import annotations

import csv
import json
import os
import shutil
from pathlib import Path

import pytest

pytest.importorskip("distributed")
pyarrow = pytest.importorskip("pyarrow")

from rigslim.batch.run import local_cluster  # noqa: E402
from rigslim.commands.cli import main  # noqa: E402

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"

TEMPLATE = """\
name: "{name}-k2"
inputs:
  gltf: "{input}"
  fps: 30
poses:
  examples: "0:10:2"
  test: "1:10:2"
steps:
  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: "{name}-k2.glb"
"""


@pytest.fixture(scope="module")
def cluster():
    from distributed import Client

    with local_cluster(workers=2, threads_per_worker=1, dashboard=False) as (c, _):
        with Client(c) as cl:
            cl.wait_for_workers(2, timeout=120)
        yield c


@pytest.fixture(scope="module")
def client(cluster):
    from distributed import Client

    with Client(cluster) as cl:
        yield cl


@pytest.fixture
def library(tmp_path):
    """8 assets: 7 small characters (huesitos variants and RiggedFigure with its .bin) and a corrupt .glb."""
    lib = tmp_path / "lib"
    lib.mkdir()
    for i in range(6):
        shutil.copy(GLTF / "huesitos.glb", lib / f"bones{i}.glb")
    shutil.copytree(GLTF / "RiggedFigure", lib / "figure")
    data = (GLTF / "huesitos.glb").read_bytes()
    (lib / "broken.glb").write_bytes(data[: len(data) // 3])  # a truncated download
    template = tmp_path / "template.yaml"
    template.write_text(TEMPLATE)
    return lib, template


def _batch(template, assets, out, cluster, *extra):
    return main(["batch", str(template), *map(str, assets), "--out", str(out), "--scheduler",
                 cluster.scheduler_address, "-q", *extra])


def _rows(out: Path) -> dict[str, dict]:
    with open(out / "summary.csv", newline="") as fh:
        return {r["name"]: r for r in csv.DictReader(fh)}


def test_corrupt_asset_fails_alone_and_rerun_skips(library, tmp_path, cluster, capsys):
    lib, template = library
    out = tmp_path / "out"
    assert _batch(template, [lib], out, cluster) == 1
    rows = _rows(out)
    assert len(rows) == 8
    assert {n for n, r in rows.items() if r["status"] == "ok"} == {f"bones{i}" for i in range(6)} | {"RiggedFigure"}
    broken = rows["broken"]
    assert broken["status"] == "failed"
    # the same line `rigslim run` prints for this asset's pipeline
    capsys.readouterr()
    assert main(["run", str(out / "broken" / "pipeline.yaml"), "-q"]) == 2
    assert broken["error"] == capsys.readouterr().err.strip()
    assert broken["error"].startswith("rigslim: error: ") and "broken.glb" in broken["error"]
    for name, r in rows.items():
        if r["status"] != "ok":
            continue
        folder = out / name
        assert (folder / f"{name}-k2.glb").stat().st_size > 0
        assert json.loads((folder / "metrics.json").read_text())["evaluations"]
        assert (folder / "record.json").is_file()
        assert int(r["vertices"]) > 0 and int(r["faces"]) > 0 and int(r["joints"]) > 1
        assert int(r["input_influences"]) == 4 and int(r["output_influences"]) == 2
        assert float(r["position_rms_pct_mean"]) >= 0 and float(r["seconds"]) > 0
        assert r["worker"].startswith("tcp://") and float(r["peak_memory_mb"]) > 0
    assert not (out / "broken" / "record.json").exists()
    assert len({r["worker"] for r in rows.values()}) == 2  # both workers took assets
    # parquet and json carry the same rows
    table = pyarrow.parquet.read_table(out / "summary.parquet").to_pylist()
    doc = json.loads((out / "summary.json").read_text())
    assert [r["name"] for r in table] == [r["name"] for r in doc["rows"]] == list(rows)
    assert doc["counts"] == {"ok": 7, "skipped": 0, "failed": 1}
    for t, d in zip(table, doc["rows"], strict=False):
        assert t["status"] == d["status"] and t["position_rms_pct_max"] == d["position_rms_pct_max"]

    # rerun: every good asset is skipped (outputs untouched), the corrupt one fails again
    mtimes = {n: (out / n / f"{n}-k2.glb").stat().st_mtime_ns for n in rows if n != "broken"}
    assert _batch(template, [lib], out, cluster) == 1
    again = _rows(out)
    assert {n for n, r in again.items() if r["status"] == "skipped"} == set(mtimes)
    assert again["broken"]["status"] == "failed"
    assert {n: (out / n / f"{n}-k2.glb").stat().st_mtime_ns for n in mtimes} == mtimes
    assert again["bones0"]["position_rms_pct_mean"] == rows["bones0"]["position_rms_pct_mean"]
    for n in mtimes:        # the skipped rows keep the record of the run that made the outputs
        assert {k: again[n][k] for k in ("seconds", "attempts", "peak_memory_mb")} == \
            {k: rows[n][k] for k in ("seconds", "attempts", "peak_memory_mb")}

    # a changed input reruns that asset only; --force reruns all
    (lib / "bones3.glb").write_bytes((GLTF / "huesitos.glb").read_bytes() + b"\0\0\0\0")
    (lib / "broken.glb").unlink()
    assert _batch(template, [lib], out, cluster) == 0
    third = _rows(out)
    assert third["bones3"]["status"] == "ok" and third["bones0"]["status"] == "skipped"
    assert _batch(template, [lib], out, cluster, "--force") == 0
    assert {r["status"] for r in _rows(out).values()} == {"ok"}


def _kill_once_while_writing(marker, name):
    """Worker-side hook: SIGKILL this worker when it has staged ``name``'s output, once (marker file)."""
    import signal

    import rigslim.io.atomic as atomic

    def hook(tmp, target):
        if Path(target).name == name and not os.path.exists(marker):
            Path(marker).write_text(str(os.getpid()))
            os.kill(os.getpid(), signal.SIGKILL)

    atomic.on_staged = hook


def _remove_hook():
    import rigslim.io.atomic as atomic

    atomic.on_staged = None


def test_killed_worker_is_retried_and_leaves_no_partial_output(library, tmp_path, cluster, client):
    lib, template = library
    (lib / "broken.glb").unlink()
    out = tmp_path / "out"
    marker = tmp_path / "killed"
    client.run(_kill_once_while_writing, str(marker), "bones2-k2.glb")
    try:
        assert _batch(template, [lib], out, cluster, "--retries", "1") == 0
    finally:
        client.run(_remove_hook)
    assert marker.is_file()  # a worker really was killed, holding bones2 with its output staged
    rows = _rows(out)
    assert rows["bones2"]["status"] == "ok" and rows["bones2"]["attempts"] == "2"
    assert all(r["attempts"] == "1" for n, r in rows.items() if n != "bones2")
    folder = out / "bones2"
    assert sorted(p.name for p in folder.iterdir()) == ["bones2-k2.glb", "metrics.json", "pipeline.yaml",
                                                        "record.json"]
    assert (folder / "bones2-k2.glb").read_bytes()[:4] == b"glTF"
    client.wait_for_workers(2, timeout=60)  # the nanny restarted the killed worker


def test_worker_deaths_past_retries_fail_with_the_reason(library, tmp_path, cluster, client):
    lib, template = library
    out = tmp_path / "out"
    marker = tmp_path / "killed"
    client.run(_kill_once_while_writing, str(marker), "bones1-k2.glb")
    try:
        assert _batch(template, [lib / "bones1.glb", lib / "bones4.glb"], out, cluster, "--retries", "0") == 1
    finally:
        client.run(_remove_hook)
    rows = _rows(out)
    assert rows["bones4"]["status"] == "ok"
    assert rows["bones1"]["status"] == "failed" and "died" in rows["bones1"]["error"]
    assert "--retries 0" in rows["bones1"]["error"]
    assert not any(p.name.startswith(".") or p.name == "record.json" for p in (out / "bones1").iterdir())
    assert not (out / "bones1" / "bones1-k2.glb").exists()
    client.wait_for_workers(2, timeout=60)


def _sleep_in_python(name):
    import time

    import rigslim.io.atomic as atomic

    def hook(tmp, target):
        if Path(target).name == name:
            for _ in range(6000):  # 60 s in small sleeps: the deadline's exception lands between them
                time.sleep(0.01)

    atomic.on_staged = hook


def test_timeout_fails_the_asset(library, tmp_path, cluster, client):
    lib, template = library
    out = tmp_path / "out"
    client.run(_sleep_in_python, "bones5-k2.glb")
    try:
        # 10 s: enough for bones0 on a worker restarted cold by the previous test, on a loaded machine
        code = _batch(template, [lib / "bones5.glb", lib / "bones0.glb"], out, cluster, "--timeout", "10")
    finally:
        client.run(_remove_hook)
    assert code == 1
    rows = _rows(out)
    assert rows["bones0"]["status"] == "ok"
    assert rows["bones5"]["status"] == "failed" and rows["bones5"]["error"] == "timed out after 10 s (--timeout)"
    assert not (out / "bones5" / "bones5-k2.glb").exists() and not (out / "bones5" / "record.json").exists()


def test_manifest_overrides(library, tmp_path, cluster):
    lib, template = library
    manifest = tmp_path / "assets.csv"
    manifest.write_text("asset,name,k,inputs.fps\n"
                        "lib/bones0.glb,one,1,\n"
                        "lib/bones1.glb,three,3,\n"
                        "lib/bones2.glb,default,,\n"
                        "lib/figure/RiggedFigure.gltf,figure,3,24\n")
    out = tmp_path / "out"
    assert _batch(template, [manifest], out, cluster) == 0
    rows = _rows(out)
    assert {n: int(r["output_influences"]) for n, r in rows.items()} == {"one": 1, "three": 3, "default": 2,
                                                                          "figure": 3}
    assert rows["one"]["asset"] == str(lib / "bones0.glb")
    assert (out / "three" / "three-k2.glb").is_file()  # {name} is the manifest's name
    figure = (out / "figure" / "pipeline.yaml").read_text()
    assert "fps: 24" in figure and "k: 3" in figure
    # a changed override reruns only that asset
    manifest.write_text(manifest.read_text().replace("lib/bones1.glb,three,3,", "lib/bones1.glb,three,4,"))
    assert _batch(template, [manifest], out, cluster) == 0
    rows = _rows(out)
    assert rows["three"]["status"] == "ok" and int(rows["three"]["output_influences"]) == 4
    assert {rows[n]["status"] for n in ("one", "default", "figure")} == {"skipped"}


def test_summary_metrics_equal_rigslim_run(library, tmp_path, cluster):
    lib, template = library
    out = tmp_path / "out"
    assert _batch(template, [lib / "figure", lib / "bones0.glb"], out, cluster) == 0
    summary = {r["name"]: r for r in json.loads((out / "summary.json").read_text())["rows"]}
    csv_rows = _rows(out)
    for name in ("RiggedFigure", "bones0"):
        metrics = tmp_path / f"{name}.json"
        assert main(["run", str(out / name / "pipeline.yaml"), "--metrics", str(metrics), "-q"]) == 0
        doc = json.loads(metrics.read_text())
        (ev,) = doc["evaluations"]
        checked = 0
        for key, value in ev["metrics"].items():
            if isinstance(value, dict):
                for stat in ("mean", "max"):
                    assert summary[name][f"{key}_{stat}"] == value[stat]
                    assert float(csv_rows[name][f"{key}_{stat}"]) == value[stat]
                    checked += 1
            else:
                assert summary[name][key] == value
        assert checked >= 4
        assert summary[name]["vertices"] == doc["mesh"]["vertices"]
        assert summary[name]["joints"] == doc["handles"]["count"]


def test_k_at_least_the_joint_count_passes_through(library, tmp_path, cluster):
    """huesitos has 9 joints: k = 9 keeps every weight (an error of exactly 0), with a note, not an error."""
    lib, _ = library
    template = tmp_path / "k9.yaml"
    template.write_text(TEMPLATE.replace("select: k-largest\n    k: 2", "select: best-fit\n    k: 9\n    by: error")
                        .replace("solve: k-largest", "solve: geometric").replace('  - write: "{name}-k2.glb"\n', ""))
    out = tmp_path / "out"
    assert _batch(template, [lib / "bones0.glb"], out, cluster) == 0
    (row,) = json.loads((out / "summary.json").read_text())["rows"]
    assert row["status"] == "ok"
    assert row["position_rms_pct_max"] == 0.0 and row["max_influences"] <= 4


def test_bad_template_or_arguments_exit_2(library, tmp_path, capsys):
    lib, template = library
    out = tmp_path / "out"
    no_input = tmp_path / "fixed.yaml"
    no_input.write_text(TEMPLATE.replace("{input}", str(lib / "bones0.glb")))
    bad_plugin = tmp_path / "bad.yaml"
    bad_plugin.write_text(TEMPLATE.replace("solve: k-largest", "solve: k-larges"))
    manifest = tmp_path / "m.csv"
    manifest.write_text("asset,kk\nlib/bones0.glb,3\n")
    cases = [
        ([str(no_input), str(lib)], "never uses {input}"),
        ([str(bad_plugin), str(lib)], "did you mean 'k-largest'"),
        ([str(template), str(manifest)], "column 'kk' sets nothing"),
        ([str(template), str(lib), "--workers", "0"], "--workers"),
        ([str(template), str(tmp_path / "empty-dir-missing.csv")], "manifest not found"),
        ([str(template), str(lib / "bones0.glb"), str(tmp_path / "missing.glb")], "asset not found"),
    ]
    for argv, text in cases:
        assert main(["batch", *argv, "--out", str(out), "-q"]) == 2
        err = capsys.readouterr().err.strip()
        assert err.startswith("rigslim: error: ") and text in err and "\n" not in err
    assert not out.exists() or not any(out.iterdir())


def test_command_starts_its_own_local_cluster(library, tmp_path, capsys):
    lib, template = library
    out = tmp_path / "out"
    code = main(["batch", str(template), str(lib / "bones0.glb"), str(lib / "figure"), "--out", str(out),
                 "--workers", "1", "--no-dashboard"])
    assert code == 0
    rows = _rows(out)
    assert {r["status"] for r in rows.values()} == {"ok"}
    cores = len(os.sched_getaffinity(0))
    assert {int(r["threads"]) for r in rows.values()} == {cores}  # 1 worker x 1 thread: all cores to BLAS
    captured = capsys.readouterr()
    assert "2 assets" in captured.out and "2 ok" in captured.out


# --- assets, names, templating (no cluster) ------------------------------------------------------

def test_names_are_stems_and_shared_stems_get_a_stable_suffix(tmp_path):
    from rigslim.batch.assets import collect_assets

    for d in ("a", "b"):
        (tmp_path / d).mkdir()
        shutil.copy(GLTF / "huesitos.glb", tmp_path / d / "hero.glb")
    shutil.copy(GLTF / "huesitos.glb", tmp_path / "a" / "villain.glb")
    (tmp_path / "a" / ".hidden").mkdir()
    shutil.copy(GLTF / "huesitos.glb", tmp_path / "a" / ".hidden" / "x.glb")
    jobs = collect_assets([str(tmp_path / "a"), str(tmp_path / "b" / "hero.glb"), str(tmp_path / "a" / "hero.glb")])
    names = [j.name for j in jobs]
    assert len(jobs) == 3 and names[1] == "villain" and names[0].startswith("hero-") and names[2].startswith("hero-")
    assert names[0] != names[2]
    again = collect_assets([str(tmp_path / "a" / "hero.glb"), str(tmp_path / "b" / "hero.glb")])
    assert {j.name for j in again} == {names[0], names[2]}  # the suffix depends on the path only


def test_asset_pipeline_substitutes_resolves_and_overrides(tmp_path):
    from rigslim.batch.assets import AssetJob, apply_overrides, asset_pipeline, override_targets

    template = {"name": "{name}", "inputs": {"mesh": "{input}", "skeleton": "rig/{name}.tgf",
                                              "weights": {"path": "w.dmat", "normalize": True}},
                "steps": [{"select": "k-largest", "k": 4}, {"solve": "poisson", "name": "fit"},
                          {"write": "out/{name}.npz"}]}
    job = AssetJob(tmp_path / "lib" / "cow.obj", "cow", {"k": "6", "fit.tolerance": "1e-6"})
    doc = asset_pipeline(template, tmp_path / "tpl" / "t.yaml", job)
    assert doc["name"] == "cow" and doc["inputs"]["mesh"] == str(tmp_path / "lib" / "cow.obj")
    assert doc["inputs"]["skeleton"] == str(tmp_path / "tpl" / "rig" / "cow.tgf")
    assert doc["inputs"]["weights"] == {"path": str(tmp_path / "tpl" / "w.dmat"), "normalize": True}
    assert doc["steps"][0]["k"] == 6 and doc["steps"][1]["tolerance"] == 1e-6
    assert doc["steps"][2] == {"write": "out/cow.npz"}  # relative: resolved in DIR/<name>/
    assert template["steps"][0]["k"] == 4  # the template is not changed
    assert override_targets(template, "clip") == [("inputs", "animation")]
    assert override_targets(template, "nothing") == [] and override_targets(template, "3.x") == [("step", (3, "x"))]
    gltf = apply_overrides({"inputs": {"gltf": "a.glb"}, "steps": []}, {"clip": "Walk", "fps": "24"}, None)
    assert gltf["inputs"] == {"gltf": "a.glb", "animation": "Walk", "fps": 24}


def test_manifest_errors_are_one_line(tmp_path):
    from rigslim.batch.assets import collect_assets
    from rigslim.errors import InputError

    cases = {"no-asset.csv": ("name,k\nx,1\n", "no 'asset' column"),
             "empty-cell.csv": ("asset,k\n,3\n", "line 2 names no asset"),
             "dup.csv": ("asset,name\na.glb,x\nb.glb,x\n", "used twice")}
    for file, (text, message) in cases.items():
        (tmp_path / file).write_text(text)
        with pytest.raises(InputError, match=message) as e:
            collect_assets([str(tmp_path / file)])
        assert "\n" not in str(e.value) and file in str(e.value)


def test_simplification_levels_give_hausdorff_columns_per_level(tmp_path):
    """A LOD template: Hausdorff (metro) at each level becomes its own summary column, in every format."""
    pytest.importorskip("pymeshlab")
    from rigslim.batch.assets import collect_assets, load_template
    from rigslim.batch.options import BatchOptions, BatchResult
    from rigslim.batch.summary import write_summary
    from rigslim.batch.task import run_asset

    template = tmp_path / "lod.yaml"
    template.write_text(TEMPLATE.replace("""  - select: k-largest
    k: 2
  - solve: k-largest
  - evaluate: [position-rms, normal-deviation, max-influences]
  - write: "{name}-k2.glb"
""", """  - decimate: quartic
    targets: [0.5, 0.25]
    max_bones: 2
  - evaluate: [metro]
"""))
    (job,) = collect_assets([str(GLTF / "huesitos.glb")])
    row = run_asset(job.as_dict(), load_template(template), str(template), str(tmp_path / "out"))
    assert row["status"] == "ok", row["error"]
    levels = sorted(k for k in row if k.startswith("hausdorff_max_pct@") and k.endswith("_max"))
    assert len(levels) == 2 and all(row[k] > 0 for k in levels)
    assert row["output_influences"] <= 2
    write_summary(BatchOptions(template, [], tmp_path / "out"), BatchResult([row], 1.0))
    table = pyarrow.parquet.read_table(tmp_path / "out" / "summary.parquet")
    assert set(levels) <= set(table.column_names)
    assert _rows(tmp_path / "out")["huesitos"][levels[0]] == repr(row[levels[0]])


def test_workers_get_thread_limits_and_this_process_keeps_its_environment(cluster, client):
    keys = ("NUMBA_NUM_THREADS", "OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "PYTHONHASHSEED")
    before = {k: os.environ.get(k) for k in keys}
    cores = len(os.sched_getaffinity(0))
    per_worker = str(max(1, cores // 2))
    got = client.run(lambda: {k: os.environ.get(k) for k in (*keys[:4], "MALLOC_TRIM_THRESHOLD_")})
    # glibc's default trim threshold: Dask's 64 KiB made every large numpy temporary a fresh mapping (1.5x CPU)
    assert len(got) == 2 and all(v == {**{k: per_worker for k in keys[:4]}, "MALLOC_TRIM_THRESHOLD_": None}
                                 for v in got.values())
    # numba must never see NUMBA_NUM_THREADS change in this process (it refuses once its threads run)
    assert os.environ.get("NUMBA_NUM_THREADS") == before["NUMBA_NUM_THREADS"]
    with local_cluster(workers=1, threads_per_worker=1, dashboard=False):
        assert os.environ.get("NUMBA_NUM_THREADS") == before["NUMBA_NUM_THREADS"]
    assert {k: os.environ.get(k) for k in keys} == before
