"""glTF reader: accessors, transforms, animation sampling, skins, real files written by other tools."""

from __future__ import annotations

import base64
import json
import struct
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from rigslim.errors import InputError, RigslimError
from rigslim.io.gltf.document import load_gltf, read_accessor
from rigslim.io.gltf.scene import sample_sampler
from rigslim.io.gltf.skin import read_gltf_skin
from rigslim.io.transforms import quaternion_matrix, slerp, trs_matrix
from rigslim.numerics.blend import linear_blend

GLTF = Path(__file__).resolve().parents[3] / "examples" / "data" / "gltf"


def _rot(q):
    return Rotation.from_quat(q).as_matrix()  # scipy uses (x, y, z, w) like glTF


def _h(R=None, t=(0, 0, 0)):
    M = np.eye(4)
    M[:3, :3] = np.eye(3) if R is None else R
    M[:3, 3] = t
    return M


# ------------------------------------------------------------------ a synthetic document with every feature


class _Builder:
    def __init__(self):
        self.data = bytearray()
        self.views, self.accessors = [], []

    def view(self, raw: bytes, stride=None):
        self.data += b"\0" * ((-len(self.data)) % 4)
        v = {"buffer": 0, "byteOffset": len(self.data), "byteLength": len(raw)}
        if stride:
            v["byteStride"] = stride
        self.data += raw
        self.views.append(v)
        return len(self.views) - 1

    def accessor(self, arr, ctype, type_, normalized=False, view=None, offset=0, count=None, **extra):
        if view is None:
            view = self.view(np.ascontiguousarray(arr).tobytes())
        acc = {"bufferView": view, "byteOffset": offset, "componentType": ctype,
               "count": count if count is not None else len(arr), "type": type_, **extra}
        if normalized:
            acc["normalized"] = True
        self.accessors.append(acc)
        return len(self.accessors) - 1


HIP = _h(_rot([0, 0, np.sin(0.2), np.cos(0.2)]), (0.1, 1.0, 0.0))       # node 1, given as a matrix
KNEE_T, KNEE_R = np.array([0.0, -0.5, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])
FOOT_T, FOOT_S = np.array([0.0, -0.4, 0.1]), np.array([1.0, 1.0, 1.0])
V4 = np.array([[0, 1, 0], [0.1, 0.5, 0], [0, 0.5, 0.1], [0, 0.1, 0]], np.float32)
W_EXPECTED = np.array([[1.0, 0, 0], [128 / 255, 127 / 255, 0], [0.2, 0, 0.8], [0, 0.3, 0.7]])


def _synthetic(tmp_path: Path, *, external=False, glb=False) -> Path:
    b = _Builder()
    # interleaved: position (12 bytes) + 4 padding bytes per vertex
    inter = np.zeros((4, 16), np.uint8)
    inter[:, :12] = V4.view(np.uint8).reshape(4, 12)
    pos = b.accessor(None, 5126, "VEC3", view=b.view(inter.tobytes(), stride=16), count=4,
                     min=V4.min(0).tolist(), max=V4.max(0).tolist())
    idx = b.accessor(np.array([0, 1, 2, 0, 2, 3], np.uint8), 5121, "SCALAR")
    j0 = b.accessor(np.array([[0, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 0], [2, 0, 0, 0]], np.uint8), 5121, "VEC4")
    w0 = b.accessor(np.array([[255, 0, 0, 0], [128, 127, 0, 0], [51, 0, 0, 0], [102, 0, 0, 0]], np.uint8),
                    5121, "VEC4", normalized=True)
    j1 = b.accessor(np.array([[0, 0, 0, 0], [0, 0, 0, 0], [2, 0, 0, 0], [1, 2, 0, 0]], np.uint16), 5123, "VEC4")
    w1 = b.accessor(np.array([[0, 0, 0, 0], [0, 0, 0, 0], [0.8, 0, 0, 0], [0.3, 0.3, 0, 0]], np.float32), 5126, "VEC4")
    # skin: inverse bind matrices = inverse rest world transforms, so the rest pose is the bind pose
    knee = _h(_rot(KNEE_R), KNEE_T)
    foot = _h(np.eye(3), FOOT_T)
    world = [HIP, HIP @ knee, HIP @ knee @ foot]
    ibm = np.array([np.linalg.inv(W).T.reshape(16) for W in world], np.float32)
    ibm_acc = b.accessor(ibm, 5126, "MAT4")
    # animation: STEP translation of the hip (matrix node -> must not be animated; animate knee/foot instead)
    t_in = b.accessor(np.array([0.0, 0.5, 1.0], np.float32), 5126, "SCALAR", min=[0.0], max=[1.0])
    step_out = b.accessor(np.array([[0, -0.5, 0], [0.2, -0.5, 0], [0.4, -0.5, 0]], np.float32), 5126, "VEC3")
    qa, qb, qc = _quat_z(0.0), _quat_z(0.6), _quat_z(1.2)
    spline = np.array([[0, 0, 0, 0], qa, [0, 0, 1.2, 0], [0, 0, 1.2, 0], qb, [0, 0, 1.2, 0],
                       [0, 0, 1.2, 0], qc, [0, 0, 0, 0]], np.float32)
    cubic_out = b.accessor(spline, 5126, "VEC4")
    scale_out = b.accessor(np.array([[1, 1, 1], [2, 1, 1], [1, 1, 1]], np.float32), 5126, "VEC3")
    # a sparse accessor (morph target): zeros with two substituted vertices
    sp_idx = b.view(np.array([1, 3], np.uint16).tobytes())
    sp_val = b.view(np.array([[0, 0.1, 0], [0, 0, 0.2]], np.float32).tobytes())
    target = len(b.accessors)
    b.accessors.append({"componentType": 5126, "count": 4, "type": "VEC3", "min": [0, 0, 0], "max": [0, 0.1, 0.2],
                        "sparse": {"count": 2, "indices": {"bufferView": sp_idx, "componentType": 5123},
                                   "values": {"bufferView": sp_val}}})
    js = {
        "asset": {"version": "2.0", "generator": "rigslim tests"},
        "scene": 0, "scenes": [{"nodes": [0, 1]}],
        "nodes": [
            {"name": "body", "mesh": 0, "skin": 0, "matrix": _h(np.eye(3), (5, 5, 5)).T.reshape(16).tolist()},
            {"name": "hip", "matrix": HIP.T.reshape(16).tolist(), "children": [2]},
            {"name": "knee", "translation": KNEE_T.tolist(), "rotation": KNEE_R.tolist(), "children": [3]},
            {"name": "foot", "translation": FOOT_T.tolist()},
        ],
        "meshes": [{"name": "leg", "primitives": [{
            "attributes": {"POSITION": pos, "JOINTS_0": j0, "WEIGHTS_0": w0, "JOINTS_1": j1, "WEIGHTS_1": w1},
            "indices": idx, "targets": [{"POSITION": target}]}], "weights": [0.0]}],
        "skins": [{"joints": [1, 2, 3], "inverseBindMatrices": ibm_acc}],
        "animations": [{"name": "Walk", "samplers": [
            {"input": t_in, "output": step_out, "interpolation": "STEP"},
            {"input": t_in, "output": cubic_out, "interpolation": "CUBICSPLINE"},
            {"input": t_in, "output": scale_out, "interpolation": "LINEAR"}],
            "channels": [{"sampler": 0, "target": {"node": 2, "path": "translation"}},
                         {"sampler": 1, "target": {"node": 2, "path": "rotation"}},
                         {"sampler": 2, "target": {"node": 3, "path": "scale"}}]}],
        "accessors": b.accessors, "bufferViews": b.views,
        "buffers": [{"byteLength": len(b.data)}],
    }
    data = bytes(b.data) + b"\0" * ((-len(b.data)) % 4)
    js["buffers"][0]["byteLength"] = len(data)
    if glb:
        text = json.dumps(js).encode()
        text += b" " * ((-len(text)) % 4)
        body = struct.pack("<II", len(text), 0x4E4F534A) + text + struct.pack("<II", len(data), 0x004E4942) + data
        path = tmp_path / "leg.glb"
        path.write_bytes(struct.pack("<III", 0x46546C67, 2, 12 + len(body)) + body)
        return path
    if external:
        (tmp_path / "leg data.bin").write_bytes(data)
        js["buffers"][0]["uri"] = "leg%20data.bin"
    else:
        js["buffers"][0]["uri"] = "data:application/octet-stream;base64," + base64.b64encode(data).decode()
    path = tmp_path / "leg.gltf"
    path.write_text(json.dumps(js))
    return path


def _quat_z(angle):
    return np.array([0, 0, np.sin(angle / 2), np.cos(angle / 2)])


def _expected_T(t):
    """Independent evaluation of the synthetic animation at time t (scipy rotations, hand formulas)."""
    step = np.array([[0, -0.5, 0], [0.2, -0.5, 0], [0.4, -0.5, 0]])[min(int(np.floor(t / 0.5 + 1e-12)), 2)]
    # CUBICSPLINE with tangent (0,0,1.2,0)*d on z of an angle/2 = 0.3 t ... evaluate the Hermite form directly
    keys = [0.0, 0.5, 1.0]
    vals = [_quat_z(0.0), _quat_z(0.6), _quat_z(1.2)]
    ins = [np.zeros(4), [0, 0, 1.2, 0], [0, 0, 1.2, 0]]
    outs = [[0, 0, 1.2, 0], [0, 0, 1.2, 0], np.zeros(4)]
    k = min(int(t // 0.5), 1)
    d = 0.5
    s = (t - keys[k]) / d
    q = ((2 * s**3 - 3 * s**2 + 1) * vals[k] + (s**3 - 2 * s**2 + s) * d * np.asarray(outs[k])
         + (-2 * s**3 + 3 * s**2) * vals[k + 1] + (s**3 - s**2) * d * np.asarray(ins[k + 1]))
    q = q / np.linalg.norm(q)
    sx = np.interp(t, keys, [1, 2, 1])
    knee = _h(_rot(q), step)
    foot = _h(np.diag([sx, 1, 1]), FOOT_T)
    world = [HIP, HIP @ knee, HIP @ knee @ foot]
    rest = [HIP, HIP @ _h(_rot(KNEE_R), KNEE_T), HIP @ _h(_rot(KNEE_R), KNEE_T) @ _h(np.eye(3), FOOT_T)]
    return np.array([(W @ np.linalg.inv(R))[:3] for W, R in zip(world, rest, strict=False)])


# ------------------------------------------------------------------ small functions against references


def test_quaternion_matrix_matches_scipy(rng):
    q = rng.normal(size=(50, 4))
    np.testing.assert_allclose(quaternion_matrix(q), Rotation.from_quat(q).as_matrix(), atol=1e-12)


def test_trs_matrix_is_T_R_S():
    q = _quat_z(0.7)
    M = trs_matrix([1, 2, 3], q, [2, 3, 4])
    np.testing.assert_allclose(M, _h(np.eye(3), (1, 2, 3)) @ _h(_rot(q)) @ np.diag([2, 3, 4, 1]), atol=1e-12)


def test_slerp_halfway_and_shorter_arc():
    q0, q1 = _quat_z(0.0), _quat_z(np.pi / 2)
    np.testing.assert_allclose(slerp(q0, q1, 0.5), _quat_z(np.pi / 4), atol=1e-12)
    # -q1 is the same rotation: slerp must take the short way and give the same result
    np.testing.assert_allclose(slerp(q0, -q1, 0.5), _quat_z(np.pi / 4), atol=1e-12)
    np.testing.assert_allclose(slerp(q0, q0, 0.3), q0, atol=1e-12)


def test_sample_step_linear_clamp():
    times = np.array([1.0, 2.0, 4.0])
    values = np.array([[0.0], [10.0], [30.0]])
    t = np.array([0.0, 1.0, 1.5, 2.0, 3.0, 5.0])
    np.testing.assert_allclose(sample_sampler(times, values, "LINEAR", t)[:, 0], [0, 0, 5, 10, 20, 30])
    np.testing.assert_allclose(sample_sampler(times, values, "STEP", t)[:, 0], [0, 0, 0, 10, 10, 30])


def test_cubicspline_reproduces_a_cubic_exactly():
    """Hermite interpolation with the true derivatives as tangents is exact on a cubic polynomial."""
    def f(t):
        return t**3 - 2 * t + 1

    def df(t):
        return 3 * t**2 - 2

    times = np.array([0.0, 0.7, 2.0])
    values = np.stack([np.stack([[df(t)], [f(t)], [df(t)]]) for t in times]).reshape(-1, 1)
    t = np.linspace(0, 2, 23)
    np.testing.assert_allclose(sample_sampler(times, values, "CUBICSPLINE", t)[:, 0], f(t), atol=1e-12)


# ------------------------------------------------------------------ the synthetic document


@pytest.mark.parametrize("kind", ["embedded", "external", "glb"])
def test_synthetic_skin_every_feature(tmp_path, kind):
    path = _synthetic(tmp_path, external=kind == "external", glb=kind == "glb")
    skin = read_gltf_skin(path, animation="Walk", fps=8)
    # mesh from a strided bufferView, ubyte indices; the skinned node's own matrix is ignored
    np.testing.assert_allclose(skin.mesh.V, V4, atol=0)
    np.testing.assert_array_equal(skin.mesh.F, [[0, 1, 2], [0, 2, 3]])
    # weights from two sets: normalized ubyte + float, the same joint in both sets summed
    np.testing.assert_allclose(skin.weights.toarray(), W_EXPECTED / W_EXPECTED.sum(1, keepdims=True), atol=1e-7)
    assert skin.handles.names == ["hip", "knee", "foot"]
    np.testing.assert_array_equal(skin.handles.parents, [-1, 0, 1])
    np.testing.assert_allclose(skin.handles.joints[1], (HIP @ _h(np.eye(3), KNEE_T))[:3, 3], atol=1e-6)
    # poses: 1 s at 8 fps = 9 frames; every T against the independent evaluation
    assert len(skin.poses) == 9
    for f in range(9):
        np.testing.assert_allclose(skin.poses.T[f], _expected_T(f / 8), atol=2e-6, err_msg=f"frame {f}")


def test_sparse_accessor_and_normalized_types(tmp_path):
    doc = load_gltf(_synthetic(tmp_path))
    np.testing.assert_allclose(read_accessor(doc, 11), [[0, 0, 0], [0, 0.1, 0], [0, 0, 0], [0, 0, 0.2]], atol=1e-7)
    w0 = read_accessor(doc, 3)
    np.testing.assert_allclose(w0[:, 0], [1.0, 128 / 255, 0.2, 0.4])
    assert read_accessor(doc, 3, normalize=False).dtype == np.uint8


def test_rest_pose_when_no_animation(tmp_path):
    path = _synthetic(tmp_path)
    js = json.loads(path.read_text())
    del js["animations"]
    path.write_text(json.dumps(js))
    skin = read_gltf_skin(path)
    assert len(skin.poses) == 1 and skin.animation is None
    np.testing.assert_allclose(skin.poses.T[0], np.tile(np.eye(3, 4), (3, 1, 1)), atol=1e-6)


def test_bad_inputs_raise_with_fix(tmp_path):
    path = _synthetic(tmp_path)
    with pytest.raises(InputError, match="no animation named 'Wlak'.*did you mean 'Walk'"):
        read_gltf_skin(path, animation="Wlak")
    with pytest.raises(InputError, match="animation index 3 is out of range"):
        read_gltf_skin(path, animation=3)
    with pytest.raises(InputError, match="fps"):
        read_gltf_skin(path, fps=0)
    bad = tmp_path / "v1.gltf"
    bad.write_text(json.dumps({"asset": {"version": "1.0"}}))
    with pytest.raises(InputError, match="not 2.x"):
        read_gltf_skin(bad)
    missing = tmp_path / "missing.gltf"
    js = json.loads(path.read_text())
    js["buffers"][0]["uri"] = "nothere.bin"
    missing.write_text(json.dumps(js))
    with pytest.raises(RigslimError, match="nothere.bin"):
        read_gltf_skin(missing)
    js = json.loads(path.read_text())
    del js["skins"]
    del js["nodes"][0]["skin"]
    path.write_text(json.dumps(js))
    with pytest.raises(InputError, match="no skin"):
        read_gltf_skin(path)


# ------------------------------------------------------------------ files written by other tools


def test_simple_skin_from_the_khronos_tutorial():
    skin = read_gltf_skin(GLTF / "simple_skin.gltf", fps=2)
    assert skin.mesh.V.shape == (10, 3) and skin.mesh.F.shape == (8, 3)
    np.testing.assert_allclose(skin.weights.toarray()[2], [0.75, 0.25])
    # keys every 0.5 s over 5.5 s: at 2 fps the frames are exactly the keys
    assert len(skin.poses) == 12
    doc = skin.document
    anim = doc.json["animations"][0]["samplers"][0]
    times, quats = read_accessor(doc, anim["input"]), read_accessor(doc, anim["output"])
    ibm = read_accessor(doc, doc.json["skins"][0]["inverseBindMatrices"]).reshape(2, 4, 4).transpose(0, 2, 1)
    for f, (t, q) in enumerate(zip(times, quats, strict=False)):
        assert abs(t - f / 2) < 1e-6
        world1 = _h(np.eye(3), (0, 1, 0)) @ _h(_rot(q))   # node 1 translation, node 2 rotation
        np.testing.assert_allclose(skin.poses.T[f, 1], (world1 @ ibm[1])[:3], atol=1e-6)
        np.testing.assert_allclose(skin.poses.T[f, 0], (_h(np.eye(3), (0, 1, 0)) @ ibm[0])[:3], atol=1e-6)


@pytest.mark.parametrize("name, vertices, joints", [("huesitos.glb", 128, 9),
                                                    ("animation_with_skeleton.glb", 2464, 14)])
def test_assimp_exports_move_rigidly(name, vertices, joints):
    """Files assimp wrote from FBX: the skinned mesh keeps its edge lengths in every sampled frame."""
    skin = read_gltf_skin(GLTF / name)
    assert skin.mesh.n_vertices == vertices and skin.handles.n == joints
    np.testing.assert_allclose(np.asarray(skin.weights.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    E = skin.mesh.edges
    rest = np.linalg.norm(skin.mesh.V[E[:, 0]] - skin.mesh.V[E[:, 1]], axis=1)
    ratios = []
    for f in range(0, len(skin.poses), max(1, len(skin.poses) // 5)):
        X = linear_blend(skin.mesh.V, skin.weights, skin.poses.T[f])
        ratios.append(np.median(np.linalg.norm(X[E[:, 0]] - X[E[:, 1]], axis=1) / rest))
    # one global scale (the exporter's unit conversion) shared by every frame; no shearing or collapse
    assert np.ptp(ratios) < 0.02 * np.mean(ratios)
    assert len(skin.poses) > 10
    assert np.ptp(skin.poses.T[:, :, :, 3], axis=0).max() > 0 or np.ptp(skin.poses.T[:, :, :, :3], axis=0).max() > 1e-3


def test_malformed_documents_are_input_errors(tmp_path):
    path = _synthetic(tmp_path)
    js = json.loads(path.read_text())
    js["nodes"][2]["children"] = "three"
    path.write_text(json.dumps(js))
    with pytest.raises(InputError, match=r"nodes\[2\]\.children: input should be a valid list"):
        read_gltf_skin(path)
    js["nodes"][2]["children"] = [3]
    js["meshes"][0]["primitives"][0]["attributes"]["JOINTS_0"] = 99
    path.write_text(json.dumps(js))
    with pytest.raises(InputError, match=r"attributes\.JOINTS_0: index 99 is out of range"):
        read_gltf_skin(path)


def test_weld_merges_seam_vertices_and_keeps_rows_summing_to_one():
    split = read_gltf_skin(GLTF / "animation_with_skeleton.glb")
    welded = read_gltf_skin(GLTF / "animation_with_skeleton.glb", weld=True)
    m = split.mesh.n_vertices
    assert welded.mesh.n_vertices < m and welded.vertex_map.shape == (m,)
    # every file vertex maps onto a welded vertex at exactly its position
    np.testing.assert_array_equal(welded.mesh.V[welded.vertex_map], split.mesh.V)
    # welded weights are the mean of the merged rows
    P = np.zeros((m, welded.mesh.n_vertices))
    P[np.arange(m), welded.vertex_map] = 1
    expected = (P.T @ split.weights.toarray()) / P.sum(axis=0)[:, None]
    np.testing.assert_allclose(welded.weights.toarray(), expected, atol=1e-12)
    np.testing.assert_allclose(np.asarray(welded.weights.sum(axis=1)).ravel(), 1.0, atol=1e-12)
    # the welded mesh is connected where the file's was cut: far fewer boundary edges
    import igl

    def boundary(F):
        b = igl.boundary_facets(F)
        return len(b[0] if isinstance(b, tuple) else b)

    assert boundary(welded.mesh.F) < boundary(split.mesh.F) / 10
    # deformation unchanged wherever the merged rows agreed
    X = linear_blend(split.mesh.V, split.weights, split.poses.T[7])
    Xw = linear_blend(welded.mesh.V, welded.weights, welded.poses.T[7])[welded.vertex_map]
    agree = np.abs(expected[welded.vertex_map] - split.weights.toarray()).max(axis=1) < 1e-12
    assert agree.mean() > 0.5
    np.testing.assert_allclose(Xw[agree], X[agree], atol=1e-9 * np.abs(X).max())


# ------------------------------------------------------------------ three.js reads the same motion


@pytest.fixture(scope="module")
def threejs():
    from support.gltf_validator import threejs_available, threejs_skinned_positions

    if not threejs_available():
        pytest.fail("three.js missing: run tools/setup-gltf-validator.sh (make test-tools)")
    return threejs_skinned_positions


def _compare_with_threejs(threejs, path, skin, frames, rtol):
    out = threejs(path, [f / skin.fps for f in frames])
    assert len(out) == 1 and out[0]["bones"] == skin.handles.n
    for j, f in enumerate(frames):
        X = linear_blend(skin.mesh.V, skin.weights, skin.poses.T[f])
        assert np.abs(out[0]["positions"][j] - X).max() <= rtol * np.abs(X).max(), f"frame {f}"


@pytest.mark.parametrize("name", ["huesitos.glb", "animation_with_skeleton.glb"])
def test_threejs_skins_assimp_files_like_the_reader(threejs, name):
    skin = read_gltf_skin(GLTF / name)
    _compare_with_threejs(threejs, GLTF / name, skin, [0, 4, 11, len(skin.poses) - 1], 1e-6)


def test_threejs_matches_step_cubicspline_matrix_nodes(threejs, tmp_path):
    """three.js's interpolants and node graph agree with the reader on the synthetic document.

    three.js (r160) reads only JOINTS_0/WEIGHTS_0, so the two-set weights are
    first reduced to one set (k = 3) by the writer; the animation, nodes and
    inverse bind matrices are the synthetic ones.
    """
    from rigslim.io.gltf.write import fixed_width_weights, write_gltf

    src = read_gltf_skin(_synthetic(tmp_path, glb=True), animation="Walk", fps=8)
    out = tmp_path / "one-set.glb"
    write_gltf(out, src, fixed_width_weights(src.weights))
    skin = read_gltf_skin(out, animation="Walk", fps=8)
    assert abs(skin.weights - src.weights).max() < 1e-7
    _compare_with_threejs(threejs, out, skin, list(range(9)), 1e-6)


def test_world_matrices_deep_chain_and_cycles():
    from rigslim.io.gltf.scene import world_matrices

    n = 3000                                           # deeper than Python's recursion limit
    parent = np.arange(-1, n - 1)
    local = np.tile(_h(np.eye(3), (0, 1, 0)), (n, 1, 1, 1))
    world = world_matrices(local, parent)
    np.testing.assert_allclose(world[:, 0, 1, 3], np.arange(1, n + 1))
    with pytest.raises(InputError, match="cycle"):
        world_matrices(local[:2], np.array([1, 0]))


def test_sampling_at_chosen_times(tmp_path):
    path = _synthetic(tmp_path)
    times = [0.3, 0.05, 0.77, 2.0]
    skin = read_gltf_skin(path, animation="Walk", times=times)
    assert len(skin.poses) == 4
    for j, t in enumerate(times):
        np.testing.assert_allclose(skin.poses.T[j], _expected_T(min(t, 1.0)), atol=2e-6)
    with pytest.raises(InputError, match="times"):
        read_gltf_skin(path, times=[-1.0])
