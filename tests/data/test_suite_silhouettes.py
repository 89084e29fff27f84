"""Issue 25: every suite character's coarsest level, rendered posed in three.js, keeps the original's silhouette.

For each character of the suite, ``rigslim lod CHAR.glb --ratios R --split``
with R = 10 % (the far level the issue is about), raised to keep at least 250
faces (at most 50 %) for the small characters (wolf 36 %, mangonel 22 %,
re_drone 13 %, minetest_character 50 %), otherwise defaults, is rendered by three.js
in headless Chromium at the index's test poses (clip, time), from the
character's side and from its front, with the camera that frames the
original in that pose (support.posed_render). The silhouette difference is
``shape_diff = (|A \\ D(B)| + |B \\ D(A)|) / |A|`` at 220 x 220 pixels, where
``D`` dilates a silhouette by 2 pixels: the pixels of either silhouette
farther than 2 pixels from the other, as a share of the original's area. An
outline moved by a pixel or two counts nothing; webbing between legs, a
collapsed tail or a spiked foot count in full, however thin.

The threshold, ``MAX_SHAPE_DIFF = 4 %`` of the silhouette area at the worst
pose and view (220 x 220 pixels), comes from measuring the two peers at
rigslim's face counts (benchmarks/lod_sheets.py; sheets and table in the
suite helper's notes, main 06eb2ad): on every suite character at least one
of glTF-Transform and gltfpack stays within it (the better peer's worst:
bcn_epileptic 0.2 %, wuson 1.5 %, frankie 2.8 %, snoutx10k 1.5 %, mrfixit
0.6 %, re_player 1.2 %, re_drone 3.8 % (at 10 %), the highest; PEER_LIMITS below for the two
characters where both peers exceed it), while the
defects the issue lists score more: webbed legs 7.7-22 %, a spike tail with a
flattened flank 9 %, a head pinched to a point 13.8 %, boxes flattened 44 %.
Each character is tested twice: with the default error bound (``--max-error``
1 %, the level a user gets, which may stop before the target) and with
``--max-error none`` (forced to the target, as the peers are run, where the
shape guards alone must keep the silhouette). Characters whose unbounded level
fails today are ``xfail(strict=True)`` with the defect
seen on the sheets; when a fix lands the test turns XPASS and fails, and the
mark is to be removed.

A self-check renders a level with a spike added (vertices of one foot pulled
down) and asserts that it fails the threshold, and mask_difference is
checked on drawn silhouettes (webbed legs, a shortened tail, an outline shift).
"""

from __future__ import annotations

import json
import struct
from pathlib import Path

import numpy as np
import pytest
from support.posed_render import View, available, mask_difference

from benchmarks.datasets import suite
from rigslim.cli import main as rigslim

MAX_SHAPE_DIFF = 0.04
SIZE = (220, 220)
RATIO = 0.1
FLOOR = 250         # faces: the far level of a small character (wolf 696, mangonel 1,158, drone 1,926 faces)

#: Where even the better peer exceeds MAX_SHAPE_DIFF at rigslim's face count, the limit is the better peer's
#: score (rigslim must not be worse than the best open tool): wolf at 250 faces, gltf-transform 7.0 % (its tail
#: thinned to a spike, a hind leg webbed), gltfpack 7.4 %; mangonel at 22 % (rigslim stops at 315 faces),
#: gltfpack 9.6 % at 273 (the throwing arm lost), gltf-transform 10.0 % (it cannot go below 512 faces; the sling
#: rope webbed into a sheet).
PEER_LIMITS: dict[str, float] = {"wolf": 0.07, "mangonel": 0.096}

#: Characters whose 10 % level fails today, with what the sheets show (benchmarks/lod_sheets.py). Six more
#: were listed until seams moved (issue 25: seam planes instead of locked seams, and unread UV sets making no
#: seams): wuson (the tail a spike, 9.0 %), frankie (the kicking arm lost, 7.8 %), snoutx10k (armour and head
#: eroded, 18.7 %), mrfixit (legs webbed, 13.2 %), re_player (head crest lost, 5.6 %) and re_drone (head
#: pinched, legs webbed, 13.8 %); all six now stay within MAX_SHAPE_DIFF unbounded.
FAILING: dict[str, str] = {
    "minetest_character": "84 -> 42 faces at 50 % with no error bound: closed boxes flattened into sheets, the head "
                          "a wedge (at 25 %, 28 faces: 44 %; gltf-transform keeps all 84 faces)",
}

browser = pytest.mark.skipif(available() is not None, reason=str(available()))


def _cases():
    out = []
    for bound in ("default", "none"):
        for c in suite(group="all"):
            marks = [pytest.mark.slow, pytest.mark.browser, browser]
            if bound == "none" and c.name in FAILING:
                marks.append(pytest.mark.xfail(strict=True, reason=FAILING[c.name]))
            out.append(pytest.param(c, bound, marks=marks, id=f"{c.name}-max-error-{bound}"))
    return out


@pytest.fixture(scope="module")
def renderer():
    from support.posed_render import PosedRenderer

    with PosedRenderer(size=SIZE) as r:
        yield r


def coarsest_level(c, folder: Path, bound: str = "default") -> Path | None:
    from benchmarks.lod_sheets import level_ratio

    out = folder / f"{c.name}.glb"
    ratio = level_ratio(RATIO, c.faces, FLOOR)
    extra = [] if bound == "default" else ["--max-error", bound]
    assert rigslim(["lod", str(c.path), "-o", str(out), "--ratios", f"{ratio:g}", "--split", *extra]) == 0
    levels = sorted(folder.glob(f"{c.name}-*.glb"))
    if not levels:        # only where the bound stops before the first collapse: the sidecar lists the source alone
        sidecar = json.loads((folder / f"{c.name}.lod.json").read_text())
        assert bound == "default" and [lv["faces"] for lv in sidecar["levels"]] == [c.faces], \
            f"rigslim lod wrote no level for {c.name}"
        return None
    return min(levels, key=lambda p: p.stat().st_size)


def worst_difference(renderer, c, original: Path, level: Path) -> tuple[float, str, list]:
    """The largest shape_diff over the index's test poses and the side and front views."""
    rows = []
    for pose in c.test_renders:
        for view in ("side_azimuth", "front_azimuth"):
            ref = renderer.render(original, clip=pose["clip"], time=pose["time"], view=View(azimuth=c.view[view]))
            lod = renderer.render(level, clip=pose["clip"], time=pose["time"], camera=ref.camera)
            m = mask_difference(ref.mask, lod.mask)
            rows.append((m["shape_diff"], f"{pose['clip']} t={pose['time']} {view.split('_')[0]}", m))
    worst = max(rows, key=lambda r: r[0])
    return worst[0], worst[1], rows


@pytest.mark.parametrize(("character", "bound"), _cases())
def test_coarsest_level_keeps_the_silhouette(character, bound, renderer, tmp_path):
    """``bound`` default: the level a user gets (``--max-error`` 1 %, which may stop before the target);
    ``none``: the far level forced to its target, where the shape guards alone must keep the silhouette."""
    level = coarsest_level(character, tmp_path, bound)
    if level is None:     # minetest's boxes at 1 %: no level is written, the user sees the source itself
        return
    worst, where, rows = worst_difference(renderer, character, character.path, level)
    table = "; ".join(f"{w}: {100 * d:.1f}%" for d, w, _ in rows)
    limit = max(MAX_SHAPE_DIFF, PEER_LIMITS.get(character.name, 0.0))
    assert worst <= limit, (f"{character.name} {level.name}: silhouette differs by {100 * worst:.1f}% "
                            f"of its area at {where} (limit {100 * limit:g}%): {table}")


def _spiked(src: Path, dst: Path, fraction: float = 0.02, drop: float = 0.15) -> None:
    """Copy a .glb with its lowest ``fraction`` of vertices (one primitive, bind pose) pulled down by ``drop``
    of the mesh height: a spike under a foot."""
    raw = bytearray(src.read_bytes())
    n = struct.unpack_from("<I", raw, 12)[0]
    doc = json.loads(raw[20:20 + n])
    bin_start = 20 + n + 8
    acc = doc["accessors"][doc["meshes"][0]["primitives"][0]["attributes"]["POSITION"]]
    bv = doc["bufferViews"][acc["bufferView"]]
    start = bin_start + bv.get("byteOffset", 0) + acc.get("byteOffset", 0)
    stride = bv.get("byteStride") or 12
    rows = np.stack([np.frombuffer(bytes(raw[start + i * stride:start + i * stride + 12]), "<f4")
                     for i in range(acc["count"])]).astype(np.float64)
    up = int(np.argmax(rows.max(axis=0) - rows.min(axis=0)))
    low = np.argsort(rows[:, up])[:max(3, int(fraction * len(rows)))]
    low = low[np.linalg.norm(rows[low] - rows[low[0]], axis=1) < 0.1 * np.ptp(rows[:, up])]
    rows[low, up] -= drop * np.ptp(rows[:, up])
    for i in low:
        raw[start + i * stride:start + i * stride + 12] = rows[i].astype("<f4").tobytes()
    acc["min"] = [float(x) for x in rows.min(axis=0)]
    text = json.dumps(doc, separators=(",", ":")).encode()
    text += b" " * (-len(text) % 4)
    body = bytes(raw[20 + n:])
    out = struct.pack("<4sII", b"glTF", 2, 12 + 8 + len(text) + len(body)) + struct.pack("<I4s", len(text),
                                                                                         b"JSON") + text + body
    dst.write_bytes(out)


@pytest.mark.slow
@pytest.mark.browser
@browser
def test_the_threshold_catches_a_spiked_foot(renderer, tmp_path):
    """The original against itself scores 0; with one foot pulled into a spike it fails the threshold."""
    c = suite(["re_player"])[0]
    spiked = tmp_path / "spiked.glb"
    _spiked(c.path, spiked)
    same, _, _ = worst_difference(renderer, c, c.path, c.path)
    assert same == 0.0
    worst, where, _ = worst_difference(renderer, c, c.path, spiked)
    assert worst > MAX_SHAPE_DIFF, f"a spiked foot scores only {100 * worst:.2f}% at {where}"


def _legs(webbed: bool = False, tail: float = 1.0, shift: int = 0) -> np.ndarray:
    """A drawn silhouette (200 x 200): body, two legs, a tail; optionally webbed legs, a shortened tail."""
    m = np.zeros((200, 200), bool)
    m[40:110, 60:140] = True                                   # body
    m[110:190, 65 + shift:85 + shift] = True                   # left leg
    m[110:190, 115 + shift:135 + shift] = True                 # right leg
    m[60:66, 140:140 + int(50 * tail)] = True                  # tail
    if webbed:
        for r in range(110, 160):                              # a web between the legs, down to mid-shin
            m[r, 85:115] = r < 160 - (r - 110) // 2
    return m


def test_mask_difference_counts_webbing_and_lost_tails_not_outline_shifts():
    ref = _legs()
    assert mask_difference(ref, ref)["shape_diff"] == 0.0
    assert mask_difference(ref, _legs(shift=1))["shape_diff"] == 0.0           # a 1-pixel shift is in the band
    webbed = mask_difference(ref, _legs(webbed=True))
    assert webbed["shape_diff"] > MAX_SHAPE_DIFF and webbed["extra"] > webbed["missing"]
    spiked_tail = mask_difference(ref, _legs(tail=0.3))
    assert spiked_tail["shape_diff"] > MAX_SHAPE_DIFF / 3 and spiked_tail["missing"] > 0
    assert webbed["iou"] < 1.0 and 0.0 < spiked_tail["iou"] < 1.0


def test_mask_difference_refuses_mismatched_or_empty_masks():
    with pytest.raises(ValueError, match="size"):
        mask_difference(np.ones((4, 4), bool), np.ones((5, 5), bool))
    with pytest.raises(ValueError, match="empty"):
        mask_difference(np.zeros((4, 4), bool), np.ones((4, 4), bool))
