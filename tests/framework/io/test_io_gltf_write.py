"""glTF writer: quantised weights, round trips, preserved content, levels, export from libigl data.

Every file written here goes through Khronos's glTF-Validator (installed by
tools/setup-gltf-validator.sh; `make test` runs it) and must have no errors.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.sparse as sp
from scipy.spatial.transform import Rotation
from support.gltf_validator import validate_gltf, validation_errors, validator_available

from rigslim.errors import InputError, StepError
from rigslim.io.gltf.document import load_gltf, read_accessor
from rigslim.io.gltf.skin import read_gltf_skin, skinning_sets
from rigslim.io.gltf.write import export_skinned, quantize_weights, skinning_sets_arrays, write_gltf
from rigslim.io.transforms import matrix_quaternion
from rigslim.model.poses import Poses
from rigslim.model.weights import ReducedWeights
from rigslim.numerics.blend import linear_blend

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"


@pytest.fixture(scope="module")
def valid():
    """``valid(path)``: assert the Khronos validator reports no error; return the report."""
    if not validator_available():
        pytest.fail("glTF-Validator missing: run tools/setup-gltf-validator.sh (make test-tools)")

    def check(path):
        report = validate_gltf(path)
        errors = validation_errors(report)
        assert not errors, f"{path}: {errors[:5]}"
        return report

    return check


def _k_largest(W: sp.csr_matrix, k: int) -> ReducedWeights:
    A = W.toarray()
    idx = np.argsort(-A, axis=1, kind="stable")[:, :k]
    val = np.take_along_axis(A, idx, 1)
    val /= val.sum(axis=1, keepdims=True)
    return ReducedWeights(idx, val, W.shape[1])


# ------------------------------------------------------------------ quantisation


@pytest.mark.parametrize("kind, scale", [("ubyte", 255), ("ushort", 65535)])
def test_quantized_rows_sum_exactly_to_one(rng, kind, scale):
    W = rng.dirichlet(np.ones(8) * 0.3, size=2000)
    Q = quantize_weights(W, kind)
    assert Q.dtype == {"ubyte": np.uint8, "ushort": np.uint16}[kind]
    np.testing.assert_array_equal(Q.astype(np.int64).sum(axis=1), scale)
    # every weight but the largest is the nearest code; the largest absorbs the rounding
    top = np.argmax(W, axis=1)
    err = np.abs(Q / scale - W)
    err[np.arange(len(W)), top] = 0
    assert err.max() <= 0.5 / scale + 1e-12
    assert np.abs(Q[np.arange(len(W)), top] / scale - W[np.arange(len(W)), top]).max() <= 3.5 / scale


def test_float_rows_sum_to_one_within_an_ulp(rng):
    W = rng.dirichlet(np.ones(4), size=5000)
    Q = quantize_weights(W, "float")
    assert Q.dtype == np.float32
    assert np.abs(Q.astype(np.float64).sum(axis=1) - 1).max() <= 2.4e-7
    np.testing.assert_allclose(Q, W, atol=3e-7)


def test_quantize_rejects_negative_and_empty_rows():
    with pytest.raises(StepError, match="nonnegative"):
        quantize_weights(np.array([[1.2, -0.2]]), "ubyte")
    with pytest.raises(StepError, match="no weight"):
        quantize_weights(np.array([[0.0, 0.0]]), "float")


def test_sets_of_four_sorted_with_zero_padding():
    idx = np.array([[3, 1, 4, 1, 5, 9], [2, 6, 5, 3, 5, 8]])
    val = np.array([[0.1, 0.3, 0.05, 0.0, 0.25, 0.3], [1.0, 0, 0, 0, 0, 0]])
    sets = skinning_sets_arrays(idx, val, "float")
    assert len(sets) == 2
    J = np.concatenate([s[0] for s in sets], 1)
    W = np.concatenate([s[1] for s in sets], 1)
    np.testing.assert_array_equal(J[0, :5], [1, 9, 5, 3, 4])   # stable order for the tie 0.3/0.3
    np.testing.assert_allclose(W[0, :5], [0.3, 0.3, 0.25, 0.1, 0.05])
    np.testing.assert_array_equal(J[0, 5:], 0)                   # zero weights point at joint 0
    np.testing.assert_array_equal(J[1], [2, 0, 0, 0, 0, 0, 0, 0])
    assert len(skinning_sets_arrays(idx[:, :4], val[:, :4] / val[:, :4].sum(1, keepdims=True))) == 1
    with pytest.raises(StepError):
        skinning_sets_arrays(idx, val, "float", n_sets=1)


def test_matrix_quaternion_matches_scipy(rng):
    R = Rotation.random(200, random_state=1).as_matrix()
    q = matrix_quaternion(R)
    np.testing.assert_allclose(Rotation.from_quat(q).as_matrix(), R, atol=1e-12)
    assert (q[:, 3] >= 0).all()
    np.testing.assert_allclose(matrix_quaternion(np.diag([1.0, -1.0, -1.0])), [1, 0, 0, 0], atol=1e-12)


# ------------------------------------------------------------------ round trips on files from other tools


def _canonical(doc, drop_skinning: bool):
    """The document with every accessor reference replaced by its decoded content (layout-free form)."""
    js = json.loads(json.dumps(doc.json))

    def acc(i):
        a = doc.json["accessors"][i]
        meta = {k: v for k, v in a.items() if k not in ("bufferView", "byteOffset", "sparse")}
        return {"meta": meta, "data": read_accessor(doc, i, normalize=False).tolist()}

    for mesh in js.get("meshes", []):
        for prim in mesh["primitives"]:
            attrs = prim["attributes"]
            if drop_skinning:
                for s in skinning_sets(attrs):
                    del attrs[f"JOINTS_{s}"], attrs[f"WEIGHTS_{s}"]
            prim["attributes"] = {k: acc(v) for k, v in attrs.items()}
            if "indices" in prim:
                prim["indices"] = acc(prim["indices"])
            prim["targets"] = [{k: acc(v) for k, v in t.items()} for t in prim.get("targets", [])]
    for skin in js.get("skins", []):
        if "inverseBindMatrices" in skin:
            skin["inverseBindMatrices"] = acc(skin["inverseBindMatrices"])
    for anim in js.get("animations", []):
        for s in anim["samplers"]:
            s["input"], s["output"] = acc(s["input"]), acc(s["output"])
    for i, img in enumerate(js.get("images", [])):
        data = (doc.buffer_view_bytes(img["bufferView"]) if "bufferView" in img
                else doc.uri_bytes(img["uri"], f"images[{i}]"))
        js["images"][i] = {"name": img.get("name"), "bytes": data.hex()}
    for key in ("accessors", "bufferViews", "buffers"):
        js.pop(key, None)
    return js


@pytest.mark.parametrize("suffix", [".glb", ".gltf"])
def test_unchanged_round_trip_gives_the_same_arrays(tmp_path, valid, suffix):
    src = read_gltf_skin(GLTF / "simple_skin.gltf")
    out = tmp_path / f"again{suffix}"
    write_gltf(out, src)
    valid(out)
    if suffix == ".gltf":
        assert (tmp_path / "again.bin").exists()
    back = read_gltf_skin(out)
    np.testing.assert_array_equal(back.mesh.V, src.mesh.V)
    np.testing.assert_array_equal(back.mesh.F, src.mesh.F)
    assert (back.weights != src.weights).nnz == 0
    np.testing.assert_array_equal(back.poses.T, src.poses.T)
    assert _canonical(back.document, False) == _canonical(src.document, False)


@pytest.mark.parametrize("name", ["huesitos.glb", "animation_with_skeleton.glb"])
@pytest.mark.parametrize("quantize", ["float", "ubyte"])
def test_reduction_keeps_every_other_part(tmp_path, valid, name, quantize):
    """assimp's files fail validation (non-normalised weights); the reduced rewrite passes and keeps the rest."""
    src = read_gltf_skin(GLTF / name)
    assert validation_errors(validate_gltf(GLTF / name))        # the original has errors
    reduced = _k_largest(src.weights, 2)
    out = tmp_path / f"reduced{Path(name).suffix}"
    write_gltf(out, src, reduced, quantize=quantize)
    valid(out)
    back = read_gltf_skin(out)
    assert _canonical(back.document, True) == _canonical(src.document, True)
    np.testing.assert_array_equal(back.mesh.V, src.mesh.V)
    np.testing.assert_array_equal(back.poses.T, src.poses.T)
    tol = 1e-7 if quantize == "float" else 2.0 / 255
    assert abs(back.weights - reduced.to_sparse()).max() <= tol
    assert np.diff(back.weights.indptr).max() <= 2
    prim = back.document.json["meshes"][0]["primitives"][0]["attributes"]
    assert skinning_sets(prim) == [0]
    # no orphaned skinning data is left in the file
    assert len(back.document.json["accessors"]) == len(src.document.json["accessors"])


@pytest.mark.parametrize("quantize", ["ushort", "float"])
def test_six_influences_use_two_sets(tmp_path, valid, quantize):
    src = read_gltf_skin(GLTF / "huesitos.glb")
    n = src.handles.n
    m = src.mesh.n_vertices
    rng = np.random.default_rng(3)
    idx = np.array([rng.choice(n, 6, replace=False) for _ in range(m)])
    val = rng.dirichlet(np.ones(6), size=m)
    out = tmp_path / "six.gltf"
    write_gltf(out, src, ReducedWeights(idx, val, n), quantize=quantize, embed=True)
    assert not (tmp_path / "six.bin").exists()
    valid(out)
    back = read_gltf_skin(out)
    assert skinning_sets(back.document.json["meshes"][0]["primitives"][0]["attributes"]) == [0, 1]
    tol = 1e-7 if quantize == "float" else 4 / 65535
    assert abs(back.weights - ReducedWeights(idx, val, n).to_sparse()).max() <= tol


def _k8_at_most(src, wide_rows=()) -> ReducedWeights:
    """k = 8 rows of ``src``'s joints with 4 distinct non-zero weights each (the other 4 slots zero), and 5 in
    ``wide_rows``."""
    n, m = src.handles.n, src.mesh.n_vertices
    rng = np.random.default_rng(5)
    idx = np.array([rng.choice(n, 8, replace=False) for _ in range(m)])
    val = np.zeros((m, 8))
    val[:, :4] = rng.dirichlet(np.ones(4), size=m)
    for v in wide_rows:
        val[v, :5] = rng.dirichlet(np.ones(5))
    return ReducedWeights(idx, val, n)


def test_sets_count_the_widest_vertex_not_k():
    """k = 8 slots with at most 4 non-zero weights are one set (no WEIGHTS_1 of zeros); a row of 5 makes two."""
    idx = np.tile(np.arange(8), (3, 1))
    val = np.zeros((3, 8))
    val[:, [1, 3, 5, 6]] = 0.25
    for kind in ("float", "ushort", "ubyte"):
        sets = skinning_sets_arrays(idx, val, kind)
        assert len(sets) == 1 and (sets[0][1] != 0).all()
    val[2, [1, 3, 5, 6, 7]] = 0.2
    assert len(skinning_sets_arrays(idx, val, "float")) == 2
    assert len(skinning_sets_arrays(idx, np.zeros((3, 8)) + np.eye(8)[:3], "float", n_sets=2)) == 2   # forced
    tiny = np.zeros((1, 8))
    tiny[0, :5] = [0.6, 0.2, 0.1, 0.099, 0.001]     # the fifth is below half a ubyte code: one set in ubyte
    assert len(skinning_sets_arrays(np.arange(8)[None], tiny, "ubyte")) == 1
    assert len(skinning_sets_arrays(np.arange(8)[None], tiny, "ushort")) == 2


@pytest.mark.parametrize("quantize", ["float", "ubyte"])
def test_k8_writes_only_the_sets_the_widest_vertex_needs(tmp_path, valid, quantize):
    src = read_gltf_skin(GLTF / "huesitos.glb")
    out = tmp_path / "k8.glb"
    stats = write_gltf(out, src, _k8_at_most(src), quantize=quantize)
    valid(out)
    assert stats["sets"] == 1
    assert skinning_sets(load_gltf(out).json["meshes"][0]["primitives"][0]["attributes"]) == [0]
    assert np.diff(read_gltf_skin(out).weights.indptr).max() == 4
    wide = _k8_at_most(src, wide_rows=[17])
    stats = write_gltf(out, src, wide, quantize=quantize)
    valid(out)
    assert stats["sets"] == 2
    back = read_gltf_skin(out)
    assert skinning_sets(back.document.json["meshes"][0]["primitives"][0]["attributes"]) == [0, 1]
    tol = 1e-7 if quantize == "float" else 2.0 / 255
    assert abs(back.weights - wide.to_sparse()).max() <= tol


def test_k8_rows_kept_exact_from_the_source_write_one_set(tmp_path, valid):
    """The lossless path (rows equal to the file's keep its bytes) trims the empty sets too."""
    src = read_gltf_skin(GLTF / "simple_skin.gltf")
    A = src.weights.toarray()                       # 2 joints, at most 2 weights per vertex
    idx = np.tile(np.arange(8) % 2, (len(A), 1))
    val = np.zeros((len(A), 8))
    val[:, :2] = A
    out = tmp_path / "k8.gltf"
    stats = write_gltf(out, src, ReducedWeights(idx, val, 2))
    valid(out)
    assert stats["vertices_kept_exact"] == len(A) and stats["sets"] == 1
    back = read_gltf_skin(out)
    assert skinning_sets(back.document.json["meshes"][0]["primitives"][0]["attributes"]) == [0]
    assert (back.weights != src.weights).nnz == 0


def test_merged_meshes_are_split_back(tmp_path, valid):
    """Two meshes with the same skin are read as one; the writer gives each its own rows back."""
    doc = load_gltf(GLTF / "huesitos.glb")
    js = json.loads(json.dumps(doc.json))
    js["meshes"].append(json.loads(json.dumps(js["meshes"][0])) | {"name": "copy"})
    skinned = next(i for i, n in enumerate(js["nodes"]) if "skin" in n)
    js["nodes"].append({"name": "copy", "mesh": 1, "skin": js["nodes"][skinned]["skin"]})
    js["scenes"][js.get("scene", 0)]["nodes"].append(len(js["nodes"]) - 1)
    from rigslim.io.gltf.write import _write_document

    two = tmp_path / "two.glb"
    _write_document(two, js, doc.buffers[0])
    src = read_gltf_skin(two)
    assert src.mesh.n_vertices == 256 and [s.mesh for s in src.slices] == [0, 1]
    m = 128
    idx = np.zeros((2 * m, 1), int)
    idx[m:] = 3                                              # second copy: everything on joint 3
    out = tmp_path / "split.glb"
    write_gltf(out, src, ReducedWeights(idx, np.ones((2 * m, 1)), src.handles.n), quantize="ubyte")
    valid(out)
    back = read_gltf_skin(out)
    np.testing.assert_array_equal(back.weights.toarray()[:m, 0], 1.0)
    np.testing.assert_array_equal(back.weights.toarray()[m:, 3], 1.0)
    only_second = read_gltf_skin(out, mesh="copy")
    assert only_second.mesh.n_vertices == m
    np.testing.assert_array_equal(only_second.weights.toarray()[:, 3], 1.0)


def test_writer_rejects_mismatched_weights(tmp_path):
    src = read_gltf_skin(GLTF / "simple_skin.gltf")
    with pytest.raises(StepError, match="rows"):
        write_gltf(tmp_path / "x.glb", src, ReducedWeights(np.zeros((3, 1)), np.ones((3, 1)), 2))
    with pytest.raises(StepError, match="nonnegative"):
        write_gltf(tmp_path / "x.glb", src, ReducedWeights(np.tile([0, 1], (10, 1)), np.tile([1.5, -0.5], (10, 1)), 2))
    assert not (tmp_path / "x.glb").exists()


# ------------------------------------------------------------------ simplified levels


def _levels(src):
    from rigslim.model.hierarchy import SimplifiedLevel

    mesh = src.mesh
    half = type(mesh)(mesh.V, mesh.F[: len(mesh.F) // 2], source="half")
    red = _k_largest(src.weights, 2)
    one = _k_largest(src.weights, 1)
    return [SimplifiedLevel(mesh, red, "full-k2"), SimplifiedLevel(half, one, "half-k1")]


@pytest.mark.parametrize("lod", [False, True])
def test_levels_as_meshes_of_their_own(tmp_path, valid, lod):
    src = read_gltf_skin(GLTF / "huesitos.glb")
    levels = _levels(src)
    out = tmp_path / "levels.glb"
    write_gltf(out, src, levels[0].weights, quantize="ubyte", levels=levels, lod=lod)
    valid(out)
    doc = load_gltf(out)
    names = [m.get("name") for m in doc.json["meshes"]]
    assert names[-2:] == ["full-k2", "half-k1"]
    for level in levels:
        back = read_gltf_skin(out, mesh=level.label)
        np.testing.assert_allclose(back.mesh.V, level.mesh.V, atol=1e-5)
        np.testing.assert_array_equal(back.mesh.F, level.mesh.F)
        assert abs(back.weights - level.weights.to_sparse()).max() <= 2 / 255
    skinned = [n for n in doc.json["nodes"] if n.get("mesh") == 0]
    if lod:
        assert "MSFT_lod" in doc.json["extensionsUsed"]
        ids = skinned[0]["extensions"]["MSFT_lod"]["ids"]
        assert [doc.json["nodes"][i]["name"] for i in ids] == ["full-k2", "half-k1"]
        assert len(skinned[0]["extras"]["MSFT_screencoverage"]) == 3
    else:
        assert [s.get("name") for s in doc.json["scenes"][-2:]] == ["full-k2", "half-k1"]


# ------------------------------------------------------------------ export from libigl-style data


@pytest.fixture(scope="module")
def elephant_small():
    from rigslim.io import read_dmat, read_mesh, read_stacked_animation, read_tgf
    from rigslim.model.weights import validate_weights

    data = Path(__file__).resolve().parents[3] / "examples" / "data"
    mesh = read_mesh(data / "elephant.obj")
    handles = read_tgf(data / "elephant.tgf")
    W = validate_weights(read_dmat(data / "elephant-weights.dmat"), mesh.n_vertices, n_handles=handles.n)
    P = read_stacked_animation(data / "elephant-anim.dmat", n_handles=handles.n)
    frames = np.arange(0, len(P), 23)
    return mesh, handles, W, Poses(P.T[frames], np.arange(len(frames)))


def test_export_elephant_reproduces_libigl_skinning(tmp_path, valid, elephant_small):
    mesh, handles, W, P = elephant_small
    out = tmp_path / "elephant.glb"
    export_skinned(out, mesh, handles, W, P, fps=10)
    valid(out)
    back = read_gltf_skin(out, fps=10)
    assert len(back.poses) == len(P)
    assert np.diff(back.weights.indptr).max() == np.diff(W.indptr).max()   # all (up to 23) influences kept
    assert abs(back.weights - W).max() < 1e-7
    scale = mesh.bbox_diagonal
    for f in range(len(P)):
        np.testing.assert_allclose(back.poses.T[f, :, :, :3], P.T[f, :, :, :3], atol=2e-6)
        np.testing.assert_allclose(back.poses.T[f, :, :, 3], P.T[f, :, :, 3], atol=2e-6 * scale)
        X0 = linear_blend(mesh.V, W, P.T[f])
        X1 = linear_blend(back.mesh.V, back.weights, back.poses.T[f])
        assert np.abs(X1 - X0).max() < 1e-6 * scale


def test_export_writes_scaled_joints_as_scale_channels(tmp_path, valid, elephant_small):
    """A rig scaled uniformly (assimp's x100 armatures, written to USD and back) or one joint scaled along its
    own axes (a leaf: a parent's non-uniform scale would shear its children, which TRS cannot hold): translation,
    rotation and scale channels reproduce the deformation (once refused as non-rigid)."""
    mesh, handles, W, P = elephant_small
    T = P.T[:3].copy()
    T[1] *= 2.0                                                 # the whole rig at twice the size in frame 1
    T[2, 5, :, :3] = T[2, 5, :, :3] @ np.diag([1.0, 1.5, 1.0])  # leaf bone 5 stretched along its local y
    out = tmp_path / "scaled.glb"
    export_skinned(out, mesh, handles, W, Poses(T), fps=10)
    valid(out)
    paths = {c["target"]["path"] for c in load_gltf(out).json["animations"][0]["channels"]}
    assert paths == {"translation", "rotation", "scale"}
    back = read_gltf_skin(out, fps=10)
    scale = mesh.bbox_diagonal
    for f in range(3):
        X0 = linear_blend(mesh.V, W, T[f])
        X1 = linear_blend(back.mesh.V, back.weights, back.poses.T[f])
        assert np.abs(X1 - X0).max() < 1e-5 * scale, f


def test_export_writes_extra_named_clips_each_with_its_frames(tmp_path, valid, elephant_small):
    """``clips`` adds one animation per named clip after ``poses``' (its own frame count, its own poses);
    without it the file has the one animation it always had."""
    mesh, handles, W, P = elephant_small
    walk, turn = Poses(P.T[2:5]), Poses(P.T[::-1].copy())
    out = tmp_path / "clips.glb"
    export_skinned(out, mesh, handles, W, P, fps=10, animation_name="Idle", clips=[("Walk", walk), ("Turn", turn)])
    valid(out)
    assert [a["name"] for a in load_gltf(out).json["animations"]] == ["Idle", "Walk", "Turn"]
    scale = mesh.bbox_diagonal
    for i, clip in enumerate((P, walk, turn)):
        back = read_gltf_skin(out, animation=i, fps=10)
        assert len(back.poses) == len(clip), i
        for f in range(len(clip)):
            X0 = linear_blend(mesh.V, W, clip.T[f])
            X1 = linear_blend(back.mesh.V, back.weights, back.poses.T[f])
            assert np.abs(X1 - X0).max() < 1e-6 * scale, (i, f)
    one = tmp_path / "one.glb"
    export_skinned(one, mesh, handles, W, P, fps=10)
    assert [a["name"] for a in load_gltf(one).json["animations"]] == ["animation"]


def test_export_rejects_sheared_or_mirrored_bones(tmp_path, elephant_small):
    mesh, handles, W, P = elephant_small
    T = P.T[:2].copy()
    T[1, 3, :, :3] = T[1, 3, :, :3] @ np.array([[1.0, 0.4, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]])   # a shear
    with pytest.raises(InputError, match="it shears"):
        export_skinned(tmp_path / "bad.glb", mesh, handles, W, Poses(T))
    T[1, 3, :, :3] = np.diag([-1.0, 1.0, 1.0])                                                     # a mirror
    with pytest.raises(InputError, match="mirrors"):
        export_skinned(tmp_path / "bad.glb", mesh, handles, W, Poses(T))
    assert not (tmp_path / "bad.glb").exists()


def _png_1x1() -> bytes:
    import struct
    import zlib

    def chunk(kind, data):
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)

    return (b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", struct.pack(">IIBBBBB", 1, 1, 8, 2, 0, 0, 0))
            + chunk(b"IDAT", zlib.compress(b"\x00\xff\x80\x00")) + chunk(b"IEND", b""))


def test_external_image_is_embedded_when_written_elsewhere(tmp_path, valid):
    doc = load_gltf(GLTF / "huesitos.glb")
    js = json.loads(json.dumps(doc.json))
    js["images"] = [{"uri": "skin%20tex.png", "name": "skin"}]
    js["samplers"] = [{"magFilter": 9729}]
    js["textures"] = [{"source": 0, "sampler": 0}]
    js["materials"][0].setdefault("pbrMetallicRoughness", {})["baseColorTexture"] = {"index": 0, "texCoord": 0}
    js["materials"][0]["extras"] = {"kept": [1, 2, 3]}
    src_dir = tmp_path / "src"
    src_dir.mkdir()
    (src_dir / "skin tex.png").write_bytes(_png_1x1())
    from rigslim.io.gltf.write import _write_document

    _write_document(src_dir / "textured.glb", js, doc.buffers[0])
    src = read_gltf_skin(src_dir / "textured.glb")
    out = tmp_path / "elsewhere" / "textured.glb"
    write_gltf(out, src, _k_largest(src.weights, 3), quantize="ushort")
    valid(out)
    back = load_gltf(out)
    img = back.json["images"][0]
    assert "uri" not in img and img["mimeType"] == "image/png"
    assert back.buffer_view_bytes(img["bufferView"]) == _png_1x1()
    assert back.json["materials"] == js["materials"] and back.json["textures"] == js["textures"]
    assert _canonical(back, True) == _canonical(src.document, True)


def test_images_glTF_cannot_embed_or_that_are_missing_stay_links(tmp_path):
    """A .tga (no glTF MIME type) is linked from the output's folder instead of being embedded as
    application/octet-stream (TEXTURE_INVALID_IMAGE_MIME_TYPE); a missing image is linked where the source
    linked it instead of failing after the whole run; a URL stays as it is; a PNG is still embedded."""
    doc = load_gltf(GLTF / "huesitos.glb")
    js = json.loads(json.dumps(doc.json))
    js["images"] = [{"uri": "skin.tga"}, {"uri": "gone%20away.png"}, {"uri": "https://example.org/t.png"},
                    {"uri": "tex/ok.png"}]
    src_dir = tmp_path / "src"
    (src_dir / "tex").mkdir(parents=True)
    (src_dir / "skin.tga").write_bytes(b"\x00\x00\x02" + bytes(15))
    (src_dir / "tex" / "ok.png").write_bytes(_png_1x1())
    from rigslim.io.gltf.write import _write_document

    _write_document(src_dir / "textured.glb", js, doc.buffers[0])
    src = read_gltf_skin(src_dir / "textured.glb")
    out = tmp_path / "out" / "deeper" / "textured.glb"
    write_gltf(out, src, _k_largest(src.weights, 3), quantize="ushort")
    imgs = load_gltf(out).json["images"]
    assert imgs[0] == {"uri": "../../src/skin.tga"} and (out.parent / imgs[0]["uri"]).resolve().is_file()
    assert imgs[1] == {"uri": "../../src/gone%20away.png"}
    assert imgs[2] == {"uri": "https://example.org/t.png"}
    assert "uri" not in imgs[3] and imgs[3]["mimeType"] == "image/png"


def test_welded_reduction_is_written_on_every_file_vertex(tmp_path, valid):
    src = read_gltf_skin(GLTF / "animation_with_skeleton.glb", weld=True)
    reduced = _k_largest(src.weights, 3)
    out = tmp_path / "welded.glb"
    write_gltf(out, src, reduced, quantize="ushort")
    valid(out)
    back = read_gltf_skin(out)                      # not welded: one row per file vertex
    assert back.mesh.n_vertices == len(src.vertex_map)
    expected = reduced.to_sparse()[src.vertex_map]
    assert abs(back.weights - expected).max() <= 2 / 65535
    # seam copies of one position carry identical weights: no cracks when the mesh moves
    X = linear_blend(back.mesh.V, back.weights, back.poses.T[10])
    for g in np.flatnonzero(np.bincount(src.vertex_map) > 1)[:50]:
        copies = np.flatnonzero(src.vertex_map == g)
        assert np.ptp(X[copies], axis=0).max() < 1e-9 * np.abs(X).max()


def test_clamp_negative_weights(tmp_path, valid):
    from rigslim.io.gltf.write import clamp_negative_weights

    W, stats = clamp_negative_weights(np.array([[1.2, -0.2, 0.0], [0.5, 0.5, 0.0]]))
    np.testing.assert_allclose(W, [[1.0, 0.0, 0.0], [0.5, 0.5, 0.0]])
    assert stats == {"clamped_vertices": 1, "most_negative": -0.2}
    src = read_gltf_skin(GLTF / "simple_skin.gltf")
    red = ReducedWeights(np.tile([0, 1], (10, 1)), np.tile([0.9, 0.1], (10, 1)), 2)
    vals = red.values.copy()
    vals[3] = [1.25, -0.25]
    stats = write_gltf(tmp_path / "c.glb", src, ReducedWeights(red.indices, vals, 2), quantize="ubyte",
                       clamp_negative=True)
    assert stats["clamped_vertices"] == 1 and stats["most_negative"] == -0.25
    valid(tmp_path / "c.glb")
    np.testing.assert_allclose(read_gltf_skin(tmp_path / "c.glb").weights.toarray()[3], [1, 0])


def test_threejs_plays_the_exported_elephant_like_libigl(tmp_path, valid, elephant_small):
    """A viewer's view: three.js's GLTFLoader and skinning give the libigl deformation of k = 4 weights."""
    from support.gltf_validator import threejs_available, threejs_skinned_positions

    if not threejs_available():
        pytest.fail("three.js missing: run tools/setup-gltf-validator.sh (make test-tools)")
    mesh, handles, W, P = elephant_small
    reduced = _k_largest(W, 4)
    out = tmp_path / "elephant-k4.glb"
    export_skinned(out, mesh, handles, reduced, P, fps=10, quantize="ubyte")
    valid(out)
    back = read_gltf_skin(out, fps=10)
    frames = [0, 5, len(P) - 1]
    three = threejs_skinned_positions(out, [f / 10 for f in frames])
    assert len(three) == 1 and three[0]["bones"] == handles.n
    for j, f in enumerate(frames):
        ours = linear_blend(back.mesh.V, back.weights, back.poses.T[f])
        libigl = linear_blend(mesh.V, reduced.to_sparse(), P.T[f])
        scale = np.abs(libigl).max()
        assert np.abs(three[0]["positions"][j] - ours).max() < 1e-6 * scale
        # ubyte weights move vertices from the float reduction by < 0.06 % of the diagonal (measured, all frames)
        assert np.linalg.norm(three[0]["positions"][j] - libigl, axis=1).max() < 1e-3 * mesh.bbox_diagonal


@pytest.mark.parametrize("lod", [False, True])
def test_export_with_levels(tmp_path, valid, elephant_small, lod):
    from rigslim.model.hierarchy import SimplifiedLevel
    from rigslim.model.mesh import Mesh

    mesh, handles, W, P = elephant_small
    reduced = _k_largest(W, 4)
    keep = np.unique(mesh.F[::4])                      # a coarse level: every 4th face, its vertices renumbered
    remap = -np.ones(mesh.n_vertices, int)
    remap[keep] = np.arange(len(keep))
    vals = reduced.values[keep].copy()
    vals[0] = [1.5, -0.5, 0, 0]                          # a negative weight, as [S09] levels may have
    level = SimplifiedLevel(Mesh(mesh.V[keep], remap[mesh.F[::4]]), ReducedWeights(reduced.indices[keep], vals, 24),
                            "quarter")
    out = tmp_path / "lod.glb"
    with pytest.raises(StepError, match="clamp_negative"):
        export_skinned(out, mesh, handles, reduced, P, levels=[level], lod=lod)
    stats = export_skinned(out, mesh, handles, reduced, P, levels=[level], lod=lod, clamp_negative=True,
                           quantize="ushort")
    assert stats == {"sets": 1, "clamped_vertices": 1, "most_negative": -0.5}
    valid(out)
    base = read_gltf_skin(out)
    assert base.mesh.n_vertices == mesh.n_vertices      # the default scene shows the full mesh only
    back = read_gltf_skin(out, mesh="quarter")
    np.testing.assert_array_equal(back.mesh.F, level.mesh.F)
    assert np.diff(back.weights.indptr).max() <= 4
    np.testing.assert_array_equal(back.weights.toarray()[0, reduced.indices[keep[0], 0]], 1.0)
    doc = load_gltf(out)
    assert ("MSFT_lod" in doc.json.get("extensionsUsed", [])) == lod
    assert len(doc.json["scenes"]) == (1 if lod else 2)


def _inverse_binds(doc, skin: int) -> np.ndarray:
    """(n, 4, 4) float32 inverse bind matrices as stored (column-major: ``[:, :, 3]`` is each last row)."""
    return np.asarray(read_accessor(doc, doc.json["skins"][skin]["inverseBindMatrices"]), np.float32).reshape(-1, 4, 4)


def test_a_rewrite_makes_the_inverse_binds_exactly_affine(tmp_path, valid):
    """re_drone.glb's inverse bind matrices end in rows like ``0.9999999`` (the validator's ACCESSOR_INVALID_IBM;
    the reader accepts them within 1e-6): a rewrite writes them with the row ``[0, 0, 0, 1]`` exactly, the other
    entries unchanged, so the output validates; the posed mesh is the same."""
    src = read_gltf_skin(GLTF / "suite" / "re_drone.glb")
    before = _inverse_binds(src.document, src.skin)
    assert not (before[:, :, 3] == [0, 0, 0, 1]).all()
    out = tmp_path / "drone.glb"
    write_gltf(out, src)
    back = read_gltf_skin(out)
    after = _inverse_binds(back.document, back.skin)
    assert (after[:, :, 3] == [0, 0, 0, 1]).all()
    np.testing.assert_array_equal(after[:, :, :3], before[:, :, :3])
    for t in (0, len(src.poses) // 2):
        np.testing.assert_allclose(linear_blend(back.mesh.V, back.weights, back.poses.T[t]),
                                   linear_blend(src.mesh.V, src.weights, src.poses.T[t]), atol=1e-5)
    valid(out)
