"""Which OpenCL CPU devices can build and run a kernel here (used by tools/setup-pocl.sh).

Prints one line per CPU device (its platform and whether the compile probe of
rigslim.device.opencl passed, or why not); exits 0 when at least one passed, 1 when
none did (or pyopencl is missing), so that setup-pocl.sh knows to install
Debian's PoCL.
"""

from __future__ import annotations

import sys


def main() -> int:
    try:
        import pyopencl as cl

        from rigslim.device.opencl import cpu_model, describe, list_devices, probe_device
    except ImportError as e:
        print(f"probe-opencl: cannot import pyopencl/rigslim ({e})")
        return 1
    cpus = [d for d in list_devices() if d.type & cl.device_type.CPU]
    print(f"probe-opencl: CPU {cpu_model()}")
    ok = False
    for d in cpus:
        reason = probe_device(d)
        ok = ok or reason is None
        print(f"probe-opencl: {describe(d)}: {'builds and runs the probe kernel' if reason is None else reason}")
    if not cpus:
        print("probe-opencl: no OpenCL CPU device")
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())
