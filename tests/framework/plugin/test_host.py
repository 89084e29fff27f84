import pytest

from rigslim import hookimpl
from rigslim.errors import PluginNotFoundError
from rigslim.plugin import STAGE_HOOKS, InfluenceSelector
from rigslim.plugin.host import PluginHost, get_host


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


def test_duplicate_names_are_an_error():
    host = PluginHost(extra=[DupModule])
    with pytest.raises(PluginNotFoundError, match="two plugins are named 'k-largest'"):
        _ = host.registry
