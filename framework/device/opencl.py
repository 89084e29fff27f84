"""OpenCL contexts and programs, shared by every OpenCL plugin.

Device choice, in order: the ``device`` argument, the ``RIGSLIM_OPENCL_DEVICE``
environment variable, then the first GPU of any platform, else the first CPU
device (PoCL: PyPI's ``pocl-binary-distribution``, which pyopencl's wheel
bundles, or Debian's ``pocl-opencl-icd`` registered in ``/etc/OpenCL/vendors``;
the wheel's ICD loader reads both).
A device string is ``"gpu"``, ``"cpu"``, ``"auto"``, or a case-insensitive
substring of a device or platform name (``"nvidia"``, ``"pocl"``).

Only devices that pass a compile probe are chosen: a tiny kernel is built and
run once per device and process (:func:`probe_device`), so a platform whose
compiler cannot target this CPU (PyPI PoCL 3.0's LLVM 14 on CPUs newer than
it, "unknown target CPU") is skipped for the next one. When none passes, the
error names the CPU, the platforms tried with their failures and the fix
(``tools/setup-pocl.sh``, which installs Debian's PoCL). Platforms whose name
or version contains a string of ``RIGSLIM_OPENCL_EXCLUDE`` (comma-separated,
e.g. ``"PoCL 3.0"``) are ignored.

Programs are built once per (context, source, options) and cached; kernels
live as ``*.cl`` files in :mod:`rigslim.kernels`. A work-group size a plugin
takes from its parameters is checked against the device and the kernel
(:func:`check_local_size`) before the first launch, so a size the device
refuses is one line naming the parameter, not ``INVALID_WORK_GROUP_SIZE``.
"""

from __future__ import annotations

import os
import re
from dataclasses import dataclass
from functools import cache
from typing import TYPE_CHECKING

from rigslim.errors import RigslimError, StepError

if TYPE_CHECKING:
    import pyopencl

ENV_DEVICE = "RIGSLIM_OPENCL_DEVICE"
ENV_EXCLUDE = "RIGSLIM_OPENCL_EXCLUDE"
#: The compile probe: built and run once per device and process.
PROBE_SOURCE = "__kernel void rigslim_probe(__global float *x) { int i = get_global_id(0); x[i] = 2.0f * x[i] + 1.0f; }"
SETUP_FIX = "run tools/setup-pocl.sh, which does apt-get install pocl-opencl-icd"


class OpenCLUnavailable(RigslimError):
    """No OpenCL platform or no matching device."""


@dataclass(frozen=True)
class CLRuntime:
    """A context, a profiling-enabled queue and the device they run on."""

    context: pyopencl.Context
    queue: pyopencl.CommandQueue
    device: pyopencl.Device

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


def _excluded(platform) -> bool:
    words = [w.strip().lower() for w in os.environ.get(ENV_EXCLUDE, "").split(",") if w.strip()]
    text = f"{platform.name} {platform.version}".lower()
    return any(w in text for w in words)


def list_devices() -> list:
    """Every OpenCL device of every platform (less those ``RIGSLIM_OPENCL_EXCLUDE`` names)."""
    cl = _import_cl()
    try:
        platforms = cl.get_platforms()
    except cl.Error:
        return []
    devices = []
    for p in platforms:
        if _excluded(p):
            continue
        try:
            devices.extend(p.get_devices())
        except cl.Error:  # a platform without devices (DEVICE_NOT_FOUND) or a broken ICD
            continue
    return devices


def device_key(device) -> tuple[str, str, str]:
    """(platform name, platform version, device name): tells apart two PoCL builds with the same names."""
    return (device.platform.name.strip(), device.platform.version.strip(), device.name.strip())


def describe(device) -> str:
    """``device (platform, LLVM version)``, as the probe script prints it."""
    return f"{device.name.strip()} ({platform_label(device.platform)})"


def platform_label(platform) -> str:
    """A short name of a platform build: ``PoCL 3.0-rc2/LLVM 14.0.6``, else its version without "OpenCL x.y"."""
    version = " ".join(platform.version.split())
    pocl, llvm = re.search(r"PoCL [^ ,]+", version), re.search(r"LLVM [^ ,]+", version)
    if pocl:
        return pocl.group(0) + (f"/{llvm.group(0)}" if llvm else "")
    label = re.sub(r"^OpenCL \d+\.\d+\s*", "", version) or platform.name.strip()
    return label[:40]


_probe_cache: dict[tuple, str | None] = {}


def _failure_line(exc: Exception) -> str:
    """The informative part of an OpenCL error (a build log's first 'error:' line), at most 60 characters."""
    lines = [ln.strip() for ln in str(exc).splitlines() if ln.strip()]
    pick = next((ln for ln in lines if "error:" in ln.lower()), lines[0] if lines else type(exc).__name__)
    pick = pick[pick.lower().find("error:") + len("error:"):].strip() if "error:" in pick.lower() else pick
    return pick if len(pick) <= 60 else pick[:57] + "..."


def _probe(device) -> str | None:
    """Build and run :data:`PROBE_SOURCE` on ``device``; None if it works, else the reason."""
    import numpy as np

    cl = _import_cl()
    try:
        ctx = cl.Context([device])
        program = cl.Program(ctx, PROBE_SOURCE).build()
        queue = cl.CommandQueue(ctx)
        x = np.arange(16, dtype=np.float32)
        buf = cl.Buffer(ctx, cl.mem_flags.READ_WRITE | cl.mem_flags.COPY_HOST_PTR, hostbuf=x)
        program.rigslim_probe(queue, x.shape, None, buf)
        out = np.empty_like(x)
        cl.enqueue_copy(queue, out, buf)
        queue.finish()
    except (cl.Error, RuntimeError, ValueError) as e:
        return _failure_line(e)
    if not np.array_equal(out, 2 * x + 1):
        return "the probe kernel computed wrong values"
    return None


def probe_device(device) -> str | None:
    """Whether ``device`` can build and run a kernel: None if so, else the reason (cached per process)."""
    key = device_key(device)
    if key not in _probe_cache:
        _probe_cache[key] = _probe(device)
    return _probe_cache[key]


def cpu_model() -> str:
    """This machine's CPU, as the kernel names it (``AMD EPYC 9555 64-Core Processor (family 26)``)."""
    name = family = None
    try:
        with open("/proc/cpuinfo") as fh:
            for line in fh:
                key, _, value = line.partition(":")
                key = key.strip()
                if key == "model name" and name is None:
                    name = value.strip()
                elif key == "cpu family" and family is None:
                    family = value.strip()
                if name and family:
                    break
    except OSError:
        pass
    if not name:
        import platform

        name = platform.processor() or platform.machine() or "unknown CPU"
    return f"{name} (family {family})" if family else name


def _first_working(candidates, what: str):
    tried = []
    for d in candidates:
        reason = probe_device(d)
        if reason is None:
            return d
        tried.append(f"{platform_label(d.platform)}: {reason}")
    raise OpenCLUnavailable(f"no OpenCL {what} builds a kernel on {cpu_model()}; tried " + "; ".join(tried),
                            field="device", fix=SETUP_FIX)


def pick_device(spec: str | None = None):
    """The first device a spec names (see module docstring) that passes the compile probe."""
    cl = _import_cl()
    spec = (spec or os.environ.get(ENV_DEVICE) or "auto").strip().lower()
    devices = list_devices()
    if not devices:
        raise OpenCLUnavailable(f"no OpenCL platform found on this machine ({cpu_model()})", field="device",
                                fix=SETUP_FIX)
    gpus = [d for d in devices if d.type & cl.device_type.GPU]
    cpus = [d for d in devices if d.type & cl.device_type.CPU]
    if spec == "auto":
        return _first_working(gpus + cpus + [d for d in devices if d not in gpus and d not in cpus], "device")
    if spec == "gpu":
        if not gpus:
            raise OpenCLUnavailable("no OpenCL GPU device", field="device",
                                    fix="use device: auto or cpu, or install the GPU's OpenCL driver")
        return _first_working(gpus, "GPU device")
    if spec == "cpu":
        if not cpus:
            raise OpenCLUnavailable(f"no OpenCL CPU device ({cpu_model()})", field="device", fix=SETUP_FIX)
        return _first_working(cpus, "CPU device")
    matches = [d for d in devices if spec in d.name.lower() or spec in d.platform.name.lower()
               or spec in d.platform.version.lower()]
    if matches:
        return _first_working(matches, f"device matching '{spec}'")
    names = ", ".join(describe(d) for d in devices)
    raise OpenCLUnavailable(f"no OpenCL device matches '{spec}'", field="device",
                            fix=f"use auto, gpu, cpu or part of one of: {names}")


@cache
def _runtime_for(key) -> CLRuntime:
    cl = _import_cl()
    device = next(d for d in list_devices() if device_key(d) == key)
    ctx = cl.Context([device])
    queue = cl.CommandQueue(ctx, properties=cl.command_queue_properties.PROFILING_ENABLE)
    return CLRuntime(ctx, queue, device)


def get_runtime(device: str | None = None) -> CLRuntime:
    """A cached context and queue on the chosen device."""
    return _runtime_for(device_key(pick_device(device)))


@cache
def _build(runtime: CLRuntime, name: str, options: tuple[str, ...]):
    cl = _import_cl()
    from rigslim.kernels import source

    return cl.Program(runtime.context, source(name)).build(options=list(options))


def build_program(runtime: CLRuntime, name: str, options=()):
    """Build the kernel file ``name`` (in rigslim.kernels) once per runtime and options."""
    return _build(runtime, name, tuple(options))


def max_local_size(runtime: CLRuntime, kernel=None) -> int:
    """The largest one-dimensional work-group ``runtime``'s device runs (of ``kernel``, when given).

    The least of ``CL_DEVICE_MAX_WORK_GROUP_SIZE``, ``CL_DEVICE_MAX_WORK_ITEM_SIZES[0]`` and, for a
    kernel, its ``CL_KERNEL_WORK_GROUP_SIZE`` on that device (which its registers and local memory
    can lower below the device's).
    """
    cl = _import_cl()
    device = runtime.device
    limit = min(int(device.max_work_group_size), int(device.max_work_item_sizes[0]))
    if kernel is not None:
        limit = min(limit, int(kernel.get_work_group_info(cl.kernel_work_group_info.WORK_GROUP_SIZE, device)))
    return max(limit, 1)


def check_local_size(runtime: CLRuntime, local_size: int | None, kernel=None, *, field: str = "local_size",
                     source: str | None = None) -> None:
    """Refuse a one-dimensional work-group size the device (or ``kernel`` on it) cannot run.

    Parameters
    ----------
    runtime : CLRuntime
        The context whose device will run the launch.
    local_size : int or None
        The work-group size asked for; None (the driver's choice) always passes.
    kernel : pyopencl.Kernel, optional
        The kernel to be launched; its ``CL_KERNEL_WORK_GROUP_SIZE`` bounds the size too.
    field, source : str
        The parameter and the plugin, for the message.

    Raises
    ------
    StepError
        When ``local_size`` is below 1 or above :func:`max_local_size` (a launch would fail with
        ``INVALID_WORK_GROUP_SIZE``); the message names the device and the range it takes.
    """
    if local_size is None:
        return
    limit = max_local_size(runtime, kernel)
    if not 1 <= local_size <= limit:
        what = "this kernel on " if kernel is not None else ""
        raise StepError(f"work-group size {local_size} is outside 1..{limit}, the sizes {what}{runtime.name} runs",
                        source=source, field=field,
                        fix=f"give {field} from 1 to {limit}, or leave it unset for the driver's choice")
