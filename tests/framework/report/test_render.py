"""Offscreen renders: the OpenGL (EGL) path against the numpy rasteriser and projected silhouettes."""

from __future__ import annotations

import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.report.render import Camera, lambert, render_mesh, render_numpy


def _icosphere(subdivisions: int = 2):
    t = (1 + 5 ** 0.5) / 2
    V = np.array([[-1, t, 0], [1, t, 0], [-1, -t, 0], [1, -t, 0], [0, -1, t], [0, 1, t], [0, -1, -t], [0, 1, -t],
                  [t, 0, -1], [t, 0, 1], [-t, 0, -1], [-t, 0, 1]], dtype=float)
    F = np.array([[0, 11, 5], [0, 5, 1], [0, 1, 7], [0, 7, 10], [0, 10, 11], [1, 5, 9], [5, 11, 4], [11, 10, 2],
                  [10, 7, 6], [7, 1, 8], [3, 9, 4], [3, 4, 2], [3, 2, 6], [3, 6, 8], [3, 8, 9], [4, 9, 5],
                  [2, 4, 11], [6, 2, 10], [8, 6, 7], [9, 8, 1]])
    V = list(V / np.linalg.norm(V, axis=1, keepdims=True))
    for _ in range(subdivisions):
        mids, newF = {}, []

        def mid(a, b, mids=mids):
            key = (min(a, b), max(a, b))
            if key not in mids:
                p = V[a] + V[b]
                V.append(p / np.linalg.norm(p))
                mids[key] = len(V) - 1
            return mids[key]

        for a, b, c in F:
            ab, bc, ca = mid(a, b), mid(b, c), mid(c, a)
            newF += [[a, ab, ca], [b, bc, ab], [c, ca, bc], [ab, bc, ca]]
        F = np.array(newF)
    return np.array(V), F


def _gl_or_skip():
    from rigslim.device.egl import EGLUnavailable
    from rigslim.report.render import gl_renderer

    try:
        return gl_renderer()
    except EGLUnavailable as e:  # pragma: no cover - CI installs Mesa's EGL (llvmpipe)
        pytest.skip(f"no EGL display: {e.problem}")


def _mask(image, background=255):
    return (image != background).any(axis=-1)


def test_camera_maps_bounding_sphere_inside_the_image():
    V, _ = _icosphere(1)
    V = V * [3.0, 1.0, 2.0] + [10.0, -4.0, 1.0]
    for proj in ("orthographic", "perspective"):
        for w, h in ((80, 40), (40, 80)):
            cam = Camera.fit(V, w, h, projection=proj, margin=1.0)
            win = cam.to_window(V)
            assert (win[:, 0] >= 0).all() and (win[:, 0] <= w).all()
            assert (win[:, 1] >= 0).all() and (win[:, 1] <= h).all()
            assert ((win[:, 2] > 0) & (win[:, 2] < 1)).all()
    # a cube seen head-on: its face spans 2 / (2 sqrt(3)) of the shorter image side
    cube = np.array([[x, y, z] for x in (-1, 1) for y in (-1, 1) for z in (-1, 1)], dtype=float)
    win = Camera.fit(cube, 90, 60, azimuth=0, elevation=0, margin=1.0).to_window(cube)
    np.testing.assert_allclose(np.ptp(win[:, :2], axis=0), [60 / 3 ** 0.5, 60 / 3 ** 0.5])
    np.testing.assert_allclose(win[:, :2].mean(axis=0), [45, 30])


def test_orthographic_silhouette_of_a_sphere_is_a_disc():
    V, F = _icosphere(3)
    cam = Camera.fit(V, 64, 64, projection="orthographic", margin=1.25)
    img = render_numpy(V, F, [0.5, 0.6, 0.7], cam)
    radius_px = 64 / 2 / 1.25 / 3 ** 0.5  # sphere radius 1, bounding-box sphere radius sqrt(3)
    yy, xx = np.mgrid[0:64, 0:64] + 0.5
    disc = (xx - 32) ** 2 + (yy - 32) ** 2 <= radius_px ** 2
    m = _mask(img)
    iou = (m & disc).sum() / (m | disc).sum()
    assert iou > 0.95


def test_numpy_shading_of_a_facing_square_is_lambert():
    V = np.array([[-1, -1, 0], [1, -1, 0], [1, 1, 0], [-1, 1, 0]], dtype=float)
    F = np.array([[0, 1, 2], [0, 2, 3]])
    cam = Camera.fit(V, 32, 32, azimuth=0, elevation=0, up_axis=1, margin=1.0)
    light = np.array([0.0, 0.6, 0.8])
    img = render_numpy(V, F, [0.8, 0.4, 0.2], cam, normals=np.tile([0, 0, 1.0], (4, 1)), light=light, ambient=0.2)
    expected = np.round(np.array([0.8, 0.4, 0.2]) * (0.2 + 0.8 * 0.8) * 255)
    assert np.array_equal(img[16, 16], expected.astype(np.uint8))
    np.testing.assert_allclose(lambert([[1, 1, 1]], [[0, 0, -2.0]], light, 0.2), [[0.84, 0.84, 0.84]])


def test_numpy_depth_test_keeps_the_nearer_triangle():
    near = np.array([[-1, -1, 0.5], [1, -1, 0.5], [0, 1, 0.5]])
    far = near * [1.5, 1.5, 1] - [0, 0, 1.0]
    V = np.r_[far, near]
    F = np.array([[3, 4, 5], [0, 1, 2]])  # nearer first, then the farther one must not overwrite
    colors = np.r_[np.tile([0, 0, 1.0], (3, 1)), np.tile([1.0, 0, 0], (3, 1))]
    cam = Camera.fit(V, 40, 40, azimuth=0, elevation=0)
    img = render_numpy(V, F, colors, cam, normals=np.tile([0, 0, 1.0], (6, 1)), light=[0, 0, 1])
    centre = cam.to_window(near.mean(axis=0, keepdims=True))[0]
    px = img[40 - 1 - int(centre[1]), int(centre[0])]
    assert px[0] > 200 and px[2] == 0


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
@pytest.mark.opengl
def test_opengl_matches_numpy_reference(projection):
    gl = _gl_or_skip()
    V, F = _icosphere(2)
    V = V * [1.0, 0.6, 0.8]
    rng = np.random.default_rng(1)
    colors = rng.uniform(0.2, 1.0, size=(len(V), 3))
    cam = Camera.fit(V, 72, 56, projection=projection, azimuth=40, elevation=25)
    ref = render_numpy(V, F, colors, cam)
    img = gl.render(V, F, colors, cam)
    assert img.shape == ref.shape == (56, 72, 3)
    m_ref, m_gl = _mask(ref), _mask(img)
    assert (m_ref ^ m_gl).sum() <= 0.01 * m_ref.sum() + 2
    both = m_ref & m_gl
    diff = np.abs(ref.astype(int) - img.astype(int))[both]
    assert np.percentile(diff, 99) <= 3
    assert diff.mean() < 0.5


@pytest.mark.opengl
def test_opengl_silhouette_matches_projected_elephant(elephant):
    gl = _gl_or_skip()
    from rigslim.numerics.blend import linear_blend

    frame = elephant.split.test[3]
    X = linear_blend(elephant.mesh.V, elephant.weights, elephant.poses.T[frame])
    cam = Camera.fit(X, 96, 72, projection="perspective")
    img = gl.render(X, elephant.mesh.F, [0.7, 0.75, 0.85], cam)
    # numpy-projected silhouette: every projected vertex lands on a covered pixel (or right beside one)
    win = cam.to_window(X)
    cols = np.clip(win[:, 0].astype(int), 0, 95)
    rows = np.clip(72 - 1 - win[:, 1].astype(int), 0, 71)
    m = _mask(img)
    grown = m.copy()
    grown[1:] |= m[:-1]
    grown[:-1] |= m[1:]
    grown[:, 1:] |= m[:, :-1]
    grown[:, :-1] |= m[:, 1:]
    assert grown[rows, cols].all()
    ref = _mask(render_numpy(X, elephant.mesh.F, [0.7, 0.75, 0.85], cam))
    assert (ref ^ m).sum() <= 0.01 * ref.sum() + 2


def test_render_mesh_backends_and_errors():
    V, F = _icosphere(0)
    cam = Camera.fit(V, 16, 16)
    img, used = render_mesh(V, F, [0.5, 0.5, 0.5], cam, backend="numpy")
    assert used == "numpy" and img.shape == (16, 16, 3) and _mask(img).any()
    with pytest.raises(InputError):
        render_mesh(V, F, [0.5, 0.5, 0.5], cam, backend="vulkan")
    with pytest.raises(InputError):
        Camera.fit(V, 0, 16)
    with pytest.raises(InputError):
        render_numpy(V, F + 100, [0.5, 0.5, 0.5], cam)


@pytest.mark.parametrize("projection", ["orthographic", "perspective"])
def test_tight_camera_centres_and_fills_the_image(projection):
    V, _ = _icosphere(1)
    V = V * [2.0, 0.5, 0.5] + [3.0, 1.0, 0.0]
    cam = Camera.fit(V, 80, 60, projection=projection, tight=True, margin=1.0)
    win = cam.to_window(V)
    lo, hi = win[:, :2].min(axis=0), win[:, :2].max(axis=0)
    np.testing.assert_allclose(0.5 * (lo + hi), [40, 30], atol=1e-6)
    # the limiting side touches both image borders
    assert np.isclose(hi[0] - lo[0], 80, atol=1e-6) or np.isclose(hi[1] - lo[1], 60, atol=1e-6)
    assert (lo >= -1e-6).all() and (hi <= [80 + 1e-6, 60 + 1e-6]).all()
