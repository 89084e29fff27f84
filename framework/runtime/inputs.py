"""A pipeline's ``inputs:`` read into an :class:`~rigslim.model.asset.Asset`, each role by its
reader, and its ``poses:`` split."""

from __future__ import annotations

from pathlib import Path

from rigslim.errors import PipelineError, closest
from rigslim.errors import PluginNotFoundError as PluginNotFound
from rigslim.model.asset import Asset
from rigslim.model.poses import FrameSplit
from rigslim.plugin.contract import StepContext
from rigslim.plugin.host import PluginHost
from rigslim.runtime.clips import clip_split, uses_clips
from rigslim.runtime.document import PipelineDoc, check_params

#: Order in which input roles are read (others follow, in file order).
ROLE_ORDER = ["gltf", "mesh", "skeleton", "cage", "weights", "animation"]


def _gltf_inputs(inputs: dict) -> dict:
    """Beside ``gltf:``, ``animation:`` (a clip name or index, not a file) and ``fps:`` are the glTF reader's."""
    inputs = dict(inputs)
    spec = inputs["gltf"]
    spec = {"path": spec} if isinstance(spec, str) else dict(spec) if isinstance(spec, dict) else spec
    if isinstance(spec, dict):
        for key in ("animation", "fps"):
            value = inputs.get(key)
            if value is not None and not isinstance(value, dict) and not (
                    isinstance(value, str) and Path(value).suffix.lower() == ".dmat"):
                spec.setdefault(key, inputs.pop(key))
        inputs["gltf"] = spec
    return inputs


def read_inputs(doc: PipelineDoc, base: Path, host: PluginHost, ctx: StepContext, source) -> Asset:
    """Fill an :class:`Asset` from the ``inputs`` section, each role by its reader."""
    asset = Asset()
    inputs = dict(doc.inputs)
    normalize = inputs.pop("normalize", None)
    if "gltf" in inputs:
        clash = [r for r in ("mesh", "skeleton", "weights", "cage") if r in inputs]
        if clash:   # the glTF reader fills the mesh, joints and weights: another file would silently replace them
            raise PipelineError(f"'gltf:' reads the mesh, skeleton and weights, so 'inputs.{clash[0]}' would replace "
                                "the glTF's own", source=source, field=f"inputs.{clash[0]}",
                                fix=f"remove '{clash[0]}:' (choose a glTF mesh with 'gltf: {{path: ..., mesh: NAME}}')")
        inputs = _gltf_inputs(inputs)
    readers = host.readers()
    specs = {}
    for role, spec in inputs.items():
        if isinstance(spec, str):
            spec = {"path": spec}
        if not isinstance(spec, dict) or "path" not in spec:
            raise PipelineError(f"input '{role}' needs a path", source=source, field=f"inputs.{role}",
                                fix=f"write '{role}: path/to/file'")
        spec = dict(spec)
        if role == "weights" and normalize is not None:
            spec.setdefault("normalize", normalize)
        specs[role] = spec
    roles_known = sorted({r.role for r in readers.values()})
    order = sorted(specs, key=lambda r: ROLE_ORDER.index(r) if r in ROLE_ORDER else len(ROLE_ORDER))
    for role in order:
        spec = dict(specs[role])
        file = Path(spec.pop("path"))
        file = file if file.is_absolute() else base / file
        name = spec.pop("reader", None)
        if name is not None:
            try:
                reader = host.reader(name)
            except PluginNotFound as e:
                raise PipelineError(e.problem, source=source, field=f"inputs.{role}.reader", fix=e.fix) from None
        else:
            cands = [r for r in readers.values() if r.role == role]
            if not cands:
                raise PipelineError(f"unknown input '{role}'", source=source, field=f"inputs.{role}",
                                    fix=closest(role, roles_known))
            fitting = host.by_suffix("reader", file.suffix, role)  # two readers: DuplicatePluginError
            if not fitting:
                sufs = sorted({s for r in cands for s in r.suffixes})
                raise PipelineError(f"no reader for '{file.suffix}' files as {role}", source=source,
                                    field=f"inputs.{role}", fix="use one of " + ", ".join(sufs))
            reader = fitting[0]
        if not file.exists():
            raise PipelineError("input file not found", source=file, field=f"inputs.{role}",
                                fix="check the path (relative paths are relative to the pipeline file)")
        params = check_params(reader, spec, source, f"inputs.{role}")
        with host.calling("reader", reader.name, f"inputs.{role}"):
            reader.read(file, asset, params, ctx)
        asset.provenance.setdefault("inputs", {})[role] = str(file)
    if asset.poses is None and asset.handles is not None:
        asset.provenance["poses"] = "rest pose only"
    if doc.poses is not None and uses_clips(doc.poses):
        gltf = _gltf_inputs(doc.inputs).get("gltf") if "gltf" in doc.inputs else None
        asset.poses, asset.split = clip_split(doc.poses, asset, base, source, gltf if isinstance(gltf, dict) else None)
    elif doc.poses is not None:
        if asset.poses is None:
            raise PipelineError("a 'poses' split is given but no animation", source=source,
                                field="inputs.animation", fix="add 'animation:' under inputs")
        asset.split = FrameSplit.from_specs(doc.poses.examples, doc.poses.test, len(asset.poses), source=source)
    return asset
