"""The plugin contract enforced at load, with deliberately broken plugin packages installed in a temporary venv.

Five packages, each broken one way (a misspelled hook, a wrong return type, an import error, a reader that
takes a suffix a built-in reader takes, a newer plugin API), are installed together into a virtual
environment layered over this one. Every command still works; each package is named in one warning line
saying what is wrong; the duplicate suffix is refused only where a pipeline would have to choose.
"""

from __future__ import annotations

import json
import os
import subprocess
import textwrap
from pathlib import Path

import pytest
from support.venvs import layered_venv

ROOT = Path(__file__).resolve().parents[3]

PACKAGES = {
    "rigslim-misspelled": ("rigslim_misspelled", '''
        import rigslim
        from rigslim.plugin import WeightSolver


        class Half(WeightSolver):
            name = "half"
            summary = "never registered: the hook below is misspelled"


        @rigslim.hookimpl
        def rigslim_weight_solver():
            return [Half()]
        '''),
    "rigslim-wrongtype": ("rigslim_wrongtype", '''
        import rigslim
        from rigslim.plugin import WeightSolver


        class Nameless:
            """Not a plugin at all."""


        class Solver(WeightSolver):
            name = "misplaced"
            summary = "a solver returned from the selectors' hook"


        @rigslim.hookimpl
        def rigslim_influence_selectors():
            return [Nameless(), Solver()]
        '''),
    "rigslim-importerror": ("rigslim_importerror", '''
        import rigslim_dependency_that_is_not_installed  # noqa: F401
        '''),
    "rigslim-dupreader": ("rigslim_dupreader", '''
        import rigslim
        from rigslim.plugin import Reader


        class FastObj(Reader):
            name = "fast-obj"
            summary = "a second reader of .obj meshes"
            role = "mesh"
            suffixes = (".obj",)

            def read(self, path, asset, params, ctx):
                raise AssertionError("never chosen silently")


        @rigslim.hookimpl
        def rigslim_readers():
            return [FastObj()]
        '''),
    "rigslim-futureapi": ("rigslim_futureapi", '''
        import rigslim
        from rigslim.plugin import InfluenceSelector

        RIGSLIM_PLUGIN_API = "2.0"


        class Future(InfluenceSelector):
            name = "from-the-future"
            summary = "written for a plugin API this rigslim does not have"


        @rigslim.hookimpl
        def rigslim_influence_selectors():
            return [Future()]
        '''),
}


def _package(folder: Path, dist: str, module: str, source: str) -> Path:
    root = folder / dist
    (root / module).mkdir(parents=True)
    (root / module / "__init__.py").write_text(textwrap.dedent(source).lstrip())
    (root / "pyproject.toml").write_text(textwrap.dedent(f'''
        [build-system]
        requires = ["setuptools>=64"]
        build-backend = "setuptools.build_meta"

        [project]
        name = "{dist}"
        version = "0.1"

        [project.entry-points.rigslim]
        {module.removeprefix("rigslim_")} = "{module}"

        [tool.setuptools]
        packages = ["{module}"]
        ''').lstrip())
    return root


@pytest.fixture(scope="module")
def venv(tmp_path_factory) -> Path:
    tmp = tmp_path_factory.mktemp("broken-plugins")
    python = layered_venv(tmp)
    sources = [str(_package(tmp / "src", dist, module, src)) for dist, (module, src) in PACKAGES.items()]
    subprocess.run([str(python), "-m", "pip", "install", "--quiet", "--no-deps", "--no-build-isolation", *sources],
                   check=True, capture_output=True, timeout=600)
    return python


def _rigslim(python: Path, *args: str, env: dict | None = None, cwd: Path | None = None):
    return subprocess.run([str(python), "-m", "rigslim.commands.cli", *args], capture_output=True, text=True,
                          timeout=600, env={**os.environ, **(env or {})}, cwd=cwd)


@pytest.fixture(scope="module")
def listing(venv):
    out = _rigslim(venv, "plugins")
    assert out.returncode == 0, out.stderr
    return out


def _line(listing, package: str) -> str:
    lines = [line for line in listing.stderr.splitlines() if f"'{package}'" in line]
    assert len(lines) == 1, listing.stderr
    assert lines[0].startswith("rigslim: warning: plugin package"), lines[0]
    return lines[0]


def test_every_command_still_works_and_lists_the_builtins(venv, listing):
    out = _rigslim(venv, "plugins", "--json")
    assert out.returncode == 0, out.stderr
    rows = {(r["stage"], r["name"]): r for r in json.loads(out.stdout)}
    assert ("weight-solver", "poisson") in rows and ("reader", "mesh") in rows
    assert ("reader", "fast-obj") in rows  # loaded, but never chosen silently (test below)
    assert all(name not in {"half", "misplaced", "from-the-future", ""} for _, name in rows)
    assert "Traceback" not in listing.stderr


def test_a_misspelled_hook_skips_the_package_naming_the_hook(listing):
    line = _line(listing, "rigslim-misspelled")
    assert "'rigslim_weight_solver' is not a rigslim hook" in line and "rigslim_weight_solvers" in line


def test_a_wrong_return_type_names_the_package_and_the_right_hook(listing):
    line = [ln for ln in listing.stderr.splitlines() if "'rigslim-wrongtype'" in ln]
    assert len(line) == 2, listing.stderr  # the nameless object and the solver, one line each
    assert any("is not an instance of InfluenceSelector" in ln and "Nameless" in ln for ln in line)
    assert any("return it from rigslim_weight_solvers()" in ln for ln in line)


def test_an_import_error_is_one_line_naming_the_package_and_its_error(listing):
    line = _line(listing, "rigslim-importerror")
    assert "failed to import rigslim_importerror" in line
    assert "ModuleNotFoundError" in line and "rigslim_dependency_that_is_not_installed" in line
    assert "RIGSLIM_DISABLE_PLUGINS=importerror" in line


def test_an_api_version_mismatch_names_both_versions(listing):
    import rigslim

    line = _line(listing, "rigslim-futureapi")
    assert "needs rigslim plugin API 2.0" in line and f"this rigslim has {rigslim.PLUGIN_API_VERSION}" in line


def test_a_duplicate_reader_suffix_is_warned_and_refused_where_a_pipeline_must_choose(venv, listing, tmp_path):
    assert any("'mesh' (rigslim" in ln and "'fast-obj' (rigslim-dupreader" in ln and "'.obj'" in ln
               for ln in listing.stderr.splitlines()), listing.stderr
    pipeline = ROOT / "examples" / "elephant-k4.yaml"  # reads elephant.obj as its mesh
    out = _rigslim(venv, "run", "-q", str(pipeline), "--metrics", str(tmp_path / "m.json"))
    assert out.returncode == 2, out.stderr
    error = [ln for ln in out.stderr.splitlines() if ln.startswith("rigslim: error:")]
    assert len(error) == 1 and "'fast-obj' (rigslim-dupreader 0.1)" in error[0] and "reader: NAME" in error[0]
    assert not (tmp_path / "m.json").exists()


def test_disabling_a_package_on_purpose(venv, tmp_path):
    out = _rigslim(venv, "run", "-q", str(ROOT / "examples" / "elephant-k4.yaml"), "--metrics",
                   str(tmp_path / "m.json"), env={"RIGSLIM_DISABLE_PLUGINS": "dupreader,importerror"})
    assert out.returncode == 0, out.stderr
    assert json.loads((tmp_path / "m.json").read_text())["evaluations"]
    listed = _rigslim(venv, "plugins", env={"RIGSLIM_DISABLE_PLUGINS": "rigslim-dupreader, importerror"})
    assert "not loaded (RIGSLIM_DISABLE_PLUGINS): dupreader, importerror" in listed.stderr
    assert "'rigslim-importerror'" not in listed.stderr


def test_a_missing_plugin_names_the_skipped_package(venv, tmp_path):
    """Asking for a plugin whose package was skipped: the one error line says why it is not there."""
    doc = tmp_path / "p.yaml"
    text = (ROOT / "examples" / "elephant-k4.yaml").read_text()
    doc.write_text(text.replace("data/", f"{ROOT / 'examples' / 'data'}/").replace("solve: geometric", "solve: half"))
    out = _rigslim(venv, "run", "-q", str(doc), env={"RIGSLIM_DISABLE_PLUGINS": "dupreader"})
    assert out.returncode == 2
    assert "no weight-solver plugin named 'half'" in out.stderr and "skipped at load" in out.stderr
