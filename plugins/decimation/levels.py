"""Levels that are what they say: face targets, an error bound, strictly decreasing face counts.

A decimation step builds one progressive hierarchy and takes its levels as
prefixes of the collapse sequence (:meth:`rigslim.model.hierarchy.ProgressiveHierarchy.prefix`).
This module chooses those prefixes:

- a face target ``t`` gives the first prefix with at most ``t`` faces;
- an error bound ``max_error`` stops every level at the longest prefix whose
  collapses all have a **geometric error** (:func:`collapse_distances`) of at
  most the bound: a level that reaches the bound before its target stops
  there, and says so (:class:`LevelChoice`);
- two targets that end at the same prefix (the second could not be reached)
  give one level: face counts strictly decrease, and the level keeps the
  finer target's name.

A level whose face count is more than 3 % above its target is named after its
target and its real face count (``quartic-25pct-394f``).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from rigslim.model.units import parse_length_bound

#: A level within this fraction above its face target counts as reaching it (its name is the target's).
REACHED = 0.03

def parse_max_error(value) -> tuple[float, str] | None:
    """``(value, unit)`` of a ``max_error`` setting: a number or ``"E%"`` is % of the diagonal, ``"Em"`` metres.

    ``None``, ``"none"`` and ``"off"`` turn the bound off (:func:`rigslim.model.units.parse_length_bound`).
    """
    return parse_length_bound(value, "max_error")


def collapse_distances(hier, Q: np.ndarray) -> np.ndarray:
    """Geometric error of every collapse: ``d_i = sqrt(E_i / w_c)``, in the units of the positions.

    Parameters
    ----------
    hier : ProgressiveHierarchy
    Q : (m, P, 4, 4) array
        Per-pose quadrics of the original vertices (the example poses; area-weighted planes).

    Notes
    -----
    ``E_i`` (``hier.errors``) is the quartic error of collapse i,
    ``sum_j sum_f area_f^j dist(v_c^j, plane_f^j)^2`` over the example poses j
    and the planes f of every source face the merged vertex c stands for. The
    trace of the 3x3 block of a plane quadric ``area n n^T`` is its area, so
    ``w_c = sum_j tr(Q_c^j[:3, :3])`` (summed through the merge tree) is the
    total weight of those planes and ``d_i`` the area-weighted RMS distance of
    the new vertex from them, over all example poses: meshoptimizer's
    normalised quadric error, for every pose at once.
    """
    m = hier.n_original
    w = np.zeros(m + hier.n_collapses)
    w[:m] = np.einsum("mpii->m", Q[..., :3, :3])
    col = hier.collapses
    for i in range(hier.n_collapses):
        w[m + i] = w[col[i, 0]] + w[col[i, 1]]
    wc = w[m:]
    return np.sqrt(np.maximum(hier.errors, 0.0) / np.where(wc > 0, wc, 1.0))


#: ``LevelChoice.same_as`` of a target that ends before the first collapse (the bound, or nothing valid).
SOURCE = "source"


@dataclass
class LevelChoice:
    """Where one face target ends: the prefix, its faces and error, and why it stopped there."""

    target: float
    target_faces: int
    collapses: int
    faces: int
    error: float
    """Largest collapse distance in the prefix (units of the positions)."""
    stopped: str | None
    """``None`` (reached), ``"max_error"`` (the bound), ``"no collapse"`` (nothing valid was left, and with
    ``prune_parts`` one part is left or none could go)."""
    label: str
    same_as: str | None = None
    """The finer level this target ended at (no level of its own), if any; :data:`SOURCE` when it ends before
    the first collapse (the bound, no valid collapse, or a target the source's face count already meets: a copy
    of the source is no level)."""
    parts_removed: int = 0
    """Parts removed whole after the last collapse to reach the target (:mod:`rigslim.plugins.decimation.prune`)."""
    removal_distance: float = 0.0
    """The largest removal distance of those parts (units of the positions; 0 when none)."""


def choose_levels(hier, targets: list[float], target_faces: list[int], distances: np.ndarray,
                  bound: float | None, method: str) -> list[LevelChoice]:
    """One :class:`LevelChoice` per target, finest first; those with ``same_as`` None have strictly
    decreasing face counts and are the levels.

    ``bound`` (units of the positions, or None) caps every level: the prefix stops before the first
    collapse whose running maximum distance exceeds it.
    """
    running = np.maximum.accumulate(distances) if len(distances) else distances
    limit = hier.n_collapses
    if bound is not None and len(running):
        over = np.flatnonzero(running > bound)
        limit = int(over[0]) if over.size else hier.n_collapses
    out: list[LevelChoice] = []
    for t, f in sorted(zip(targets, target_faces, strict=True), key=lambda x: -x[1]):
        hit = np.flatnonzero(hier.n_faces <= f)
        k = int(hit[0]) + 1 if hit.size else hier.n_collapses
        if f >= len(hier.F):
            k = 0
        stopped = None
        if k > limit:
            k, stopped = limit, "max_error"
        elif not hit.size and f < len(hier.F):
            stopped = "no collapse"
        levels = [c for c in out if c.same_as is None]
        same = levels[-1].label if levels and k <= levels[-1].collapses else None
        if k == 0:
            same = SOURCE                              # not one collapse: the source itself, no level
        if same is not None and same != SOURCE:
            k = levels[-1].collapses                   # the same prefix as a finer level: one level
        faces = hier.faces_after(k)
        error = float(running[k - 1]) if k else 0.0
        label = level_label(method, t, f, faces)
        out.append(LevelChoice(t, f, k, faces, error, stopped, label, same))
    return out


def level_label(method: str, t: float, target_faces: int, faces: int) -> str:
    """The level's name: its target's (:func:`target_name`), and its real face count where that is more than
    :data:`REACHED` above the target (``quartic-25pct-394f``)."""
    label = target_name(method, t, target_faces)
    return label + f"-{faces}f" if faces > (1 + REACHED) * target_faces else label


def target_name(method: str, t: float, faces: int) -> str:
    """``quartic-25pct`` for a fraction, ``quartic-600f`` for a face count."""
    return f"{method}-{t * 100:g}pct" if t < 1 else f"{method}-{faces}f"
