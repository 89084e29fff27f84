"""Headless OpenGL contexts through EGL, shared by every OpenGL plugin.

No window system is needed: the context is made current without a surface
(``EGL_KHR_surfaceless_context``) and programs draw into framebuffer objects
or capture with transform feedback. Displays are tried in this order:

1. ``device``: ``eglQueryDevicesEXT`` + ``eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT)``,
   what the NVIDIA driver offers on a headless GPU machine;
2. ``surfaceless``: ``eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA = 0x31DD)``,
   Mesa (llvmpipe on a CPU-only machine);
3. ``default``: ``eglGetDisplay(EGL_DEFAULT_DISPLAY)``.

The first one on which an OpenGL (not ES) core-profile context of the asked
version (4.3 by default: compute shaders, SSBOs, debug output) can be made
current wins.

PyOpenGL picks its platform once, at its first import, from the
``PYOPENGL_PLATFORM`` environment variable; :func:`create_context` sets it to
``egl`` when unset, so import :mod:`OpenGL` only after calling it (or set
``PYOPENGL_PLATFORM=egl`` yourself).

Example
-------
>>> from rigslim.device.egl import create_context
>>> ctx = create_context()                        # doctest: +SKIP
>>> ctx.renderer, ctx.version                     # doctest: +SKIP
('llvmpipe (LLVM 15.0.6, 256 bits)', '4.5 (Core Profile) Mesa 22.3.6')
>>> ctx.make_current()                            # doctest: +SKIP
>>> ctx.close()                                   # doctest: +SKIP
"""

from __future__ import annotations

import ctypes
import os
import threading
from dataclasses import dataclass, field

from rigslim.errors import RigslimError

#: ``EGL_PLATFORM_SURFACELESS_MESA`` (EGL_MESA_platform_surfaceless).
EGL_PLATFORM_SURFACELESS_MESA = 0x31DD
#: ``EGL_PLATFORM_DEVICE_EXT`` (EGL_EXT_platform_device).
EGL_PLATFORM_DEVICE_EXT = 0x313F
#: Display kinds, in the order :func:`create_context` tries them.
PLATFORMS = ("device", "surfaceless", "default")

# PyOpenGL reads this once, at its first import: importing this module first is enough.
os.environ.setdefault("PYOPENGL_PLATFORM", "egl")

_lock = threading.Lock()
_shared: dict = {}


class EGLUnavailable(RigslimError):
    """No EGL display on which an OpenGL context of the asked version can be created."""


@dataclass(eq=False)
class EGLContext:
    """A headless OpenGL context and what it runs on.

    Attributes
    ----------
    platform : {"device", "surfaceless", "default"}
        Which display kind the context was made on.
    renderer, version, vendor : str
        ``glGetString`` of ``GL_RENDERER``, ``GL_VERSION`` and ``GL_VENDOR``
        (e.g. ``"llvmpipe (LLVM 15.0.6, 256 bits)"``, ``"4.5 (Core Profile) Mesa 22.3.6"``).
    egl_version, egl_vendor : str
        The display's ``EGL_VERSION`` and ``EGL_VENDOR``.
    attempts : list of str
        One line per display tried before this one and why it failed.
    display, context :
        The raw EGL handles.
    """

    platform: str
    renderer: str
    version: str
    vendor: str
    egl_version: str
    egl_vendor: str
    display: object = field(repr=False)
    context: object = field(repr=False)
    attempts: list = field(default_factory=list)
    closed: bool = False

    @property
    def info(self) -> dict:
        """Plain-data description (for reports and benchmark JSON)."""
        return {"platform": self.platform, "renderer": self.renderer, "version": self.version,
                "vendor": self.vendor, "egl_version": self.egl_version, "egl_vendor": self.egl_vendor}

    @property
    def is_software(self) -> bool:
        """True on Mesa's CPU rasterisers (llvmpipe, softpipe, lavapipe)."""
        r = self.renderer.lower()
        return any(s in r for s in ("llvmpipe", "softpipe", "swrast", "lavapipe"))

    def make_current(self) -> None:
        """Make this context current on the calling thread (no surface)."""
        from OpenGL import EGL

        if self.closed:
            raise EGLUnavailable("the OpenGL context was closed", field="context",
                                 fix="create a new one with rigslim.device.egl.create_context()")
        if not EGL.eglMakeCurrent(self.display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, self.context):
            raise EGLUnavailable(f"eglMakeCurrent failed (0x{EGL.eglGetError():04X})", field="context",
                                 fix="create the context on this thread")

    def release(self) -> None:
        """Make no context current on the calling thread."""
        from OpenGL import EGL

        EGL.eglMakeCurrent(self.display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, EGL.EGL_NO_CONTEXT)

    def close(self) -> None:
        """Destroy the context (the display stays initialised for others)."""
        from OpenGL import EGL

        if not self.closed:
            self.release()
            EGL.eglDestroyContext(self.display, self.context)
            self.closed = True

    def __enter__(self) -> EGLContext:
        self.make_current()
        return self

    def __exit__(self, *exc) -> None:
        self.close()


def _import_egl():
    wanted = os.environ.setdefault("PYOPENGL_PLATFORM", "egl")
    if wanted != "egl":
        raise EGLUnavailable(f"PYOPENGL_PLATFORM is '{wanted}', not 'egl'", field="PYOPENGL_PLATFORM",
                             fix="unset PYOPENGL_PLATFORM or set it to egl")
    try:
        import OpenGL
        import OpenGL.platform
        from OpenGL import EGL
    except ImportError:
        raise EGLUnavailable("PyOpenGL is not installed", field="opengl",
                             fix="pip install 'rigslim[opengl]'") from None
    except Exception as e:  # libEGL missing: PyOpenGL raises on loading the platform
        raise EGLUnavailable(f"cannot load libEGL ({e})", field="libEGL",
                             fix="install libegl1 and libgl1-mesa-dri (tools/setup-egl.sh)") from None
    plat = type(OpenGL.platform.PLATFORM).__name__
    if "EGL" not in plat:
        raise EGLUnavailable(f"PyOpenGL was already imported with the {plat} platform", field="PYOPENGL_PLATFORM",
                             fix="set PYOPENGL_PLATFORM=egl before anything imports OpenGL")
    return EGL


def _short(e: Exception) -> str:
    """A one-line description of an EGL/PyOpenGL exception (EGLError reprs span many lines)."""
    err = getattr(e, "err", None)
    if err is not None:
        return str(getattr(err, "name", None) or err)
    return f"{type(e).__name__}: {str(e).splitlines()[0] if str(e) else ''}"


def _displays(EGL, platforms, device_index):
    """Yield (platform name, display or None, note) for each display kind to try."""
    for kind in platforms:
        try:
            if kind == "device":
                from OpenGL.EGL.EXT.device_enumeration import eglQueryDevicesEXT
                from OpenGL.EGL.EXT.platform_base import eglGetPlatformDisplayEXT

                count = EGL.EGLint()
                if not eglQueryDevicesEXT(0, None, ctypes.pointer(count)) or count.value == 0:
                    yield kind, None, "no EGL devices"
                    continue
                devices = (EGL.EGLDeviceEXT * count.value)()
                eglQueryDevicesEXT(count.value, devices, ctypes.pointer(count))
                order = range(count.value) if device_index is None else [device_index]
                for i in order:
                    if i >= count.value:
                        yield f"device {i}", None, f"only {count.value} EGL devices"
                        continue
                    yield f"device {i}", eglGetPlatformDisplayEXT(EGL_PLATFORM_DEVICE_EXT, devices[i], None), ""
            elif kind == "surfaceless":
                from OpenGL.EGL.EXT.platform_base import eglGetPlatformDisplayEXT

                yield kind, eglGetPlatformDisplayEXT(EGL_PLATFORM_SURFACELESS_MESA, None, None), ""
            elif kind == "default":
                yield kind, EGL.eglGetDisplay(EGL.EGL_DEFAULT_DISPLAY), ""
            else:
                raise EGLUnavailable(f"unknown EGL platform '{kind}'", field="platforms",
                                     fix="use some of " + ", ".join(PLATFORMS))
        except EGLUnavailable:
            raise
        except Exception as e:  # missing extension entry points, driver errors
            yield kind, None, _short(e)


def _try_display(EGL, display, major: int, minor: int):
    """Initialise a display and make a core context current on it; return (context, note)."""
    from OpenGL import GL

    if not display:
        return None, "no display"
    vmaj, vmin = EGL.EGLint(), EGL.EGLint()
    try:
        if not EGL.eglInitialize(display, ctypes.pointer(vmaj), ctypes.pointer(vmin)):
            return None, f"eglInitialize failed (0x{EGL.eglGetError():04X})"
    except Exception as e:
        return None, f"eglInitialize failed ({_short(e)})"
    config, n = EGL.EGLConfig(), EGL.EGLint()
    try:
        if not EGL.eglBindAPI(EGL.EGL_OPENGL_API):
            return None, "no desktop OpenGL API"
        for attrs in ([EGL.EGL_SURFACE_TYPE, EGL.EGL_PBUFFER_BIT, EGL.EGL_RENDERABLE_TYPE, EGL.EGL_OPENGL_BIT,
                       EGL.EGL_NONE],
                      [EGL.EGL_RENDERABLE_TYPE, EGL.EGL_OPENGL_BIT, EGL.EGL_NONE]):
            arr = (EGL.EGLint * len(attrs))(*attrs)
            if EGL.eglChooseConfig(display, arr, ctypes.pointer(config), 1, ctypes.pointer(n)) and n.value > 0:
                break
        else:
            return None, "no config with OpenGL rendering"
    except Exception as e:
        return None, f"no OpenGL config ({_short(e)})"
    attrs = [EGL.EGL_CONTEXT_MAJOR_VERSION, major, EGL.EGL_CONTEXT_MINOR_VERSION, minor,
             EGL.EGL_CONTEXT_OPENGL_PROFILE_MASK, EGL.EGL_CONTEXT_OPENGL_CORE_PROFILE_BIT, EGL.EGL_NONE]
    try:
        context = EGL.eglCreateContext(display, config, EGL.EGL_NO_CONTEXT, (EGL.EGLint * len(attrs))(*attrs))
    except Exception as e:  # PyOpenGL raises EGLError (EGL_BAD_MATCH for an unsupported version)
        return None, f"no OpenGL {major}.{minor} core context ({_short(e)})"
    if not context:
        return None, f"no OpenGL {major}.{minor} core context"
    try:
        current = EGL.eglMakeCurrent(display, EGL.EGL_NO_SURFACE, EGL.EGL_NO_SURFACE, context)
    except Exception as e:
        current, why = False, _short(e)
    else:
        why = "" if current else "returned false"
    if not current:
        EGL.eglDestroyContext(display, context)
        return None, f"eglMakeCurrent without surface failed ({why})"

    def text(name):
        value = GL.glGetString(name)
        return value.decode(errors="replace") if value else ""

    info = dict(renderer=text(GL.GL_RENDERER), version=text(GL.GL_VERSION), vendor=text(GL.GL_VENDOR),
                egl_version=f"{vmaj.value}.{vmin.value}",
                egl_vendor=(EGL.eglQueryString(display, EGL.EGL_VENDOR) or b"").decode(errors="replace"))
    return (context, info), ""


def create_context(major: int = 4, minor: int = 3, *, platforms=PLATFORMS,
                   device_index: int | None = None) -> EGLContext:
    """Create a headless OpenGL core-profile context and make it current.

    Parameters
    ----------
    major, minor : int
        Minimum OpenGL version (core profile); 4.3 by default.
    platforms : sequence of {"device", "surfaceless", "default"}
        Display kinds to try, in order.
    device_index : int, optional
        Only this EGL device on the ``device`` platform (default: each in turn).
        The ``RIGSLIM_EGL_DEVICE`` environment variable sets it too.

    Returns
    -------
    EGLContext
        Current on the calling thread; ``.info`` has the renderer string.

    Raises
    ------
    EGLUnavailable
        When no display kind yields a context; the message lists why each failed.
    """
    EGL = _import_egl()
    if device_index is None and os.environ.get("RIGSLIM_EGL_DEVICE", "").strip().isdigit():
        device_index = int(os.environ["RIGSLIM_EGL_DEVICE"])
    attempts = []
    for kind, display, note in _displays(EGL, platforms, device_index):
        if display is None or note:
            attempts.append(f"{kind}: {note or 'no display'}")
            continue
        made, note = _try_display(EGL, display, major, minor)
        if made is None:
            attempts.append(f"{kind}: {note}")
            continue
        context, info = made
        return EGLContext(platform=kind.split()[0], display=display, context=context, attempts=attempts, **info)
    raise EGLUnavailable(f"no EGL display gives an OpenGL {major}.{minor} core context ({'; '.join(attempts)})",
                         field="EGL", fix="install Mesa's EGL and DRI drivers (tools/setup-egl.sh) or a GPU driver")


def shared_context(major: int = 4, minor: int = 3) -> EGLContext:
    """One context per process and version, created on first use and made current on every call.

    Plugins that only need *a* context (deformers, offscreen renderers) share
    it instead of creating one each; EGL contexts are current per thread, so
    call this (or ``make_current``) on the thread that issues GL calls.
    """
    with _lock:
        ctx = _shared.get((major, minor))
        if ctx is None or ctx.closed:
            ctx = _shared[(major, minor)] = create_context(major, minor)
        else:
            ctx.make_current()
        return ctx
