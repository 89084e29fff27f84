"""The pipeline document: the YAML validated, its steps parsed, ``--set`` overrides applied."""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Literal, cast

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from rigslim.errors import PipelineError, brief, closest
from rigslim.errors import PluginNotFoundError as PluginNotFound
from rigslim.io.yamlio import load_yaml_file
from rigslim.plugin.contract import STEP_STAGES
from rigslim.plugin.host import PluginHost, get_host


class ClipFrames(BaseModel):
    """One side of a two-clip ``poses:``, or (``clips:``) of several clips (:mod:`rigslim.runtime.clips`)."""

    model_config = ConfigDict(extra="forbid")
    clip: str | int | None = None
    frames: str | int | list[str | int] | None = None
    clips: Literal["all"] | list[str | int] | None = None
    count: int | None = Field(None, ge=1, description="clips: example frames in all, evenly over the clips")



class PoseSpec(BaseModel):
    model_config = ConfigDict(extra="forbid")
    examples: str | int | list[str | int] | ClipFrames
    test: str | int | list[str | int] | ClipFrames

    @field_validator("examples", "test", mode="before")
    @classmethod
    def _one_clip_form(cls, v):
        """A mapping side is either ``{clip, frames}`` or ``{clips, count}`` (one message, not the union's);
        true/false is no frame (pydantic would read it as frame 1 or 0)."""
        if isinstance(v, bool) or (isinstance(v, list) and any(isinstance(x, bool) for x in v)):
            raise ValueError("true/false is not a frame number")
        if isinstance(v, dict):
            if ("clip" in v) == ("clips" in v):
                raise ValueError("give either 'clip' (one clip) or 'clips' (several, or 'all')")
            if "clips" in v and "frames" in v:
                raise ValueError("'frames' goes with 'clip'; with 'clips' the frames are sampled (examples: 'count')")
            if "clip" in v and "count" in v:
                raise ValueError("'count' goes with 'clips'; with 'clip' give 'frames'")
        return v


class PipelineDoc(BaseModel):
    """The validated YAML document."""

    model_config = ConfigDict(extra="forbid")
    name: str | None = None
    description: str | None = None
    inputs: dict[str, Any] = {}
    poses: PoseSpec | None = None
    steps: list[dict[str, Any]]

    @field_validator("steps")
    @classmethod
    def _nonempty(cls, v):
        if not v:
            raise ValueError("a pipeline needs at least one step")
        return v


@dataclass
class Step:
    """One parsed step: exactly one of ``plugin``, ``metrics`` and ``output`` says what it runs."""

    index: int           # 1-based
    key: str             # stage key in YAML ("solve")
    stage: str           # stage name ("weight-solver")
    params: dict
    name: str
    plugin: str | None = None                     # the plugin a generate/select/solve/... step runs
    metrics: list[tuple[str, dict]] = field(default_factory=list)  # evaluate: (metric name, parameters)
    output: str | None = None                     # write/report: the output path (as written)

    @property
    def label(self) -> str:
        """What the step runs, for messages and the metrics document: the plugin, the metrics or the path."""
        if self.key == "evaluate":
            return ",".join(n for n, _ in self.metrics)
        return self.plugin if self.plugin is not None else str(self.output)


def _format_validation(err: ValidationError) -> tuple[str, str]:
    e = err.errors()[0]
    loc = ".".join(str(x) for x in e["loc"])
    return loc, e["msg"]


#: The accepted forms of ``poses.examples`` and ``poses.test`` (docs/pipelines.md), for messages.
POSE_FORMS = ("a frame spec ('0:60:5', '1,5,9', 7 or a list of those), {clip: NAME, frames: SPEC} "
              "or {clips: all or [NAMES], count: N}")
#: The accepted forms of each field of a mapping side, for messages.
CLIP_FIELD_FORMS = {"clip": "a clip name or index", "frames": "a frame spec ('0:60:5', '1,5,9', 7 or a list of those)",
                    "clips": "all or a list of clip names or indices", "count": "a whole number >= 1"}


def _user_loc(loc: tuple) -> tuple:
    """A pydantic error location without its union-branch tags (``str``, ``int``, ``list[...]``, ``ClipFrames``,
    ``literal[...]``): the path the user wrote (``poses.examples.frames``)."""
    def tag(x) -> bool:
        return isinstance(x, str) and (x in ("str", "int", "float", "bool", "none") or "[" in x or x[:1].isupper())
    return tuple(x for x in loc if not tag(x))


def _poses_error(errors: list, value: Any, path: Path) -> PipelineError:
    """One line for a malformed ``poses:`` naming the user's field (``poses.examples``, not the union branch
    ``poses.examples.str``) and the accepted forms, instead of the first of pydantic's per-branch errors."""
    first = errors[0]
    loc = _user_loc(first["loc"])
    example = "write e.g. poses: {examples: '0:60:5', test: '1:60:5'} (docs/pipelines.md)"
    if len(loc) == 1:
        return PipelineError(f"poses is {brief(value)}, not a mapping of 'examples' and 'test'", source=path,
                             field="poses", fix=example)
    side, field = loc[1], f"poses.{loc[1]}"
    if first["type"] == "extra_forbidden" and len(loc) == 2:
        return PipelineError(f"unknown key '{side}'", source=path, field="poses",
                             fix=closest(str(side), PoseSpec.model_fields))
    if first["type"] == "missing":
        return PipelineError(f"'{side}' is missing; poses needs both 'examples' and 'test'", source=path, field=field,
                             fix=f"give {field} as {POSE_FORMS}")
    if first["type"] == "value_error":  # PoseSpec._one_clip_form: its own message
        return PipelineError(str(first["msg"]).removeprefix("Value error, "), source=path, field=field,
                             fix=f"give {field} as {POSE_FORMS}")
    given = value.get(side) if isinstance(value, dict) else None
    inner = [e for e in errors if _user_loc(e["loc"])[:2] == loc[:2] and len(_user_loc(e["loc"])) > 2]
    if isinstance(given, dict) and inner:  # a mapping side: the first of its own fields that is wrong
        key = _user_loc(inner[0]["loc"])[2]
        same = [e for e in inner if _user_loc(e["loc"])[2] == key]
        if same[0]["type"] == "extra_forbidden":
            return PipelineError(f"unknown key '{key}'", source=path, field=field,
                                 fix=closest(str(key), ClipFrames.model_fields))
        forms = CLIP_FIELD_FORMS.get(str(key), "see docs/pipelines.md")
        got = brief(given.get(key))
        what = f"{same[0]['msg'].lower()} (got {got})" if len(same) == 1 else f"{got} is none of the accepted forms"
        return PipelineError(what, source=path, field=f"{field}.{key}", fix=f"give {field}.{key} as {forms}")
    return PipelineError(f"{brief(given)} is none of the accepted forms", source=path, field=field,
                         fix=f"give {field} as {POSE_FORMS}")


def load_pipeline(path, overrides: Sequence[str] = (), host: PluginHost | None = None, *,
                  raw: dict | None = None) -> tuple[PipelineDoc, list[Step]]:
    """Read, validate and parse a pipeline file.

    Parameters
    ----------
    path : path to the YAML file
    overrides : list of "STEP.PARAM=VALUE"
        STEP is a step's ``name``, its stage key, its plugin name or its
        1-based index; VALUE is parsed as YAML.
    raw : dict, optional
        The document itself (as YAML would load it); ``path`` then only names
        it in messages, and its folder is where relative paths resolve.
    """
    host = host or get_host()
    path = Path(path)
    if raw is None:
        raw = cast("dict | None", load_yaml_file(path))  # UTF-8, no repeated keys, bounded aliases and nesting
    if not isinstance(raw, dict):
        raise PipelineError("the document is not a mapping", source=path, field="top level",
                            fix="start with 'inputs:', 'poses:' and 'steps:'")
    odd = next((k for k in raw if not isinstance(k, str)), None)
    if odd is not None or any(not isinstance(k, str) for k in raw):
        raise PipelineError(f"top-level key {brief(odd)} is not a name", source=path, field="top level",
                            fix="the top-level keys are " + ", ".join(PipelineDoc.model_fields))
    try:
        doc = PipelineDoc.model_validate(raw)
    except ValidationError as err:
        if err.errors()[0]["loc"][:1] == ("poses",):
            raise _poses_error(err.errors(), raw.get("poses"), path) from None
        loc, msg = _format_validation(err)
        top = loc.split(".")[0]
        fix = closest(top, PipelineDoc.model_fields) if "extra" in err.errors()[0]["type"] else \
            "see docs/pipelines.md"
        raise PipelineError(msg, source=path, field=loc, fix=fix) from None
    steps = [_parse_step(i, s, path, host) for i, s in enumerate(doc.steps, 1)]
    for item in overrides:
        _apply_override(item, steps, path, host)
    return doc, steps


def _parse_step(index: int, raw: dict, path: Path, host: PluginHost) -> Step:
    if not isinstance(raw, dict):
        raise PipelineError(f"step {index} is not a mapping", source=path, field=f"steps[{index}]",
                            fix="write each step as '- solve: poisson' with its parameters below")
    keys = [k for k in raw if k in STEP_STAGES]
    if len(keys) != 1:
        unknown = [k for k in raw if k not in STEP_STAGES and k != "name"]
        hint = closest(unknown[0], STEP_STAGES) if unknown and not keys else \
            "give exactly one of " + ", ".join(STEP_STAGES)
        what = f"unknown stage '{unknown[0]}'" if unknown and not keys else \
            f"step has {len(keys)} stage keys ({', '.join(keys) or 'none'})"
        raise PipelineError(what, source=path, field=f"steps[{index}]", fix=hint)
    key = keys[0]
    stage = STEP_STAGES[key]
    params = {k: v for k, v in raw.items() if k not in (key, "name")}
    value = raw[key]
    if key == "evaluate":
        metrics = _parse_metrics(value, index, path, host)
        return Step(index, key, stage, params, str(raw.get("name") or f"evaluate{index}"), metrics=metrics)
    if key in ("write", "report"):
        if not isinstance(value, str):
            raise PipelineError(f"{key} needs an output path", source=path, field=f"steps[{index}].{key}",
                                fix="write e.g. 'write: out/weights.npz' or 'report: out/report.html'")
        return Step(index, key, stage, params, str(raw.get("name") or f"{key}{index}"), output=value)
    if not isinstance(value, str):
        raise PipelineError(f"'{key}' needs a plugin name", source=path, field=f"steps[{index}].{key}",
                            fix=closest("", host.plugins(stage)))
    try:
        plugin_obj = host.get(stage, value)
    except PluginNotFound as e:
        raise PipelineError(e.problem, source=path, field=f"steps[{index}].{key}", fix=e.fix) from None
    check_params(plugin_obj, params, path, f"steps[{index}]")
    return Step(index, key, stage, params, str(raw.get("name") or value), plugin=value)


def _parse_metrics(value, index, path, host) -> list[tuple[str, dict]]:
    items: list[tuple[str, dict]]
    if isinstance(value, str):
        items = [(value, {})]
    elif isinstance(value, list):
        items = []
        for v in value:
            if isinstance(v, str):
                items.append((v, {}))
            elif isinstance(v, dict) and len(v) == 1:
                (n, p), = v.items()
                items.append((n, p or {}))
            else:
                raise PipelineError(f"cannot read metric entry {brief(v)}", source=path,
                                    field=f"steps[{index}].evaluate", fix="list metric names")
    elif isinstance(value, dict):
        items = [(n, p or {}) for n, p in value.items()]
    else:
        raise PipelineError("evaluate needs metric names", source=path, field=f"steps[{index}].evaluate",
                            fix="write e.g. 'evaluate: [position-rms, normal-deviation]'")
    for n, p in items:
        if not isinstance(n, str) or not isinstance(p, dict):
            raise PipelineError(f"metric entry {brief(n)}: {brief(p)} is not 'name: {{parameters}}'", source=path,
                                field=f"steps[{index}].evaluate", fix="write e.g. 'evaluate: {position-rms: {}}' "
                                "or a list of metric names")
    for n, p in items:
        try:
            metric = host.get("metric", n)
        except PluginNotFound as e:
            raise PipelineError(e.problem, source=path, field=f"steps[{index}].evaluate", fix=e.fix) from None
        check_params(metric, p, path, f"steps[{index}].evaluate.{n}")
    return items


def check_params(plugin, params: dict, path, where: str):
    try:
        return plugin.parse_params(params)
    except ValidationError as err:
        # An unknown name usually explains a "missing" one too (a typo): report it first.
        e = sorted(err.errors(), key=lambda x: x["type"] != "extra_forbidden")[0]
        loc = ".".join(str(x) for x in e["loc"])
        if e["type"] == "extra_forbidden":
            fields = plugin.Params.model_fields
            fix = closest(loc, fields) if fields else f"'{plugin.name}' takes no parameters"
            raise PipelineError(f"unknown parameter '{loc}' for {plugin.stage} '{plugin.name}'", source=path,
                                field=f"{where}.{loc}", fix=fix) from None
        fields = ", ".join(plugin.Params.model_fields) or "none"
        raise PipelineError(f"{e['msg'].lower()} (got {brief(e.get('input'))})" if e["type"] != "missing"
                            else "required parameter is missing", source=path, field=f"{where}.{loc}",
                            fix=f"{plugin.stage} '{plugin.name}' takes: {fields}") from None


def _apply_override(item: str, steps: list[Step], path: Path, host: PluginHost) -> None:
    """One ``--set``: ``STEP.PARAM=VALUE`` sets a parameter; ``STEP=PLUGIN`` (or ``STEP.KEY=PLUGIN``,
    KEY the step's stage key) replaces the step's plugin, keeping the parameters the new plugin takes."""
    lhs = item.split("=", 1)[0]
    if "=" not in item or not lhs.strip():
        raise PipelineError(f"--set '{item}' is not STEP.PARAM=VALUE or STEP=PLUGIN", source=path, field="--set",
                            fix="write e.g. --set select.k=6 or --set solve=poisson")
    value = item.split("=", 1)[1]
    target, param = lhs.rsplit(".", 1) if "." in lhs else (lhs, None)
    matches = [s for s in steps if target in (s.name, s.key, str(s.index)) or
               (s.plugin is not None and s.plugin == target)]
    if not matches:
        names = [s.name for s in steps] + [s.key for s in steps]
        raise PipelineError(f"--set names no step '{target}'", source=path, field="--set", fix=closest(target, names))
    try:
        parsed = yaml.safe_load(value)
    except yaml.YAMLError:
        parsed = value
    for step in matches:
        if step.key == "evaluate":
            raise PipelineError("--set cannot change evaluate steps", source=path, field="--set",
                                fix="edit the pipeline file")
        if param is None or param == step.key:
            if not isinstance(parsed, str) or not parsed.strip():
                what = "an output path" if step.key in ("write", "report") else "a plugin name"
                raise PipelineError(f"--set '{item}' gives {parsed!r}, not {what}", source=path, field="--set",
                                    fix=f"write e.g. --set {target}=NAME (rigslim plugins lists the names)"
                                    if what == "a plugin name" else f"write e.g. --set {target}=out/file")
            if step.key in ("write", "report"):
                step.output = parsed
                fitting = host.by_suffix("writer", Path(parsed).suffix) if step.key == "write" and \
                    "writer" not in step.params else []
                if fitting:     # another format: the parameters its writer does not take are dropped
                    step.params = {k: v for k, v in step.params.items() if k in fitting[0].Params.model_fields}
                continue
            if step.name == step.plugin:
                step.name = parsed  # a default name (the plugin's) follows the plugin
            step.plugin = parsed
            try:
                plugin = host.get(step.stage, parsed)
            except PluginNotFound as e:
                raise PipelineError(e.problem, source=path, field="--set", fix=e.fix) from None
            # Parameters of the old plugin that the new one does not take are dropped.
            step.params = {k: v for k, v in step.params.items() if k in plugin.Params.model_fields}
            check_params(plugin, step.params, path, f"steps[{step.index}]")
            continue
        step.params[param] = parsed
        if step.plugin is not None:
            check_params(host.get(step.stage, step.plugin), step.params, path, f"steps[{step.index}]")
