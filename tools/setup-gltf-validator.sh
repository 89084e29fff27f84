#!/usr/bin/env bash
# Install the glTF checkers the tests run with node, idempotently, into tools/node/:
#   - Khronos glTF-Validator (npm package "gltf-validator"): every glTF a test writes must have no errors;
#   - three.js (npm package "three"): its GLTFLoader and skinning, a viewer's reading of the same files.
# Needs node >= 16 and npm on PATH; does nothing when the pinned versions are already there.
set -euo pipefail
cd "$(dirname "$0")"
PREFIX="node"
PACKAGES=("gltf-validator@2.0.0-dev.3.10" "three@0.160.0")
missing=()
for spec in "${PACKAGES[@]}"; do
    name="${spec%@*}"
    version="${spec##*@}"
    pkg="$PREFIX/node_modules/$name/package.json"
    if ! { [ -f "$pkg" ] && grep -q "\"version\": *\"$version\"" "$pkg"; }; then
        missing+=("$spec")
    fi
done
[ "${#missing[@]}" -eq 0 ] && exit 0
if ! command -v node >/dev/null || ! command -v npm >/dev/null; then
    echo "setup-gltf-validator: node and npm are needed (e.g. apt-get install nodejs npm)" >&2
    exit 1
fi
mkdir -p "$PREFIX"
npm install --silent --no-audit --no-fund --prefix "$PREFIX" "${PACKAGES[@]}"
echo "setup-gltf-validator: installed ${missing[*]} in tools/$PREFIX"
