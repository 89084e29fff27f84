"""Issue 21 item 3: glTF read as the specification says, or refused in one line.

Each file is built by :mod:`support.hostile_gltf` next to a plain twin (float positions and weights, ubyte
joints); the hostile encoding must pose exactly like the twin (quantised positions: within their step), and
``rigslim reduce`` of it must write a file the Khronos validator accepts.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.gltf_validator import validate_gltf, validation_errors, validator_available
from support.hostile_gltf import build_gltf, posed_file_positions, random_parts, rigid_parts

from rigslim.commands.cli import main
from rigslim.errors import InputError, PipelineError
from rigslim.io.gltf.document import load_gltf

TIMES = [0.0, 0.3, 0.55, 1.0]


def _parts():
    return random_parts(np.random.default_rng(11), 2, 3, 4)


def _posed(path):
    return np.stack(posed_file_positions(path, TIMES))


def _reduce_and_validate(src, tmp_path):
    out = tmp_path / f"{src.stem}-k2.glb"
    assert main(["reduce", str(src), "-o", str(out), "-k", "2"]) == 0
    if validator_available():
        assert validation_errors(validate_gltf(out)) == []
    return out


@pytest.mark.parametrize("encoding", [dict(joints_normalized=True), dict(joints="f32"), dict(joints="u16"),
                                      dict(sparse_weights=True), dict(weights="u16")])
def test_skinning_encodings_pose_like_the_plain_twin(tmp_path, encoding):
    """Normalized JOINTS bound every vertex to joint 0; float joints were truncated."""
    twin = build_gltf(tmp_path / "twin.glb", _parts(), n_joints=4, weights=encoding.get("weights", "f32"))
    odd = build_gltf(tmp_path / "odd.glb", _parts(), n_joints=4, **encoding)
    np.testing.assert_array_equal(_posed(odd), _posed(twin))
    out, ref = _reduce_and_validate(odd, tmp_path), _reduce_and_validate(twin, tmp_path)
    np.testing.assert_allclose(_posed(out), _posed(ref), atol=1e-6)   # the same reduction as the twin's


def test_non_integral_float_joints_are_refused_in_one_line(tmp_path):
    parts = rigid_parts(2)
    parts[0].J = parts[0].J.astype(float)
    parts[0].J[3, 0] = 0.5
    src = build_gltf(tmp_path / "half.glb", parts, n_joints=2, joints="f32")
    with pytest.raises(InputError, match="not a whole number") as e:
        posed_file_positions(src, [0.0])
    assert "JOINTS_0" in str(e.value) and "\n" not in str(e.value)


@pytest.mark.parametrize("kind", ["i16", "i8", "u16"])
def test_khr_mesh_quantization_positions(tmp_path, kind):
    twin = build_gltf(tmp_path / "twin.glb", _parts(), n_joints=4)
    q = build_gltf(tmp_path / f"q{kind}.glb", _parts(), n_joints=4, positions=kind)
    step = {"i16": 1 / 32767, "i8": 1 / 127, "u16": 1 / 65535}[kind] * 3.0   # the mesh is 3 units long
    assert np.abs(_posed(q) - _posed(twin)).max() <= step
    _reduce_and_validate(q, tmp_path)


@pytest.mark.parametrize("codec", ["meshopt", "draco"])
def test_compressed_files_are_decoded(tmp_path, codec):
    """EXT_meshopt_compression's empty fallback buffer was read as the weights; Draco was refused."""
    pytest.importorskip("meshopt" if codec == "meshopt" else "DracoPy")
    parts = rigid_parts(3)
    twin = build_gltf(tmp_path / "twin.glb", parts, n_joints=3)
    packed = build_gltf(tmp_path / f"{codec}.glb", parts, n_joints=3, **{codec: True})
    doc = load_gltf(packed)
    assert doc.decoded and not doc.json.get("extensionsRequired")
    np.testing.assert_allclose(_posed(packed), _posed(twin), atol=1e-6)
    out = _reduce_and_validate(packed, tmp_path)
    assert "compression" not in str(load_gltf(out).json.get("extensionsUsed"))


def _position_bounds(path) -> list[tuple[list, list, list, list]]:
    """Per POSITION accessor of the file: its declared min and max, and the min and max of its stored values."""
    from rigslim.io.gltf.document import read_accessor

    doc = load_gltf(path)
    out = []
    for i in sorted({p["attributes"]["POSITION"] for m in doc.json["meshes"] for p in m["primitives"]}):
        X = read_accessor(doc, i, normalize=False)
        acc = doc.json["accessors"][i]
        out.append((acc["min"], acc["max"], X.min(axis=0).tolist(), X.max(axis=0).tolist()))
    return out


def _glb_json(path) -> dict:
    """The JSON chunk of a .glb, as stored (before any decoding)."""
    import json
    import struct

    data = Path(path).read_bytes()
    (length,) = struct.unpack_from("<I", data, 12)
    return json.loads(data[20:20 + length])


def test_lossy_draco_positions_get_the_bounds_of_their_decoded_values(tmp_path):
    """A Draco stream quantised to 11 bits decodes a little off the bounds the exporter declared from the
    original positions (gltf-transform's `draco` does this at its default 14 bits); `reduce` and `lod` wrote
    those stale bounds out uncompressed, which the validator reports as ACCESSOR_MAX_MISMATCH."""
    pytest.importorskip("DracoPy")
    parts = rigid_parts(3)
    rng = np.random.default_rng(7)
    for part in parts:                      # off the quantisation grid, as a real character is
        part.V = part.V + rng.normal(scale=0.01, size=part.V.shape)
    packed = build_gltf(tmp_path / "draco11.glb", parts, n_joints=3, draco=True, draco_bits=11)
    declared = [(a["min"], a["max"]) for a in _glb_json(packed)["accessors"] if a.get("type") == "VEC3" and "min" in a]
    decoded = _position_bounds(packed)
    assert [(lo, hi) for lo, hi, _, _ in decoded] != declared      # the case: the declared bounds are stale
    out = _reduce_and_validate(packed, tmp_path)
    lod = tmp_path / "draco11-lod.glb"
    assert main(["lod", str(packed), "-o", str(lod), "--ratios", "0.5", "--max-error", "none"]) == 0
    if validator_available():
        assert validation_errors(validate_gltf(lod)) == []
    for path in (packed, out, lod):
        for lo, hi, stored_lo, stored_hi in _position_bounds(path):
            assert (lo, hi) == (stored_lo, stored_hi), path.name


def test_unknown_required_extension_is_refused_and_harmless_ones_pass(tmp_path):
    bad = build_gltf(tmp_path / "bad.glb", rigid_parts(2), n_joints=2, required=("EXT_made_up_geometry",))
    with pytest.raises(InputError, match="requires the extension EXT_made_up_geometry") as e:
        load_gltf(bad)
    assert "extensionsRequired[0]" in str(e.value)
    assert main(["reduce", str(bad), "-o", str(tmp_path / "o.glb"), "-k", "1"]) == 2
    ok = build_gltf(tmp_path / "ok.glb", rigid_parts(2), n_joints=2, required=("KHR_materials_emissive_strength",))
    _posed(ok)


def test_gltf_and_mesh_inputs_together_are_refused(tmp_path):
    from rigslim.runtime.run import run_pipeline

    src = build_gltf(tmp_path / "a.glb", rigid_parts(2), n_joints=2)
    (tmp_path / "m.obj").write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 3\n")
    yml = tmp_path / "p.yaml"
    yml.write_text(f"inputs:\n  gltf: {src}\n  mesh: m.obj\nsteps:\n  - evaluate: [max-influences]\n")
    with pytest.raises(PipelineError, match="inputs.mesh"):
        run_pipeline(yml)
