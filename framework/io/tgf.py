"""Trivial Graph Format skeletons, as libigl writes them.

Joint lines ``index x y z [...]``, a ``#`` line, bone lines ``a b [...]``
(1-based joint indices, parent first), optionally a closing ``#``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.model.handles import Handles


def read_tgf(path) -> Handles:
    """Read a TGF skeleton into skeleton :class:`Handles` (one handle per bone)."""
    path = Path(path)
    try:
        lines = path.read_text().splitlines()
    except (OSError, UnicodeDecodeError) as e:
        raise InputError(f"cannot read file ({e})", source=path, field="path", fix="check the path") from None
    joints, bones, section = [], [], 0
    for number, line in enumerate(lines, 1):
        s = line.strip()
        if not s:
            continue
        if s.startswith("#"):
            section += 1
            continue
        tok = s.split()
        try:
            if section == 0:
                joints.append([float(t) for t in tok[1:4]])
                if len(joints[-1]) != 3:
                    raise ValueError
            elif section == 1:
                bones.append([int(tok[0]) - 1, int(tok[1]) - 1])
        except (ValueError, IndexError):
            what = "joint 'index x y z'" if section == 0 else "bone 'parent child'"
            raise InputError(f"line {number} is not a {what} line", source=path, field=f"line {number}",
                             fix="repair the TGF file") from None
    if not joints or not bones:
        raise InputError("no joints or no bones", source=path, field="bones",
                         fix="a TGF skeleton lists joints, '#', then bones")
    B = np.array(bones)
    if B.min() < 0 or B.max() >= len(joints):
        raise InputError(f"a bone refers to a joint outside 1..{len(joints)}", source=path, field="bones",
                         fix="repair the TGF file")
    _check_forest(B, path)
    J = np.array(joints)
    if not np.isfinite(J).all():
        raise InputError("joint positions contain NaN or inf", source=path, field="joints", fix="repair the TGF file")
    return Handles.skeleton(J, B, source=str(path))


def _check_forest(B: np.ndarray, path) -> None:
    """Bones ``parent -> child`` (0-based joints) must form a forest: no self-loop, one parent per joint, no cycle."""
    parent: dict[int, int] = {}
    for i, (a, b) in enumerate(B.tolist()):
        if a == b:
            raise InputError(f"bone {i + 1} joins joint {a + 1} to itself", source=path, field=f"bones[{i + 1}]",
                             fix="repair the TGF file (bones are 'parent child' pairs of different joints)")
        if b in parent:
            raise InputError(f"joint {b + 1} has two parents (joints {parent[b] + 1} and {a + 1})", source=path,
                             field=f"bones[{i + 1}]", fix="repair the TGF file (the skeleton must be a tree)")
        parent[b] = a
    done: set[int] = set()
    for start in parent:
        chain: list[int] = []
        j = start
        while j in parent and j not in done:
            if j in chain:
                cycle = chain[chain.index(j):]
                raise InputError("the bones form a cycle through joints " + " -> ".join(str(c + 1) for c in cycle[:8]),
                                 source=path, field="bones", fix="repair the TGF file (the skeleton must be a tree)")
            chain.append(j)
            j = parent[j]
        done.update(chain)
