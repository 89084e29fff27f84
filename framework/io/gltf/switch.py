"""LOD switch hints of a glTF output: each level's test-pose error, its switch distance and screen coverage.

The glTF writer (``lod: true``) measures every level posed on the pipeline's test poses against the full
mesh (:func:`rigslim.numerics.level_error.level_errors`: max and RMS two-sided distance in metres, glTF
poses being in world space) and turns the maximum into the screen coverage at which it projects to
``pixel_error`` pixels (:func:`rigslim.numerics.screen_coverage.coverage_series`). The values go

- into ``MSFT_screencoverage`` in the ``extras`` of each node carrying ``MSFT_lod``;
- into ``extras.rigslim_lod`` of each level node (``level``, ``error_max_m``, ``error_rms_m``,
  ``screen_coverage``, ``switch_distance_m``) so that the file says what its levels cost;
- into the write step's report (``switch``), from which ``rigslim lod`` writes its ``--report`` rows and,
  with ``--split``, the sidecar ``OUT.lod.json``.

Up to ``switch_frames`` (12) test frames are measured, evenly spread over the test set, with every vertex
and ``switch_samples`` (5,000) area-uniform points per side from a fixed generator (the maxima lie at
vertices; RMS a few % above ``rigslim compare``'s 20,000-sample figure): docs/gltf.md, "Switch coverage".
"""

from __future__ import annotations

from rigslim.model.poses import spread_frames
from rigslim.numerics.level_error import bounding_radius, level_errors
from rigslim.numerics.screen_coverage import coverage_series

__all__ = ["level_switch", "measured_frames"]


#: At most ``most`` of ``n`` test frames, evenly spread (:func:`rigslim.model.poses.spread_frames`).
measured_frames = spread_frames


def _measured(asset, levels, frames: list[int], samples: int) -> list[dict]:
    """Level errors, measured once per asset and set of levels (several writes of one run share them)."""
    key = (tuple(id(lv) for lv in levels), tuple(frames), samples)
    cached = asset.extras.get("level_errors")
    if cached is not None and cached[0] == key:
        return cached[1]
    T = asset.test_poses().T[frames]
    errors = level_errors(asset.mesh, asset.weights, T, levels, samples=samples)
    asset.extras["level_errors"] = (key, errors)
    return errors


def level_switch(asset, levels, *, pixel_error: float, fov: float, resolution: int, aspect: float,
                 frames: int = 12, samples: int = 5000, error: str = "max") -> dict:
    """The switch hints of ``levels`` (module docstring).

    Returns
    -------
    dict
        ``coverage`` (``MSFT_screencoverage``: one value per level and the node's), ``node_extras``
        (per level), ``levels`` (per level: label, faces, ``error_max_m``, ``error_rms_m``,
        ``screen_coverage``, ``switch_distance_m``), and the camera: ``pixel_error``, ``fov_deg``,
        ``resolution``, ``aspect``, ``bounding_radius_m``, ``test_frames`` (how many were measured).

    ``frames``: at most this many test frames are measured, evenly spread (0: all); ``samples``: surface
    samples per side and frame; ``error``: the coverage bounds the ``max`` error (every point of every
    measured frame within P pixels) or the ``rms`` one (on average).
    """
    asset.require("mesh", "weights", "poses", "split", step="write: gltf (LOD switch coverage)")
    T = asset.test_poses().T
    radius = bounding_radius(asset.mesh.V, asset.weights, T[0])
    chosen = measured_frames(len(T), frames)
    errors = _measured(asset, levels, chosen, samples)
    T = T[chosen]
    key = "error_rms" if error == "rms" else "error_max"
    series = coverage_series([e[key] for e in errors], radius, pixel_error=pixel_error, fov=fov,
                             resolution=resolution, aspect=aspect)
    rows, extras = [], []
    for i, (lv, e) in enumerate(zip(levels, errors, strict=True)):
        row = {"label": lv.label, "faces": lv.n_faces, "error_max_m": e["error_max"], "error_rms_m": e["error_rms"],
               "screen_coverage": series["level_coverage"][i], "switch_distance_m": series["switch_distance_m"][i]}
        rows.append(row)
        extras.append({"rigslim_lod": {"level": i + 1} | {k: v for k, v in row.items() if k != "faces"}})
    return {"coverage": series["coverage"], "node_extras": extras, "levels": rows, "pixel_error": pixel_error,
            "fov_deg": fov, "resolution": resolution, "aspect": aspect, "error": error, "bounding_radius_m": radius,
            "test_frames": int(len(T))}
