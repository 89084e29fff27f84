"""The report's renders: full, reduced and normal-deviation images of chosen test frames
(:mod:`rigslim.report.render`)."""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from rigslim.errors import InputError
from rigslim.report.summary import EvaluationRow

#: Colour map of the normal-deviation renders (pale yellow: none, dark red: the scale's maximum).
HEAT_CMAP = "YlOrRd"
#: Smallest top of the normal-deviation colour scale (degrees): a report whose deviations all stay below it
#: is drawn in the low colours (a degree is hardly visible in the shading) instead of stretched to dark red.
HEAT_FLOOR_DEGREES = 1.0
#: Colours of the full and reduced deformation renders.
FULL_COLOR = (0.72, 0.76, 0.86)
REDUCED_COLOR = (0.88, 0.76, 0.60)
LEVEL_COLOR = (0.70, 0.84, 0.70)



def normal_deviation_degrees(full_normals: np.ndarray, reduced_normals: np.ndarray) -> np.ndarray:
    """Per-vertex angle in degrees between two normal fields.

    Notes
    -----
    ``theta_v = atan2(|n_v x nhat_v|, n_v . nhat_v)``, accurate for small
    angles (the per-vertex term of the ``normal_rms_rad`` metric).
    """
    cross = np.linalg.norm(np.cross(full_normals, reduced_normals), axis=1)
    dot = np.einsum("ij,ij->i", full_normals, reduced_normals)
    return np.degrees(np.arctan2(cross, dot))


def heat_colors(values: np.ndarray, vmax: float, cmap: str = HEAT_CMAP) -> np.ndarray:
    """(m, 3) RGB in [0, 1] of ``values / vmax`` (clipped) through a matplotlib colour map."""
    from matplotlib import colormaps

    t = np.clip(np.asarray(values, dtype=np.float64) / max(vmax, 1e-12), 0.0, 1.0)
    return colormaps[cmap](t)[:, :3]


@dataclass
class RenderedFrame:
    """The images of one test frame of runs that share their inputs."""

    run: str  # the runs' names
    frame: int
    full: np.ndarray
    #: [(row label, image, heat image, max deviation in degrees, RMS deviation in radians)]
    reduced: list
    levels: list = field(default_factory=list)  # [(level label, faces, image)] of a simplification
    #: Where the frame lies in a run of several clips (``clip 'run', frame 12``; :func:`frame_place`), else "".
    place: str = ""


@dataclass
class RenderSet:
    frames: list = field(default_factory=list)
    heat_max: float = 0.0
    backend: str = ""
    notes: list = field(default_factory=list)


def frame_place(split, f: int) -> str:
    """``clip 'NAME', frame F`` of stack frame ``f`` of a run of several clips (the clip it falls in and its
    own frame number, :attr:`~rigslim.model.poses.FrameSplit.segments`); "" for a run of one clip."""
    for s in (getattr(split, "segments", None) or []):
        if s["start"] <= f < s["start"] + s["frames"]:
            return f"clip '{s['clip']}', frame {f - s['start']}"
    return ""


def _clip_ranges(split) -> str:
    """The stacked clips' frame ranges (``; clips stacked: 'walk' 0..57, 'run' 58..81``), "" for one clip."""
    segments = getattr(split, "segments", None) or []
    if not segments:
        return ""
    return "; clips stacked: " + ", ".join(f"'{s['clip']}' {s['start']}..{s['start'] + s['frames'] - 1}"
                                           for s in segments)


def render_rows(rows: list[EvaluationRow], data: dict, *, frames=None, width: int = 320, height: int = 270,
                backend: str = "auto", projection: str = "perspective", azimuth: float = 30.0,
                elevation: float = 15.0, up_axis: int = 1, heat_max: float | None = None,
                progress: Callable = lambda it, total=None, description="": it) -> RenderSet:
    """Render chosen test frames of every run: full, each reduced, each normal-deviation heat map.

    Parameters
    ----------
    rows : evaluation rows (all runs)
    data : dict
        ``id(document) -> RenderData``; runs without an entry are skipped.
    frames : list of int, optional
        Animation frames to render; default the worst test frame (largest
        position error) of the first evaluation of each group of runs that
        share inputs and test frames (one full render serves the group).
    heat_max : float, optional
        Top of the colour scale in degrees; default the largest 99th
        percentile of the per-vertex deviation over all renders, so that one
        outlying vertex does not wash out the scale, and at least
        :data:`HEAT_FLOOR_DEGREES`, so that tiny deviations are drawn in the
        low colours: ``top = max(max_r p99(theta_r), 1 degree)``. Vertices
        above the top are drawn in its colour (clipped); each heat map's
        entry keeps its own maximum for the caption.

    Notes
    -----
    Full: ``v^j = sum_i w_{v,i} T_i^j [v; 1]`` with the input weights;
    reduced: the same with the reduced weights; simplified levels
    (``asset.levels`` of a ``decimate`` step, in-pipeline reports
    only): each level's rest mesh blended with its own weights. The full
    deformation is shaded with its area-weighted normals (the reference of
    the ``normal_rms_rad`` metric), the reduced one with the normals of the
    normal estimator its evaluation used (``recomputed`` unless a
    ``normals:`` step chose another); the heat map colours the reduced
    deformation by ``theta_v`` (:func:`normal_deviation_degrees`) between
    the two, the per-vertex term of ``normal_rms_rad``.
    All images of one frame share one camera fitted to the full deformation.
    """
    from rigslim.report.render import render_mesh

    out = RenderSet()
    jobs = _frame_jobs(rows, data, frames, out.notes)
    heat_jobs: list = []  # (reduced entry, positions, normals, per-vertex deviation, camera, faces)
    view = {"width": width, "height": height, "projection": projection, "azimuth": azimuth, "elevation": elevation,
            "up_axis": up_axis}
    for group, name, asset, f in progress(jobs, total=len(jobs), description="rendering frames"):
        rf, out.backend = _render_frame(group, name, asset, f, data, view, backend, heat_jobs)
        out.frames.append(rf)
    # heat maps last: their colour scale is shared by every render of the report
    tops = [float(np.percentile(dev, 99)) for _, _, _, dev, _, _ in heat_jobs]
    out.heat_max = float(heat_max) if heat_max else max(tops + [HEAT_FLOOR_DEGREES])
    for entry, Xr, Nr, dev, cam, F in heat_jobs:
        entry[2], _ = render_mesh(Xr, F, heat_colors(dev, out.heat_max), cam, normals=Nr, backend=backend)
    return out


def _frame_jobs(rows: list[EvaluationRow], data: dict, frames, notes: list[str]) -> list[tuple]:
    """``(group, name, asset, frame)`` of every render: runs of the same inputs and test frames share one
    full render per frame (the given ``frames``, else the group's worst test frame)."""
    jobs = []
    groups: dict = {}
    for r in rows:
        if id(r.document) not in data:
            continue
        inputs = r.document.get("inputs")
        key = (json.dumps(inputs, sort_keys=True), tuple(r.frames)) if inputs else id(r.document)
        groups.setdefault(key, []).append(r)
    for group in groups.values():
        asset = data[id(group[0].document)].asset
        runs = list(dict.fromkeys(r.run for r in group))
        name = ", ".join(runs)
        if asset.mesh is None or asset.weights is None or asset.poses is None:
            notes.append(f"{name}: no mesh, weights or poses to render")
            continue
        wanted = list(frames) if frames else [group[0].worst_frame()]
        for f in dict.fromkeys(wanted):
            if f is None:
                continue
            if not 0 <= int(f) < len(asset.poses):
                raise InputError(f"frame {f} is outside the animation (0..{len(asset.poses) - 1}"
                                 f"{_clip_ranges(asset.split)})", source=group[0].source or group[0].run,
                                 field="frames", fix="choose test frames of the run")
            if group[0].frames and int(f) not in group[0].frames:
                place = frame_place(asset.split, int(f))
                notes.append(f"{name}: frame {f}{f' ({place})' if place else ''} is not a test frame")
            jobs.append((group, name, asset, int(f)))
    return jobs


def _render_frame(group: list[EvaluationRow], name: str, asset, f: int, data: dict, view: dict, backend: str,
                  heat_jobs: list) -> tuple[RenderedFrame, str]:
    """Frame ``f`` of a group of runs: the full deformation, each run's reduced one (its heat map is queued
    on ``heat_jobs``), each simplified level; all with one camera fitted to the full deformation. Returns
    the frame and the renderer used."""
    from rigslim.numerics.blend import linear_blend, per_vertex_normals
    from rigslim.report.render import Camera, render_mesh

    F = asset.mesh.F
    T = asset.poses.T[f]
    X = linear_blend(asset.mesh.V, asset.weights, T)
    N = per_vertex_normals(X, F)
    cam = Camera.fit(X, view["width"], view["height"], projection=view["projection"], azimuth=view["azimuth"],
                     elevation=view["elevation"], up_axis=view["up_axis"], tight=True)
    full, used = render_mesh(X, F, FULL_COLOR, cam, normals=N, backend=backend)
    rf = RenderedFrame(name, f, full, [], place=frame_place(asset.split, f))
    for r in group:
        R = data[id(r.document)].reduced.get(r.step)
        if R is None:
            continue
        Xr = linear_blend(asset.mesh.V, R, T)
        Nr = _estimated_normals(asset, R, T, Xr, data[id(r.document)].normals.get(r.step))
        img, _ = render_mesh(Xr, F, REDUCED_COLOR, cam, normals=Nr, backend=backend)
        dev = normal_deviation_degrees(N, Nr)
        entry = [r.label, img, None, float(dev.max()), float(np.sqrt(np.mean(np.radians(dev) ** 2)))]
        rf.reduced.append(entry)
        heat_jobs.append((entry, Xr, Nr, dev, cam, F))
    for level in data[id(group[0].document)].asset.levels:
        Xl = linear_blend(level.mesh.V, level.weights, T)
        img, _ = render_mesh(Xl, level.mesh.F, LEVEL_COLOR, cam, backend=backend)
        rf.levels.append((str(level.label), int(level.mesh.n_faces), img))
    return rf, used


def _estimated_normals(asset, R, T, Xr, estimator) -> np.ndarray:
    """Unit normals of a reduced deformation from the named normal estimator (default recomputed)."""
    from rigslim.numerics.blend import per_vertex_normals

    name, params = estimator or ("recomputed", {})
    if name == "recomputed" and not params:
        return per_vertex_normals(Xr, asset.mesh.F)
    from rigslim.plugin import NormalEstimator
    from rigslim.plugin.host import get_host

    plugin = get_host().get("normal-estimator", name)
    assert isinstance(plugin, NormalEstimator)  # the host loads only NormalEstimator instances as estimators
    N = np.asarray(plugin.estimate(asset.mesh, R, asset.handles, T, Xr, plugin.parse_params(params)),
                   dtype=np.float64)
    length = np.linalg.norm(N, axis=1, keepdims=True)
    return np.divide(N, length, out=np.zeros_like(N), where=length > 0)
