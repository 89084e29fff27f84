"""Issue 21 item 6: ``rigslim lod`` on primitives with no triangles (POINTS, LINES) is one line and exit 2,
never a traceback or a "bug in rigslim" message from inside the quadrics."""

from __future__ import annotations

import json
import struct

import pytest
from support.hostile_gltf import build_gltf, rigid_parts, write_glb

from rigslim.cli import main


@pytest.mark.parametrize("method", ["quartic", "static-qslim"])
@pytest.mark.parametrize(("mode", "name"), [(0, "points"), (1, "lines")])
def test_lod_of_a_mesh_without_triangles_is_refused_in_one_line(tmp_path, capsys, mode, name, method):
    """Every method: static-qslim handed pymeshlab the empty face list ("does not have Any Faces", a bug line)."""
    raw = build_gltf(tmp_path / "parts.glb", rigid_parts()).read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    js = json.loads(raw[20:20 + n])
    data = raw[28 + n:28 + n + struct.unpack_from("<I", raw, 20 + n)[0]]
    for mesh in js["meshes"]:
        for prim in mesh["primitives"]:
            prim["mode"] = mode
    src = write_glb(tmp_path / f"{name}.glb", js, data)
    out = tmp_path / "lod.glb"
    assert main(["lod", str(src), "-o", str(out), "--ratios", "0.5", "--method", method]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("rigslim: error: ") and "\n" not in err
    assert "no triangles" in err and "bug" not in err
    assert not out.exists()
