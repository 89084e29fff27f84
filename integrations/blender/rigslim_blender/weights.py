"""Skin weights between Blender and rigslim: the request arrays, and writing vertex groups back."""

from __future__ import annotations

from typing import Any

import bpy
import numpy as np

from .scene import Skin


def request_weights(skin: Skin) -> dict[str, Any]:
    """The (m, n') weight triplets for the worker, rows summing to one.

    Vertices Blender leaves at rest (no deform weight) get weight one on an extra handle n whose
    transform is the identity in every pose (:func:`rest_handle_poses`), so the fit sees them as
    they move: not at all.
    """
    n = len(skin.bones)
    rows, cols, vals = skin.rows, skin.cols, skin.values
    extra = np.flatnonzero(skin.unweighted)
    if len(extra):
        rows = np.concatenate([rows, extra])
        cols = np.concatenate([cols, np.full(len(extra), n, np.int64)])
        vals = np.concatenate([vals, np.ones(len(extra))])
    return {"n_vertices": np.int64(skin.n_vertices), "n_handles": np.int64(n + (len(extra) > 0)),
            "w_rows": rows, "w_cols": cols, "w_values": vals}


def rest_handle_poses(skin: Skin, T: np.ndarray) -> np.ndarray:
    """(p, n', 3, 4): the bone transforms, plus the identity rest handle when some vertex has no weight."""
    if not skin.unweighted.any():
        return T
    ident = np.zeros((T.shape[0], 1, 3, 4))
    ident[:, 0, :, :3] = np.eye(3)
    return np.concatenate([T, ident], axis=1)


def blender_rows(skin: Skin, indices: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop the rest handle from reduced weights and renormalise, as Blender's armature deform does at run time.

    Returns the (m, k) handle indices (-1 where empty) and weights of the deforming bones.
    """
    n = len(skin.bones)
    idx = np.asarray(indices, np.int64).copy()
    val = np.asarray(values, np.float64).copy()
    drop = (idx >= n) | (val <= 0.0)
    idx[drop], val[drop] = -1, 0.0
    total = val.sum(axis=1, keepdims=True)
    val = np.where(total > 0, val / np.where(total > 0, total, 1.0), 0.0)
    idx[val <= 0.0] = -1
    return idx, val


def write_groups(obj: bpy.types.Object, skin: Skin, idx: np.ndarray, val: np.ndarray) -> int:
    """Replace the deform groups' weights of ``obj`` by ``(idx, val)`` (other groups are left alone).

    Returns the number of group entries written.
    """
    everyone = list(range(len(obj.data.vertices)))
    groups = [obj.vertex_groups[int(g)] for g in skin.groups]
    for vg in groups:
        vg.remove(everyone)
    written = 0
    for v, (ii, ww) in enumerate(zip(idx.tolist(), val.tolist(), strict=True)):
        for i, w in zip(ii, ww, strict=True):
            if i >= 0 and w > 0.0:
                groups[i].add([v], w, "REPLACE")
                written += 1
    return written


def deform_counts(obj: bpy.types.Object) -> tuple[np.ndarray, np.ndarray]:
    """Per vertex: the number of deform-bone groups with a non-zero weight, and their weight sum."""
    arm = obj.find_armature() or next((m.object for m in obj.modifiers if m.type == "ARMATURE"), None)
    deform = {b.name for b in arm.data.bones if b.use_deform} if arm else set()
    is_deform = {vg.index for vg in obj.vertex_groups if vg.name in deform}
    m = len(obj.data.vertices)
    count, total = np.zeros(m, np.int64), np.zeros(m)
    for v in obj.data.vertices:
        for g in v.groups:
            if g.group in is_deform and g.weight > 0.0:
                count[v.index] += 1
                total[v.index] += g.weight
    return count, total


def fixed_rows(skin: Skin, k: int) -> tuple[np.ndarray, np.ndarray]:
    """A skin's weight triplets as (m, k) handle indices (-1 where empty) and weights, largest first."""
    m = skin.n_vertices
    idx, val = np.full((m, k), -1, np.int64), np.zeros((m, k))
    order = np.lexsort((-skin.values, skin.rows))
    rows, cols, vals = skin.rows[order], skin.cols[order], skin.values[order]
    start = np.searchsorted(rows, np.arange(m))
    slot = np.arange(len(rows)) - start[rows]
    keep = slot < k
    idx[rows[keep], slot[keep]], val[rows[keep], slot[keep]] = cols[keep], vals[keep]
    return idx, val
