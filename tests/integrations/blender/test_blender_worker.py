"""The parts of the Blender extension that run without Blender: the worker, the runner, the zip builder."""

from __future__ import annotations

import importlib.util
import json
import os
import stat
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import rigslim

ROOT = Path(__file__).resolve().parents[3]
PKG = ROOT / "integrations" / "blender" / "rigslim_blender"


def load(name: str, path: Path):
    spec = importlib.util.spec_from_file_location(name, path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[name] = module                  # dataclasses look their module up
    spec.loader.exec_module(module)
    return module


worker = load("rigslim_blender_worker", PKG / "worker.py")
runner = load("rigslim_blender_runner", PKG / "runner.py")
build = load("rigslim_blender_build", ROOT / "integrations" / "blender" / "build.py")


def strip(n_bones: int = 4, rings: int = 12, seed: int = 0):
    """A grid strip along z with smooth weights over every bone and random rotations of each bone."""
    rng = np.random.default_rng(seed)
    xs, zs = np.linspace(0, 1, 4), np.linspace(0, 4, rings)
    V = np.array([(x, 0.0, z) for z in zs for x in xs])
    F = []
    for r in range(rings - 1):
        for c in range(3):
            i = r * 4 + c
            F += [(i, i + 1, i + 5), (i, i + 5, i + 4)]
    centres = (np.arange(n_bones) + 0.5) * 4 / n_bones
    W = np.exp(-((V[:, 2:3] - centres[None]) / 0.8) ** 2)
    W /= W.sum(axis=1, keepdims=True)
    T = np.zeros((10, n_bones, 3, 4))
    for p in range(10):
        for b in range(n_bones):
            a = rng.normal(scale=0.4, size=3)
            K = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
            th = np.linalg.norm(a)
            R = np.eye(3) + np.sin(th) / th * K + (1 - np.cos(th)) / th**2 * K @ K
            pivot = np.array([0.5, 0, centres[b]])
            T[p, b, :, :3], T[p, b, :, 3] = R, pivot - R @ pivot
    return V, np.array(F, np.int64), W, T


def request(V, F, W, T, **more):
    rows, cols = np.nonzero(W)
    return {"protocol": np.int64(1), "V": V, "F": F, "poses": T, "n_vertices": np.int64(len(V)),
            "n_handles": np.int64(W.shape[1]), "w_rows": rows, "w_cols": cols, "w_values": W[rows, cols], **more}


def run_worker(tmp_path, command: str, req: dict):
    np.savez(tmp_path / "req.npz", **req)
    proc = subprocess.run([sys.executable, str(PKG / "worker.py"), command, str(tmp_path / "req.npz"),
                           str(tmp_path / "res.npz")], capture_output=True, text=True)
    lines = [json.loads(s) for s in proc.stdout.splitlines() if s.strip()]
    res = dict(np.load(tmp_path / "res.npz")) if proc.returncode == 0 else None
    return proc.returncode, lines, res


def test_reduce_is_rigslims_default_reduction(tmp_path):
    V, F, W, T = strip()
    rc, lines, res = run_worker(tmp_path, "reduce", request(V, F, W, T, k=np.int64(2)))
    assert rc == 0, lines
    assert all("progress" in ln for ln in lines)
    direct = rigslim.reduce_weights((V, F), W, T, k=2)
    np.testing.assert_allclose(res["values"], direct.values, atol=1e-12)
    np.testing.assert_array_equal(res["indices"], direct.indices)
    import inspect

    defaults = inspect.signature(rigslim.reduce_weights).parameters
    assert str(res["select"]) == str(defaults["select"].default) and str(res["solve"]) == str(defaults["solve"].default)


def test_reduce_error_is_one_json_line(tmp_path):
    V, F, W, T = strip()
    rc, lines, _ = run_worker(tmp_path, "reduce", request(V, F, W[:-1], T, k=np.int64(2),
                                                           n_vertices=np.int64(len(V))))
    assert rc == 2
    assert len(lines) >= 1 and "error" in lines[-1] and "\n" not in lines[-1]["error"]


def test_lod_levels_keep_uvs_and_bone_limit(tmp_path):
    V, F, W, T = strip(rings=16)
    L = np.arange(F.size, dtype=np.int64).reshape(F.shape)            # one loop per triangle corner
    uv = np.c_[V[:, 0], V[:, 2] / 4.0][F.ravel()]                      # a continuous UV map: one chart
    keys = np.unique(uv, axis=0, return_inverse=True)[1].reshape(F.shape)
    req = request(V, F, W, T, L=L, n_loops=np.int64(F.size), loop_values=uv, corner_keys=keys.astype(np.int64),
                  ratios=np.array([0.5, 0.25]), max_bones=np.int64(2), extra_params=np.str_("{}"))
    rc, lines, res = run_worker(tmp_path, "lod", req)
    assert rc == 0, lines
    assert int(res["n_levels"]) == 2
    direct = rigslim.simplify((V, F), W, T, targets=[0.5, 0.25], max_bones=2)   # the strip is mostly boundary,
    for i, level in enumerate(direct.levels):                                    # kept: the library decides
        faces, Vl = res[f"l{i}_faces"], res[f"l{i}_V"]
        assert len(faces) == level.n_faces and len(Vl) == level.n_vertices
        np.testing.assert_allclose(Vl, level.mesh.V)
        assert faces.max() < len(Vl)
        assert ((res[f"l{i}_weights"] > 0).sum(axis=1) <= 2).all()
        np.testing.assert_allclose(res[f"l{i}_weights"].sum(axis=1), 1.0, atol=1e-9)
        # the UV map is the linear function (x, z / 4) of the rest position: resampled corners keep it
        values = res[f"l{i}_values"]
        corners = Vl[faces]
        np.testing.assert_allclose(values[..., 0], corners[..., 0], atol=1e-9)
        np.testing.assert_allclose(values[..., 1], corners[..., 2] / 4.0, atol=1e-9)
        assert np.isin(res[f"l{i}_source"], np.arange(len(F))).all()


def test_seam_free_pairs_stop_at_seams():
    F = np.array([[0, 1, 2], [2, 1, 3], [2, 3, 4]])
    same = np.zeros((3, 3), np.int64)
    assert _pairs(worker.seam_free_pairs(F, same)) == {(0, 1), (1, 2)}
    seam = same.copy()
    seam[2] = [5, 6, 7]                                                 # the third triangle's corners differ
    assert _pairs(worker.seam_free_pairs(F, seam)) == {(0, 1)}


def _pairs(fab) -> set[tuple[int, int]]:
    return {(min(int(a), int(b)), max(int(a), int(b))) for a, b in zip(*fab, strict=True)}


def test_version_reports_defaults_and_decimator_parameters():
    info = runner.check(sys.executable)
    assert info["version"] == rigslim.__version__
    assert info["simplify_method"] == "quartic"
    assert {"max_bones", "targets", "max_error"} <= set(info["decimator_parameters"])


def test_find_python(tmp_path, monkeypatch):
    monkeypatch.delenv("RIGSLIM_PYTHON", raising=False)
    monkeypatch.setenv("PATH", str(tmp_path))
    with pytest.raises(runner.RunnerError) as err:
        runner.find_python("")
    msg = str(err.value)
    assert "\n" not in msg and "rigslim Python" in msg and "RIGSLIM_PYTHON" in msg
    with pytest.raises(runner.RunnerError, match="is not a program"):
        runner.find_python(str(tmp_path / "nothing"))
    script = tmp_path / "rigslim"
    script.write_text(f"#!{sys.executable}\nprint('hi')\n")
    script.chmod(script.stat().st_mode | stat.S_IXUSR)
    assert runner.find_python("") == (sys.executable, f"the rigslim command ({script})")
    assert runner.find_python(str(script))[0] == sys.executable
    monkeypatch.setenv("RIGSLIM_PYTHON", sys.executable)
    assert runner.find_python("") == (sys.executable, "RIGSLIM_PYTHON")


def test_check_names_a_python_without_rigslim(tmp_path):
    fake = tmp_path / "python"
    fake.write_text("#!/bin/sh\necho 'no module named rigslim' >&2\nexit 1\n")
    fake.chmod(0o755)
    with pytest.raises(runner.RunnerError) as err:
        runner.check(str(fake))
    assert "no module named rigslim" in str(err.value) and "\n" not in str(err.value)


def test_manifest_checks():
    import tomllib

    good = tomllib.loads((PKG / "blender_manifest.toml").read_text())
    assert build.manifest_problems(good) == []
    bad = dict(good, tagline="A tagline that ends with a full stop.", id="9lives", license=["MIT"])
    problems = " ".join(build.manifest_problems(bad))
    assert "tagline" in problems and "id" in problems and "license" in problems
    assert build.manifest_problems({k: v for k, v in good.items() if k != "version"}) == ["version: missing"]
    assert build.manifest_problems(dict(good, permissions={"files": "x" * 70})) != []


def test_build_writes_the_zip(tmp_path):
    proc = subprocess.run([sys.executable, str(ROOT / "integrations/blender/build.py"), "--output", str(tmp_path),
                           "--blender-ext", os.devnull + "-none"], capture_output=True, text=True)
    # a validator path that does not exist is a one-line error and no zip
    assert proc.returncode == 2 and not list(tmp_path.glob("*.zip"))
    assert len(proc.stderr.strip().splitlines()) == 1
