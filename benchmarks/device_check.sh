#!/usr/bin/env bash
# Every GPU measurement of the deformers and the small-QP kernel in one call (benchmarks/device_check.py).
#
# On the lent GPU machine (one call; `.device` built once by the shared prepare.sh and carried):
#     source .device/prelude.sh; bash benchmarks/device_check.sh
# On a CPU-only machine (PoCL + llvmpipe), to test it end to end with small meshes:
#     OUT=/tmp/device-check DEVICE_CHECK_LEVELS="0 1" bash benchmarks/device_check.sh
#
# Environment: OUT (results folder, default out/device-check), DEVICE_CHECK_LEVELS (elephant subdivision
# levels, default "3 4": 386,050 and 1,544,194 vertices; "3 5" adds the 6.2M-vertex mesh instead),
# DEVICE_CHECK_FRAMES (poses per row, default 8), DEVICE_CHECK_DEVICE (OpenCL device spec, default auto:
# the GPU when there is one), PYTHON (default .venv/bin/python when present, else python3).
# Writes $OUT/device_check.json, $OUT/device_check.md, $OUT/device_check.log and $OUT/nvidia-smi.txt.
set -euo pipefail
cd "$(dirname "$0")/.."
OUT=${OUT:-out/device-check}
LEVELS=${DEVICE_CHECK_LEVELS:-"3 4"}
FRAMES=${DEVICE_CHECK_FRAMES:-8}
if [ -z "${PYTHON:-}" ]; then
  if [ -x .venv/bin/python ]; then PYTHON=.venv/bin/python; else PYTHON=python3; fi
fi
mkdir -p "$OUT"

# NVIDIA OpenCL: the driver library is on the GPU machine but not registered with the ICD loader.
if ldconfig -p 2>/dev/null | grep -q 'libnvidia-opencl\.so\.1'; then
  if [ -w /etc/OpenCL/vendors ] || mkdir -p /etc/OpenCL/vendors 2>/dev/null; then
    [ -f /etc/OpenCL/vendors/nvidia.icd ] || echo libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd
  fi
  echo "NVIDIA OpenCL registered (/etc/OpenCL/vendors/nvidia.icd)"
else
  echo "no libnvidia-opencl.so.1: OpenCL runs on whatever ICD is installed (PoCL on a CPU machine)"
fi
# NVIDIA EGL for headless OpenGL (glvnd vendor file), unless one is chosen already.
for f in /usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json /usr/share/glvnd/egl_vendor.d/10_nvidia.json; do
  if [ -z "${__EGL_VENDOR_LIBRARY_FILENAMES:-}" ] && [ -f "$f" ]; then
    export __EGL_VENDOR_LIBRARY_FILENAMES=$f
    echo "NVIDIA EGL vendor: $f"
  fi
done
nvidia-smi > "$OUT/nvidia-smi.txt" 2>&1 || echo "no nvidia-smi" > "$OUT/nvidia-smi.txt"

args=(--out "$OUT" --frames "$FRAMES")
# shellcheck disable=SC2206
args+=(--levels $LEVELS)
if [ -n "${DEVICE_CHECK_DEVICE:-}" ]; then args+=(--device "$DEVICE_CHECK_DEVICE"); fi
export PYTHONUNBUFFERED=1
"$PYTHON" benchmarks/device_check.py "${args[@]}" 2>&1 | tee "$OUT/device_check.log"
exit "${PIPESTATUS[0]}"
