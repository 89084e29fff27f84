"""A skin of its own for each level of detail: only the joints the level's vertices use.

A level whose weights use ``u`` of the source skin's ``n`` joints (a joint budget dropped some, or the
decimation removed every vertex of a joint) gets a new ``skins`` entry on its mesh node:

- ``joints``: the used joints' nodes, in the source skin's order;
- ``inverseBindMatrices``: the source skin's matrices of those joints, with the last row written as
  exactly ``[0, 0, 0, 1]`` (the validator's ``ACCESSOR_INVALID_IBM`` refuses the ``0.9999999`` some
  exporters write);
- ``skeleton`` (and ``name``) copied from the source skin;

and its ``JOINTS_n`` hold positions in that list: handle ``h`` becomes ``local[h]``, the rank of ``h``
among the used joints. Since joint ``i`` of the new skin is the same node with the same inverse bind
matrix as handle ``used[i]``, ``sum_c w_c G(joint_{J_c}) IBM_{J_c} v`` is unchanged in every pose
(``tests/framework/io/test_level_skins.py`` poses both in numpy and three.js). Nodes are never
removed: joints a level leaves out keep animating, and anything attached to them.
"""

from __future__ import annotations

import numpy as np

from rigslim.io.gltf.document import read_accessor

__all__ = ["LevelSkin", "level_skin", "source_inverse_binds", "used_joints"]


def used_joints(indices: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Sorted handle indices with a non-zero weight somewhere in ``(indices, values)`` (any shapes alike)."""
    return np.unique(np.asarray(indices)[np.asarray(values) != 0]).astype(np.int64)


def source_inverse_binds(source) -> np.ndarray:
    """(n, 4, 4) inverse bind matrices of the source skin (identity where the skin has none)."""
    sk = source.document.json["skins"][source.skin]
    n = len(source.joints)
    if "inverseBindMatrices" not in sk:
        return np.broadcast_to(np.eye(4), (n, 4, 4)).copy()
    ibm = read_accessor(source.document, sk["inverseBindMatrices"]).reshape(-1, 4, 4).transpose(0, 2, 1)
    return np.asarray(ibm[:n], np.float64)


class LevelSkin:
    """The skin of one level mesh: its index in ``skins`` and the handle -> JOINTS index map."""

    def __init__(self, skin: int, used: np.ndarray, n_handles: int):
        self.skin = int(skin)
        self.used = np.asarray(used, np.int64)
        self.local = np.zeros(n_handles, np.int64)
        self.local[self.used] = np.arange(len(self.used))

    @property
    def n_joints(self) -> int:
        return len(self.used)

    def remap(self, indices: np.ndarray) -> np.ndarray:
        """Handle indices as indices into this skin's ``joints``."""
        return self.local[np.asarray(indices, np.int64)]


def level_skin(js: dict, blob, source, used: np.ndarray, label: str, ibm: np.ndarray | None = None) -> LevelSkin:
    """The :class:`LevelSkin` of a level mesh using handles ``used``: the source skin when it uses them all,
    else a new ``skins`` entry appended to ``js`` (its matrices written through ``blob``)."""
    n = len(source.joints)
    used = np.asarray(used, np.int64)
    if len(used) == 0:
        used = np.zeros(1, np.int64)         # a mesh without weight still needs one joint to be skinned
    if len(used) == n:
        return LevelSkin(source.skin, np.arange(n), n)
    ibm = source_inverse_binds(source) if ibm is None else ibm
    mats = np.array(ibm[used], np.float64)
    mats[:, 3, :] = [0.0, 0.0, 0.0, 1.0]
    src = js["skins"][source.skin]
    skin = {"joints": [int(source.joints[h]) for h in used],
            "inverseBindMatrices": blob.new_accessor(mats.transpose(0, 2, 1).reshape(len(used), 16)
                                                     .astype(np.float32), 5126, "MAT4", target=None)}
    if "skeleton" in src:
        skin["skeleton"] = src["skeleton"]
    skin["name"] = f"{src.get('name', f'skin{source.skin}')}-{label}"
    js.setdefault("skins", []).append(skin)
    return LevelSkin(len(js["skins"]) - 1, used, n)
