"""Angles between two sets of unit normals ([P10] fig. 10's normal error), and their statistics.

Shared by the ``normal-deviation`` metric and the Poisson solver's held-out choice of lambda.
"""

from __future__ import annotations

import numpy as np

__all__ = ["normal_angles", "normal_rms_angle", "normal_statistics"]


def normal_angles(N: np.ndarray, Nhat: np.ndarray) -> np.ndarray:
    """Per-vertex angle (rad) ``atan2(|n x nhat|, n . nhat)`` between unit normals, accurate for small angles."""
    cross = np.linalg.norm(np.cross(N, Nhat), axis=1)
    dot = np.einsum("ij,ij->i", N, Nhat)
    return np.arctan2(cross, dot)


def normal_rms_angle(N: np.ndarray, Nhat: np.ndarray) -> float:
    """``sqrt(mean_v angle(n_v, nhat_v)^2)`` in radians, for unit normals."""
    return float(np.sqrt(np.mean(normal_angles(N, Nhat) ** 2)))


def normal_statistics(theta: np.ndarray, areas: np.ndarray | None = None) -> dict:
    """RMS, median, 95th and 99th percentiles, count above 90 degrees and (with ``areas``)
    the area-weighted RMS of per-vertex angles ``theta``."""
    out = {"normal_rms_rad": float(np.sqrt(np.mean(theta ** 2))),
           "normal_median_rad": float(np.percentile(theta, 50)),
           "normal_p95_rad": float(np.percentile(theta, 95)),
           "normal_p99_rad": float(np.percentile(theta, 99)),
           "normal_flipped": int(np.count_nonzero(theta > 0.5 * np.pi))}
    if areas is not None and areas.sum() > 0:
        out["normal_area_rms_rad"] = float(np.sqrt(np.sum(areas * theta ** 2) / np.sum(areas)))
    return out
