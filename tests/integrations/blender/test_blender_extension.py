"""The Blender extension (integrations/blender), headless: built, validated by Blender, installed, run.

Blender is the ``bpy`` module in ``.venv-blender`` (tools/setup-blender.sh, run by ``make test``): it
pins numpy < 2, so it runs in a subprocess (tests/support/blender_driver.py), and the extension runs
rigslim out of process in this test's own Python, as it would run a user's installation.
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
BLENDER_PY = ROOT / ".venv-blender" / "bin" / "python"
DRIVER = ROOT / "tests" / "support" / "blender_driver.py"
BUILD = ROOT / "integrations" / "blender" / "build.py"

pytestmark = [pytest.mark.blender, pytest.mark.slow]


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory) -> Path:
    if not BLENDER_PY.exists():
        pytest.fail(f"{BLENDER_PY} is missing: run tools/setup-blender.sh (make test does)")
    out = tmp_path_factory.mktemp("dist")
    proc = subprocess.run([sys.executable, str(BUILD), "--output", str(out)], capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert "validated by" in proc.stdout and "blender_ext.py" in proc.stdout, proc.stdout
    return out / "rigslim-0.1.0.zip"


def run_driver(zip_path: Path, tmp: Path, *extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("RIGSLIM_PYTHON", "PYTHONPATH")}
    env["BLENDER_USER_RESOURCES"] = str(tmp / "blender-user")
    out = tmp / "result.json"
    proc = subprocess.run([str(BLENDER_PY), str(DRIVER), "--zip", str(zip_path), "--rigslim-python", sys.executable,
                           "--out", str(out), *extra], capture_output=True, text=True, env=env, timeout=1800)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-3000:]
    return json.loads(out.read_text())


@pytest.fixture(scope="module")
def tube(extension_zip, tmp_path_factory) -> dict:
    return run_driver(extension_zip, tmp_path_factory.mktemp("tube"), "--k", "2", "--ratios", "0.5, 0.25",
                      "--max-bones", "2")


@pytest.fixture(scope="module")
def tube_smooth(extension_zip, tmp_path_factory) -> dict:
    """The tube with the smooth solver, whose fit loses to Limit Total here: the operator keeps Limit Total's."""
    return run_driver(extension_zip, tmp_path_factory.mktemp("smooth"), "--k", "2", "--solve", "smooth",
                      "--skip-lods")


@pytest.fixture(scope="module")
def tube_clips(extension_zip, tmp_path_factory) -> dict:
    """Fitted on Bend only, measured on Twist (a held-out action)."""
    return run_driver(extension_zip, tmp_path_factory.mktemp("clips"), "--k", "2", "--actions", "Bend",
                      "--test-actions", "Twist", "--skip-lods")


def test_zip_matches_blenders_own_build(extension_zip, tmp_path):
    ext = next((ROOT / ".venv-blender" / "lib").glob("python3*/site-packages/bpy/*/scripts/addons_core/bl_pkg/"
                                                     "cli/blender_ext.py"))
    theirs = tmp_path / "theirs.zip"
    proc = subprocess.run([sys.executable, str(ext), "build", "--source-dir",
                           str(ROOT / "integrations/blender/rigslim_blender"), "--output-filepath", str(theirs)],
                          capture_output=True, text=True)
    assert proc.returncode == 0, proc.stdout + proc.stderr
    ours = sorted(zipfile.ZipFile(extension_zip).namelist())
    assert ours == sorted(zipfile.ZipFile(theirs).namelist())
    assert "blender_manifest.toml" in ours and "worker.py" in ours


def test_limit_influences_groups(tube):
    assert tube["limit_status"] == ["FINISHED"]
    assert tube["input_groups"]["max_groups"] > 2                 # the input really had more than k
    g = tube["groups"]
    assert g["max_groups"] <= 2
    assert g["weighted"] == tube["input_groups"]["weighted"]
    assert g["max_sum_error"] < 1e-5                              # Blender stores float32 weights


def test_limit_influences_beats_limit_total_on_held_out_frames(tube):
    ours, indep = tube["limit"], tube["independent"]
    assert ours["measured_frames"] == indep["frames"] > 0
    assert ours["held_out_frames"] == indep["frames"]
    # the operator's own figures are what Blender measures when it poses the three meshes
    assert ours["kept"] == "rigslim"                              # the fit wins on the tube: nothing to fall back to
    assert ours["rms_pct"] == pytest.approx(indep["rms_pct"], rel=1e-6)
    assert ours["limit_total_rms_pct"] == pytest.approx(indep["limit_total_rms_pct"], rel=1e-6)
    assert indep["rms_pct"] <= indep["limit_total_rms_pct"]
    assert indep["limit_total_rms_pct"] > 0.05                  # Limit Total really loses something here
    assert tube["temporary_objects_left"] == []
    assert tube["undo_flag"]


def test_generate_lods(tube):
    assert tube["lod_status"] == ["FINISHED"]
    lods = tube["lods"]
    assert [lv["name"] for lv in lods] == ["Tube_LOD1", "Tube_LOD2"]
    faces = [tube["source_faces"] * 2] + [lv["faces"] for lv in lods]   # the source has quads
    assert faces == sorted(faces, reverse=True) and len(set(faces)) == 3
    for lv, ratio in zip(lods, (0.5, 0.25), strict=True):
        assert abs(lv["faces"] - ratio * tube["source_faces"] * 2) <= 2
        assert lv["parent"] == "Tube" and lv["armature"] == "Rig" and lv["valid"]
        assert lv["groups_are_bones"] and lv["max_groups"] <= 2 and lv["max_sum_error"] < 1e-5
        assert lv["materials"] == tube["source_materials"] and lv["material_indices"] == [0, 1]
        assert lv["uv_layers"] == ["UVMap"] and lv["uv_finite"]
        assert 0.0 <= lv["uv_min"] and lv["uv_max"] <= 1.0
        assert lv["posed_moved"] > 0.5                        # it follows the armature
        assert lv["posed_distance_pct"] < 5.0                 # and stays on the posed full mesh


def test_errors_are_one_line(tube):
    missing = tube["errors"]["missing_rigslim"]
    assert "\n" not in missing and "rigslim Python" in missing and "Traceback" not in missing
    bad = tube["errors"]["bad_action"]
    assert "\n" not in bad and "NoSuchAction" in bad and "Bend" in bad


def test_generate_lods_max_error(tube):
    """rigslim's max_error stops levels early: never fewer faces than without it, and the old children go."""
    free = {lv["name"]: lv["faces"] for lv in tube["lod_record"]["levels"]}
    bounded = tube["lod_bounded"]["levels"]
    assert tube["lod_bounded_children"] == [lv["name"] for lv in bounded]
    assert all(lv["faces"] >= free[lv["name"]] for lv in bounded)
    assert any(lv["faces"] > free[lv["name"]] for lv in bounded)


def test_limit_influences_keeps_limit_total_when_the_fit_is_worse(tube_smooth):
    rec, indep = tube_smooth["limit"], tube_smooth["independent"]
    assert rec["solve"] == "smooth" and rec["rms_pct"] > rec["limit_total_rms_pct"]   # the raw fit lost
    assert rec["kept"] == "limit_total"
    assert indep["rms_pct"] == pytest.approx(indep["limit_total_rms_pct"], rel=1e-6)   # what is on the mesh now
    assert tube_smooth["groups"]["max_groups"] <= 2 and tube_smooth["groups"]["max_sum_error"] < 1e-5


def test_limit_influences_held_out_action(tube_clips):
    rec, indep = tube_clips["limit"], tube_clips["independent"]
    # Bend fitted, Twist measured
    assert rec["fitted_frames"] == 40 and rec["held_out_frames"] == indep["frames"] == 40
    on_mesh = rec["rms_pct"] if rec["kept"] == "rigslim" else rec["limit_total_rms_pct"]
    assert indep["rms_pct"] == pytest.approx(on_mesh, rel=1e-6)
    assert indep["rms_pct"] <= indep["limit_total_rms_pct"] * (1 + 1e-9)
    assert tube_clips["groups"]["max_groups"] <= 2
