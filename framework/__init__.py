"""rigslim: fewer weights and fewer triangles for animated meshes, same motion.

The host package. Import cost is kept small: numpy and scipy are the only
heavy imports here; libigl, OpenCL, OpenGL, pymeshlab and pygltflib are
imported by the plugins that need them, when they run.
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("rigslim")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

from rigslim.errors import RigslimError  # noqa: E402
from rigslim.numba_threads import configure as _configure_numba_threads  # noqa: E402

_configure_numba_threads()  # before numba is imported: a new-enough TBB, or none (rigslim.numba_threads)

__all__ = ["__version__", "RigslimError"]

from rigslim.hookspecs import hookimpl  # noqa: E402

__all__.append("hookimpl")
