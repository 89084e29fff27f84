from pathlib import Path

import pytest

from rigslim import hookimpl
from rigslim.errors import DuplicatePluginError, PluginError, PluginNotFoundError
from rigslim.plugin import STAGE_HOOKS, InfluenceSelector
from rigslim.plugin.host import PluginHost, PluginLoadWarning, get_host


def test_builtins_come_from_entry_points():
    host = get_host()
    infos = {(i.stage, i.name): i for i in host.infos()}
    for stage, name in [("reader", "mesh"), ("reader", "tgf"), ("reader", "dmat-weights"),
                        ("reader", "dmat-animation"), ("writer", "npz"), ("writer", "dmat"),
                        ("influence-selection", "k-largest"), ("weight-solver", "k-largest"),
                        ("deformer", "numpy"), ("normal-estimator", "recomputed"),
                        ("metric", "position-rms"), ("metric", "normal-deviation"), ("metric", "max-influences")]:
        info = infos[(stage, name)]
        assert info.package == "rigslim" and info.version and info.summary
    assert set(host.registry) == set(STAGE_HOOKS)


def test_closest_name_suggested():
    with pytest.raises(PluginNotFoundError, match="did you mean 'k-largest'"):
        get_host().get("weight-solver", "k_largest")


class Dup(InfluenceSelector):
    name = "k-largest"
    summary = "a clash"


class DupModule:
    @staticmethod
    @hookimpl
    def rigslim_influence_selectors():
        return [Dup()]


def test_duplicate_names_are_warned_and_refused_when_asked_for():
    """Nothing is shadowed silently: a duplicate name warns at load and is an error where a pipeline uses it."""
    with pytest.warns(PluginLoadWarning, match="two influence-selection plugins are named 'k-largest'"):
        host = PluginHost(extra=[DupModule])
        _ = host.registry
    with pytest.raises(DuplicatePluginError, match=r"named 'k-largest' \(rigslim .* and DupModule\)"):
        host.get("influence-selection", "k-largest")
    assert not isinstance(DuplicatePluginError("x"), PluginNotFoundError)
    assert host.get("weight-solver", "k-largest").name == "k-largest"  # the solver of that name is unambiguous


class Broken(InfluenceSelector):
    name = "broken"
    summary = "raises, or returns the wrong type"

    def select(self, asset, params, ctx):
        if asset.provenance.get("mode") == "raise":
            raise ZeroDivisionError("division by zero in the plugin")
        return [[0, 1]] * asset.mesh.n_vertices


class BrokenModule:
    @staticmethod
    @hookimpl
    def rigslim_influence_selectors():
        return [Broken()]


@pytest.mark.parametrize("mode,match", [
    ("raise", r"steps\[1\]\.select: influence-selection 'broken' \(BrokenModule\) failed: ZeroDivisionError: "
              "division by zero in the plugin"),
    ("type", r"influence-selection 'broken': select\(\) returned .* \(list\), not InfluenceSets"),
])
def test_plugin_failures_name_the_plugin_and_the_step(elephant, mode, match, tmp_path):
    from rigslim.runtime.run import run_pipeline

    host = PluginHost(extra=[BrokenModule])
    pipeline = tmp_path / "p.yaml"
    data = elephant.provenance.get("inputs", {})
    pipeline.write_text("inputs: {mesh: %s}\nsteps:\n  - select: broken\n" % (Path(__file__).resolve().parents[3]
                                                                             / "examples/data/elephant.obj"))
    import rigslim.runtime.inputs as inputs

    real = inputs.read_inputs

    def read(*args, **kwargs):
        asset = real(*args, **kwargs)
        asset.provenance["mode"] = mode
        return asset

    with pytest.MonkeyPatch.context() as mp:
        mp.setattr("rigslim.runtime.run.read_inputs", read)
        with pytest.raises(PluginError, match=match) as info:
            run_pipeline(pipeline, host=host)
    assert data is not None and "\n" not in info.value.one_line()
    if mode == "raise":
        assert isinstance(info.value.__cause__, ZeroDivisionError)


def test_contract_checks_of_hook_results():
    class NoSummary(InfluenceSelector):
        name = "no-summary"

    class Module:
        @staticmethod
        @hookimpl
        def rigslim_influence_selectors():
            return [NoSummary()]

        @staticmethod
        @hookimpl
        def rigslim_weight_solvers():
            return "not a list"

    with pytest.warns(PluginLoadWarning) as caught:
        host = PluginHost(extra=[Module])
        names = {i.name for i in host.infos()}
    messages = [str(w.message) for w in caught]
    assert any("'no-summary' needs a one-line summary" in m for m in messages)
    assert any("rigslim_weight_solvers() returned 'not a list', not a list of WeightSolver" in m for m in messages)
    assert "no-summary" not in names and "poisson" in names
    assert len(host.problems) == len(messages)


def test_api_version_rule():
    import rigslim
    from rigslim.plugin.host import api_problem

    major, minor = (int(x) for x in rigslim.PLUGIN_API_VERSION.split("."))
    assert api_problem(f"{major}.{minor}") is None and api_problem(f"{major}.0") is None
    assert "needs rigslim plugin API" in api_problem(f"{major}.{minor + 1}")
    assert "needs rigslim plugin API" in api_problem(f"{major + 1}.0")
    assert "is not \"MAJOR.MINOR\"" in api_problem("one")
