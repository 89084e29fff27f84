"""Trivial Graph Format skeletons, as libigl writes them.

Joint lines ``index x y z [...]``, a ``#`` line, bone lines ``a b [...]``
(1-based joint indices, parent first), optionally a closing ``#``.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.handles import Handles


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
    return Handles.skeleton(np.array(joints), B, source=str(path))
