"""When to switch levels of detail: the screen coverage at which a level's animated error is P pixels.

The camera is perspective with vertical field of view ``theta``, a viewport ``H`` pixels high and
aspect ratio ``a`` (width / height). A length ``e`` at depth ``z`` covers

    p(e, z) = e H / (2 z tan(theta / 2))   pixels.

The object's bounding sphere has radius ``r`` (half the diagonal of the full mesh's world-space
bounding box in the first test pose) and its centre is at distance ``d``; its nearest point is at
depth ``d - r``, where an error ``e`` projects largest. The error is at most ``P`` pixels everywhere
on the object when

    d >= d_P(e) = r + e H / (2 P tan(theta / 2))           (the switch distance).

Screen coverage is Babylon.js's (the runtime that reads ``MSFT_lod`` with ``MSFT_screencoverage``):
the area of the bounding sphere's disc on screen over the screen's area,

    c(d) = pi r^2 / (4 a d^2 tan^2(theta / 2)),  clipped to [0, 1].

So a level of error ``e`` may be shown at every coverage up to ``c(d_P(e))``. ``MSFT_screencoverage``
is ``[c_0, ..., c_L]`` for the node and its ``L`` levels: level ``i`` (0 the full mesh) shows while
``c_i <= coverage < c_(i-1)``, so ``c_(i-1) = c(d_P(e_i^+))`` with ``e_i^+ = max_(j <= i) e_j`` (a
coarser level never switches in nearer than a finer one) and ``c_L = 0`` (the coarsest is never culled).

An engine with another bounding volume ``r'`` rescales: ``c' = c (r' / r)^2``; the switch distances
``d_P`` do not depend on the coverage convention at all.
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["DEFAULT_ASPECT", "DEFAULT_FOV", "DEFAULT_PIXEL_ERROR", "DEFAULT_RESOLUTION", "coverage_distance",
           "coverage_series", "screen_coverage", "switch_distance"]

DEFAULT_PIXEL_ERROR = 1.0
DEFAULT_FOV = 60.0
DEFAULT_RESOLUTION = 1080
DEFAULT_ASPECT = 16.0 / 9.0


def switch_distance(error: float, radius: float, *, pixel_error: float = DEFAULT_PIXEL_ERROR,
                    fov: float = DEFAULT_FOV, resolution: float = DEFAULT_RESOLUTION) -> float:
    """``d_P(e) = r + e H / (2 P tan(theta / 2))``: the nearest centre distance at which error ``e`` (metres)
    projects to at most ``pixel_error`` pixels (``fov`` in degrees, ``resolution`` = H pixels)."""
    half = math.tan(math.radians(fov) / 2.0)
    return float(radius + max(float(error), 0.0) * resolution / (2.0 * pixel_error * half))


def screen_coverage(distance: float, radius: float, *, fov: float = DEFAULT_FOV,
                    aspect: float = DEFAULT_ASPECT) -> float:
    """``c(d) = pi r^2 / (4 a d^2 tan^2(theta / 2))`` clipped to [0, 1] (module docstring)."""
    half = math.tan(math.radians(fov) / 2.0)
    if distance <= 0:
        return 1.0
    return float(min(1.0, math.pi * radius * radius / (4.0 * aspect * distance * distance * half * half)))


def coverage_distance(coverage: float, radius: float, *, fov: float = DEFAULT_FOV,
                      aspect: float = DEFAULT_ASPECT) -> float:
    """The centre distance at which the object covers ``coverage`` of the screen (:func:`screen_coverage` inverted)."""
    half = math.tan(math.radians(fov) / 2.0)
    return float(radius * math.sqrt(math.pi / (4.0 * aspect * coverage)) / half)


def coverage_series(errors, radius: float, *, pixel_error: float = DEFAULT_PIXEL_ERROR, fov: float = DEFAULT_FOV,
                    resolution: float = DEFAULT_RESOLUTION, aspect: float = DEFAULT_ASPECT) -> dict:
    """``MSFT_screencoverage`` of a node with levels of errors ``errors`` (finest first, metres).

    Returns
    -------
    dict
        ``coverage``: ``L + 1`` values, non-increasing, ending with 0 (module docstring);
        ``switch_distance_m``: per level the centre distance from which it may show (``d_P(e_i^+)``);
        ``level_coverage``: per level the largest coverage at which it may show (``c_(i-1)``).
    """
    e = np.maximum.accumulate(np.maximum(np.asarray(errors, float), 0.0)) if len(errors) else np.zeros(0)
    dist = [switch_distance(x, radius, pixel_error=pixel_error, fov=fov, resolution=resolution) for x in e]
    cov = [screen_coverage(d, radius, fov=fov, aspect=aspect) for d in dist]
    return {"coverage": cov + [0.0], "switch_distance_m": dist, "level_coverage": cov}
