#!/usr/bin/env bash
# Headless OpenGL for the OpenGL deformer tests: libEGL (glvnd) with Mesa's EGL
# vendor and DRI drivers (llvmpipe). Idempotent: does nothing when present.
set -euo pipefail
need=()
have_lib() { ldconfig -p 2>/dev/null | grep -q "$1"; }
have_lib 'libEGL.so.1 '      || need+=(libegl1)
have_lib 'libEGL_mesa.so.0 ' || need+=(libegl-mesa0)
have_lib 'libGL.so.1 '       || need+=(libgl1)
have_lib 'libgbm.so.1 '      || need+=(libgbm1)
# llvmpipe lives in Mesa's DRI driver package (swrast_dri.so / libgallium).
if ! ls /usr/lib/*/dri/swrast_dri.so >/dev/null 2>&1; then need+=(libgl1-mesa-dri); fi
if [ ${#need[@]} -eq 0 ]; then
    echo "setup-egl: libEGL, Mesa EGL and llvmpipe already installed"
    exit 0
fi
echo "setup-egl: installing ${need[*]}"
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
export DEBIAN_FRONTEND=noninteractive
$SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
$SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq --no-install-recommends "${need[@]}"
