"""rigslim.device.opencl: device choice by a compile probe, the one-line error, and a working CPU device in CI.

The probe-selection logic is driven with a fake probe that fails the way PyPI's
PoCL 3.0 (LLVM 14) fails on CPUs newer than its LLVM ("unknown target CPU
'generic'"); the real fallback path is exercised by excluding the PyPI platform
with ``RIGSLIM_OPENCL_EXCLUDE`` in a subprocess (Debian's PoCL is then chosen
where tools/setup-pocl.sh installed it, else the error is checked).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import pytest

pytest.importorskip("pyopencl")

import pyopencl as cl  # noqa: E402

from rigslim.device import opencl  # noqa: E402
from rigslim.device.opencl import OpenCLUnavailable  # noqa: E402

ROOT = Path(__file__).resolve().parents[3]
ZEN5_FAILURE = ("clBuildProgram failed: BUILD_PROGRAM_FAILURE - clBuildProgram failed: BUILD_PROGRAM_FAILURE\n\n"
                "Build on <pyopencl.Device 'pthread-AMD EPYC 9555' on 'Portable Computing Language'>:\n\n"
                "error: unknown target CPU 'generic'\nnote: valid target CPU values are: nocona, core2, ...")


def cpu_devices():
    return [d for d in opencl.list_devices() if d.type & cl.device_type.CPU]


def test_ci_has_a_working_cpu_device():
    """In CI (CI=true) an OpenCL CPU device that builds kernels is required: this fails, never skips."""
    working = [d for d in cpu_devices() if opencl.probe_device(d) is None]
    if os.environ.get("CI", "").lower() != "true" and not working:
        pytest.skip("no OpenCL CPU device builds kernels here (run tools/setup-pocl.sh); required in CI")
    tried = "; ".join(f"{opencl.describe(d)}: {opencl.probe_device(d)}" for d in cpu_devices()) or "none"
    assert working, f"no OpenCL CPU device builds the probe kernel on {opencl.cpu_model()}; tried {tried}"
    runtime = opencl.get_runtime("cpu")
    assert opencl.probe_device(runtime.device) is None


def test_failure_line_is_the_build_error():
    assert opencl._failure_line(RuntimeError(ZEN5_FAILURE)) == "unknown target CPU 'generic'"
    assert len(opencl._failure_line(RuntimeError("x" * 500))) == 60


def test_probe_is_cached_per_device(monkeypatch):
    devices = cpu_devices()
    if not devices:
        pytest.skip("no OpenCL CPU device")
    calls = []
    monkeypatch.setattr(opencl, "_probe_cache", {})
    monkeypatch.setattr(opencl, "_probe", lambda d: calls.append(d) or None)
    for _ in range(3):
        assert opencl.probe_device(devices[0]) is None
    assert len(calls) == 1


class FakePlatform:
    def __init__(self, name, version):
        self.name, self.version = name, version


class FakeDevice:
    def __init__(self, name, platform, type_=cl.device_type.CPU):
        self.name, self.platform, self.type = name, platform, type_


POCL_PYPI = FakePlatform("Portable Computing Language", "OpenCL 3.0 PoCL 3.0-rc2  Linux, Release, RELOC, LLVM 14.0.6")
POCL_DEBIAN = FakePlatform("Portable Computing Language", "OpenCL 3.0 PoCL 3.1+debian  Linux, Release, LLVM 15.0.6")


@pytest.fixture
def fake_platforms(monkeypatch):
    """Two PoCL CPU devices; the PyPI one fails the probe as on a Zen 5 CPU."""
    pypi = FakeDevice("pthread-AMD EPYC 9555", POCL_PYPI)
    debian = FakeDevice("cpu-skylake-avx512-AMD EPYC 9555", POCL_DEBIAN)
    monkeypatch.setattr(opencl, "_probe_cache", {})
    failing = {opencl.device_key(pypi)}
    monkeypatch.setattr(opencl, "_probe",
                        lambda d: opencl._failure_line(RuntimeError(ZEN5_FAILURE))
                        if opencl.device_key(d) in failing else None)
    devices = [pypi, debian]
    monkeypatch.setattr(opencl, "list_devices", lambda: list(devices))
    return pypi, debian, failing


@pytest.mark.parametrize("spec", ["auto", "cpu", "pocl", "amd epyc"])
def test_selection_skips_a_platform_that_cannot_build(fake_platforms, spec):
    pypi, debian, _ = fake_platforms
    assert opencl.pick_device(spec) is debian


def test_selection_keeps_the_first_that_builds(fake_platforms):
    pypi, debian, failing = fake_platforms
    failing.clear()
    assert opencl.pick_device("cpu") is pypi


def test_no_device_builds_one_line_error(fake_platforms, monkeypatch):
    pypi, debian, failing = fake_platforms
    failing.add(opencl.device_key(debian))
    monkeypatch.setattr(opencl, "cpu_model", lambda: "AMD EPYC 9555 64-Core Processor (family 26)")
    with pytest.raises(OpenCLUnavailable) as err:
        opencl.pick_device("cpu")
    line = err.value.one_line()
    assert "\n" not in line and len(line) <= 300 and " ... " not in line   # whole, not clipped
    assert "AMD EPYC 9555 64-Core Processor (family 26)" in line          # the CPU
    assert "PoCL 3.0-rc2/LLVM 14.0.6" in line and "PoCL 3.1+debian/LLVM 15.0.6" in line   # the platforms tried
    assert "unknown target CPU 'generic'" in line                        # why
    assert "tools/setup-pocl.sh" in line and "pocl-opencl-icd" in line   # the fix


def test_exclude_env_hides_platforms(monkeypatch):
    devices = opencl.list_devices()
    if not devices:
        pytest.skip("no OpenCL device")
    monkeypatch.setenv(opencl.ENV_EXCLUDE, devices[0].platform.version.strip())
    assert all(d.platform.version.strip() != devices[0].platform.version.strip() for d in opencl.list_devices())


def test_fallback_when_the_pypi_pocl_is_excluded():
    """The PyPI PoCL hidden as if it could not build: Debian's PoCL is chosen if installed, else one clear line."""
    code = ("from rigslim.device.opencl import get_runtime, OpenCLUnavailable\n"
            "try:\n    r = get_runtime('cpu'); print('OK', r.device.platform.version)\n"
            "except OpenCLUnavailable as e:\n    print('ERR', e.one_line())\n")
    env = dict(os.environ, RIGSLIM_OPENCL_EXCLUDE="PoCL 3.0-rc2", RIGSLIM_OPENCL_DEVICE="")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=300)
    assert out.returncode == 0, out.stderr
    others = [d for d in cpu_devices() if "PoCL 3.0-rc2" not in d.platform.version and opencl.probe_device(d) is None]
    if others:
        assert out.stdout.startswith("OK") and "PoCL 3.0-rc2" not in out.stdout
    else:
        line = out.stdout.strip()
        assert line.startswith("ERR") and "tools/setup-pocl.sh" in line and "\n" not in line


def test_probe_script_reports_devices():
    out = subprocess.run([sys.executable, str(ROOT / "tools" / "probe-opencl.py")], capture_output=True, text=True,
                         timeout=300)
    working = [d for d in cpu_devices() if opencl.probe_device(d) is None]
    assert out.returncode == (0 if working else 1)
    assert out.stdout.startswith("probe-opencl: CPU ")


def test_check_local_size_takes_the_kernels_bound():
    """A kernel whose CL_KERNEL_WORK_GROUP_SIZE is below the device's (registers, local memory) lowers the range:
    a size within the device's but above the kernel's is refused, naming the kernel's bound."""
    from rigslim.errors import StepError

    try:
        rt = opencl.get_runtime()
    except OpenCLUnavailable as e:
        pytest.skip(f"no OpenCL device: {e}")

    class SmallKernel:
        def get_work_group_info(self, param, device):
            assert param == cl.kernel_work_group_info.WORK_GROUP_SIZE and device == rt.device
            return 16

    device_limit = opencl.max_local_size(rt)
    assert device_limit == min(rt.device.max_work_group_size, rt.device.max_work_item_sizes[0])
    assert opencl.max_local_size(rt, SmallKernel()) == min(16, device_limit)
    opencl.check_local_size(rt, None, SmallKernel())
    opencl.check_local_size(rt, min(16, device_limit), SmallKernel())
    for bad in (0, -1, 17):
        with pytest.raises(StepError, match=r"blend: local_size: .*outside 1\.\.16, the sizes this kernel on"):
            opencl.check_local_size(rt, bad, SmallKernel(), source="blend")
