"""The handles of a linear blend deformation: a skeleton's bones or a cage's vertices.

docs/algorithms.md section 1: every deformation rigslim handles is
``v^j = sum_i a_{v,i} T_i^j [v; 1]`` with one 3x4 transform per handle and
pose. A skeleton's handles are its bones (``T_i`` = pose transform times
inverse bind matrix, ``[I | 0]`` at rest); a cage's handles are its vertices
(``T_i = [0 | c_i]``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from rigslim.model.mesh import Mesh


@dataclass(frozen=True, eq=False)
class Handles:
    """The n handles of a deformation.

    Parameters
    ----------
    kind : {"skeleton", "cage"}
    names : list of str
        One name per handle.
    joints : (J, 3) float array, optional
        Skeleton joint positions (rest pose).
    bones : (n, 2) int array, optional
        Skeleton bones as (parent joint, child joint) pairs; handle i is bone i.
    parents : (n,) int array, optional
        Parent bone of each bone (-1 for roots).
    cage : Mesh, optional
        The control cage (rest positions) when ``kind == "cage"``.
    source : str, optional
    """

    kind: Literal["skeleton", "cage"]
    names: list[str]
    joints: np.ndarray | None = None
    bones: np.ndarray | None = None
    parents: np.ndarray | None = None
    cage: Mesh | None = None
    source: str | None = field(default=None, compare=False)

    @property
    def n(self) -> int:
        """Number of handles."""
        return len(self.names)

    @property
    def is_cage(self) -> bool:
        return self.kind == "cage"

    def rest_transforms(self) -> np.ndarray:
        """(n, 3, 4) transforms of the rest pose.

        ``[I | 0]`` for bones; ``[0 | c_i]`` for cage vertices, so that in
        both cases ``sum_i a_{v,i} T_i [v; 1] = v`` for weights with linear
        precision.
        """
        if self.is_cage:
            assert self.cage is not None  # a "cage" kind carries its cage (from_cage)
            return cage_transforms(self.cage.V[None])[0]
        T = np.zeros((self.n, 3, 4))
        T[:, :, :3] = np.eye(3)
        return T

    @staticmethod
    def skeleton(joints: np.ndarray, bones: np.ndarray, source: str | None = None,
                 names: list[str] | None = None) -> Handles:
        """A skeleton from joint positions and (parent, child) bone edges."""
        joints = np.asarray(joints, dtype=np.float64)
        bones = np.asarray(bones, dtype=np.int64).reshape(-1, 2)
        child_of = {int(c): b for b, (_, c) in enumerate(bones)}
        parents = np.array([child_of.get(int(p), -1) for p, _ in bones], dtype=np.int64)
        names = names or [f"bone{b}" for b in range(len(bones))]
        return Handles("skeleton", names, joints=joints, bones=bones, parents=parents, source=source)

    @staticmethod
    def from_cage(cage: Mesh, source: str | None = None) -> Handles:
        """Handles for the vertices of a closed triangle cage."""
        return Handles("cage", [f"cage{i}" for i in range(cage.n_vertices)], cage=cage,
                       source=source or cage.source)


def cage_transforms(C: np.ndarray) -> np.ndarray:
    """Handle transforms of cage poses.

    Parameters
    ----------
    C : (p, n, 3) array
        Cage vertex positions in each of p poses.

    Returns
    -------
    (p, n, 3, 4) array
        ``T_i^j = [0 | c_i^j]`` (docs/algorithms.md section 1).
    """
    C = np.asarray(C, dtype=np.float64)
    T = np.zeros(C.shape[:2] + (3, 4))
    T[..., 3] = C
    return T
