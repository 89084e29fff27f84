"""Switch coverage checked on screen: posed in three.js at the coverage written for a level, the level's
silhouette is within ``--pixel-error`` pixels of the full character's (headless Chromium, SwiftShader).

``rigslim lod --split`` writes each level's coverage range and the bounding radius it assumed into
``OUT.lod.json``. For level i the camera is put at the distance where the character covers exactly the
level's ``max_coverage`` (where it switches in), looking at the centre of the full character's posed
bounding box, with the field of view, viewport height and aspect of the run; the full input and the
level file are rendered at test frames of the run the writer measured (never example frames). The screen-space error is
the symmetric Hausdorff distance between the two silhouettes in pixels (``silhouette_hausdorff``).

Tolerance: 1 pixel, for the rasterisation of two silhouettes at pixel centres (each boundary moves by
up to half a pixel) and for Metro's sampled maximum, which can only under-estimate the true one.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from support.posed_render import PosedRenderer, available

from rigslim.commands.cli import main
from rigslim.commands.compare import posed_surfaces
from rigslim.io.gltf.switch import measured_frames
from rigslim.numerics.screen_coverage import coverage_distance

ROOT = Path(__file__).resolve().parents[3]
CHARACTER = ROOT / "examples" / "data" / "gltf" / "suite" / "wuson.glb"
CLIP, PIXELS, FOV, HEIGHT = "Wuson_Walk", 2.0, 40.0, 240
TOLERANCE = 1.0

pytestmark = [pytest.mark.slow, pytest.mark.browser,
              pytest.mark.skipif(available() is not None, reason=str(available()))]


def silhouette_hausdorff(a: np.ndarray, b: np.ndarray) -> float:
    """``max(max_{p in B} d(p, A), max_{q in A} d(q, B))`` in pixels (distance transforms)."""
    from scipy.ndimage import distance_transform_edt

    if not a.any() or not b.any():
        return float("inf")
    return float(max(distance_transform_edt(~a)[b].max(), distance_transform_edt(~b)[a].max()))


def test_silhouette_hausdorff():
    a = np.zeros((20, 20), bool)
    a[5:10, 5:10] = True
    b = np.roll(a, 3, axis=1)
    assert silhouette_hausdorff(a, a) == 0 and silhouette_hausdorff(a, b) == 3


@pytest.fixture(scope="module")
def split(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("switch")
    out = tmp / "wuson.glb"
    assert main(["lod", str(CHARACTER), "-o", str(out), "--clip", CLIP, "--ratios", "0.5,0.2", "--split",
                 "--max-joints", "0.5", "--pixel-error", str(PIXELS), "--fov", str(FOV), "--resolution", str(HEIGHT),
                 "--report", str(tmp / "report.json")]) == 0
    sidecar = json.loads((tmp / "wuson.lod.json").read_text())
    report = json.loads((tmp / "report.json").read_text())
    return tmp, sidecar, report


def test_each_level_is_within_p_pixels_at_its_coverage(split):
    tmp, sidecar, report = split
    cam = sidecar["camera"]
    assert (cam["pixel_error"], cam["fov_deg"], cam["resolution"]) == (PIXELS, FOV, HEIGHT)
    r, aspect = sidecar["bounding_radius_m"], cam["aspect"]
    (held_out,) = report["clips"]["test"]                              # the test frames of the one clip
    assert held_out["clip"] == CLIP
    fps = report["pipeline"]["inputs"]["gltf"]["fps"]
    test = held_out["frames"]
    chosen = measured_frames(len(test), 12)            # the test frames the writer measured (switch_frames)
    times = [test[i] / fps for i in chosen[:: max(1, len(chosen) // 3)][:3]]
    width = int(round(aspect * HEIGHT))
    measured = []
    with PosedRenderer(size=(width, HEIGHT)) as renderer:
        for level in sidecar["levels"][1:]:
            d = coverage_distance(level["max_coverage"], r, fov=FOV, aspect=aspect)
            assert d >= level["switch_distance_m"] * (1 - 1e-9)
            for t in times:
                P, _, _ = posed_surfaces(CHARACTER, clip=CLIP, times=[t])
                centre = 0.5 * (P[0].min(axis=0) + P[0].max(axis=0))
                eye = centre + d * np.array([0.0, np.sin(0.15), np.cos(0.15)])
                camera = {"eye": eye.tolist(), "target": centre.tolist(), "fov": FOV, "near": max(d - 3 * r, 1e-3 * d),
                          "far": d + 3 * r}
                full = renderer.render(CHARACTER, clip=CLIP, time=t, camera=camera)
                lod = renderer.render(tmp / level["file"], clip=CLIP, time=t, camera=camera)
                assert full.mask.sum() > 200, "the character covers too few pixels to measure"
                measured.append((level["label"], t, silhouette_hausdorff(full.mask, lod.mask)))
    worst = max(m[2] for m in measured)
    print("silhouette Hausdorff (px) per level and time:", measured)
    assert worst <= PIXELS + TOLERANCE, measured


def test_sidecar_lists_every_level(split):
    tmp, sidecar, report = split
    levels = sidecar["levels"]
    assert [lv["level"] for lv in levels] == [0, 1, 2]
    assert levels[0]["label"] == "input" and (tmp / levels[0]["file"]).resolve() == CHARACTER.resolve()
    for lv, row in zip(levels[1:], report["levels"], strict=True):
        assert (tmp / lv["file"]).is_file()
        assert lv["faces"] == row["faces"] and lv["joints"] == row["joints"]
        budget = row["joint_budget"]      # half of wuson's 37 joints, unless the error bound stopped the merges
        assert row["joints"] <= 19 or (budget["stopped"] == "max_error" and budget["next_error"] > budget["max_error"])
        assert lv["error_max_m"] == row["error_max_m"] > 0 and lv["error_rms_m"] <= lv["error_max_m"]
        assert lv["min_coverage"] <= lv["max_coverage"]
    assert levels[-1]["min_coverage"] == 0.0 and levels[0]["max_coverage"] == 1.0
    for x, y in zip(levels, levels[1:], strict=False):
        assert y["max_coverage"] == x["min_coverage"]
