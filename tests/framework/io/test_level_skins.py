"""Per-level skins (framework/io/gltf/level_skins.py): only the joints a level uses, JOINTS re-indexed.

One suite character (mrfixit: 75 joints, the IQM conversion that validates with no issue) simplified
to two levels with joint budgets, written twice from the same levels: with per-level skins and with
every level on the source skin. Both must pose identically in every frame, in rigslim's reader
(numpy) and in three.js.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from support.gltf_validator import threejs_available, threejs_skinned_positions, validate_gltf, validator_available

from rigslim.commands.compare import posed_surfaces
from rigslim.io.gltf.document import load_gltf, read_accessor
from rigslim.io.gltf.lod import lod_nodes
from rigslim.io.gltf.skin import skinning_sets
from rigslim.io.gltf.write import split_levels, write_gltf
from rigslim.runtime.run import run_pipeline

ROOT = Path(__file__).resolve().parents[3]
CHARACTER = ROOT / "examples" / "data" / "gltf" / "suite" / "mrfixit.glb"
BUDGETS = [30, 12]

pytestmark = pytest.mark.slow


@pytest.fixture(scope="module")
def lod(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("level_skins")
    doc = {"name": "level-skins", "inputs": {"gltf": {"path": str(CHARACTER)}},
           "poses": {"examples": "0:120:6", "test": "3:120:6"},
           "steps": [{"decimate": "quartic", "targets": [0.5, 0.2], "max_bones": 4, "joint_budget": BUDGETS},
                     {"write": str(tmp / "skins.glb"), "lod": True, "quantize": "float", "clamp_negative": True}]}
    result = run_pipeline(tmp / "p.yaml", raw=doc)
    asset = result.asset
    plain = tmp / "one-skin.glb"
    write_gltf(plain, asset.extras["gltf"], None, quantize="float", levels=asset.levels, lod=True,
               clamp_negative=True, hierarchy=asset.hierarchy, level_skins=False)
    return {"asset": asset, "skins": tmp / "skins.glb", "plain": plain, "tmp": tmp, "result": result}


def _level_nodes(js):
    (node, ids), = lod_nodes(js).items()
    return node, ids


def _weighted_local_joints(doc, mesh) -> set[int]:
    out = set()
    for prim in doc.json["meshes"][mesh]["primitives"]:
        attrs = prim["attributes"]
        for s in skinning_sets(attrs):
            J = np.asarray(read_accessor(doc, attrs[f"JOINTS_{s}"])).reshape(-1)
            W = np.asarray(read_accessor(doc, attrs[f"WEIGHTS_{s}"])).reshape(-1)
            out |= set(J[W > 0].tolist())
    return out


def test_each_level_skin_holds_exactly_the_joints_it_uses(lod):
    doc = load_gltf(lod["skins"])
    js = doc.json
    node, ids = _level_nodes(js)
    source = lod["asset"].extras["gltf"]
    assert js["nodes"][node]["skin"] == source.skin and len(js["skins"][source.skin]["joints"]) == 75
    for level, (nid, budget) in enumerate(zip(ids, BUDGETS, strict=True)):
        lv_node = js["nodes"][nid]
        skin = js["skins"][lv_node["skin"]]
        assert lv_node["skin"] != source.skin
        local = _weighted_local_joints(doc, lv_node["mesh"])
        assert local == set(range(len(skin["joints"])))           # every listed joint carries weight
        weights = lod["asset"].levels[level].weights
        used = np.unique(weights.indices[weights.values > 0])
        assert skin["joints"] == [source.joints[h] for h in used]  # exactly the level's joints, source order
        assert len(skin["joints"]) <= budget
        ibm = np.asarray(read_accessor(doc, skin["inverseBindMatrices"])).reshape(-1, 4, 4)
        assert len(ibm) == len(skin["joints"]) and np.array_equal(ibm[:, :, 3], np.tile([0, 0, 0, 1], (len(ibm), 1)))


def test_dropped_joints_stay_in_the_hierarchy_and_the_animation_is_unchanged(lod):
    src, out = load_gltf(CHARACTER).json, load_gltf(lod["skins"]).json
    n = len(src["nodes"])
    for a, b in zip(src["nodes"], out["nodes"][:n], strict=True):
        assert a.get("children") == b.get("children") and a.get("name") == b.get("name")
    assert [x["channels"] for x in src["animations"]] == [x["channels"] for x in out["animations"]]


def test_reindexed_levels_pose_like_the_source_skin_in_numpy(lod):
    times = np.arange(0, 4.0, 1 / 15)
    for level in (1, 2):
        P, F, _ = posed_surfaces(lod["skins"], clip=None, times=times, level=level)
        Q, G, _ = posed_surfaces(lod["plain"], clip=None, times=times, level=level)
        assert np.array_equal(F, G)
        diag = float(np.linalg.norm(Q[0].max(axis=0) - Q[0].min(axis=0)))
        assert np.abs(P - Q).max() <= 1e-6 * diag


def _untextured(path: Path) -> Path:
    """A copy without images (three.js under node has no image decoder); geometry and skin unchanged."""
    import copy

    from rigslim.io.gltf.write import write_pruned

    doc = load_gltf(path)
    js = copy.deepcopy(doc.json)
    for m in js.get("materials", []):
        for part in (m, m.get("pbrMetallicRoughness", {})):
            for key in [k for k in part if k.endswith("Texture")]:
                del part[key]
    for key in ("textures", "images", "samplers"):
        js.pop(key, None)
    out = path.with_name(path.stem + "-untextured.glb")
    write_pruned(out, doc, js)
    return out


@pytest.mark.skipif(not threejs_available(), reason="three.js missing (tools/setup-gltf-validator.sh)")
def test_reindexed_levels_pose_like_the_source_skin_in_threejs(lod):
    tmp = lod["tmp"]
    a = [tmp / "s-50.glb", tmp / "s-20.glb"]
    b = [tmp / "p-50.glb", tmp / "p-20.glb"]
    split_levels(lod["skins"], a)
    split_levels(lod["plain"], b)
    times = [0.0, 0.7, 1.9, 3.3]
    for x, y, budget in zip(a, b, BUDGETS, strict=True):
        mx, my = threejs_skinned_positions(_untextured(x), times), threejs_skinned_positions(_untextured(y), times)
        assert len(mx) == len(my) == 2                                 # one SkinnedMesh per primitive
        assert all(m["bones"] <= budget for m in mx) and all(m["bones"] == 75 for m in my)
        X = np.concatenate([m["positions"] for m in mx], axis=1)
        Y = np.concatenate([m["positions"] for m in my], axis=1)
        diag = float(np.linalg.norm(np.ptp(Y[0], axis=0)))
        assert np.abs(X - Y).max() <= 1e-5 * diag
        P, _, _ = posed_surfaces(x, clip=None, times=times)           # and three.js agrees with rigslim
        assert np.abs(P - X).max() <= 1e-5 * diag


@pytest.mark.skipif(not validator_available(), reason="glTF-Validator missing (tools/setup-gltf-validator.sh)")
def test_level_skins_validate(lod):
    tmp = lod["tmp"]
    files = [lod["skins"], tmp / "v-50.glb", tmp / "v-20.glb"]
    split_levels(lod["skins"], files[1:])
    for f in files:
        report = validate_gltf(f)
        assert report["issues"]["numErrors"] == 0, (f.name, report["issues"]["messages"][:5])
    assert len(load_gltf(files[2]).json["skins"]) == 1              # a level file carries only its own skin
