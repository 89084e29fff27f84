"""Smoke test of benchmarks/deform_throughput.py on the unsubdivided elephant (the full run is manual)."""

from __future__ import annotations

import json
from pathlib import Path

ROOT = Path(__file__).resolve().parents[3]


def test_benchmark_writes_json_and_markdown(tmp_path, monkeypatch):
    monkeypatch.syspath_prepend(str(ROOT))
    from benchmarks.deform_throughput import main

    out = tmp_path / "deform"
    assert main(["--levels", "0", "--frames", "2", "--k", "full,4", "--backends", "numpy,opencl",
                 "--out", str(out)]) == 0
    doc = json.loads(out.with_suffix(".json").read_text())
    assert doc["mesh"]["vertices"] == 6034 and doc["machine"]["nproc"] >= 1
    combos = {(r["backend"], r["weights"], r["normals"], r["layout"]) for r in doc["rows"]}
    assert ("numpy", "full", False, "sparse") in combos and ("numpy", "k=4", True, "fixed") in combos
    if "opencl" in doc["devices"]:
        assert {("opencl", "full", True, "csr"), ("opencl", "k=4", False, "compact")} <= combos
        assert doc["speedup_over_numpy_full"]["opencl k=4"] > 0
    for r in doc["rows"]:
        assert r["device_ms"] > 0 and r["fps"] > 0 and r["gb_per_s"] > 0
        assert r["bytes_per_frame"] > 6034 * 12
    text = out.with_suffix(".md").read_text()
    assert "| backend | weights |" in text and "GPU" in text


def test_quick_json_has_the_documented_keys(tmp_path, monkeypatch, capsys):
    """``--quick --json FILE``: copy_gbps and rows of {backend, weights, layout, normals, device_ms, frame_ms, gbps}."""
    monkeypatch.syspath_prepend(str(ROOT))
    from benchmarks.deform_throughput import QUICK_ROW_KEYS, main

    path = tmp_path / "quick.json"
    assert main(["--quick", "--levels", "0", "--frames", "2", "--copy-mib", "16", "--json", str(path)]) == 0
    doc = json.loads(path.read_text())
    assert doc["copy_gbps"] > 0 and doc["mesh"]["vertices"] == 6034
    assert QUICK_ROW_KEYS == ("backend", "weights", "layout", "normals", "device_ms", "frame_ms", "gbps")
    for r in doc["rows"]:
        assert set(r) == set(QUICK_ROW_KEYS)
        assert r["weights"] == "full" or isinstance(r["weights"], int)
        assert isinstance(r["normals"], bool) and r["device_ms"] > 0 and r["frame_ms"] > 0 and r["gbps"] > 0
    combos = {(r["backend"], r["weights"], r["layout"], r["normals"]) for r in doc["rows"]}
    assert ("numpy", "full", "sparse", False) in combos
    for k in (8, 4):
        for layout in ("fixed", "compact"):
            assert {("cpu", k, layout, False), ("cpu", k, layout, True)} <= combos
    assert doc["recomputed_normals"]["ms"] > 0
    assert "| backend | weights |" in path.with_suffix(".md").read_text()
    assert "copy_gbps" in capsys.readouterr().out
