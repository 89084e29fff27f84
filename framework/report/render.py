"""Offscreen renders of deformed meshes: OpenGL through headless EGL, and a numpy reference.

A :class:`Camera` fitted to a bounding box maps world points to clip space
(``clip = P V [x; 1]``, orthographic or perspective); the mesh is shaded
with two-sided Lambert lighting of per-vertex colours and drawn with a depth
buffer into an RGBA8 framebuffer object (:class:`GLRenderer`, shaders
``kernels/render_vertex.glsl`` and ``kernels/render_fragment.glsl``), then
read back with ``glReadPixels``. :func:`render_numpy` rasterises the same
triangles in numpy (pixel centres, perspective-correct attributes, z-buffer):
the reference the OpenGL path is tested against, and the fallback when no
EGL display exists.

Example
-------
>>> import numpy as np
>>> from rigslim.report.render import Camera, render_mesh
>>> V = np.array([[0., 0, 0], [1, 0, 0], [0, 1, 0]]); F = np.array([[0, 1, 2]])
>>> cam = Camera.fit(V, 64, 48)
>>> image, backend = render_mesh(V, F, np.full((3, 3), 0.8), cam)   # doctest: +SKIP
>>> image.shape
(48, 64, 3)
"""

from __future__ import annotations

import math
import threading
from dataclasses import dataclass

import numpy as np

from rigslim.errors import InputError

#: Background colour of renders (RGB in [0, 1]): white, so that renders sit on the report page.
BACKGROUND = (1.0, 1.0, 1.0)
#: Share of light that does not depend on the normal.
AMBIENT = 0.25


def _normalize(v) -> np.ndarray:
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v)
    if n == 0:
        raise InputError("zero-length direction", field="camera", fix="give a non-zero direction")
    return v / n


@dataclass(frozen=True)
class Camera:
    """A pinhole or orthographic camera and its image size.

    Attributes
    ----------
    view : (4, 4) array
        World to eye coordinates (right-handed, looking down -z).
    projection : (4, 4) array
        Eye to clip coordinates (OpenGL conventions, depth in [-1, 1]).
    width, height : int
        Image size in pixels.
    eye_direction : (3,) array
        Unit vector from the scene towards the eye (for the headlight).
    up : (3,) array
        Unit up vector of the image.
    """

    view: np.ndarray
    projection: np.ndarray
    width: int
    height: int
    eye_direction: np.ndarray
    up: np.ndarray

    @staticmethod
    def fit(points, width: int, height: int, *, azimuth: float = 30.0, elevation: float = 15.0,
            up_axis: int = 1, projection: str = "orthographic", margin: float = 1.05,
            fov_degrees: float = 30.0, tight: bool = False) -> Camera:
        """A camera that sees the whole bounding sphere of ``points``.

        Parameters
        ----------
        points : (m, 3) array
            Everything that should be in view (e.g. all deformed frames stacked).
        width, height : int
            Image size in pixels.
        azimuth, elevation : float
            Viewing direction in degrees: azimuth around the up axis from the
            axis after it (``(up_axis + 1) % 3``: z when y is up), elevation above the horizon.
        up_axis : {0, 1, 2}
            World axis that points up in the image.
        projection : {"orthographic", "perspective"}
        margin : float
            Bounding-sphere radius is multiplied by this before fitting.
        fov_degrees : float
            Vertical (or, for portrait images, horizontal) field of view of the
            perspective camera.
        tight : bool
            Zoom so that the points themselves (not their bounding sphere)
            fill the image up to ``margin``, centred: with ``c`` the centre of
            the points' NDC bounding box and ``e`` their largest NDC offset
            from it, the x and y rows of the projection become
            ``(P_xy - c P_w) / (margin e)``.

        Notes
        -----
        With centre ``c`` and radius ``r`` of the bounding box's sphere, the
        eye sits at ``e = c + d w`` (``w`` the unit eye direction), ``d = 3 r``
        for orthographic and ``d = margin r / sin(fov / 2)`` for perspective
        cameras; the view matrix is the usual look-at ``[R | -R e]`` with rows
        right, up, ``w``. Orthographic: ``x_ndc = x_eye / s_x``,
        ``y_ndc = y_eye / s_y`` with ``s = margin r`` stretched by the aspect
        ratio; perspective: ``f = cot(fov / 2)`` (scaled by the aspect ratio
        when the image is portrait).
        """
        P = np.asarray(points, dtype=np.float64).reshape(-1, 3)
        _check_fit(P, width, height, projection, up_axis)
        lo, hi = P.min(axis=0), P.max(axis=0)
        centre = 0.5 * (lo + hi)
        radius = max(0.5 * float(np.linalg.norm(hi - lo)), 1e-12)
        w, right, cam_up = _eye_axes(up_axis, azimuth, elevation)
        proj, dist = _projection(projection, radius, width / height, margin, fov_degrees)
        eye = centre + dist * w
        view = np.eye(4)
        view[0, :3], view[1, :3], view[2, :3] = right, cam_up, w
        view[:3, 3] = -view[:3, :3] @ eye
        if tight:
            _tighten(proj, view, P, margin)
        return Camera(view, proj, int(width), int(height), w, cam_up)

    @property
    def mvp(self) -> np.ndarray:
        """World to clip matrix ``P V``."""
        return self.projection @ self.view

    def clip(self, X) -> np.ndarray:
        """(m, 4) clip coordinates of (m, 3) world points."""
        X = np.asarray(X, dtype=np.float64)
        return np.c_[X, np.ones(len(X))] @ self.mvp.T

    def to_window(self, X) -> np.ndarray:
        """(m, 3) window coordinates ``(x, y, z)``: pixels from the bottom-left corner, depth in [0, 1].

        Notes
        -----
        ``x_w = (x_c / w_c + 1) W / 2``, ``y_w = (y_c / w_c + 1) H / 2``,
        ``z_w = (z_c / w_c + 1) / 2``, as OpenGL's viewport transform with
        the default depth range.
        """
        C = self.clip(X)
        ndc = C[:, :3] / C[:, 3:4]
        return np.c_[(ndc[:, 0] + 1) * self.width / 2, (ndc[:, 1] + 1) * self.height / 2, (ndc[:, 2] + 1) / 2]

    def headlight(self) -> np.ndarray:
        """Unit direction towards a light above and left of the eye."""
        right = self.view[0, :3]
        return _normalize(self.eye_direction + 0.45 * self.up - 0.3 * right)


def _check_fit(P: np.ndarray, width: int, height: int, projection: str, up_axis: int) -> None:
    """The arguments of :meth:`Camera.fit`, one InputError naming the first that is wrong."""
    if len(P) == 0 or not np.isfinite(P).all():
        raise InputError("cannot fit a camera to no (or non-finite) points", field="points",
                         fix="give the deformed vertex positions")
    if int(width) < 1 or int(height) < 1:
        raise InputError(f"image size {width}x{height} is empty", field="width/height",
                         fix="give a positive width and height")
    if projection not in ("orthographic", "perspective"):
        raise InputError(f"unknown projection '{projection}'", field="projection",
                         fix="use 'orthographic' or 'perspective'")
    if up_axis not in (0, 1, 2):
        raise InputError(f"up_axis {up_axis} is not 0, 1 or 2", field="up_axis", fix="use 0 (x), 1 (y) or 2 (z)")


def _eye_axes(up_axis: int, azimuth: float, elevation: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """``(w, right, up)`` of :meth:`Camera.fit`: the unit eye direction, at ``azimuth`` around the up axis
    from the axis after it and ``elevation`` above the horizon (degrees), and the image's right and up."""
    up = np.zeros(3)
    up[up_axis] = 1.0
    front = np.zeros(3)
    front[(up_axis + 1) % 3] = 1.0
    side = np.cross(up, front)
    az, el = math.radians(azimuth), math.radians(elevation)
    w = _normalize(math.cos(el) * (math.cos(az) * front + math.sin(az) * side) + math.sin(el) * up)
    right = _normalize(np.cross(up, w)) if abs(np.dot(up, w)) < 1 - 1e-9 else _normalize(np.cross(front, w))
    return w, right, np.cross(w, right)


def _projection(projection: str, radius: float, aspect: float, margin: float,
                fov_degrees: float) -> tuple[np.ndarray, float]:
    """The 4 x 4 projection of :meth:`Camera.fit` for a bounding sphere of ``radius`` and the eye's distance
    from its centre (the formulas of its Notes)."""
    if projection == "orthographic":
        dist = 3.0 * radius
        near, far = radius * 0.5, dist + 2.0 * radius
        s = margin * radius
        sx, sy = (s * aspect, s) if aspect >= 1 else (s, s / aspect)
        proj = np.array([[1 / sx, 0, 0, 0], [0, 1 / sy, 0, 0],
                         [0, 0, -2 / (far - near), -(far + near) / (far - near)], [0, 0, 0, 1]])
    else:
        half = math.radians(fov_degrees) / 2
        dist = margin * radius / math.sin(half)
        near, far = max(dist - 1.5 * radius, 1e-3 * radius), dist + 1.5 * radius
        f = 1.0 / math.tan(half) * min(1.0, aspect)
        proj = np.array([[f / aspect, 0, 0, 0], [0, f, 0, 0],
                         [0, 0, (far + near) / (near - far), 2 * far * near / (near - far)], [0, 0, -1, 0]])
    return proj, dist


def _tighten(proj: np.ndarray, view: np.ndarray, P: np.ndarray, margin: float) -> None:
    """``tight`` of :meth:`Camera.fit`, in place: the x and y rows of ``proj`` become
    ``(P_xy - c P_w) / (margin e)``, centring the points' NDC bounding box and filling the image with it."""
    C = np.c_[P, np.ones(len(P))] @ (proj @ view).T
    ndc = C[:, :2] / C[:, 3:4]
    mid = 0.5 * (ndc.min(axis=0) + ndc.max(axis=0))
    extent = float(np.max(np.abs(ndc - mid)))
    if extent > 0:
        proj[:2] = (proj[:2] - np.outer(mid, proj[3])) / (margin * extent)


def lambert(colors, normals, light, ambient: float = AMBIENT) -> np.ndarray:
    """Two-sided Lambert shading, the formula of ``render_fragment.glsl``.

    Parameters
    ----------
    colors : (..., 3) array in [0, 1]
    normals : (..., 3) array
        Normalised here (zero vectors give ambient light only).
    light : (3,) unit vector towards the light
    ambient : float

    Returns
    -------
    (..., 3) array
        ``c (a + (1 - a) |n . l|)``.
    """
    N = np.asarray(normals, dtype=np.float64)
    length = np.linalg.norm(N, axis=-1, keepdims=True)
    N = np.divide(N, length, out=np.zeros_like(N), where=length > 0)
    d = np.abs(N @ np.asarray(light, dtype=np.float64))
    return np.asarray(colors, dtype=np.float64) * (ambient + (1 - ambient) * d)[..., None]


def _to_uint8(rgb) -> np.ndarray:
    return np.round(np.clip(rgb, 0.0, 1.0) * 255.0).astype(np.uint8)


def _check_mesh(V, F, colors, normals):
    V = np.ascontiguousarray(V, dtype=np.float64)
    F = np.ascontiguousarray(F, dtype=np.int64)
    m = len(V)
    if V.ndim != 2 or V.shape[1] != 3 or F.ndim != 2 or F.shape[1] != 3:
        raise InputError(f"mesh arrays have shapes {V.shape} and {F.shape}", field="V/F",
                         fix="give (m, 3) positions and (f, 3) triangles")
    if F.size and (F.min() < 0 or F.max() >= m):
        raise InputError("face indices outside the vertex range", field="F", fix="check the triangles")
    colors = np.broadcast_to(np.asarray(colors, dtype=np.float64), (m, 3))
    if normals is None:
        from rigslim.numerics.blend import per_vertex_normals

        normals = per_vertex_normals(V, F) if F.size else np.zeros((m, 3))
    normals = np.asarray(normals, dtype=np.float64)
    if normals.shape != (m, 3):
        raise InputError(f"normals have shape {normals.shape}, expected ({m}, 3)", field="normals",
                         fix="give one normal per vertex")
    return V, F, colors, normals


def render_numpy(V, F, colors, camera: Camera, *, normals=None, light=None, ambient: float = AMBIENT,
                 background=BACKGROUND) -> np.ndarray:
    """Rasterise a shaded triangle mesh in numpy (the reference of :class:`GLRenderer`).

    Parameters
    ----------
    V : (m, 3) array
        World positions.
    F : (f, 3) int array
    colors : (m, 3) or (3,) array in [0, 1]
    camera : Camera
    normals : (m, 3) array, optional
        Per-vertex normals (default: area-weighted normals of ``V``).
    light : (3,) array, optional
        Default ``camera.headlight()``.
    ambient : float
    background : RGB in [0, 1]

    Returns
    -------
    (H, W, 3) uint8 array, row 0 at the top.

    Notes
    -----
    A pixel ``(i, j)`` is covered by a triangle when its centre
    ``(i + 1/2, j + 1/2)`` has barycentric coordinates ``lambda >= 0`` in
    window space; depth ``z = sum lambda_a z_a`` is linear in window space and
    the nearest fragment wins (``<``, as ``GL_LESS``). Colours and normals
    use perspective-correct weights ``lambda_a / w_a / sum_b lambda_b / w_b``
    (identical for orthographic cameras) and are shaded per pixel by
    :func:`lambert`. Triangles with a vertex behind the eye (``w <= 0``) are
    skipped; the fitted cameras never produce them.
    """
    V, F, colors, normals = _check_mesh(V, F, colors, normals)
    W, H = camera.width, camera.height
    light = camera.headlight() if light is None else _normalize(light)
    C = camera.clip(V)
    win = camera.to_window(V) if len(V) else np.zeros((0, 3))
    depth = np.full((H, W), np.inf)
    out_color = np.zeros((H, W, 3))
    out_normal = np.zeros((H, W, 3))
    for tri in F:
        w = C[tri, 3]
        if np.any(w <= 0):
            continue
        p = win[tri]
        x0, x1 = p[:, 0].min(), p[:, 0].max()
        y0, y1 = p[:, 1].min(), p[:, 1].max()
        i0, i1 = max(math.ceil(x0 - 0.5), 0), min(math.floor(x1 - 0.5), W - 1)
        j0, j1 = max(math.ceil(y0 - 0.5), 0), min(math.floor(y1 - 0.5), H - 1)
        if i0 > i1 or j0 > j1:
            continue
        area = (p[1, 0] - p[0, 0]) * (p[2, 1] - p[0, 1]) - (p[2, 0] - p[0, 0]) * (p[1, 1] - p[0, 1])
        if abs(area) < 1e-12:
            continue
        px, py = np.meshgrid(np.arange(i0, i1 + 1) + 0.5, np.arange(j0, j1 + 1) + 0.5)
        l0 = ((p[1, 0] - px) * (p[2, 1] - py) - (p[2, 0] - px) * (p[1, 1] - py)) / area
        l1 = ((p[2, 0] - px) * (p[0, 1] - py) - (p[0, 0] - px) * (p[2, 1] - py)) / area
        l2 = 1.0 - l0 - l1
        inside = (l0 >= 0) & (l1 >= 0) & (l2 >= 0)
        if not inside.any():
            continue
        lam = np.stack([l0[inside], l1[inside], l2[inside]], axis=1)
        z = lam @ p[:, 2]
        rows = py[inside].astype(int)
        cols = px[inside].astype(int)
        nearer = z < depth[rows, cols]
        if not nearer.any():
            continue
        rows, cols, lam, z = rows[nearer], cols[nearer], lam[nearer], z[nearer]
        persp = lam / w
        persp /= persp.sum(axis=1, keepdims=True)
        depth[rows, cols] = z
        out_color[rows, cols] = persp @ colors[tri]
        out_normal[rows, cols] = persp @ normals[tri]
    covered = np.isfinite(depth)
    image = np.empty((H, W, 3))
    image[:] = np.asarray(background, dtype=np.float64)
    image[covered] = lambert(out_color[covered], out_normal[covered], light, ambient)
    return _to_uint8(image)[::-1]


class GLRenderer:
    """Draws shaded meshes into an offscreen framebuffer through headless EGL.

    One renderer owns a shader program, a vertex array with position, normal
    and colour buffers, and an RGBA8 + 24-bit depth framebuffer object that is
    re-allocated when the image size changes. It uses the process's shared
    OpenGL 3.3 core context (:func:`rigslim.device.egl.shared_context`).

    Raises
    ------
    rigslim.device.egl.EGLUnavailable
        When no EGL display gives an OpenGL context.
    """

    def __init__(self):
        from rigslim.device.egl import shared_context

        self.context = shared_context(3, 3)
        from OpenGL import GL

        from rigslim.kernels import source

        self.GL = GL
        self.program = self._link(source("render_vertex.glsl"), source("render_fragment.glsl"))
        self.vao = GL.glGenVertexArrays(1)
        self.buffers = GL.glGenBuffers(4)
        self.fbo = None
        self.size = None
        self._rbos = None

    @property
    def renderer_name(self) -> str:
        return self.context.renderer

    def _link(self, vs_src: str, fs_src: str):
        GL = self.GL
        shaders = []
        for kind, src in ((GL.GL_VERTEX_SHADER, vs_src), (GL.GL_FRAGMENT_SHADER, fs_src)):
            sh = GL.glCreateShader(kind)
            GL.glShaderSource(sh, src)
            GL.glCompileShader(sh)
            if not GL.glGetShaderiv(sh, GL.GL_COMPILE_STATUS):
                raise RuntimeError("render shader does not compile: " + GL.glGetShaderInfoLog(sh).decode())
            shaders.append(sh)
        prog = GL.glCreateProgram()
        for sh in shaders:
            GL.glAttachShader(prog, sh)
        GL.glLinkProgram(prog)
        if not GL.glGetProgramiv(prog, GL.GL_LINK_STATUS):
            raise RuntimeError("render program does not link: " + GL.glGetProgramInfoLog(prog).decode())
        for sh in shaders:
            GL.glDeleteShader(sh)
        return prog

    def _framebuffer(self, width: int, height: int):
        GL = self.GL
        if self.size == (width, height):
            GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
            return
        if self.fbo is not None:
            GL.glDeleteFramebuffers(1, [self.fbo])
            GL.glDeleteRenderbuffers(2, self._rbos)
        self.fbo = GL.glGenFramebuffers(1)
        self._rbos = GL.glGenRenderbuffers(2)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self.fbo)
        for rbo, fmt, attach in ((self._rbos[0], GL.GL_RGBA8, GL.GL_COLOR_ATTACHMENT0),
                                 (self._rbos[1], GL.GL_DEPTH_COMPONENT24, GL.GL_DEPTH_ATTACHMENT)):
            GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rbo)
            GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, fmt, width, height)
            GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, attach, GL.GL_RENDERBUFFER, rbo)
        status = GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER)
        if status != GL.GL_FRAMEBUFFER_COMPLETE:
            raise RuntimeError(f"offscreen framebuffer incomplete (0x{int(status):04X})")
        self.size = (width, height)

    def render(self, V, F, colors, camera: Camera, *, normals=None, light=None, ambient: float = AMBIENT,
               background=BACKGROUND) -> np.ndarray:
        """Same arguments and result as :func:`render_numpy`, drawn by OpenGL."""
        GL = self.GL
        V, F, colors, normals = _check_mesh(V, F, colors, normals)
        light = camera.headlight() if light is None else _normalize(light)
        self.context.make_current()
        W, H = camera.width, camera.height
        self._framebuffer(W, H)
        GL.glViewport(0, 0, W, H)
        GL.glClearColor(*[float(c) for c in background], 1.0)
        GL.glClearDepth(1.0)
        GL.glEnable(GL.GL_DEPTH_TEST)
        GL.glDepthFunc(GL.GL_LESS)
        GL.glDisable(GL.GL_CULL_FACE)
        GL.glDisable(GL.GL_BLEND)
        GL.glClear(GL.GL_COLOR_BUFFER_BIT | GL.GL_DEPTH_BUFFER_BIT)
        GL.glUseProgram(self.program)
        GL.glBindVertexArray(self.vao)
        for loc, data in enumerate((V, normals, colors)):
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self.buffers[loc])
            arr = np.ascontiguousarray(data, dtype=np.float32)
            GL.glBufferData(GL.GL_ARRAY_BUFFER, arr.nbytes, arr, GL.GL_STREAM_DRAW)
            GL.glEnableVertexAttribArray(loc)
            GL.glVertexAttribPointer(loc, 3, GL.GL_FLOAT, GL.GL_FALSE, 0, None)
        idx = np.ascontiguousarray(F, dtype=np.uint32)
        GL.glBindBuffer(GL.GL_ELEMENT_ARRAY_BUFFER, self.buffers[3])
        GL.glBufferData(GL.GL_ELEMENT_ARRAY_BUFFER, max(idx.nbytes, 4), idx if idx.size else None,
                        GL.GL_STREAM_DRAW)
        GL.glUniformMatrix4fv(GL.glGetUniformLocation(self.program, "u_mvp"), 1, GL.GL_TRUE,
                              np.ascontiguousarray(camera.mvp, dtype=np.float32))
        GL.glUniform3f(GL.glGetUniformLocation(self.program, "u_light"), *[float(x) for x in light])
        GL.glUniform1f(GL.glGetUniformLocation(self.program, "u_ambient"), float(ambient))
        if idx.size:
            GL.glDrawElements(GL.GL_TRIANGLES, int(idx.size), GL.GL_UNSIGNED_INT, None)
        GL.glPixelStorei(GL.GL_PACK_ALIGNMENT, 1)
        raw = GL.glReadPixels(0, 0, W, H, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE)
        GL.glBindVertexArray(0)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        pixels = np.frombuffer(raw if isinstance(raw, (bytes, bytearray)) else np.asarray(raw).tobytes(),
                               dtype=np.uint8).reshape(H, W, 4)
        return np.ascontiguousarray(pixels[::-1, :, :3])


_local = threading.local()


def gl_renderer() -> GLRenderer:
    """This thread's :class:`GLRenderer`, created on first use."""
    r = getattr(_local, "renderer", None)
    if r is None:
        r = _local.renderer = GLRenderer()
    return r


def render_mesh(V, F, colors, camera: Camera, *, normals=None, light=None, ambient: float = AMBIENT,
                background=BACKGROUND, backend: str = "auto") -> tuple[np.ndarray, str]:
    """Render a shaded mesh with OpenGL (EGL) or, failing that, numpy.

    Parameters
    ----------
    backend : {"auto", "opengl", "numpy"}
        ``auto`` uses OpenGL when an EGL context can be made, else numpy.
    Other parameters as :func:`render_numpy`.

    Returns
    -------
    image : (H, W, 3) uint8 array
    used : str
        ``"opengl: <GL renderer>"`` or ``"numpy"`` (and why OpenGL was not used).
    """
    if backend not in ("auto", "opengl", "numpy"):
        raise InputError(f"unknown render backend '{backend}'", field="backend",
                         fix="use 'auto', 'opengl' or 'numpy'")
    kw = dict(normals=normals, light=light, ambient=ambient, background=background)
    why = ""
    if backend in ("auto", "opengl"):
        from rigslim.device.egl import EGLUnavailable

        try:
            r = gl_renderer()
            return r.render(V, F, colors, camera, **kw), f"opengl: {r.renderer_name}"
        except EGLUnavailable as e:
            if backend == "opengl":
                raise
            why = f" (no OpenGL: {e.problem})"
    return render_numpy(V, F, colors, camera, **kw), "numpy" + why


def png_bytes(image: np.ndarray) -> bytes:
    """PNG encoding of an (H, W, 3) uint8 image."""
    import io

    from PIL import Image

    buf = io.BytesIO()
    Image.fromarray(np.ascontiguousarray(image, dtype=np.uint8)).save(buf, format="PNG", optimize=True)
    return buf.getvalue()
