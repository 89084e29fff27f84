#!/usr/bin/env bash
# Install the Khronos glTF-Validator (npm package "gltf-validator") into tools/node/,
# idempotently. Tests that write glTF files run it with node (rigslim.io.gltf_validator).
# Needs node >= 16 and npm on PATH; does nothing when the pinned version is already there.
set -euo pipefail
cd "$(dirname "$0")"
VERSION="2.0.0-dev.3.10"
PREFIX="node"
PKG="$PREFIX/node_modules/gltf-validator/package.json"
if [ -f "$PKG" ] && grep -q "\"version\": *\"$VERSION\"" "$PKG"; then
    exit 0
fi
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    echo "setup-gltf-validator: node and npm are needed (e.g. apt-get install nodejs npm)" >&2
    exit 1
fi
mkdir -p "$PREFIX"
npm install --silent --no-audit --no-fund --prefix "$PREFIX" "gltf-validator@$VERSION"
echo "setup-gltf-validator: gltf-validator $VERSION installed in tools/$PREFIX"
