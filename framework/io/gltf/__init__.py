"""glTF 2.0: reading skinned characters, writing them back (reduced, with levels of detail), one job per module.

- :mod:`~rigslim.io.gltf.schema`: the document checked against the parts of the schema rigslim reads;
- :mod:`~rigslim.io.gltf.document`: .gltf/.glb parsing, buffers and accessors (:func:`load_gltf`);
- :mod:`~rigslim.io.gltf.scene`: the node hierarchy and sampled animation clips;
- :mod:`~rigslim.io.gltf.skin`: a skinned mesh read into mesh, joints, weights and poses
  (:func:`read_gltf_skin`);
- :mod:`~rigslim.io.gltf.primitives`: each primitive's vertex attributes, faces welded by position;
- :mod:`~rigslim.io.gltf.seams`: UV/normal seams and charts, attribute quadrics;
- :mod:`~rigslim.io.gltf.lod`: per-level primitives and MSFT_lod documents;
- :mod:`~rigslim.io.gltf.write`: writing skins, reduced weights and levels (:func:`~rigslim.io.gltf.write.write_gltf`).

The names below are those ``rigslim.io.gltf`` had as one module.
"""

from rigslim.io.gltf.document import (
    CHUNK_BIN,
    CHUNK_JSON,
    COMPONENT_DTYPES,
    GLB_MAGIC,
    MAX_FRAME_NODES,
    MAX_FRAMES,
    TYPE_SIZES,
    GltfDocument,
    external_uris_allowed,
    load_gltf,
    read_accessor,
)
from rigslim.io.gltf.scene import (
    animation_duration,
    find_animation,
    local_matrices,
    node_matrix,
    node_parents,
    node_trs,
    sample_sampler,
    sampler_keys,
    world_matrices,
)
from rigslim.io.gltf.skin import GltfSkin, PrimitiveSlice, read_gltf_skin, skinning_sets, weld_vertices

__all__ = ["CHUNK_BIN", "CHUNK_JSON", "COMPONENT_DTYPES", "GLB_MAGIC", "MAX_FRAMES", "MAX_FRAME_NODES", "TYPE_SIZES",
           "GltfDocument", "GltfSkin", "PrimitiveSlice", "animation_duration", "external_uris_allowed",
           "find_animation", "load_gltf", "local_matrices", "node_matrix", "node_parents", "node_trs",
           "read_accessor", "read_gltf_skin", "sample_sampler", "sampler_keys", "skinning_sets", "weld_vertices",
           "world_matrices"]
