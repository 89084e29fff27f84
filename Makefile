# The two commands of the README. Both work on a fresh machine with nothing but Python 3.11+.
PYTHON ?= python3
VENV   ?= .venv
PY      = $(VENV)/bin/python
PIP     = $(PY) -m pip

.PHONY: demo test lint install install-test test-tools clean blender-extension

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --quiet --upgrade pip
	$(PIP) install --quiet -e '.[all]'
	@# compile the default reduction's and the LOD chain's numba kernels once into numba's cache (tools/warm-numba.py)
	$(PY) tools/warm-numba.py
	@# byte-compile rigslim's own modules too (an editable install; PYTHONDONTWRITEBYTECODE would recompile them every run)
	$(PY) -m compileall -q framework plugins kernels > /dev/null
	touch $@

$(VENV)/.installed-test: $(VENV)/.installed
	$(PIP) install --quiet -e '.[test]'
	$(PIP) install --quiet -e examples/rigslim-absweights
	touch $@

install: $(VENV)/.installed

install-test: $(VENV)/.installed-test

## demo: create .venv, install rigslim, reduce the elephant to 4 weights and print the errors
demo: install
	$(VENV)/bin/rigslim run examples/elephant-k4.yaml --metrics examples/out/elephant-k4.json
	@# an LOD chain of a small character (its kernels were compiled by make install)
	$(VENV)/bin/rigslim lod examples/data/gltf/huesitos.glb -o examples/out/huesitos-lod.glb --ratios 0.5,0.25

## test-tools: system tools some tests drive (each tools/setup-*.sh installs one, idempotently)
test-tools:
	@for script in tools/setup-*.sh; do [ -f "$$script" ] && VENV=$(VENV) bash "$$script" || exit 1; done

## test: create .venv, install rigslim with test extras and the tools tests need, run pytest
test: install-test test-tools
	$(PY) -m pytest -q $(PYTEST_ARGS)

## lint: ruff over the tree, the import contracts (tools/lint-imports.sh), mypy over the plugin contract
lint: install-test
	$(VENV)/bin/ruff check .
	bash tools/lint-imports.sh
	bash tools/mypy-contract.sh

## blender-extension: the installable Blender extension, dist/rigslim-VERSION.zip (docs/blender.md)
blender-extension:
	$(PYTHON) integrations/blender/build.py --output dist

clean:
	rm -rf $(VENV) .venv-blender examples/out build dist *.egg-info
