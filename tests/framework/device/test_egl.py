"""Headless EGL contexts (rigslim.device.egl): display fallbacks, version, info, errors."""

from __future__ import annotations

import pytest

from rigslim.device.egl import EGLUnavailable, create_context, shared_context

pytestmark = pytest.mark.opengl


@pytest.fixture(scope="module")
def context():
    try:
        ctx = create_context()
    except EGLUnavailable as e:
        pytest.skip(f"no EGL display can give an OpenGL 4.3 core context here: {e}")
    yield ctx
    ctx.close()


def test_context_is_core_43_and_reports_renderer(context):
    from OpenGL import GL

    context.make_current()
    major = GL.glGetIntegerv(GL.GL_MAJOR_VERSION)
    minor = GL.glGetIntegerv(GL.GL_MINOR_VERSION)
    assert (int(major), int(minor)) >= (4, 3)
    assert GL.glGetIntegerv(GL.GL_CONTEXT_PROFILE_MASK) & GL.GL_CONTEXT_CORE_PROFILE_BIT
    assert context.renderer and context.version
    assert context.platform in ("device", "surfaceless", "default")
    assert set(context.info) >= {"platform", "renderer", "version", "vendor"}


def test_surfaceless_mesa_display_works_alone(context):
    """The Mesa surfaceless platform (0x31DD) on its own; on NVIDIA-only machines it may be absent."""
    if context.platform == "device" and not context.is_software:
        pytest.skip(f"not a Mesa machine ({context.renderer})")
    ctx = create_context(platforms=("surfaceless",))
    try:
        assert ctx.platform == "surfaceless"
        assert ctx.renderer == context.renderer
    finally:
        ctx.close()
        context.make_current()


def test_context_draws_into_framebuffer(context):
    """A clear into a renderbuffer reads back: the context really renders without a surface."""
    import numpy as np
    from OpenGL import GL

    context.make_current()
    fbo = GL.glGenFramebuffers(1)
    rbo = GL.glGenRenderbuffers(1)
    GL.glBindRenderbuffer(GL.GL_RENDERBUFFER, rbo)
    GL.glRenderbufferStorage(GL.GL_RENDERBUFFER, GL.GL_RGBA8, 4, 4)
    GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, fbo)
    GL.glFramebufferRenderbuffer(GL.GL_FRAMEBUFFER, GL.GL_COLOR_ATTACHMENT0, GL.GL_RENDERBUFFER, rbo)
    assert GL.glCheckFramebufferStatus(GL.GL_FRAMEBUFFER) == GL.GL_FRAMEBUFFER_COMPLETE
    GL.glClearColor(0.0, 1.0, 0.0, 1.0)
    GL.glClear(GL.GL_COLOR_BUFFER_BIT)
    pixels = np.frombuffer(GL.glReadPixels(0, 0, 4, 4, GL.GL_RGBA, GL.GL_UNSIGNED_BYTE), dtype=np.uint8)
    GL.glBindFramebuffer(GL.GL_FRAMEBUFFER, 0)
    GL.glDeleteFramebuffers(1, [fbo])
    GL.glDeleteRenderbuffers(1, [rbo])
    assert (pixels.reshape(-1, 4) == [0, 255, 0, 255]).all()


def test_shared_context_is_reused(context):
    a = shared_context()
    b = shared_context()
    assert a is b and not a.closed
    context.make_current()


def test_unknown_platform_and_impossible_version_are_one_line_errors(context):
    with pytest.raises(EGLUnavailable, match="unknown EGL platform"):
        create_context(platforms=("wayland-please",))
    with pytest.raises(EGLUnavailable) as err:
        create_context(9, 9)
    assert "9.9" in str(err.value) and "\n" not in str(err.value) and err.value.fix
    context.make_current()


def test_closed_context_cannot_be_made_current(context):
    ctx = create_context(platforms=(context.platform,) if context.platform != "device" else ("device",))
    ctx.close()
    with pytest.raises(EGLUnavailable, match="closed"):
        ctx.make_current()
    context.make_current()
