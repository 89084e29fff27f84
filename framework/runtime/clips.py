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
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.model.poses import FrameSplit, Poses, parse_frames


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
    """Whether a ``poses:`` spec (examples, test) names a clip on either side."""
    return any(_clip_of(side)[0] is not None for side in (spec.examples, spec.test))


def clip_split(spec, asset, base: Path, source, gltf_params: dict | None = None) -> tuple[Poses, FrameSplit]:
    """Stacked poses and the split of a two-clip ``poses:`` spec.

    Returns
    -------
    poses : Poses
        The clips' poses, stacked; frame numbers ``0..p-1`` over the stack.
    split : FrameSplit
        Example and test frames as stack frame numbers, with :attr:`FrameSplit.clips`.
    """
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
