"""The vertex attributes of a glTF skin's primitives (:class:`PrimitiveData`), and its faces welded by position."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rigslim.errors import InputError, StepError
from rigslim.io.gltf.document import read_accessor
from rigslim.io.gltf.skin import GltfSkin, primitive_triangles, skinning_sets

#: Attributes that never lock a vertex (hard edges are interpolated, not kept).
SOFT_ATTRIBUTES = ("NORMAL", "TANGENT")


@dataclass
class PrimitiveData:
    """The carried attributes of one source primitive, decoded to float64.

    Attributes
    ----------
    index : int
        Position in ``GltfSkin.slices``.
    attributes : dict name -> (count, c) array
        Every attribute but POSITION, JOINTS_n and WEIGHTS_n.
    targets : list of dict name -> (count, c) array
        Morph target deltas (POSITION, NORMAL, TANGENT, ...).
    faces : (f, 3) int64 array
        Triangles in the primitive's own vertex numbering.
    unseen : frozenset of str
        ``TEXCOORD_n`` sets no texture of the primitive's material reads (:func:`texcoords_read`): carried,
        but a seam in them shows nowhere, so they make no seams.
    """

    index: int
    count: int
    attributes: dict[str, np.ndarray]
    targets: list[dict[str, np.ndarray]] = field(default_factory=list)
    faces: np.ndarray = field(default_factory=lambda: np.zeros((0, 3), np.int64))
    unseen: frozenset[str] = frozenset()

    def seam_columns(self) -> list[np.ndarray]:
        """The attribute blocks whose differences make seams: all but NORMAL, TANGENT and the unseen UV sets,
        then every morph target block."""
        cols = [v for k, v in self.attributes.items() if k not in SOFT_ATTRIBUTES and k not in self.unseen]
        return cols + [v for t in self.targets for v in t.values()]

    def columns(self) -> list[tuple[str, int]]:
        """``(key, width)`` of every carried column block: attributes, then ``"t{j}/{name}"`` target blocks."""
        out = [(k, v.shape[1]) for k, v in self.attributes.items()]
        for j, t in enumerate(self.targets):
            out += [(f"t{j}/{k}", v.shape[1]) for k, v in t.items()]
        return out

    def matrix(self) -> np.ndarray:
        """(count, C) the column blocks side by side, in :meth:`columns` order."""
        blocks = list(self.attributes.values()) + [v for t in self.targets for v in t.values()]
        return np.hstack(blocks) if blocks else np.zeros((self.count, 0))


def primitive_data(skin: GltfSkin) -> list[PrimitiveData]:
    """Decode the carried attributes, morph targets and triangles of every primitive the skin reader used."""
    doc, js = skin.document, skin.document.json
    out = []
    for i, sl in enumerate(skin.slices):
        prim = js["meshes"][sl.mesh]["primitives"][sl.primitive]
        attrs = prim.get("attributes", {})
        sets = skinning_sets(attrs)
        skip = {"POSITION"} | {f"JOINTS_{s}" for s in sets} | {f"WEIGHTS_{s}" for s in sets}
        values = {}
        for name in sorted(attrs):
            if name in skip:
                continue
            a = np.asarray(read_accessor(doc, attrs[name]), np.float64).reshape(sl.count, -1)
            if len(a) != sl.count:
                raise InputError(f"attribute {name} has {len(a)} elements, POSITION {sl.count}", source=doc.path,
                                 field=f"meshes[{sl.mesh}].primitives[{sl.primitive}].attributes.{name}",
                                 fix="re-export the file")
            values[name] = a
        targets = []
        for _j, t in enumerate(prim.get("targets", [])):
            targets.append({name: np.asarray(read_accessor(doc, t[name]), np.float64).reshape(sl.count, -1)
                            for name in sorted(t)})
        idx = (np.asarray(read_accessor(doc, prim["indices"]), np.int64) if "indices" in prim
               else np.arange(sl.count, dtype=np.int64))
        read = texcoords_read(js, prim)
        unseen = frozenset(k for k in values if k.startswith("TEXCOORD_") and int(k[9:]) not in read)
        out.append(PrimitiveData(i, sl.count, values, targets, primitive_triangles(prim.get("mode", 4), idx), unseen))
    return out


def texcoords_read(js: dict, prim: dict) -> set[int]:
    """The ``TEXCOORD_n`` sets the textures of a primitive's material read.

    Every texture reference in the material, extensions included, is an object with ``index`` and an
    optional ``texCoord`` (default 0; ``KHR_texture_transform`` may override it); each ``texCoord`` found
    anywhere counts too. A primitive without a material reads none.
    """
    mat = prim.get("material")
    materials = js.get("materials", [])
    if not isinstance(mat, int) or not 0 <= mat < len(materials):
        return set()
    found: set[int] = set()

    def walk(node) -> None:
        if isinstance(node, dict):
            if "index" in node and isinstance(node.get("index"), int):
                tc = node.get("texCoord", 0)
                found.add(tc if isinstance(tc, int) else 0)
            for key, value in node.items():
                if key == "texCoord" and isinstance(value, int):
                    found.add(value)
                walk(value)
        elif isinstance(node, list):
            for value in node:
                walk(value)

    walk(materials[mat])
    return found


def welded_vertex_map(skin: GltfSkin) -> np.ndarray:
    """(N_file,) the welded vertex each file vertex became (``GltfSkin.vertex_map``; the identity unwelded)."""
    total = sum(s.count for s in skin.slices)
    return np.arange(total) if skin.vertex_map is None else np.asarray(skin.vertex_map, np.int64)


def welded_faces(skin: GltfSkin, data: list[PrimitiveData]) -> list[tuple[np.ndarray, np.ndarray]]:
    """Per primitive: the welded faces the reader kept and their file-vertex corners (global file ids)."""
    vmap = welded_vertex_map(skin)
    out = []
    for d, sl in zip(data, skin.slices, strict=False):
        Ff = d.faces + sl.start
        Fw = vmap[Ff]
        keep = (Fw[:, 0] != Fw[:, 1]) & (Fw[:, 1] != Fw[:, 2]) & (Fw[:, 2] != Fw[:, 0])
        out.append((Fw[keep], Ff[keep]))
    F = np.concatenate([w for w, _ in out]) if out else np.zeros((0, 3), np.int64)
    if F.shape != skin.mesh.F.shape or not np.array_equal(F, skin.mesh.F):
        raise StepError("the simplified mesh is not the one read from this glTF file's skinned primitives",
                        field="levels", fix="simplify the mesh read from this file (no step may replace it)")
    return out
