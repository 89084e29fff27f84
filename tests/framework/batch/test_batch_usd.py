"""``rigslim batch`` over a folder of USD characters: found by suffix, one template, every output validated."""

from __future__ import annotations

import json
from pathlib import Path

from rigslim.commands.cli import main
from rigslim.io.usd.check import check_usd
from rigslim.io.usd.read import read_usd_skin

ROOT = Path(__file__).resolve().parents[3]
GLTF = ROOT / "examples" / "data" / "gltf"

TEMPLATE = """\
inputs:
  usd: '{input}'
poses:
  examples: "0:20:4"
  test: "2:20:4"
steps:
  - select: k-largest
    k: 1
  - solve: k-largest
  - evaluate: [position-rms]
  - write: '{name}-k1.usda'
"""


def test_batch_finds_and_reduces_usd_assets(tmp_path):
    library = tmp_path / "library"
    library.mkdir()
    for name in ("huesitos.glb", "animation_with_skeleton.glb"):   # the library as USD, exported by rigslim
        assert main(["reduce", str(GLTF / name), "-o", str(library / f"{Path(name).stem}.usdc"), "-k", "16"]) == 0
    (tmp_path / "template.yaml").write_text(TEMPLATE)
    out = tmp_path / "out"
    code = main(["batch", str(tmp_path / "template.yaml"), str(library), "--out", str(out), "--workers", "1",
                 "--no-dashboard", "-q"])
    assert code == 0
    summary = json.loads((out / "summary.json").read_text())
    rows = summary["rows"]
    assert sorted(r["name"] for r in rows) == ["animation_with_skeleton", "huesitos"]
    assert all(r["status"] == "ok" for r in rows)
    for name in ("huesitos", "animation_with_skeleton"):
        written = next((out / name).rglob(f"{name}-k1.usda"))
        assert check_usd(written) == []
        assert [p.element_size for p in read_usd_skin(written).parts] == [1]
