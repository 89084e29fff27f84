"""Structure of a glTF document checked before anything is decoded.

:func:`check_document` validates the JSON of a glTF 2.0 file, so that the
reader can trust it: every property the reader uses has its type and range
(pydantic models in strict mode: ``"10"``, ``true`` and ``2.5`` are not
counts), every index points into its array, the node hierarchy is a forest
(no node is its own child, no cycle, no node with two parents), every
bufferView lies inside its buffer and every accessor inside its bufferView.
A problem becomes one :class:`~rigslim.errors.InputError` naming the file
and the JSON path (``accessors[3].count``).

Limits (documented in docs/gltf.md):

- an accessor without a bufferView (zeros, perhaps with sparse
  substitution) holds at most :data:`MAX_ZEROS_COMPONENTS` components, as it
  is the only array whose size the file's real bytes do not bound.
"""

from __future__ import annotations

import math
from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator
from pydantic_core import PydanticCustomError

from rigslim.errors import InputError, brief

COMPONENT_SIZES = {5120: 1, 5121: 1, 5122: 2, 5123: 2, 5125: 4, 5126: 4}
TYPE_SIZES = {"SCALAR": 1, "VEC2": 2, "VEC3": 3, "VEC4": 4, "MAT2": 4, "MAT3": 9, "MAT4": 16}
#: Most components an accessor without a bufferView may have (zeros the reader must allocate).
MAX_ZEROS_COMPONENTS = 1 << 25
FIX = "re-export the file; check it with the glTF-Validator"

Index = Annotated[int, Field(ge=0)]
Finite = Annotated[float, Field(allow_inf_nan=False)]


class _Model(BaseModel):
    model_config = ConfigDict(strict=True, extra="allow")

    @model_validator(mode="before")
    @classmethod
    def _no_null(cls, data):
        """JSON ``null`` is no value a glTF property may take (leave the property out instead)."""
        if isinstance(data, dict):
            for key, value in data.items():
                if value is None and key in cls.model_fields:
                    raise PydanticCustomError("null", "'{key}' is null; leave the property out instead",
                                              {"key": key})
        return data


class AssetInfo(_Model):
    version: str


class Buffer(_Model):
    uri: str | None = None
    byteLength: Annotated[int, Field(ge=1)]


class BufferView(_Model):
    buffer: Index
    byteOffset: Index = 0
    byteLength: Annotated[int, Field(ge=1)]
    byteStride: Annotated[int, Field(ge=4, le=252)] | None = None


class SparseIndices(_Model):
    bufferView: Index
    byteOffset: Index = 0
    componentType: Literal[5121, 5123, 5125]


class SparseValues(_Model):
    bufferView: Index
    byteOffset: Index = 0


class Sparse(_Model):
    count: Annotated[int, Field(ge=1)]
    indices: SparseIndices
    values: SparseValues


class Accessor(_Model):
    bufferView: Index | None = None
    byteOffset: Index = 0
    componentType: Literal[5120, 5121, 5122, 5123, 5125, 5126]
    normalized: bool = False
    count: Annotated[int, Field(ge=1)]
    type: Literal["SCALAR", "VEC2", "VEC3", "VEC4", "MAT2", "MAT3", "MAT4"]
    max: list[float] | None = None
    min: list[float] | None = None
    sparse: Sparse | None = None


class Node(_Model):
    children: list[Index] = []
    mesh: Index | None = None
    skin: Index | None = None
    matrix: Annotated[list[Finite], Field(min_length=16, max_length=16)] | None = None
    translation: Annotated[list[Finite], Field(min_length=3, max_length=3)] | None = None
    rotation: Annotated[list[Finite], Field(min_length=4, max_length=4)] | None = None
    scale: Annotated[list[Finite], Field(min_length=3, max_length=3)] | None = None
    name: str | None = None

    @field_validator("rotation")
    @classmethod
    def _unit(cls, q):
        if q is not None and math.sqrt(sum(c * c for c in q)) < 1e-6:
            raise ValueError("rotation is a zero quaternion, which is no rotation; write a unit quaternion "
                             "(x, y, z, w), e.g. [0, 0, 0, 1]")
        return q


class Primitive(_Model):
    attributes: dict[str, Index]
    indices: Index | None = None
    mode: Annotated[int, Field(ge=0, le=6)] = 4
    targets: list[dict[str, Index]] | None = None


class MeshModel(_Model):
    primitives: Annotated[list[Primitive], Field(min_length=1)]
    name: str | None = None


class Skin(_Model):
    inverseBindMatrices: Index | None = None
    skeleton: Index | None = None
    joints: Annotated[list[Index], Field(min_length=1)]

    @field_validator("joints")
    @classmethod
    def _distinct(cls, joints):
        seen: set[int] = set()
        for i, j in enumerate(joints):
            if j in seen:       # the specification requires distinct joints; a written copy would be invalid
                raise ValueError(f"node {j} is listed twice (joints[{i}]); a skin's joints must be distinct: "
                                 "re-export the file")
            seen.add(j)
        return joints


class Target(_Model):
    node: Index | None = None
    path: str


class Channel(_Model):
    sampler: Index
    target: Target


class Sampler(_Model):
    input: Index
    output: Index
    interpolation: Literal["LINEAR", "STEP", "CUBICSPLINE"] = "LINEAR"


class Animation(_Model):
    channels: list[Channel]
    samplers: list[Sampler]
    name: str | None = None


class Scene(_Model):
    nodes: list[Index] = []


class Image(_Model):
    uri: str | None = None
    bufferView: Index | None = None


class Document(_Model):
    asset: AssetInfo
    scene: Index | None = None
    scenes: list[Scene] = []
    nodes: list[Node] = []
    meshes: list[MeshModel] = []
    skins: list[Skin] = []
    animations: list[Animation] = []
    accessors: list[Accessor] = []
    bufferViews: list[BufferView] = []
    buffers: list[Buffer] = []
    images: list[Image] = []
    # read by no reader but copied into outputs: at least an array of objects, as the glTF schema says
    materials: list[dict] = []
    textures: list[dict] = []
    samplers: list[dict] = []
    cameras: list[dict] = []
    extensionsUsed: list[str] = []
    extensionsRequired: list[str] = []
    extensions: dict = {}


def json_path(loc) -> str:
    """``('accessors', 3, 'count')`` as ``accessors[3].count``."""
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        else:
            out += ("." if out else "") + str(part)
    return out or "top level"


def _fail(path, field: str, problem: str, fix: str = FIX):
    raise InputError(problem, source=path, field=field, fix=fix)


def check_document(js, path) -> Document:
    """Validate a glTF document's JSON (see the module docstring); returns the typed view.

    Raises
    ------
    InputError
        Naming ``path`` and the JSON path of the first problem found.
    """
    if not isinstance(js, dict):
        _fail(path, "top level", f"the glTF JSON is a {type(js).__name__}, not an object", "give a glTF 2.0 file")
    version = js.get("asset", {}).get("version") if isinstance(js.get("asset"), dict) else None
    if isinstance(version, str) and not version.startswith("2."):
        _fail(path, "asset.version", f"glTF version {brief(version)} is not 2.x",
              "convert the file to glTF 2.0 (e.g. with Blender or assimp)")
    try:
        doc = Document.model_validate(js)
    except ValidationError as err:
        e = err.errors()[0]
        loc = [p for p in e["loc"] if not (isinstance(p, str) and (p.startswith("function-") or "[" in p))]
        if e["type"] == "null":
            loc.append(e["ctx"]["key"])
        msg = e["msg"].removeprefix("Value error, ")
        problem = msg[0].lower() + msg[1:]
        if e["type"] not in ("missing", "null"):
            problem += f" (got {brief(e.get('input'))})"
        _fail(path, json_path(loc), problem)
    _check_references(doc, path)
    _check_hierarchy(doc, path)
    _check_ranges(doc, path)
    return doc


def _check_references(doc: Document, path) -> None:
    counts = {"nodes": len(doc.nodes), "meshes": len(doc.meshes), "skins": len(doc.skins),
              "accessors": len(doc.accessors), "bufferViews": len(doc.bufferViews), "buffers": len(doc.buffers),
              "scenes": len(doc.scenes)}

    def ref(where: str, value, kind: str):
        if value is not None and value >= counts[kind]:
            _fail(path, where, f"index {value} is out of range (the file has {counts[kind]} {kind})")

    ref("scene", doc.scene, "scenes")
    for i, s in enumerate(doc.scenes):
        for j, n in enumerate(s.nodes):
            ref(f"scenes[{i}].nodes[{j}]", n, "nodes")
    for i, node in enumerate(doc.nodes):
        for j, c in enumerate(node.children):
            ref(f"nodes[{i}].children[{j}]", c, "nodes")
        ref(f"nodes[{i}].mesh", node.mesh, "meshes")
        ref(f"nodes[{i}].skin", node.skin, "skins")
    for i, m in enumerate(doc.meshes):
        for j, p in enumerate(m.primitives):
            where = f"meshes[{i}].primitives[{j}]"
            for name, a in p.attributes.items():
                ref(f"{where}.attributes.{name}", a, "accessors")
            ref(f"{where}.indices", p.indices, "accessors")
            for t, target in enumerate(p.targets or []):
                for name, a in target.items():
                    ref(f"{where}.targets[{t}].{name}", a, "accessors")
    for i, skin in enumerate(doc.skins):
        ref(f"skins[{i}].inverseBindMatrices", skin.inverseBindMatrices, "accessors")
        ref(f"skins[{i}].skeleton", skin.skeleton, "nodes")
        for j, joint in enumerate(skin.joints):
            ref(f"skins[{i}].joints[{j}]", joint, "nodes")
    for i, anim in enumerate(doc.animations):
        for j, channel in enumerate(anim.channels):
            if channel.sampler >= len(anim.samplers):
                _fail(path, f"animations[{i}].channels[{j}].sampler",
                      f"index {channel.sampler} is out of range (the animation has {len(anim.samplers)} samplers)")
            ref(f"animations[{i}].channels[{j}].target.node", channel.target.node, "nodes")
        for j, sampler in enumerate(anim.samplers):
            ref(f"animations[{i}].samplers[{j}].input", sampler.input, "accessors")
            ref(f"animations[{i}].samplers[{j}].output", sampler.output, "accessors")
    for i, acc in enumerate(doc.accessors):
        ref(f"accessors[{i}].bufferView", acc.bufferView, "bufferViews")
        if acc.sparse is not None:
            ref(f"accessors[{i}].sparse.indices.bufferView", acc.sparse.indices.bufferView, "bufferViews")
            ref(f"accessors[{i}].sparse.values.bufferView", acc.sparse.values.bufferView, "bufferViews")
    for i, v in enumerate(doc.bufferViews):
        ref(f"bufferViews[{i}].buffer", v.buffer, "buffers")
    for i, im in enumerate(doc.images):
        ref(f"images[{i}].bufferView", im.bufferView, "bufferViews")


def _check_hierarchy(doc: Document, path) -> None:
    """Every node has at most one parent and no node is its own ancestor."""
    parent = [-1] * len(doc.nodes)
    for i, n in enumerate(doc.nodes):
        for j, c in enumerate(n.children):
            if c == i:
                _fail(path, f"nodes[{i}].children[{j}]", f"node {i} is its own child",
                      "repair the node hierarchy (it must be a tree)")
            if parent[c] >= 0:
                _fail(path, f"nodes[{i}].children[{j}]",
                      f"node {c} is a child of nodes {parent[c]} and {i} (a node has one parent)",
                      "repair the node hierarchy (it must be a tree)")
            parent[c] = i
    state = [0] * len(doc.nodes)  # 0 unseen, 1 on the current chain, 2 done
    for start in range(len(doc.nodes)):
        chain, j = [], start
        while j >= 0 and state[j] == 0:
            state[j] = 1
            chain.append(j)
            j = parent[j]
        if j >= 0 and state[j] == 1:
            cycle = chain[chain.index(j):]
            _fail(path, f"nodes[{j}].children", "the node hierarchy has a cycle through nodes "
                  + " -> ".join(map(str, cycle[::-1][:8])) + (" ..." if len(cycle) > 8 else ""),
                  "repair the node hierarchy (it must be a tree)")
        for k in chain:
            state[k] = 2


def accessor_layout(doc: Document, index: int) -> tuple[int, int, int]:
    """(element bytes, stride, bytes spanned) of accessor ``index`` with a bufferView."""
    acc = doc.accessors[index]
    if acc.bufferView is None:
        raise ValueError(f"accessors[{index}] has no bufferView")
    size = COMPONENT_SIZES[acc.componentType]
    ncomp = TYPE_SIZES[acc.type]
    if acc.type in ("MAT2", "MAT3") and size < 4:  # columns padded to 4 bytes (spec 3.6.2.4)
        rows = int(round(math.sqrt(ncomp)))
        elem = rows * (((rows * size + 3) // 4) * 4)
    else:
        elem = size * ncomp
    view = doc.bufferViews[acc.bufferView]
    stride = view.byteStride or elem
    return elem, stride, acc.byteOffset + stride * (acc.count - 1) + elem


def _check_ranges(doc: Document, path) -> None:
    for i, v in enumerate(doc.bufferViews):
        length = doc.buffers[v.buffer].byteLength
        if v.byteOffset + v.byteLength > length:
            _fail(path, f"bufferViews[{i}]", f"bytes {v.byteOffset}..{v.byteOffset + v.byteLength} lie past the "
                  f"end of buffers[{v.buffer}] ({length} bytes)")
    for i, a in enumerate(doc.accessors):
        where = f"accessors[{i}]"
        if a.bufferView is None:
            if a.count * TYPE_SIZES[a.type] > MAX_ZEROS_COMPONENTS:
                _fail(path, f"{where}.count", f"{a.count} {a.type} elements without a bufferView exceed the "
                      f"limit of {MAX_ZEROS_COMPONENTS} components", "give the accessor a bufferView")
        else:
            elem, stride, end = accessor_layout(doc, i)
            view = doc.bufferViews[a.bufferView]
            if view.byteStride is not None and view.byteStride < elem:
                _fail(path, f"bufferViews[{a.bufferView}].byteStride",
                      f"stride {view.byteStride} is smaller than an element of {where} ({elem} bytes)")
            if end > view.byteLength:
                _fail(path, f"{where}.count", f"{a.count} elements need {end} bytes, bufferViews[{a.bufferView}] "
                      f"holds {view.byteLength}")
        if a.sparse is not None:
            s = a.sparse
            if s.count > a.count:
                _fail(path, f"{where}.sparse.count", f"{s.count} substitutions for {a.count} elements")
            for part, comp in (("indices", s.indices.componentType), ("values", a.componentType)):
                sub = getattr(s, part)
                n = s.count * (COMPONENT_SIZES[comp] * (1 if part == "indices" else TYPE_SIZES[a.type]))
                view = doc.bufferViews[sub.bufferView]
                if sub.byteOffset + n > view.byteLength:
                    _fail(path, f"{where}.sparse.{part}", f"{s.count} entries need {sub.byteOffset + n} bytes, "
                          f"bufferViews[{sub.bufferView}] holds {view.byteLength}")
