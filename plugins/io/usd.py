"""USD / UsdSkel reader and writer plugins (role ``usd``; ``.usd`` / ``.usda`` / ``.usdc`` / ``.usdz``).

The reader fills the mesh (every mesh bound to one skeleton), the skeleton
(one handle per joint), the weights and the poses of one ``SkelAnimation`` at
once; the writer puts reduced weights (``elementSize = k``) and simplified
levels (a ``LOD`` variant set, or ``UsdLod`` items) back into the source
stage, or exports a new UsdSkel character from any other input (a glTF skin,
a libigl mesh + skeleton + animation). See docs/usd.md. Needs ``usd-core``
(``pip install 'rigslim[usd]'``).
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from rigslim.plugin import Params, Reader, Writer

if TYPE_CHECKING:
    from pathlib import Path

    from rigslim.model.asset import Asset
    from rigslim.plugin import StepContext

USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


class UsdReaderParams(Params):
    skeleton: str | None = None
    """Path or name of the Skeleton whose meshes to read, when several skeletons have skinned meshes."""
    mesh: str | None = None
    """Read only this Mesh (path or name); default every mesh bound to the skeleton, merged."""
    animation: str | None = None
    """Path or name of the SkelAnimation to sample (default skel:animationSource; none: the rest pose)."""
    fps: float = 30.0
    """Frame f is time code t0 + f * timeCodesPerSecond / fps, t0 the clip's first key."""
    times: list[float] | None = None
    """Sample at these times (seconds after t0) instead."""
    normalize: bool = True
    """Divide each point's weights by their sum; false rejects rows off by more than 1e-6."""


class UsdReader(Reader[UsdReaderParams]):
    name = "usd"
    summary = ("UsdSkel character (.usd/.usda/.usdc/.usdz): meshes bound to one Skeleton, joints as handles, "
               "jointIndices/jointWeights, one SkelAnimation sampled at fps")
    role = "usd"
    suffixes = USD_SUFFIXES

    def read(self, path: Path, asset: Asset, params: UsdReaderParams, ctx: StepContext) -> None:
        from rigslim.io.usd.read import read_usd_skin

        skin = read_usd_skin(path, skeleton=params.skeleton, mesh=params.mesh, animation=params.animation,
                             fps=params.fps, times=params.times, normalize=params.normalize)
        asset.mesh, asset.handles, asset.weights, asset.poses = skin.mesh, skin.handles, skin.weights, skin.poses
        asset.extras["usd"] = skin
        for note in skin.notes:
            ctx.log(note)
        asset.provenance["usd"] = {"path": str(path), "skeleton": skin.skeleton, "meshes": [p.path for p in skin.parts],
                                   "element_sizes": [p.element_size for p in skin.parts],
                                   "animation": skin.animation or "rest pose only", "fps": skin.fps,
                                   "frames": len(skin.poses), "vertices": skin.mesh.n_vertices, "notes": skin.notes}


class UsdWriterParams(Params):
    levels: bool = True
    """Write the simplified levels a decimate step made."""
    lod: Literal["variant", "prims"] = "variant"
    """Layout of levels: a ``LOD`` variant set on the model prim, or ``UsdLod`` items (docs/usd.md)."""
    fps: float = 30.0
    """Frame rate of an exported animation (glTF inputs keep the rate they were sampled at)."""
    keep_input_weights: bool = True
    """With no solve step, keep the file's influences (else write the weights as read, normalised)."""
    clamp_negative: bool = False
    """Set negative weights to zero and renormalise those rows instead of failing."""


class UsdWriter(Writer[UsdWriterParams]):
    name = "usd"
    summary = ("UsdSkel (.usd/.usda/.usdc/.usdz): the source stage with reduced weights (elementSize = k) and "
               "levels (LOD variant set or UsdLod prims), or a new UsdSkel character from any skeleton input")
    suffixes = USD_SUFFIXES

    def write(self, path: Path, asset: Asset, params: UsdWriterParams, ctx: StepContext) -> None:
        from rigslim.io.usd.write import write_usd

        levels = (asset.levels or None) if params.levels else None
        source = asset.extras.get("usd")
        reduced = asset.reduced
        if source is not None and source.mesh is asset.mesh:
            if reduced is None and not params.keep_input_weights:
                from rigslim.io.gltf.write import fixed_width_weights

                asset.require("weights", step="write: usd")
                reduced = fixed_width_weights(asset.weights)
            stats = write_usd(path, source, reduced, levels=levels, hierarchy=asset.hierarchy, lod=params.lod,
                              clamp_negative=params.clamp_negative)
            mode = "rewrite"
        else:
            stats = self._export(path, asset, params, levels)
            mode = "export"
        if stats.get("clamped_vertices"):
            ctx.log(f"{stats['clamped_vertices']} vertices had negative weights (down to "
                    f"{stats['most_negative']:.3g}): set to zero and renormalised")
        ctx.report.update(stats)
        ctx.report.update({"mode": mode, "k": asset.reduced.k if asset.reduced is not None else None})

    @staticmethod
    def _export(path: Path, asset: Asset, params: UsdWriterParams, levels) -> dict:
        """A new UsdSkel stage from the asset, then levels through the same writer as a USD source."""
        from rigslim.io.usd.export import bind_transforms, build_stage
        from rigslim.io.usd.read import usd_skin_of_stage
        from rigslim.io.usd.write import save_stage, write_usd

        asset.require("mesh", "handles", step="write: usd")
        assert asset.mesh is not None and asset.handles is not None
        weights = asset.reduced if asset.reduced is not None else asset.weights
        if weights is None:
            asset.require("weights", step="write: usd")
        gltf = asset.extras.get("gltf")
        bind = bind_transforms(asset.handles, gltf if gltf is not None and gltf.mesh is asset.mesh else None)
        name = getattr(asset.mesh, "source", None) or "Character"
        from_gltf = gltf is not None and gltf.mesh is asset.mesh
        # a glTF's frames keep the rate they were sampled at
        fps = gltf.fps if from_gltf and gltf is not None else params.fps
        bound, poses, clips = _animations(asset, gltf if from_gltf else None, fps)
        stage = build_stage(asset.mesh, asset.handles, weights, poses, fps=fps, bind=bind,
                            name=_stem(name), clips=clips, animation_name=bound)
        from rigslim.io.atomic import scratch_folder

        # textures: beside the output (NAME_textures/), or packaged into a .usdz from a scratch folder
        with scratch_folder("rigslim-usdz-textures-") as scratch:
            folder = scratch if path.suffix.lower() == ".usdz" else path.parent / f"{path.stem}_textures"
            looks = {}
            if from_gltf:
                from rigslim.io.usd.export import add_gltf_looks

                looks = add_gltf_looks(stage, gltf, textures=folder)
            if not levels:
                save_stage(stage, path)
                k = asset.reduced.k if asset.reduced is not None else None
                return {"element_size": k, "levels": 0, "lod": None, "meshes": 1, **looks}
            skin = usd_skin_of_stage(stage, asset.mesh, asset.handles, asset.weights, poses, path)
            return looks | write_usd(path, skin, None, levels=levels, hierarchy=asset.hierarchy, lod=params.lod,
                                     clamp_negative=params.clamp_negative)


def _animations(asset: Asset, gltf, fps: float) -> tuple[str, object, list | None]:
    """The clips an exported character gets: the bound one's name and poses, and the others ``(name, Poses)``.

    ``asset.poses`` may stack several clips (a ``clips:`` split, :mod:`rigslim.runtime.clips`): the bound
    ``SkelAnimation`` holds only its own clip's frames. From a glTF input (``gltf``) that is the clip the
    input read, the segment of that name in the stack or else the poses read with the input, and every
    other animation of the file follows, read again; from any other input the stack's first clip, the
    others after it under their names.
    """
    split = asset.split
    segments = (split.segments if split is not None else None) or []
    if gltf is not None:
        label = _segment_label(gltf)
        segment = next((s for s in segments if s["clip"] == label), None) if asset.poses is not None else None
        poses = _segment(asset.poses, segment) if segment is not None else gltf.poses
        return _clip_name(gltf), poses, _other_gltf_clips(gltf, fps)
    if asset.poses is None or len(segments) < 2:
        return "Animation", asset.poses, None
    parts = [("Animation" if s["clip"] == "input animation" else str(s["clip"]), _segment(asset.poses, s))
             for s in segments]
    return parts[0][0], parts[0][1], parts[1:]


def _segment(poses, segment: dict):
    """The frames of one clip of stacked poses (a :attr:`FrameSplit.segments` entry)."""
    from rigslim.model.poses import Poses

    start, count = int(segment["start"]), int(segment["frames"])
    return Poses(poses.T[start:start + count], source=f"{poses.source} ({segment['clip']})")


def _segment_label(gltf) -> str | None:
    """The label :func:`rigslim.runtime.clips.load_clip` gives the glTF clip the input read (None: no clip)."""
    if gltf.animation is None:
        return None
    return gltf.document.json["animations"][gltf.animation].get("name", f"#{gltf.animation}")


def _other_gltf_clips(gltf, fps: float) -> list:
    """``(name, Poses)`` of the glTF's other animations (the read one is the bound SkelAnimation)."""
    from rigslim.io.gltf.skin import read_gltf_skin

    anims = gltf.document.json.get("animations", [])
    out = []
    for i, anim in enumerate(anims):
        if i == gltf.animation:
            continue
        other = read_gltf_skin(gltf.document.path, animation=i, fps=fps, skin=gltf.skin, weld=False,
                               allow_external_uris=gltf.document.allow_external_uris)
        out.append((anim.get("name") or f"clip{i}", other.poses))
    return out


def _clip_name(gltf) -> str:
    if gltf.animation is None:
        return "Animation"
    return gltf.document.json["animations"][gltf.animation].get("name") or f"clip{gltf.animation}"


def _stem(source: str) -> str:
    from pathlib import Path

    stem = Path(str(source).split(" ")[0]).stem
    return stem or "Character"


READERS = [UsdReader]
WRITERS = [UsdWriter]
