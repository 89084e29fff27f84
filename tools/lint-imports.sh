#!/usr/bin/env bash
# Check the import direction (the contracts under [tool.importlinter] in pyproject.toml) with import-linter.
#
# framework/, plugins/ and kernels/ map onto one import package (rigslim, rigslim.plugins, rigslim.kernels;
# see pyproject.toml), which import-linter cannot follow through the editable install's import hook; so
# this copies the same tree into a temporary folder and checks it there.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir "$tmp/rigslim"
cp -r "${RIGSLIM_SOURCE:-$root}/framework/." "$tmp/rigslim/"
cp -r "${RIGSLIM_SOURCE:-$root}/plugins" "$tmp/rigslim/plugins"
cp -r "${RIGSLIM_SOURCE:-$root}/kernels" "$tmp/rigslim/kernels"
find "$tmp" -name __pycache__ -prune -exec rm -rf {} +
LINT=${LINT_IMPORTS:-lint-imports}
[ -x "$root/.venv/bin/lint-imports" ] && LINT="$root/.venv/bin/lint-imports"
cd "$tmp"
PYTHONPATH="$tmp" "$LINT" --no-cache "$@" "$root/pyproject.toml"
