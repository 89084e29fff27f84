"""--set: parameters, replacing a step's plugin (STEP=PLUGIN), and one-line errors (exit 2)."""

import pytest

from rigslim.commands.cli import main
from rigslim.errors import PipelineError
from rigslim.runtime.document import load_pipeline

PIPELINE = """
inputs:
  mesh: data/elephant.obj
  skeleton: data/elephant.tgf
  weights: data/elephant-weights.dmat
  animation: data/elephant-anim.dmat
poses: {examples: "0:457:45", test: "5:457:7"}
steps:
  - select: k-largest
    k: 4
  - solve: poisson
    position_weight: 0.1
  - evaluate: [position-rms]
  - write: out/w.npz
"""


def steps_of(path, *overrides):
    _, steps = load_pipeline(path, list(overrides))
    return {s.key: s for s in steps}


def test_replace_plugins(write_pipeline):
    path = write_pipeline(PIPELINE)
    s = steps_of(path, "select=best-fit", "solve=geometric")
    assert s["select"].plugin == "best-fit" and s["select"].params == {"k": 4}
    assert s["select"].name == "best-fit"
    # position_weight is Poisson's: dropped for geometric, which does not take it
    assert s["solve"].plugin == "geometric" and s["solve"].params == {}


def test_replace_then_set_a_parameter_of_the_new_plugin(write_pipeline):
    path = write_pipeline(PIPELINE)
    s = steps_of(path, "select=best-fit", "select.by=error", "best-fit.k=5")
    assert s["select"].params == {"k": 5, "by": "error"}


def test_stage_key_form_and_write_path(write_pipeline):
    path = write_pipeline(PIPELINE)
    s = steps_of(path, "select.select=best-fit", "write=out/other.npz")
    assert s["select"].plugin == "best-fit" and s["write"].output == "out/other.npz"


@pytest.mark.parametrize("item,message", [
    ("select.select=[1]", "gives [1], not a plugin name"),
    ("select=", "not a plugin name"),
    ("solve=nope", "no weight-solver plugin named 'nope'"),
    ("write={a: 1}", "not an output path"),
    ("=x", "is not STEP.PARAM=VALUE or STEP=PLUGIN"),
    ("nostep=geometric", "names no step 'nostep'"),
    ("evaluate=position-rms", "cannot change evaluate steps"),
    ("select=best-fit", None),
])
def test_errors_are_one_line_exit_2(write_pipeline, capsys, item, message):
    path = write_pipeline(PIPELINE)
    if message is None:
        load_pipeline(path, [item])
        return
    with pytest.raises(PipelineError, match=message.replace("[", r"\[").replace("]", r"\]")):
        load_pipeline(path, [item])
    code = main(["run", "-q", str(path), "--set", item])
    _, err = capsys.readouterr()
    assert code == 2
    assert len(err.strip().splitlines()) == 1 and "Traceback" not in err and "--set" in err


def test_run_with_replaced_plugins(write_pipeline, capsys):
    path = write_pipeline(PIPELINE)
    code = main(["run", "-q", str(path), "--set", "select=best-fit", "--set", "solve=geometric"])
    out, _ = capsys.readouterr()
    assert code == 0 and "position_rms_pct" in out


def test_another_output_format_drops_what_its_writer_does_not_take(write_pipeline):
    """--set write=x.usda on a glTF write step with quantize: 'unknown parameter quantize for writer usd' once;
    the usd writer takes no quantize, so it is dropped like a replaced plugin's parameters."""
    path = write_pipeline(PIPELINE.replace("  - write: out/w.npz", "  - write: out/w.glb\n    quantize: ubyte"))
    assert steps_of(path)["write"].params == {"quantize": "ubyte"}
    s = steps_of(path, "write=out/w.usda")
    assert str(s["write"].output) == "out/w.usda" and "quantize" not in s["write"].params
