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
