"""Double-sided sheets: faces the source holds twice, with opposite winding, simplified once.

Game characters draw thin parts (ears, fins, a cape, a skirt, a flag) as a
sheet whose every triangle is stored twice, once per side: the faces
``(i, j, k)`` and ``(i, k, j)`` on the same (welded) vertices, each with its own
normals. To the collapse loop such a sheet is not a surface: every inner edge
has four faces and every outline edge two faces that meet at 360 degrees, so
no edge of it passes the topology guards (:func:`rigslim.plugins.decimation.setup.collapsible_edges`,
the link condition) and the whole sheet, with the vertices around it, stays at
full resolution while the rest of the character is decimated around it. On
the sweep characters this stopped far levels short of their targets (the 0 A.D.
crocodile, 12 twin pairs: 103 faces for a 70-face target; the soldier, 48
pairs: 132 for 93) and spent a far level's faces on the wolf's ears.

The decimation therefore simplifies one side: :func:`back_faces` marks the
second face of every opposite-wound pair, the loop runs on the others (the
sheet is then an open surface whose outline is a border, with border
quadrics and border collapses), and :func:`with_back_faces` puts the back
faces into the hierarchy. A back face has its front face's three vertices, so
under any prefix of the collapses it degenerates exactly when its front face
does and is otherwise that face reversed: every level is double-sided where
the source was, and the writer gives the back side's corners the back faces'
own attributes (they lie across a seam: their normals differ). Faces stored
twice with the same winding are not sheets and stay in the loop as they are.
"""

from __future__ import annotations

from collections import defaultdict

import numpy as np

from rigslim.model.hierarchy import ProgressiveHierarchy

__all__ = ["back_faces", "face_deaths", "with_back_faces"]


def _orientation(F: np.ndarray) -> np.ndarray:
    """(f,) bool: whether each face lists its vertices in the cyclic order of its sorted vertices."""
    lo = np.argmin(F, axis=1)
    nxt = F[np.arange(len(F)), (lo + 1) % 3]
    prv = F[np.arange(len(F)), (lo + 2) % 3]
    return nxt < prv


def back_faces(F: np.ndarray) -> np.ndarray:
    """(f,) bool: the back face of every pair of faces on the same three vertices with opposite winding.

    Within a group of faces on the same vertices, the faces of the first face's winding are fronts and
    each face of the other winding is the back of one front, in index order, while fronts are left;
    faces of a group left unpaired (the same winding twice) are not backs, nor is a face that repeats a
    vertex (it has no winding).
    """
    F = np.asarray(F, np.int64).reshape(-1, 3)
    back = np.zeros(len(F), bool)
    if len(F) < 2:
        return back
    key = np.sort(F, axis=1)
    order = np.lexsort((np.arange(len(F)), key[:, 2], key[:, 1], key[:, 0]))
    k = key[order]
    new = np.r_[True, (k[1:] != k[:-1]).any(axis=1)]
    starts = np.flatnonzero(new)
    sizes = np.diff(np.r_[starts, len(F)])
    if not (sizes > 1).any():
        return back
    orient = _orientation(F)
    for s, n in zip(starts[sizes > 1].tolist(), sizes[sizes > 1].tolist(), strict=True):
        group = order[s:s + n]
        if k[s, 0] == k[s, 1] or k[s, 1] == k[s, 2]:
            continue
        first = orient[group[0]]
        fronts = group[orient[group] == first]
        backs = group[orient[group] != first]
        back[backs[:len(fronts)]] = True
    return back


def face_deaths(F: np.ndarray, collapses: np.ndarray, m: int) -> np.ndarray:
    """(f,) int64: the collapse after which each face of ``F`` is degenerate (``len(collapses)``: never).

    Collapse t merges ``collapses[t]`` into vertex ``m + t``; a face dies when two of its corners merge.
    Only the vertices of ``F`` are followed (a dictionary of their faces), so the cost is one look-up per
    collapse plus the faces of ``F`` touched.
    """
    F = np.asarray(F, np.int64).reshape(-1, 3)
    c = len(collapses)
    death = np.full(len(F), c, np.int64)
    rows = F.tolist()
    at: dict[int, set[int]] = defaultdict(set)
    for f, row in enumerate(rows):
        for x in row:
            at[x].add(f)
    for t, (a, b) in enumerate(np.asarray(collapses, np.int64).reshape(-1, 2).tolist()):
        fa, fb = at.pop(a, None), at.pop(b, None)
        if not fa and not fb:
            continue
        v = m + t
        live: set[int] = set()
        for f in (fa or set()) | (fb or set()):
            row = [v if x == a or x == b else x for x in rows[f]]
            rows[f] = row
            if row[0] == row[1] or row[1] == row[2] or row[2] == row[0]:
                death[f] = t
                for x in row:
                    if x != v:
                        at[x].discard(f)
            else:
                live.add(f)
        if live:
            at[v] = live
    return death


def with_back_faces(hier: ProgressiveHierarchy, F: np.ndarray, back: np.ndarray) -> ProgressiveHierarchy:
    """The hierarchy ``hier`` built on ``F[~back]`` as one on all of ``F``: the same vertices and collapses, the
    face counts with every back face alive as long as its front face (:func:`back_faces`)."""
    F = np.asarray(F, np.int64).reshape(-1, 3)
    backs = F[back]
    death = face_deaths(backs, hier.collapses, hier.n_original)
    gone = np.cumsum(np.bincount(death, minlength=hier.n_collapses + 1)[:hier.n_collapses])
    n_faces = hier.n_faces + len(backs) - gone
    return ProgressiveHierarchy(hier.V, hier.weights, F, hier.collapses, hier.errors, n_faces, hier.method,
                                hier.params)
