#!/usr/bin/env bash
# Blender as a Python module (PyPI's "bpy") for the headless Blender extension tests
# (tests/integrations/blender/test_blender_extension.py, docs/blender.md). bpy pins numpy < 2 and Python 3.11, so it
# lives in a venv of its own ($BLENDER_VENV, default .venv-blender), as Blender's own Python does:
# the extension runs rigslim (the project's .venv) out of process. Idempotent: does nothing when
# the pinned version is already installed.
set -euo pipefail
cd "$(dirname "$0")/.."
BLENDER_VENV="${BLENDER_VENV:-.venv-blender}"
BPY_VERSION="${BPY_VERSION:-5.0.1}"
PY311="${PYTHON311:-python3.11}"
if [ -x "$BLENDER_VENV/bin/python" ] && \
   "$BLENDER_VENV/bin/python" -c "import importlib.metadata as m, sys; sys.exit(m.version('bpy') != '$BPY_VERSION')" 2>/dev/null; then
    echo "setup-blender: bpy $BPY_VERSION already installed in $BLENDER_VENV"
    exit 0
fi
if ! command -v "$PY311" >/dev/null 2>&1; then
    echo "setup-blender: bpy $BPY_VERSION needs Python 3.11 ($PY311 not found; set PYTHON311=/path/to/python3.11)" >&2
    exit 1
fi
echo "setup-blender: installing bpy $BPY_VERSION into $BLENDER_VENV (about 370 MB)"
"$PY311" -m venv "$BLENDER_VENV"
"$BLENDER_VENV/bin/python" -m pip install --quiet --upgrade pip
"$BLENDER_VENV/bin/python" -m pip install --quiet "bpy==$BPY_VERSION"
"$BLENDER_VENV/bin/python" -c "import bpy; print('setup-blender: Blender', bpy.app.version_string)"
