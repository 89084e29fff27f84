#!/usr/bin/env bash
# An OpenCL CPU device for the OpenCL tests. PyPI's PoCL (bundled with pyopencl's wheel,
# pocl-binary-distribution) cannot compile for CPUs newer than its LLVM ("unknown target CPU");
# then this installs Debian's pocl-opencl-icd, which the wheel's ICD loader finds in
# /etc/OpenCL/vendors, and rigslim.device.opencl picks whichever device passes its compile probe.
# Idempotent: does nothing when a CPU device already builds kernels.
# Usage: tools/setup-pocl.sh [--force]   (--force installs Debian's PoCL even when PyPI's works)
set -euo pipefail
cd "$(dirname "$0")/.."
PY="${VENV:-.venv}/bin/python"
force=0
[ "${1:-}" = "--force" ] && force=1
if [ ! -x "$PY" ]; then
    echo "setup-pocl: $PY not found; run 'make install-test' first" >&2
    exit 1
fi
if [ "$force" -eq 0 ] && "$PY" tools/probe-opencl.py; then
    echo "setup-pocl: an OpenCL CPU device builds kernels; nothing to install"
    exit 0
fi
if dpkg-query -W -f='${Status}' pocl-opencl-icd 2>/dev/null | grep -q "install ok installed"; then
    echo "setup-pocl: Debian's pocl-opencl-icd is already installed"
else
    if ! command -v apt-get >/dev/null; then
        echo "setup-pocl: no OpenCL CPU device builds kernels and apt-get is missing:" \
             "install your distribution's PoCL (pocl-opencl-icd) or a CPU OpenCL driver by hand" >&2
        exit 1
    fi
    echo "setup-pocl: installing Debian's pocl-opencl-icd"
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
    $SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq --no-install-recommends pocl-opencl-icd
fi
if "$PY" tools/probe-opencl.py; then
    echo "setup-pocl: done"
else
    echo "setup-pocl: still no OpenCL CPU device that builds kernels (see the lines above)" >&2
    exit 1
fi
