"""What ``rigslim report`` reads, checked before anything is drawn.

:func:`read_metrics_document` reads a metrics JSON written by
``rigslim run --metrics``, or the ``--report`` document of ``rigslim reduce``
or ``rigslim lod`` (:func:`command_run`: the run it holds under ``run``)
(UTF-8, at most :data:`MAX_BYTES`, strict JSON), and checks the parts the report uses with pydantic models
in strict mode:
``evaluations`` is a non-empty list of objects, each metric (and each value
of a simplified level in ``levels``, schema version 2) is a number,
``null``, a string, or ``{"mean", "max", "per_frame"}`` of numbers (``null``
where a value was not finite); ``steps`` and ``frames`` have their types.
Problems are one :class:`~rigslim.errors.InputError` naming the file and the
JSON path (``evaluations[0].metrics.position_rms_pct.mean``).
:func:`check_render_size` bounds the render size before any pixel buffer
is allocated.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

from pydantic import BaseModel, ConfigDict, Field, ValidationError

from rigslim.errors import InputError, brief
from rigslim.io.jsonsafe import finite_copy

#: Largest metrics JSON read (bytes).
MAX_BYTES = 256 << 20
#: Largest render side (pixels); a render holds width x height x 4 bytes per frame and evaluation.
MAX_RENDER_SIDE = 8192
FIX = "give the file written by 'rigslim run --metrics FILE.json'"
#: ``schema`` of the ``--report`` documents of the one-command front ends (``rigslim reduce``, ``lod``, ...).
COMMAND_SCHEMA = "rigslim-gltf-command"
#: The commands whose ``--report`` holds a pipeline run (``run``) and its pipeline (``pipeline``).
RUN_COMMANDS = ("reduce", "lod")

Number = int | float | None


class _Model(BaseModel):
    model_config = ConfigDict(strict=True, extra="allow")


def _check_metric(value, where: str, path) -> None:
    """A metric is a scalar, a list of numbers, or an :class:`Aggregate`-like mapping of those."""
    def fail(field, got, what):
        raise InputError(f"{what} (got {brief(got)})", source=path, field=field, fix=FIX)

    def number(x):
        return x is None or (isinstance(x, (int, float)) and not isinstance(x, bool))

    if value is None or isinstance(value, (int, float, str, bool)):
        return
    if isinstance(value, list):
        for i, x in enumerate(value):
            if not number(x):
                fail(f"{where}[{i}]", x, "a list metric holds numbers")
        return
    if not isinstance(value, dict):
        fail(where, value, "a metric is a number, a list of numbers or {mean, max, per_frame}")
    for key, x in value.items():
        if key in ("mean", "max") and not number(x):
            fail(f"{where}.{key}", x, f"'{key}' is a number or null")
        elif key == "per_frame":
            if not isinstance(x, list):
                fail(f"{where}.per_frame", x, "'per_frame' is a list of numbers")
            _check_metric(x, f"{where}.per_frame", path)
        elif isinstance(x, (dict, list)) and not (isinstance(x, list) and all(number(y) for y in x)):
            fail(f"{where}.{key}", x, "a metric's parts are numbers, strings or lists of numbers")


class Histogram(_Model):
    input: list[Annotated[int, Field(ge=0)]] | None = None
    reduced: list[Annotated[int, Field(ge=0)]] | None = None


class LevelEntry(_Model):
    """One simplified level's values (schema version 2): ``name`` and metrics like ``metrics``'s."""

    name: str


class EvaluationEntry(_Model):
    name: str | None = None
    step: int | None = None
    metrics: dict = {}
    levels: list[LevelEntry] | None = None
    influence_histogram: Histogram | None = None


class StepEntry(_Model):
    stage: str | None = None
    plugin: str | None = None
    k: int | None = None
    seconds: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0


class Frames(_Model):
    examples: list[int] | None = None
    test: list[int] | None = None


class MetricsDocument(_Model):
    name: str | None = None
    steps: list[StepEntry] = []
    frames: Frames | None = None
    evaluations: Annotated[list[EvaluationEntry], Field(min_length=1)]


def _json_path(loc) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif isinstance(part, str) and (part[:1].isupper() or "[" in part or part in ("int", "float", "str", "bool",
                                                                                     "list", "none", "dict")):
            continue  # pydantic's union-member labels, not JSON keys
        else:
            out += ("." if out else "") + part
    return out or "top level"


def command_run(doc, path) -> dict:
    """The metrics document of a command's ``--report`` (``rigslim reduce`` or ``rigslim lod``); ``doc`` itself
    when it is no command report.

    The run's document is ``doc["run"]``; the pipeline the command ran (``doc["pipeline"]``, in memory: the run
    records no pipeline file) goes with it as ``pipeline_document``, and ``command_report`` keeps the command
    and, for a file of several skins (``per_skin``: one run per skin, ``run`` the last skin's for ``reduce``,
    the first's for ``lod``), the skins.

    Raises
    ------
    InputError
        For the report of another command (no run in it), or a run that measured nothing, with the option
        that makes one.
    """
    if not isinstance(doc, dict) or doc.get("schema") != COMMAND_SCHEMA:
        return doc
    command = doc.get("command")
    run = doc.get("run")
    if command not in RUN_COMMANDS or not isinstance(run, dict):
        raise InputError(f"a 'rigslim {command}' report holds no pipeline run", source=path, field="command",
                         fix="give the --report of 'rigslim reduce' or 'rigslim lod', or a 'rigslim run --metrics' "
                             "file")
    if not run.get("evaluations"):
        how = ("'rigslim lod ... --measure --report FILE.json' measures the levels" if command == "lod" else
               "'rigslim reduce' measures only an animated input (frames >= 2) it reduces (k below the joint "
               "count)")
        raise InputError(f"the 'rigslim {command}' run measured nothing", source=path, field="run.evaluations",
                         fix=how)
    run = dict(run)
    if isinstance(doc.get("pipeline"), dict):
        run["pipeline_document"] = doc["pipeline"]
    skins = [s.get("skin") for s in doc.get("per_skin") or [] if isinstance(s, dict)]
    run["command_report"] = {"command": command, "input": doc.get("input"), **({"skins": skins} if skins else {})}
    return run


def check_metrics_document(doc, path) -> dict:
    """Validate a parsed metrics document (see the module docstring); returns it unchanged."""
    if not isinstance(doc, dict) or not isinstance(doc.get("evaluations"), list):
        raise InputError("no 'evaluations' list", source=path, field="evaluations",
                         fix="give the file of 'rigslim run PIPELINE.yaml --metrics FILE.json' (a pipeline with an "
                             "'evaluate' step) or of 'rigslim reduce|lod ... --report FILE.json'")
    if not doc["evaluations"]:
        raise InputError("the document has no evaluation", source=path, field="evaluations",
                         fix="add an 'evaluate' step to the pipeline")
    try:
        checked = MetricsDocument.model_validate(doc)
    except ValidationError as err:
        errors = err.errors()
        # a union reports one error per member: the deepest path is the most telling
        e = max(errors, key=lambda x: len(x["loc"]))
        problem = e["msg"][0].lower() + e["msg"][1:]
        if e["type"] != "missing":
            problem += f" (got {brief(e.get('input'))})"
        raise InputError(problem, source=path, field=_json_path(e["loc"]), fix=FIX) from None
    for i, ev in enumerate(checked.evaluations):
        for name, value in ev.metrics.items():
            _check_metric(value, f"evaluations[{i}].metrics.{name}", path)
        for j, level in enumerate(ev.levels or []):
            for name, value in (level.model_extra or {}).items():
                _check_metric(value, f"evaluations[{i}].levels[{j}].{name}", path)
    return doc


def read_metrics_document(path) -> dict:
    """Read, parse and check a metrics JSON file."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            data = f.read(MAX_BYTES + 1)
    except OSError as e:
        raise InputError(f"cannot read metrics JSON ({e.strerror})", source=path, field="path", fix=FIX) from None
    if len(data) > MAX_BYTES:
        raise InputError(f"larger than {MAX_BYTES >> 20} MiB", source=path, field="path", fix=FIX)
    try:
        text = data.decode("utf-8-sig")
    except UnicodeDecodeError as e:
        raise InputError(f"not UTF-8 text (byte {data[e.start]:#04x} at offset {e.start})", source=path,
                         field="document", fix=FIX) from None

    try:
        doc = json.loads(text)
    except json.JSONDecodeError as e:
        raise InputError(f"not JSON (line {e.lineno}: {e.msg})", source=path, field="document", fix=FIX) from None
    except RecursionError:
        raise InputError("the JSON is nested too deeply", source=path, field="document", fix=FIX) from None
    # NaN / Infinity (older rigslim versions wrote them) read as missing values, like the null written now
    return check_metrics_document(command_run(finite_copy(doc), path), path)


def check_render_size(width, height, field: str = "size") -> None:
    """Refuse render sizes outside 1..MAX_RENDER_SIDE pixels per side."""
    for value in (width, height):
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= MAX_RENDER_SIDE:
            raise InputError(f"render size {brief(width)}x{brief(height)} is outside 1..{MAX_RENDER_SIDE} pixels "
                             "per side", field=field, fix="give e.g. --size 320x270")
