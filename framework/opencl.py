"""OpenCL contexts and programs, shared by every OpenCL plugin.

Device choice, in order: the ``device`` argument, the ``RIGSLIM_OPENCL_DEVICE``
environment variable, then the first GPU of any platform, else the first CPU
device (PoCL, installed from PyPI by ``pocl-binary-distribution``).
A device string is ``"gpu"``, ``"cpu"``, ``"auto"``, or a case-insensitive
substring of a device or platform name (``"nvidia"``, ``"pocl"``).

Programs are built once per (context, source, options) and cached; kernels
live as ``*.cl`` files in :mod:`rigslim.kernels`.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from functools import lru_cache

from rigslim.errors import RigslimError

ENV_DEVICE = "RIGSLIM_OPENCL_DEVICE"


class OpenCLUnavailable(RigslimError):
    """No OpenCL platform or no matching device."""


@dataclass(frozen=True)
class CLRuntime:
    """A context, a profiling-enabled queue and the device they run on."""

    context: object
    queue: object
    device: object

    @property
    def name(self) -> str:
        return f"{self.device.name.strip()} ({self.device.platform.name.strip()})"


def _import_cl():
    try:
        import pyopencl as cl
    except ImportError:
        raise OpenCLUnavailable("pyopencl is not installed", field="device",
                                fix="pip install 'rigslim[opencl]' (pyopencl and pocl-binary-distribution)") from None
    return cl


def list_devices() -> list:
    """Every OpenCL device of every platform."""
    cl = _import_cl()
    try:
        platforms = cl.get_platforms()
    except cl.LogicError:
        return []
    return [d for p in platforms for d in p.get_devices()]


def pick_device(spec: str | None = None):
    """The device a spec names (see module docstring)."""
    cl = _import_cl()
    spec = (spec or os.environ.get(ENV_DEVICE) or "auto").strip().lower()
    devices = list_devices()
    if not devices:
        raise OpenCLUnavailable("no OpenCL platform found", field="device",
                                fix="pip install pocl-binary-distribution, or install a GPU driver's ICD")
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    cpus = [d for d in devices if d.type & cl.device_type.CPU]
    if spec == "auto":
        return (gpus or cpus or devices)[0]
    if spec == "gpu":
        if not gpus:
            raise OpenCLUnavailable("no OpenCL GPU device", field="device",
                                    fix="use device: auto or cpu, or install the GPU's OpenCL driver")
        return gpus[0]
    if spec == "cpu":
        if not cpus:
            raise OpenCLUnavailable("no OpenCL CPU device", field="device", fix="pip install pocl-binary-distribution")
        return cpus[0]
    for d in devices:
        if spec in d.name.lower() or spec in d.platform.name.lower():
            return d
    names = ", ".join(f"{d.name.strip()} ({d.platform.name.strip()})" for d in devices)
    raise OpenCLUnavailable(f"no OpenCL device matches '{spec}'", field="device",
                            fix=f"use auto, gpu, cpu or part of one of: {names}")


@lru_cache(maxsize=None)
def _runtime_for(device_key) -> CLRuntime:
    cl = _import_cl()
    device = next(d for d in list_devices() if (d.platform.name, d.name) == device_key)
    ctx = cl.Context([device])
    queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    return CLRuntime(ctx, queue, device)


def get_runtime(device: str | None = None) -> CLRuntime:
    """A cached context and queue on the chosen device."""
    d = pick_device(device)
    return _runtime_for((d.platform.name, d.name))


@lru_cache(maxsize=None)
def _build(runtime: CLRuntime, name: str, options: tuple[str, ...]):
    cl = _import_cl()
    from rigslim.kernels import source

    return cl.Program(runtime.context, source(name)).build(options=list(options))


def build_program(runtime: CLRuntime, name: str, options=()):
    """Build the kernel file ``name`` (in rigslim.kernels) once per runtime and options."""
    return _build(runtime, name, tuple(options))
