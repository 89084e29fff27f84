#!/usr/bin/env bash
# Type-check framework/ and plugins/ with mypy, and the example plugin package strictly.
#
# The source folders map onto one import package (framework/ -> rigslim, plugins/ -> rigslim.plugins,
# kernels/ -> rigslim.kernels, see pyproject.toml), which an editable install resolves through an import
# hook mypy cannot follow; so this builds the same tree from symbolic links in a temporary folder and
# checks the contract modules there.
set -euo pipefail
cd "$(dirname "$0")/.."
root=$(pwd)
tmp=$(mktemp -d)
trap 'rm -rf "$tmp"' EXIT
mkdir "$tmp/rigslim"
for entry in framework/*; do ln -s "$root/$entry" "$tmp/rigslim/$(basename "$entry")"; done
ln -s "$root/plugins" "$tmp/rigslim/plugins"
ln -s "$root/kernels" "$tmp/rigslim/kernels"
MYPY=${MYPY:-mypy}
[ -x "$root/.venv/bin/mypy" ] && MYPY="$root/.venv/bin/mypy"
cd "$tmp"
# Both trees: framework/ (rigslim) and plugins/ (rigslim.plugins); the modules let off are named in
# pyproject.toml ([[tool.mypy.overrides]]: numba kernels only; every other module must pass).
"$MYPY" --config-file "$root/pyproject.toml" --cache-dir "${MYPY_CACHE_DIR:-/dev/null}" -p rigslim "$@"
# The example plugin package, strictly: what docs/plugins.md teaches type-checks.
cp -r "$root/examples/rigslim-absweights/rigslim_absweights" "$tmp/"
"$MYPY" --config-file "$root/pyproject.toml" --cache-dir /dev/null --follow-imports=silent --strict \
    -p rigslim_absweights
