"""The OpenGL deformer: a GLSL vertex shader (``kernels/blend_vertex.glsl``) with transform feedback.

As in [P10] section 5, weights and indices are vertex attributes (k rounded
up to a multiple of 4: ``ivec4``/``vec4`` attribute pairs, int32/float32 or
uint16/float16 in the compact layout) and the handle transforms are a
texture buffer. Rasterisation is switched off; ``glDrawArrays(GL_POINTS)``
runs the shader once per vertex and transform feedback captures positions
(and normals) into buffers that are read back. The context is headless EGL
(:func:`rigslim.device.egl.shared_context`): llvmpipe on a CPU machine, the NVIDIA
driver on a GPU one. Device time per frame comes from a ``GL_TIME_ELAPSED``
query (``last_seconds``), except on software renderers (llvmpipe), whose
query does not cover the vertex shading done inside the draw call: there
``last_seconds`` is the wall time of draw + ``glFinish`` and the query's
reading is kept in ``last_query_seconds``.
"""

from __future__ import annotations

import ctypes
import time
from typing import Literal

import numpy as np

import rigslim.device.egl  # noqa: F401  (light; sets PYOPENGL_PLATFORM=egl unless set, before anything imports OpenGL)
from rigslim.errors import StepError
from rigslim.plugin import Deformer
from rigslim.plugins.deformers.base import (
    DeformerParams,
    DeviceBound,
    Layout,
    check_weights,
    handle_data,
    n_handles_of,
    pack_weights,
    resolve_normals,
    rest_normal_data,
)

_NORMALS_CODE = {None: 0, "blended-matrix": 1, "approximate-affine": 2}


def _one(name) -> int:
    """A GL object name from a glGen* call (PyOpenGL returns an int or a 1-element array)."""
    return int(np.atleast_1d(name)[0])


def compile_program(source: str, defines: dict, varyings: list[str]):
    """Compile and link a vertex-only program whose outputs ``varyings`` go to separate feedback buffers."""
    from OpenGL import GL

    header = "#version 430 core\n" + "".join(f"#define {k} {v}\n" for k, v in defines.items())
    shader = GL.glCreateShader(GL.GL_VERTEX_SHADER)
    GL.glShaderSource(shader, header + source)
    GL.glCompileShader(shader)
    if not GL.glGetShaderiv(shader, GL.GL_COMPILE_STATUS):
        log = GL.glGetShaderInfoLog(shader).decode(errors="replace")
        raise RuntimeError(f"vertex shader does not compile: {log}")
    program = GL.glCreateProgram()
    GL.glAttachShader(program, shader)
    names = (ctypes.c_char_p * len(varyings))(*[v.encode() for v in varyings])
    GL.glTransformFeedbackVaryings(program, len(varyings),
                                   ctypes.cast(names, ctypes.POINTER(ctypes.POINTER(ctypes.c_char))),
                                   GL.GL_SEPARATE_ATTRIBS)
    GL.glLinkProgram(program)
    GL.glDeleteShader(shader)
    if not GL.glGetProgramiv(program, GL.GL_LINK_STATUS):
        log = GL.glGetProgramInfoLog(program).decode(errors="replace")
        raise RuntimeError(f"vertex program does not link: {log}")
    return program


class OpenGLBound(DeviceBound):
    """Vertex buffers, a handle texture buffer and feedback buffers for one mesh and weights."""

    backend = "opengl"

    def __init__(self, mesh, weights, normals_mode, handles, layout: str, fit_precision: str = "auto"):
        from rigslim.device.egl import shared_context
        from rigslim.kernels import source

        n = n_handles_of(weights)
        super().__init__(mesh.n_vertices, n, normals_mode)
        self.context = shared_context()      # before the first OpenGL import: it fixes PyOpenGL's platform
        from OpenGL import GL
        if layout == "csr":
            raise StepError("the OpenGL deformer takes weights as vertex attributes, not CSR", field="layout",
                            fix="use layout: fixed or compact (sparse input weights are padded to their widest row)")
        self.packed = pack_weights(weights, "fixed" if layout == "auto" else layout, n)
        self.layout = self.packed.layout
        self.C0 = handles.cage.V if (handles is not None and handles.is_cage) else None
        m = self.n_vertices
        k4 = max(1, -(-self.packed.k // 4))
        max_attribs = int(GL.glGetIntegerv(GL.GL_MAX_VERTEX_ATTRIBS))
        if 2 + 2 * k4 > max_attribs:
            raise StepError(f"k = {self.packed.k} needs {2 + 2 * k4} vertex attributes; this GL has {max_attribs}",
                            field="k", fix="reduce the weights to fewer influences, or use the opencl deformer")
        self.k4 = k4
        #: approximate-affine fit in double precision (GLSL 4.00+ has doubles; positions stay float32)
        self.fit_double = normals_mode == "approximate-affine" and fit_precision != "single"
        compact = self.layout == "compact"
        idx = np.zeros((m, 4 * k4), dtype=np.uint16 if compact else np.int32)
        val = np.zeros((m, 4 * k4), dtype=np.float16 if compact else np.float32)
        idx[:, :self.packed.k] = self.packed.indices
        val[:, :self.packed.k] = self.packed.values
        self._attribute_bytes = idx.nbytes + val.nbytes
        rest = np.ascontiguousarray(mesh.V, dtype=np.float32)
        self._mesh, self._weights_in, self._handles_in = mesh, self.packed.effective, handles

        self.context.make_current()
        self._upload_vertex_arrays(rest, idx, val)
        self._create_handle_texture(n)
        self._create_feedback_targets(m)
        self._source = source("blend_vertex.glsl")
        self._programs: dict[bool, int] = {}
        self._host_positions = np.empty((m, 3), dtype=np.float32)
        self._host_normals = np.empty((m, 3), dtype=np.float32)

    def _upload_vertex_arrays(self, rest: np.ndarray, idx: np.ndarray, val: np.ndarray) -> None:
        """The vertex array: rest positions (attribute 0), normal data (1, a constant until the first normals
        frame), then ``k4`` attributes of 4 handle indices and ``k4`` of 4 weights."""
        from OpenGL import GL

        k4, compact = self.k4, self.layout == "compact"
        self._vao: int | None = _one(GL.glGenVertexArrays(1))  # None once closed
        GL.glBindVertexArray(self._vao)
        self._buffers = [int(b) for b in np.atleast_1d(GL.glGenBuffers(4))]
        b_rest, b_normal, b_idx, b_val = self._buffers

        def array_buffer(buf, array):
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, buf)
            GL.glBufferData(GL.GL_ARRAY_BUFFER, array.nbytes, array, GL.GL_STATIC_DRAW)

        array_buffer(b_rest, rest)
        GL.glEnableVertexAttribArray(0)
        GL.glVertexAttribPointer(0, 3, GL.GL_FLOAT, GL.GL_FALSE, 12, None)
        GL.glVertexAttrib4f(1, 0.0, 0.0, 0.0, 0.0)     # normal data: a buffer on the first normals frame
        self._has_normal_data = False
        array_buffer(b_idx, idx)
        itype, isize = (GL.GL_UNSIGNED_SHORT, 2) if compact else (GL.GL_INT, 4)
        for j in range(k4):
            GL.glEnableVertexAttribArray(2 + j)
            GL.glVertexAttribIPointer(2 + j, 4, itype, 4 * k4 * isize, ctypes.c_void_p(4 * j * isize))
        array_buffer(b_val, val)
        vtype, vsize = (GL.GL_HALF_FLOAT, 2) if compact else (GL.GL_FLOAT, 4)
        for j in range(k4):
            GL.glEnableVertexAttribArray(2 + k4 + j)
            GL.glVertexAttribPointer(2 + k4 + j, 4, vtype, GL.GL_FALSE, 4 * k4 * vsize,
                                     ctypes.c_void_p(4 * j * vsize))
        GL.glBindVertexArray(0)

    def _create_handle_texture(self, n: int) -> None:
        """The handle records: a texture buffer of n * 5 RGBA32F texels, rewritten each frame."""
        from OpenGL import GL

        self._tbo = _one(GL.glGenBuffers(1))
        GL.glBindBuffer(GL.GL_TEXTURE_BUFFER, self._tbo)
        GL.glBufferData(GL.GL_TEXTURE_BUFFER, n * 5 * 16, None, GL.GL_DYNAMIC_DRAW)
        self._texture = _one(GL.glGenTextures(1))
        GL.glBindTexture(GL.GL_TEXTURE_BUFFER, self._texture)
        GL.glTexBuffer(GL.GL_TEXTURE_BUFFER, GL.GL_RGBA32F, self._tbo)

    def _create_feedback_targets(self, m: int) -> None:
        """Transform feedback buffers (positions and normals, 12 bytes per vertex each), the query that
        counts them, and a 1x1 framebuffer for the draw calls."""
        from OpenGL import GL

        self._feedback = [int(b) for b in np.atleast_1d(GL.glGenBuffers(2))]
        for buf in self._feedback:
            GL.glBindBuffer(GL.GL_TRANSFORM_FEEDBACK_BUFFER, buf)
            GL.glBufferData(GL.GL_TRANSFORM_FEEDBACK_BUFFER, max(m, 1) * 12, None, GL.GL_STREAM_READ)
        GL.glBindBuffer(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 0)
        self._query = _one(GL.glGenQueries(1))
        # A surfaceless context has no default framebuffer and a draw call wants a complete one,
        # even with rasterisation discarded: a 1x1 colour renderbuffer does.
        self._rbo = _one(GL.glGenRenderbuffers(1))
        GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, self._rbo)
        GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, 1, 1)
        self._fbo = _one(GL.glGenFramebuffers(1))
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, self._rbo)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)

    def _program(self, normals: bool):
        """The program for this normal mode, linked (and normal data uploaded) on first use."""
        from OpenGL import GL

        if normals and not self._has_normal_data:
            data = rest_normal_data(self.normals_mode, self._mesh, self._weights_in, self._handles_in)
            data = np.ascontiguousarray(data, dtype=np.float32)
            GL.glBindVertexArray(self._vao)
            GL.glBindBuffer(GL.GL_ARRAY_BUFFER, self._buffers[1])
            GL.glBufferData(GL.GL_ARRAY_BUFFER, data.nbytes, data, GL.GL_STATIC_DRAW)
            GL.glEnableVertexAttribArray(1)
            GL.glVertexAttribPointer(1, 4, GL.GL_FLOAT, GL.GL_FALSE, 16, None)
            GL.glBindVertexArray(0)
            self._has_normal_data = True
        if normals not in self._programs:
            code = _NORMALS_CODE[self.normals_mode] if normals else 0
            varyings = ["out_position", "out_normal"] if normals else ["out_position"]
            program = compile_program(self._source, {"K4": self.k4, "WEIGHT_LOCATION": 2 + self.k4,
                                                     "NORMALS": code, "FIT_DOUBLE": int(self.fit_double)},
                                      varyings)
            GL.glUseProgram(program)
            GL.glUniform1i(GL.glGetUniformLocation(program, "handles"), 0)
            self._programs[normals] = program
        return self._programs[normals]

    def launch(self, T: np.ndarray, normals: bool = False, read: bool = True) -> None:
        """Upload T, run the shader over all vertices with transform feedback; optionally read back."""
        from OpenGL import GL

        self.context.make_current()
        records = handle_data(T, self.C0)
        GL.glBindBuffer(GL.GL_TEXTURE_BUFFER, self._tbo)
        GL.glBufferSubData(GL.GL_TEXTURE_BUFFER, 0, records.nbytes, records)
        GL.glActiveTexture(GL.GL_TEXTURE0)
        GL.glBindTexture(GL.GL_TEXTURE_BUFFER, self._texture)
        GL.glUseProgram(self._program(normals))
        GL.glBindVertexArray(self._vao)
        GL.glBindBufferBase(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 0, self._feedback[0])
        if normals:
            GL.glBindBufferBase(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 1, self._feedback[1])
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, self._fbo)
        GL.glEnable(GL.GL_RASTERIZER_DISCARD)
        start = time.perf_counter()
        GL.glBeginQuery(GL.GL_TIME_ELAPSED, self._query)
        GL.glBeginTransformFeedback(GL.GL_POINTS)
        GL.glDrawArrays(GL.GL_POINTS, 0, self.n_vertices)
        GL.glEndTransformFeedback()
        GL.glEndQuery(GL.GL_TIME_ELAPSED)
        if self.context.is_software:
            GL.glFinish()
            wall = time.perf_counter() - start
        GL.glDisable(GL.GL_RASTERIZER_DISCARD)
        GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
        if read:
            GL.glBindBuffer(GL.GL_TRANSFORM_FEEDBACK_BUFFER, self._feedback[0])
            GL.glGetBufferSubData(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 0, self._host_positions.nbytes,
                                  self._host_positions.ctypes.data_as(ctypes.c_void_p))
            if normals:
                GL.glBindBuffer(GL.GL_TRANSFORM_FEEDBACK_BUFFER, self._feedback[1])
                GL.glGetBufferSubData(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 0, self._host_normals.nbytes,
                                      self._host_normals.ctypes.data_as(ctypes.c_void_p))
        elapsed = ctypes.c_uint64(0)
        GL.glGetQueryObjectui64v(self._query, GL.GL_QUERY_RESULT, ctypes.byref(elapsed))
        self.last_query_seconds = elapsed.value * 1e-9
        # llvmpipe shades vertices on the CPU inside the draw call; its timer query does not cover that
        # work (it reads ~50 ns), so software renderers report the wall time of draw + glFinish instead.
        self.last_seconds = wall if self.context.is_software else self.last_query_seconds
        GL.glBindBufferBase(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 0, 0)
        GL.glBindBufferBase(GL.GL_TRANSFORM_FEEDBACK_BUFFER, 1, 0)
        GL.glBindVertexArray(0)
        GL.glUseProgram(0)

    def bytes_per_frame(self, normals: bool) -> int:
        m = self.n_vertices
        moved = 12 * m + self._attribute_bytes + self.n_handles * 80 + 12 * m
        if normals:
            moved += 16 * m + 12 * m
        return int(moved)

    def close(self) -> None:
        from OpenGL import GL

        if getattr(self, "_vao", None) is None or self.context.closed:
            return
        self.context.make_current()
        for program in self._programs.values():
            GL.glDeleteProgram(program)
        GL.glDeleteBuffers(len(self._buffers), self._buffers)
        GL.glDeleteBuffers(len(self._feedback), self._feedback)
        GL.glDeleteBuffers(1, [self._tbo])
        GL.glDeleteTextures(1, [self._texture])
        GL.glDeleteQueries(1, [self._query])
        GL.glDeleteFramebuffers(1, [self._fbo])
        GL.glDeleteRenderbuffers(1, [self._rbo])
        GL.glDeleteVertexArrays(1, [self._vao])
        self._vao = None


class OpenGLDeformer(Deformer):
    """Linear blend skinning in a GLSL vertex shader, read back with transform feedback.

    Notes
    -----
    The shader evaluates ``v' = (sum_l w_l T_{i_l}) [v; 1]`` per vertex, with
    the same normal formulas as the OpenCL kernel (``kernels/blend_vertex.glsl``
    is its twin); the numpy reference is
    :class:`rigslim.plugins.deformers.numpy_deformer.NumpyDeformer`.
    """

    name = "opengl"
    summary = ("GLSL vertex shader (kernels/blend_vertex.glsl) with transform feedback in a headless EGL "
               "context; weights/indices as vertex attributes, transforms in a texture buffer")

    class Params(DeformerParams):
        layout: Layout = "auto"
        """Attribute layout: auto/fixed (int32 + float32) or compact (uint16 + float16). Sparse input weights are
        padded to their widest row."""
        fit_precision: Literal["auto", "single", "double"] = "auto"
        """Arithmetic of the approximate-affine fit: auto/double (GLSL doubles) or single (float32: error about
        cond(P) * 6e-8 rad)."""

    def bind(self, mesh, weights, params=None, handles=None, ctx=None) -> OpenGLBound:
        params = params if params is not None else self.Params()
        weights = check_weights(mesh, weights, source="opengl deformer")
        mode = resolve_normals(params.normals, handles)
        return OpenGLBound(mesh, weights, mode, handles, params.layout, params.fit_precision)
