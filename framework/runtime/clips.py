"""Fitting on one clip and testing on another: the two-clip form of a pipeline's ``poses:``.

::

    poses:
      examples: {clip: ROM, frames: "0:60:5"}   # fit on a range-of-motion clip
      test: {clip: Run}                         # measure on a gameplay clip (all its frames)

A ``clip`` is

- an animation of the glTF input, by name or index (sampled like the input
  clip: same frame rate, skin and mesh), or
- an animation file (``.dmat``, libigl's stacked transforms), relative to
  the pipeline file;

``frames`` (default: every frame of the clip) uses the usual frame specs
(:func:`rigslim.model.poses.parse_frames`). A side without ``clip`` uses the input
``animation:``. The poses of the clips are stacked into one :class:`Poses`
(the first clip's frames first), so every step and metric works unchanged;
:attr:`FrameSplit.clips` keeps each side's clip name and its own frame numbers
for the metrics document. Frames of different clips never overlap; frames of
the same clip follow the one-clip rule (test frames that are also example
frames are dropped).

Several clips (``clips:``, a list or ``all``: every animation of the glTF input)::

    poses:
      examples: {clips: all, count: 24}   # 24 example frames in all, evenly over every clip
      test: {clips: all}                  # held-out frames of every clip

The example frames are shared out over the example clips in proportion to
their lengths (at least :data:`MIN_CLIP_EXAMPLES` each); a clip of n frames with e examples gets
the step ``s = max(3, ceil(n / e))``: examples at frames ``0, s, 2s, ...``,
and the other frames alternately validation frames (the solvers' guard,
:attr:`FrameSplit.validation`) and test frames
(:func:`rigslim.model.poses.sample_clip_frames`), so the three never meet. A
test clip that is not an example clip (a held-out clip) is tested on all its frames. Where the clips'
shares add up to more than ``EXAMPLE_CAP * count`` (48 by default: a game character's dozens of clips, 3
examples each), farthest-point sampling of the example poses, compared by the posed positions of 256 of
the mesh's vertices (:func:`pose_descriptors`), keeps that many; the others become validation frames
(:func:`rigslim.model.poses.thin_examples`). The Red Eclipse player with its 62 clips: 48 example poses
over 34 clips instead of 150, and ``rigslim lod --ratios 0.5,0.25,0.1`` 2.83 s instead of 6.84 s.
``--clip`` of the commands is ``clips: [NAME]``. :attr:`FrameSplit.segments` records where each clip lies in
the stack (cross-validation across clips uses it).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.model.poses import (
    MIN_CLIP_EXAMPLES,
    FrameSplit,
    Poses,
    parse_frames,
    sample_clip_frames,
    thin_examples,
)
from rigslim.numerics.blend import linear_blend

__all__ = ["DEFAULT_EXAMPLE_COUNT", "EXAMPLE_CAP", "MIN_CLIP_EXAMPLES", "clip_split", "load_clip",
           "multi_clip_split", "pose_descriptors", "sample_clip_frames", "thin_examples", "uses_clips"]


def _clip_of(side) -> tuple[object | None, object]:
    """``(clip, frames)`` of one side of the spec (clip None: the input animation)."""
    if isinstance(side, dict):
        return side.get("clip"), side.get("frames", None)
    if hasattr(side, "clip"):
        return side.clip, side.frames
    return None, side


def load_clip(clip, asset, base: Path, source, where: str, gltf_params: dict | None = None) -> tuple[str, Poses]:
    """The poses of one named clip (module docstring); ``where`` names the field in errors."""
    skin = asset.extras.get("gltf")
    names = []
    if skin is not None:
        from rigslim.io.gltf.skin import read_gltf_skin

        anims = skin.document.json.get("animations", [])
        names = [a.get("name", f"#{i}") for i, a in enumerate(anims)]
        index = None
        if isinstance(clip, str) and clip in names:
            index = names.index(clip)
        elif isinstance(clip, int) and not isinstance(clip, bool) and 0 <= clip < len(anims):
            index = clip
        if index is not None:
            params = {k: v for k, v in (gltf_params or {}).items()
                      if k in ("mesh", "normalize", "weld", "allow_external_uris")}
            read = read_gltf_skin(skin.document.path, animation=index, fps=skin.fps, skin=skin.skin, **params)
            if read.poses.n_handles != asset.handles.n:
                raise InputError(f"clip '{clip}' moves {read.poses.n_handles} joints, the skin has {asset.handles.n}",
                                 source=source, field=where, fix="choose an animation of the same skin")
            return names[index], read.poses
    if isinstance(clip, str) and Path(clip).suffix.lower() == ".dmat":
        from rigslim.io import read_stacked_animation

        file = Path(clip) if Path(clip).is_absolute() else base / clip
        if not file.exists():
            raise InputError(f"clip file '{clip}' not found", source=source, field=where,
                             fix="check the path (relative paths are relative to the pipeline file)")
        n = asset.handles.n if asset.handles is not None else None
        return clip, read_stacked_animation(file, n_handles=n)
    available = f"the glTF input's animations are {', '.join(repr(n) for n in names)}" if names else \
        "there is no glTF input with named animations"
    raise InputError(f"no clip {clip!r} ({available})", source=source, field=where,
                     fix="name an animation of the glTF input, or give an animation file (.dmat) "
                         "relative to the pipeline file")


def uses_clips(spec) -> bool:
    """Whether a ``poses:`` spec (examples, test) names a clip (or clips) on either side."""
    return any(_clip_of(side)[0] is not None or _clips_of(side) is not None for side in (spec.examples, spec.test))


def _clips_of(side):
    """The ``clips`` of one side (None: not the several-clip form)."""
    if isinstance(side, dict):
        return side.get("clips")
    return getattr(side, "clips", None)


#: Example frames of a ``clips:`` split when ``count`` is not given.
DEFAULT_EXAMPLE_COUNT = 24

#: At most ``EXAMPLE_CAP * count`` example frames: the clips' shares (at least :data:`MIN_CLIP_EXAMPLES` each)
#: of a file with many clips are thinned to that many by farthest-point sampling of their poses.
EXAMPLE_CAP = 2

#: Vertices (evenly spread over the mesh's order) whose posed positions describe a pose for the thinning.
DESCRIPTOR_VERTICES = 256


def pose_descriptors(asset, T: np.ndarray) -> np.ndarray:
    """(len(T), d) descriptors of the poses ``T`` (p, n, 3, 4): the posed positions of
    :data:`DESCRIPTOR_VERTICES` vertices of the asset's mesh under its weights, flattened, so that poses are
    compared by how far they move the surface; without a mesh and weights, the transforms themselves."""
    mesh, weights = getattr(asset, "mesh", None), getattr(asset, "weights", None)
    if mesh is None or weights is None:
        return np.asarray(T, np.float64).reshape(len(T), -1)
    rows = np.unique(np.linspace(0, mesh.n_vertices - 1, DESCRIPTOR_VERTICES).astype(np.int64))
    V, W = mesh.V[rows], weights[rows]
    return np.stack([linear_blend(V, W, T[j]).ravel() for j in range(len(T))])


def _clip_names(clips, asset, source, where) -> list[object]:
    """The clips a ``clips:`` entry names: ``all`` -> every animation of the glTF input (indices), else the list."""
    if clips != "all":
        if not clips:
            raise InputError("'clips' lists no clip", source=source, field=where,
                             fix="name at least one clip, or write 'clips: all'")
        return list(clips)
    skin = asset.extras.get("gltf")
    anims = skin.document.json.get("animations", []) if skin is not None else []
    if anims:
        return list(range(len(anims)))
    if asset.poses is not None:
        return [None]       # the input animation, the only clip there is
    raise InputError("'clips: all' but the input has no animation", source=source, field=where,
                     fix="add 'animation:' under inputs, or use a glTF input with animations")


def multi_clip_split(spec, asset, base: Path, source, gltf_params: dict | None = None) -> tuple[Poses, FrameSplit]:
    """Stacked poses and the split of a ``clips:`` spec (module docstring): examples, validation, test."""
    ex_side, te_side = spec.examples, spec.test
    if _clips_of(ex_side) is None or _clips_of(te_side) is None:
        bad = "examples" if _clips_of(ex_side) is None else "test"
        raise InputError("one side of 'poses' gives 'clips' and the other does not", source=source,
                         field=f"poses.{bad}", fix="give 'clips:' on both sides (e.g. test: {clips: all})")
    count = getattr(ex_side, "count", None) if not isinstance(ex_side, dict) else ex_side.get("count")
    count = DEFAULT_EXAMPLE_COUNT if count is None else int(count)
    loaded: dict[str, Poses] = {}
    order: list[str] = []
    by_name: dict[object, tuple[str, Poses]] = {}      # each clip sampled once, though both sides name it

    def load(names, where):
        labels = []
        for clip in names:
            if clip is None:
                label, poses = "input animation", asset.poses
            elif clip in by_name:
                label, poses = by_name[clip]
            else:
                label, poses = by_name[clip] = load_clip(clip, asset, base, source, where, gltf_params)
            if label not in loaded:
                loaded[label] = poses
                order.append(label)
            if label not in labels:
                labels.append(label)
        return labels

    fit = load(_clip_names(_clips_of(ex_side), asset, source, "poses.examples.clips"), "poses.examples.clips")
    held = load(_clip_names(_clips_of(te_side), asset, source, "poses.test.clips"), "poses.test.clips")
    shares = sample_clip_frames([len(loaded[c]) for c in fit], count)
    shares = thin_examples(shares, lambda c, frames: pose_descriptors(asset, loaded[fit[c]].T[frames]),
                           EXAMPLE_CAP * count)
    sampled = dict(zip(fit, shares, strict=True))
    starts, segments, at = {}, [], 0
    for label in order:
        starts[label] = at
        segments.append({"clip": label, "start": at, "frames": len(loaded[label])})
        at += len(loaded[label])
    ex, val, te = [], [], []
    clips: dict[str, list[dict]] = {"examples": [], "validation": [], "test": []}
    for label in fit:
        e, v, _ = sampled[label]
        ex += [starts[label] + f for f in e]
        val += [starts[label] + f for f in v]
        clips["examples"].append({"clip": label, "frames": e})
        if v:
            clips["validation"].append({"clip": label, "frames": v})
    for label in held:
        t = sampled[label][2] if label in sampled else list(range(len(loaded[label])))
        te += [starts[label] + f for f in t]
        if t:
            clips["test"].append({"clip": label, "frames": t})
    if not te:
        raise InputError("the test clips leave no held-out frame", source=source, field="poses.test",
                         fix="test on clips of at least 2 frames, or on a clip that is not an example clip")
    T = np.concatenate([loaded[c].T for c in order], axis=0)
    split = FrameSplit(ex, te, [], clips=clips, validation=val, segments=segments)
    return Poses(T, source=" + ".join(order)), split


def clip_split(spec, asset, base: Path, source, gltf_params: dict | None = None) -> tuple[Poses, FrameSplit]:
    """Stacked poses and the split of a two-clip ``poses:`` spec.

    Returns
    -------
    poses : Poses
        The clips' poses, stacked; frame numbers ``0..p-1`` over the stack.
    split : FrameSplit
        Example and test frames as stack frame numbers, with :attr:`FrameSplit.clips`.
    """
    if _clips_of(spec.examples) is not None or _clips_of(spec.test) is not None:
        return multi_clip_split(spec, asset, base, source, gltf_params)
    sides = {}
    for name, side in (("examples", spec.examples), ("test", spec.test)):
        clip, frames = _clip_of(side)
        where = f"poses.{name}.clip"
        if clip is None:
            if asset.poses is None:
                raise InputError(f"poses.{name} names no clip and there is no input animation", source=source,
                                 field=f"poses.{name}", fix="give a clip, or 'animation:' under inputs")
            sides[name] = ("input animation", asset.poses, frames)
        else:
            label, poses = load_clip(clip, asset, base, source, where, gltf_params)
            sides[name] = (label, poses, frames)
    offsets: dict[str, int] = {}
    parts: list[Poses] = []
    for name in ("examples", "test"):
        label, poses, _ = sides[name]
        if label not in offsets:
            offsets[label] = sum(len(p) for p in parts)
            parts.append(poses)
    T = np.concatenate([p.T for p in parts], axis=0)
    local = {}
    for name in ("examples", "test"):
        label, poses, frames = sides[name]
        spec_frames = frames if frames is not None else f"0:{len(poses)}"
        local[name] = parse_frames(spec_frames, len(poses), source=source, field_name=f"poses.{name}.frames")
    ex = [offsets[sides["examples"][0]] + f for f in local["examples"]]
    te = [offsets[sides["test"][0]] + f for f in local["test"]]
    dropped_local = sorted(set(local["test"]) & set(local["examples"])) \
        if sides["examples"][0] == sides["test"][0] else []
    te = [f for f in te if f not in set(ex)]
    if not te:
        raise InputError("every test frame is also an example frame", source=source, field="poses.test",
                         fix="choose test frames that are not example frames")
    clips = {name: {"clip": sides[name][0], "frames": [f for f in local[name]
                                                         if name == "examples" or f not in dropped_local]}
             for name in ("examples", "test")}
    split = FrameSplit(ex, te, [offsets[sides["test"][0]] + f for f in dropped_local], clips=clips)
    return Poses(T, source=" + ".join(offsets)), split
