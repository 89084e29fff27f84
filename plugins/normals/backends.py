"""Normal estimation on a deformer back end (OpenCL kernel or GLSL shader).

The blended-matrix and approximate-affine estimators take ``backend:
numpy | cpu | opencl | opengl``. For the compiled and GPU back ends the estimator binds the
deformer of that back end with in-kernel normals once per (mesh, weights,
handles) and reads the normals it computes beside the positions, so that an
evaluation measures exactly what the kernel or shader produces.
"""

from __future__ import annotations

from typing import Literal

import numpy as np

Backend = Literal["numpy", "cpu", "opencl", "opengl"]

_bound: dict = {}


def bound_deformer(backend: str, mode: str, mesh, weights, handles, device: str | None = None):
    """A deformer of ``backend`` bound with ``normals=mode``, cached by object identity."""
    key = (backend, mode, device)
    entry = _bound.get(key)
    if entry is not None and entry[0] is mesh and entry[1] is weights and entry[2] is handles:
        return entry[3]
    if entry is not None:
        entry[3].close()
    from rigslim.plugin import Deformer
    from rigslim.plugin.host import get_host

    # the deformer plugin of that name, through the host: no plugin package imports another
    deformer = get_host().get("deformer", backend)
    assert isinstance(deformer, Deformer)  # the host loads only Deformer instances as deformers
    raw = {"normals": mode}
    if device is not None and backend == "opencl":
        raw["device"] = device
    bound = deformer.bind(mesh, weights, deformer.parse_params(raw), handles=handles)
    _bound[key] = (mesh, weights, handles, bound)
    return bound


def normals_from_backend(backend: str, mode: str, mesh, weights, handles, T, device: str | None = None) -> np.ndarray:
    """(m, 3) float64 unit normals of pose T computed by the back end's kernel or shader."""
    bound = bound_deformer(backend, mode, mesh, weights, handles, device)
    _, N = bound.deform(np.asarray(T, dtype=np.float64), normals=True)
    return np.asarray(N, dtype=np.float64)
