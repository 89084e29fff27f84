#!/usr/bin/env bash
# Type-check the plugin contract with mypy.
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
"$MYPY" --config-file "$root/pyproject.toml" --cache-dir /dev/null --follow-imports=silent \
    -m rigslim.plugin -m rigslim.plugin.contract -m rigslim.plugin.hookspecs -m rigslim.plugin.host \
    -m rigslim.plugin.evaluation -m rigslim.model.asset -m rigslim.api -m rigslim.runtime.metrics_document \
    -m rigslim.numerics.k_largest -m rigslim.compat -m rigslim.commands.plugins "$@"
# The example plugin package, strictly: what docs/plugins.md teaches type-checks.
cp -r "$root/examples/rigslim-absweights/rigslim_absweights" "$tmp/"
"$MYPY" --config-file "$root/pyproject.toml" --cache-dir /dev/null --follow-imports=silent --strict \
    -p rigslim_absweights
