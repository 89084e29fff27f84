#!/usr/bin/env bash
# Test characters and peers for the glTF commands (tests/framework/commands/test_gltf_commands.py, benchmarks/gltf_lod.py):
#   - Debian's assimp-testmodels (assimp's test scenes, ~21 MB) and assimp-utils (the `assimp` converter):
#     the FBX characters are converted to .glb with `assimp export IN.fbx OUT.glb -fglb2`;
#   - gltfpack (npm package "gltfpack", meshoptimizer's glTF simplifier, pinned) and glTF-Transform's CLI
#     (npm package "@gltf-transform/cli", pinned) into tools/node/: the peers of benchmarks/gltf_lod.py
#     (benchmarks/peers.py runs them).
# Khronos' RiggedFigure/RiggedSimple come from Debian's qt3d5-examples, a 266 MB package: small copies are
# committed in examples/data/gltf/ instead (provenance in its README).
# Idempotent: does nothing when everything is there.
set -euo pipefail
cd "$(dirname "$0")"
GLTFPACK="gltfpack@1.3.0"
GLTF_TRANSFORM="@gltf-transform/cli@4.5.1"
need_apt=0
if ! command -v assimp >/dev/null 2>&1 || [ ! -d /usr/share/assimp/models/FBX ]; then need_apt=1; fi
need_npm=0
for spec in "$GLTFPACK" "$GLTF_TRANSFORM"; do
    pkg="node/node_modules/${spec%@*}/package.json"
    if ! { [ -f "$pkg" ] && grep -q "\"version\": *\"${spec##*@}\"" "$pkg"; }; then need_npm=1; fi
done
if [ "$need_apt" -eq 0 ] && [ "$need_npm" -eq 0 ]; then
    exit 0
fi
if [ "$need_apt" -eq 1 ]; then
    echo "setup-testmodels: installing assimp-utils assimp-testmodels"
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    export DEBIAN_FRONTEND=noninteractive
    $SUDO apt-get -o DPkg::Lock::Timeout=600 update -qq
    $SUDO apt-get -o DPkg::Lock::Timeout=600 install -y -qq --no-install-recommends assimp-utils assimp-testmodels
fi
if [ "$need_npm" -eq 1 ]; then
    if ! command -v npm >/dev/null; then
        echo "setup-testmodels: npm is needed for gltfpack and gltf-transform (e.g. apt-get install npm)" >&2
        exit 1
    fi
    mkdir -p node
    npm install --silent --no-audit --no-fund --prefix node "$GLTFPACK" "$GLTF_TRANSFORM"
    echo "setup-testmodels: installed $GLTFPACK $GLTF_TRANSFORM in tools/node"
fi
