"""Issue 21 item 4: every file rigslim writes passes the validator, whatever the source: a skinning bufferView
of byteStride 33 is rewritten at every level (level 0 of ``lod`` kept the source's bytes, and their stride),
and a skin that lists one joint twice is refused in one line (a copy of it could not be valid)."""

from __future__ import annotations

import numpy as np
import pytest
from support.gltf_validator import validate_gltf, validation_errors, validator_available
from support.hostile_gltf import build_gltf, random_parts

from rigslim.cli import main


def _source(tmp_path, **kw):
    return build_gltf(tmp_path / "src.glb", random_parts(np.random.default_rng(1), 3, 3, 4), 4, **kw)


@pytest.mark.parametrize("argv", [["reduce", "-k", "2"], ["lod", "--ratios", "0.5"],
                                  ["lod", "--ratios", "0.5", "--max-error", "none"]], ids=" ".join)
def test_a_stride_of_33_is_repaired_at_every_level(tmp_path, argv):
    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")
    src = _source(tmp_path, weight_stride=33)
    assert validation_errors(validate_gltf(src))          # the source itself is invalid
    out = tmp_path / "out.glb"
    assert main([argv[0], str(src), "-o", str(out), *argv[1:]]) == 0
    assert validation_errors(validate_gltf(out)) == []


@pytest.mark.parametrize("command", [["reduce", "-k", "2"], ["lod", "--ratios", "0.5"]], ids=" ".join)
def test_a_skin_listing_a_joint_twice_is_refused_in_one_line(tmp_path, capsys, command):
    src = _source(tmp_path, duplicate_joint=True)
    out = tmp_path / "out.glb"
    assert main([command[0], str(src), "-o", str(out), *command[1:]]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and "skins[0].joints" in err and "listed twice" in err
    assert not out.exists()


def test_a_mesh_whose_parts_all_go_gets_an_empty_level_node(tmp_path, capsys):
    """Three meshes, one part each: at 30 % with no bound two parts are removed whole (plugins/decimation/
    prune.py). Their nodes' level nodes hold no mesh and no skin (nothing shows there), the file validates,
    ``compare`` reads the level, and stderr says the level stopped with one part left."""
    import json

    from rigslim.io.gltf.document import load_gltf

    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")
    src = build_gltf(tmp_path / "src.glb", random_parts(np.random.default_rng(1), 3, 3, 4), 4, separate_meshes=True)
    out, rep = tmp_path / "out.glb", tmp_path / "r.json"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.3", "--max-error", "none", "--report", str(rep)]) == 0
    assert validation_errors(validate_gltf(out)) == []
    t = json.loads(rep.read_text())["targets"][0]
    assert t["parts_removed"] == 2 and t["stopped"] == "no collapse"
    js = load_gltf(out).json
    levels = [js["nodes"][n["extensions"]["MSFT_lod"]["ids"][0]] for n in js["nodes"] if "extensions" in n]
    assert sum("mesh" in lv for lv in levels) == 1
    assert all("skin" not in lv for lv in levels if "mesh" not in lv)
    assert "no collapse was left and one part is left" in capsys.readouterr().err
    assert main(["compare", str(src), str(out), "--level", "1", "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["faces"] == t["faces"]
