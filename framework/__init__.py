"""rigslim: fewer weights and fewer triangles for animated meshes, same motion.

The host package. Import cost is kept small: numpy and scipy are the only
heavy imports here; libigl, OpenCL, OpenGL, pymeshlab and pygltflib are
imported by the plugins that need them, when they run. The Python API
(:mod:`rigslim.api`, docs/python.md) is loaded on first use::

    import rigslim

    rigslim.registry()["weight-solver"]                  # plugins by stage
    result = rigslim.Pipeline.from_yaml("examples/elephant-k4.yaml").run()
    reduced = rigslim.reduce_weights(mesh, weights, poses, k=4, solve="poisson")

The subpackages, by purpose (docs/layout.md): :mod:`rigslim.model`, :mod:`rigslim.numerics`,
:mod:`rigslim.io`, :mod:`rigslim.plugin`, :mod:`rigslim.runtime`, :mod:`rigslim.report`,
:mod:`rigslim.batch`, :mod:`rigslim.commands`, and :mod:`rigslim.device` beside them. The module paths
from before that layout (``rigslim.mesh``, ``rigslim.pipeline``...) still import (:mod:`rigslim.compat`).
"""

from importlib.metadata import PackageNotFoundError
from importlib.metadata import version as _version
from typing import Any

try:
    __version__ = _version("rigslim")
except PackageNotFoundError:  # running from a source tree that is not installed
    __version__ = "0.0.0+unknown"

from rigslim.compat import install as _install_old_paths  # noqa: E402

_install_old_paths()

from rigslim.device.numba_threads import configure as _configure_numba_threads  # noqa: E402
from rigslim.errors import RigslimError  # noqa: E402

_configure_numba_threads()  # before numba is imported: a new-enough TBB, or none (rigslim.device.numba_threads)

from rigslim.plugin.contract import PLUGIN_API_VERSION  # noqa: E402
from rigslim.plugin.hookspecs import hookimpl  # noqa: E402

__all__ = ["__version__", "PLUGIN_API_VERSION", "RigslimError", "hookimpl", "Pipeline", "RunResult", "reduce_weights",
           "registry", "simplify"]

_API = {"Pipeline": "rigslim.api", "reduce_weights": "rigslim.api", "registry": "rigslim.api",
        "simplify": "rigslim.api", "RunResult": "rigslim.runtime.run"}


def __getattr__(name: str) -> Any:
    if name in _API:
        import importlib

        value = getattr(importlib.import_module(_API[name]), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module 'rigslim' has no attribute {name!r}")


def __dir__() -> list[str]:
    return sorted(set(globals()) | set(__all__))
