"""``rigslim compare`` above its large-mesh threshold (issue 21 item 7): the Hausdorff distance on a few evenly
spread frames, said in the JSON, each of those frames measured exactly as the all-frames path measures it.

The threshold is lowered (``large_faces``) so that the bundled 1,536-triangle tube stands in for a 2.6M-triangle
mesh.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from rigslim.commands.cli import main
from rigslim.commands.compare import compare, hausdorff_frame_indices, posed_surfaces

pytest.importorskip("pymeshlab")

TUBE = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf" / "tube_two_materials.glb"


@pytest.mark.parametrize("n, cap", [(31, 3), (31, 1), (31, 30), (5, 4), (2, 1), (100, 7)])
def test_frame_indices_one_per_equal_run(n, cap):
    """Exactly ``cap`` frames, increasing, the i-th inside the i-th of ``cap`` equal runs of the ``n`` frames."""
    idx = hausdorff_frame_indices(n, cap)
    assert len(idx) == cap and idx == sorted(set(idx))
    for i, j in enumerate(idx):
        assert i * n / cap <= j < (i + 1) * n / cap


@pytest.mark.parametrize("cap", [0, 31, 40])
def test_frame_indices_all_frames(cap):
    assert hausdorff_frame_indices(31, cap) == list(range(31))


@pytest.fixture(scope="module")
def reduced(tmp_path_factory):
    """The tube with one influence per vertex: same vertices and faces, other weights (a real posing error)."""
    out = tmp_path_factory.mktemp("cmp") / "k1.glb"
    assert main(["reduce", str(TUBE), "-o", str(out), "-k", "1"]) == 0
    return out


# pymeshlab draws its face samples at random; every vertex is a sample too, so a frame's max (at a vertex here)
# agrees closely and the RMS within the sampling noise of SAMPLES points per direction: the error here sits on a
# few faces, so the RMS of one frame varies by up to 7.8 % between two runs at 4,000 samples and 6.3 % at 16,000
# (measured over 4 x 4 frame pairs; a CI run failed at 6.6 % with the 5 % this allowed before).
SAMPLES = 4000
RMS_REL, MAX_REL = 0.15, 0.02


def test_capped_frames_agree_with_the_exact_path(reduced):
    exact = compare(TUBE, reduced, samples=SAMPLES, hausdorff_frames=0, large_faces=100)
    fast = compare(TUBE, reduced, samples=SAMPLES, large_faces=100)         # 1,536 faces > 100: capped
    assert exact["hausdorff_all_frames"] and not fast["hausdorff_all_frames"]
    n = len(exact["frames"])
    assert fast["hausdorff_frame_cap"] == 3
    spread = [exact["frames"][j] for j in hausdorff_frame_indices(n, 3)]
    assert set(spread) <= set(fast["hausdorff_frames"]) and len(fast["hausdorff_frames"]) <= 4
    # the frame of the largest vertex-to-vertex distance is always measured (same topology)
    times = [f / exact["fps"] for f in exact["frames"]]
    Pr, Pc = posed_surfaces(TUBE, clip=None, times=times)[0], posed_surfaces(reduced, clip=None, times=times)[0]
    far = int(np.argmax(np.linalg.norm(Pc - Pr, axis=-1).max(axis=1)))
    assert exact["frames"][far] in fast["hausdorff_frames"]
    for j, frame in enumerate(fast["hausdorff_frames"]):
        k = exact["frames"].index(frame)
        assert fast["per_frame_rms_m"][j] == pytest.approx(exact["per_frame_rms_m"][k], rel=RMS_REL)
        assert fast["per_frame_max_m"][j] == pytest.approx(exact["per_frame_max_m"][k], rel=MAX_REL)
    assert fast["hausdorff_max_m"] <= exact["hausdorff_max_m"] * (1 + MAX_REL)
    # the vertex-to-vertex bound holds on every frame, the skipped ones too
    assert fast["hausdorff_max_bound_m"] == fast["position_max_m"] > 0
    assert max(exact["per_frame_max_m"]) <= fast["hausdorff_max_bound_m"] * (1 + 1e-9)
    # the vertex-wise figures do not depend on the cap
    for key in ("position_rms_m", "position_max_m", "normal_rms_rad"):
        assert fast[key] == exact[key]


def test_small_mesh_keeps_every_frame(reduced):
    res = compare(TUBE, reduced, frames="0:31:6", samples=2000)
    assert res["hausdorff_all_frames"] and res["hausdorff_frames"] == res["frames"]
    assert res["hausdorff_frame_cap"] == 0 and len(res["per_frame_max_m"]) == len(res["frames"])


def test_cap_is_in_the_json_and_the_text(reduced, capsys):
    assert main(["compare", str(TUBE), str(reduced), "--hausdorff-frames", "2", "--samples", "2000", "--json"]) == 0
    res = json.loads(capsys.readouterr().out)
    assert res["hausdorff_frame_cap"] == 2 and not res["hausdorff_all_frames"]
    assert 2 <= len(res["hausdorff_frames"]) <= 3 and set(res["hausdorff_frames"]) <= set(res["frames"])
    assert main(["compare", str(TUBE), str(reduced), "--hausdorff-frames", "2", "--samples", "2000"]) == 0
    text = capsys.readouterr().out
    assert f"Hausdorff on {len(res['hausdorff_frames'])} of {len(res['frames'])} frames" in text
    assert "--hausdorff-frames 0 for all" in text


def test_negative_cap_is_one_line_and_exit_2(capsys):
    assert main(["compare", str(TUBE), str(TUBE), "--hausdorff-frames", "-1"]) == 2
    err = capsys.readouterr().err.strip()
    assert "--hausdorff-frames" in err and "\n" not in err and "Traceback" not in err


def test_vertex_errors_leave_out_vertices_without_a_normal():
    """A vertex no face of non-zero area touches has a zero normal: compare once counted it as pi/2 between a
    file and itself (normal RMS 0.0489 rad on a 1,033-vertex CSM conversion)."""
    from rigslim.commands.compare import vertex_errors

    V = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0], [0, 0, 1], [5, 5, 5]])
    F = np.array([[0, 1, 2], [0, 2, 3], [0, 3, 1], [4, 4, 4]])            # vertex 4: only a (4, 4, 4) face
    P = np.stack([V, V])
    errors, _ = vertex_errors(P, P.copy(), F, diag=1.0)
    assert errors["normal_rms_rad"] < 1e-6 and errors["position_rms_m"] == 0.0       # pi/2 on 1 of 5 once: 0.70
