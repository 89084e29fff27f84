"""Issue 21 item 6: a 3,000 s clip (90,001 frames at 30 fps) is compared on a bounded set of frames.

Without ``--frames``, ``rigslim compare`` used every frame of the clip: 90,001 Hausdorff measurements (it ran
until killed) and a (frames, vertices, 3) array per file. It now takes
:data:`rigslim.commands.compare.MAX_DEFAULT_FRAMES` evenly spread frames and says so.
"""

from __future__ import annotations

import json
import struct

import numpy as np
from support.hostile_gltf import build_gltf, rigid_parts, write_glb

from rigslim.cli import main
from rigslim.commands.compare import MAX_DEFAULT_FRAMES


def long_clip(tmp_path, seconds: float = 3000.0):
    """The hostile builder's 1 s clip with every key time scaled to ``seconds``."""
    raw = build_gltf(tmp_path / "parts.glb", rigid_parts()).read_bytes()
    n = struct.unpack_from("<I", raw, 12)[0]
    js = json.loads(raw[20:20 + n])
    data = bytearray(raw[28 + n:28 + n + struct.unpack_from("<I", raw, 20 + n)[0]])
    for a in {s["input"] for s in js["animations"][0]["samplers"]}:
        acc = js["accessors"][a]
        off = js["bufferViews"][acc["bufferView"]].get("byteOffset", 0) + acc.get("byteOffset", 0)
        t = np.frombuffer(bytes(data[off:off + 4 * acc["count"]]), np.float32) * np.float32(seconds)
        data[off:off + 4 * acc["count"]] = t.tobytes()
        acc["min"], acc["max"] = [float(t.min())], [float(t.max())]
    return write_glb(tmp_path / "long.glb", js, bytes(data))


def test_compare_on_a_3000_s_clip_takes_evenly_spread_frames(tmp_path, capsys):
    src = long_clip(tmp_path)
    assert main(["compare", str(src), str(src), "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["clip_frames"] == 90001
    frames = res["frames"]
    assert len(frames) == MAX_DEFAULT_FRAMES and frames[0] == 0 and frames[-1] == 90000
    assert np.ptp(np.diff(frames)) <= 1                       # evenly spread
    assert res["hausdorff_max_m"] < 1e-5 and res["position_max_m"] == 0.0


def test_compare_frames_still_choose_any_frames_of_a_long_clip(tmp_path, capsys):
    src = long_clip(tmp_path)
    assert main(["compare", str(src), str(src), "--json", "--frames", "89990:90001:5"]) == 0
    assert json.loads(capsys.readouterr().out)["frames"] == [89990, 89995, 90000]
