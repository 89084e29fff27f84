"""glTF 2.0 reader and writer plugins (role ``gltf``; ``.glb`` / ``.gltf``).

The reader fills the mesh, the skeleton (one handle per joint), the weights
and the poses of one animation clip at once; the writer puts reduced weights
(and simplified levels) back into the same document, or exports a new
skinned document from libigl-style inputs. See docs/gltf.md.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Literal

from pydantic import Field

from rigslim.plugin import Params, Reader, Writer

if TYPE_CHECKING:
    from pathlib import Path

    from rigslim.model.asset import Asset
    from rigslim.plugin import Params, StepContext


class GltfReaderParams(Params):
    animation: str | int | None = None
    """Clip name or index (default the first); a file without animations gives one frame, the rest pose."""
    fps: float = 30.0
    """Frame f is the pose at time f / fps s, for f = 0 .. floor(duration * fps)."""
    mesh: str | int | None = None
    """Read only this mesh (name or index); default every mesh a node instantiates with the skin, merged."""
    skin: int | None = None
    """Which skin, when mesh nodes use several (default the only one)."""
    normalize: bool = True
    """Divide each vertex's weights by their sum; false rejects rows off by more than 1e-6."""
    weld: bool = True
    """Merge vertices at identical positions (docs/gltf.md)."""
    times: list[float] | None = None
    """Sample the clip at these times (seconds) instead; frame j is times[j]."""
    allow_external_uris: bool | None = None  # None: RIGSLIM_ALLOW_EXTERNAL_URIS / --allow-external-uris
    """Let buffer/image URIs name files outside the glTF's folder (default: RIGSLIM_ALLOW_EXTERNAL_URIS)."""


class GltfReader(Reader[GltfReaderParams]):
    name = "gltf"
    summary = "skinned glTF 2.0 (.glb/.gltf): mesh, joints as handles, JOINTS_n/WEIGHTS_n, one animation sampled at fps"
    role = "gltf"
    suffixes = (".glb", ".gltf")

    def read(self, path: Path, asset: Asset, params: GltfReaderParams, ctx: StepContext) -> None:
        from rigslim.io.gltf.skin import read_gltf_skin

        skin = read_gltf_skin(path, animation=params.animation, fps=params.fps, mesh=params.mesh,
                              skin=params.skin, normalize=params.normalize, weld=params.weld,
                              times=params.times, allow_external_uris=params.allow_external_uris)
        asset.mesh, asset.handles, asset.weights, asset.poses = skin.mesh, skin.handles, skin.weights, skin.poses
        asset.extras["gltf"] = skin
        clip = "rest pose only" if skin.animation is None else \
            skin.document.json["animations"][skin.animation].get("name", f"#{skin.animation}")
        asset.provenance["gltf"] = {"path": str(path), "skin": skin.skin, "primitives": len(skin.slices),
                                    "animation": clip, "fps": skin.fps, "frames": len(skin.poses),
                                    "file_vertices": sum(p.count for p in skin.slices),
                                    "welded_vertices": skin.mesh.n_vertices}


class GltfWriterParams(Params):
    quantize: Literal["float", "ushort", "ubyte"] = "float"
    """Encoding of WEIGHTS_n: float32, or normalised ushort / ubyte (every row still sums to one)."""
    sets: int | None = None
    """Number of JOINTS_n/WEIGHTS_n sets (default: as many as each primitive's widest vertex needs)."""
    levels: bool = True
    """Write the simplified levels a decimate step made."""
    lod: bool = False
    """Link the levels from each skinned node with MSFT_lod (false: each level in a scene of its own)."""
    embed: bool = False
    """.gltf only: the buffer as one data URI instead of a .bin beside it."""
    fps: float = 30.0
    """Frame rate of an exported animation (glTF inputs keep the rate they were sampled at)."""
    keep_input_weights: bool = True
    """With no solve step, keep the file's skinning bytes when they sum to one (else write them normalised)."""
    clamp_negative: bool = False
    """Set negative weights to zero and renormalise those rows instead of failing (glTF weights are >= 0)."""
    coverage: Literal["measured", "halving"] = "measured"
    """With ``lod``: ``MSFT_screencoverage`` from each level's test-pose error (:mod:`rigslim.io.gltf.switch`),
    or the unmeasured series 0.5, 0.25, ..."""
    pixel_error: float = Field(1.0, gt=0)
    """Measured coverage: the level may show where its error projects to at most this many pixels ..."""
    fov: float = Field(60.0, gt=0, lt=180)
    """... for a camera of this vertical field of view (degrees) ..."""
    resolution: int = Field(1080, ge=1)
    """... and a viewport this many pixels high ..."""
    aspect: float = Field(16.0 / 9.0, gt=0)
    """... and this width / height (coverage is the bounding sphere's share of the screen area)."""
    switch_error: Literal["max", "rms"] = "max"
    """Measured coverage from each level's largest test-pose error (every point within ``pixel_error``)
    or its RMS (on average)."""
    switch_frames: int = Field(12, ge=0)
    """Measured coverage: at most this many test frames, evenly spread (0: every test frame) ..."""
    switch_samples: int = Field(5000, ge=100)
    """... and this many surface samples per side and frame."""
    level_skins: bool = True
    """Each level mesh gets a skin of only the joints its vertices use (false: the source skin)."""
    split: bool = False
    """With ``lod``: each level a file of its own beside the output, named after its face target
    (``OUT-50.glb``, ``OUT-25.glb``; a face count: ``OUT-500f.glb``; another level: ``OUT-LABEL.glb``), and
    ``OUT.lod.json`` saying when each shows (:mod:`rigslim.io.gltf.sidecar`); ``OUT`` itself is not written.
    What ``rigslim lod --split`` writes."""


class GltfWriter(Writer[GltfWriterParams]):
    name = "gltf"
    summary = "glTF 2.0 (.glb/.gltf): the source document with reduced weights (k<=4: one set, 5..8: two) and levels"
    suffixes = (".glb", ".gltf")

    def write(self, path: Path, asset: Asset, params: GltfWriterParams, ctx: StepContext) -> None:
        if params.split:
            _write_split(self, path, asset, params, ctx)
        else:
            self.write_file(path, asset, params, ctx)

    def write_file(self, path: Path, asset: Asset, params: GltfWriterParams, ctx: StepContext) -> None:
        """The one output file (``split`` aside)."""
        from rigslim.io.gltf.write import export_skinned, fixed_width_weights, write_gltf

        levels = (asset.levels or None) if params.levels else None
        source = asset.extras.get("gltf")
        if source is not None:
            from rigslim.io.gltf.lod import input_joints_valid, input_skinning_strides_valid, input_weights_normalized

            reduced = asset.reduced
            renormalised = False
            if reduced is None and params.keep_input_weights and asset.weights is not None \
                    and not (input_weights_normalized(source) and input_joints_valid(source)
                             and input_skinning_strides_valid(source)):
                # the file's own bytes do not sum to one (the validator's ACCESSOR_WEIGHTS_NON_NORMALIZED):
                # write the weights as read (normalised) instead of keeping them
                renormalised = True
            if reduced is None and (renormalised or not params.keep_input_weights):
                asset.require("weights", step="write: gltf")
                reduced = fixed_width_weights(asset.weights)
            switch = None
            if levels and params.lod and params.coverage == "measured":
                from rigslim.io.gltf.switch import level_switch

                switch = level_switch(asset, levels, pixel_error=params.pixel_error, fov=params.fov,
                                      resolution=params.resolution, aspect=params.aspect,
                                      frames=params.switch_frames, samples=params.switch_samples,
                                      error=params.switch_error)
                ctx.report["switch"] = switch
            stats = write_gltf(path, source, reduced, quantize=params.quantize, sets=params.sets, levels=levels,
                               lod=params.lod, embed=params.embed, clamp_negative=params.clamp_negative,
                               hierarchy=asset.hierarchy if levels else None,
                               coverage=switch["coverage"] if switch else None,
                               level_extras=switch["node_extras"] if switch else None,
                               level_skins=params.level_skins)
            if renormalised:
                stats["renormalised_input_weights"] = True
                ctx.log("the file's weights do not sum to one: written normalised")
            ctx.report.update(stats)
            mode = "rewrite"
        else:
            asset.require("mesh", "handles", step="write: gltf")
            weights = asset.reduced if asset.reduced is not None else asset.weights
            if weights is None:
                asset.require("weights", step="write: gltf")
            usd = asset.extras.get("usd")
            if usd is not None and usd.mesh is asset.mesh:     # a USD character: its materials, UVs, normals too
                from rigslim.io.usd.looks import export_with_looks

                stats = export_with_looks(path, usd, asset.mesh, asset.handles, weights, asset.poses,
                                          levels=levels, hierarchy=asset.hierarchy, fps=params.fps,
                                          quantize=params.quantize, embed=params.embed, lod=params.lod,
                                          clamp_negative=params.clamp_negative)
                for note in stats.pop("looks_notes"):
                    ctx.log(note)
            else:
                stats = export_skinned(path, asset.mesh, asset.handles, weights, asset.poses, fps=params.fps,
                                       quantize=params.quantize, embed=params.embed, levels=levels, lod=params.lod,
                                       clamp_negative=params.clamp_negative)
            ctx.report.update(stats)
            mode = "export"
        if ctx.report.get("clamped_vertices"):
            ctx.log(f"{ctx.report['clamped_vertices']} vertices had negative weights (down to "
                    f"{ctx.report['most_negative']:.3g}): set to zero and renormalised")
        ctx.report.update({"mode": mode, "quantize": params.quantize,
                           "k": asset.reduced.k if asset.reduced is not None else None,
                           "levels": len(levels) if levels else 0})


READERS = [GltfReader]
WRITERS = [GltfWriter]


def _write_split(writer: GltfWriter, path: Path, asset: Asset, params: GltfWriterParams, ctx: StepContext) -> None:
    """``split: true``: the ``MSFT_lod`` file into a scratch folder, then each level cut out of it into a file of
    its own (:func:`rigslim.io.gltf.write.split_levels`) and the sidecar, both staged with the run's outputs.
    Without levels (no decimate step, or none reached its target) only the sidecar is written."""
    from pathlib import Path

    import rigslim
    from rigslim.errors import StepError
    from rigslim.io.atomic import refuse_input_as_output, scratch_folder
    from rigslim.io.gltf.sidecar import level_rows, sidecar_path, split_outputs, switch_camera, write_sidecar
    from rigslim.io.gltf.write import split_levels

    if not (params.lod and params.levels):
        raise StepError("true needs lod: true and levels: true (it cuts the MSFT_lod levels into files of their "
                        "own)", field="split", fix="set lod: true (and leave levels on), or leave split out")
    labels = [lv.label for lv in asset.levels or []]
    steps = list((ctx.document or {}).get("steps") or [])
    outputs = split_outputs(path, labels, steps)
    sidecar = sidecar_path(path)
    named = {f"split ({p.name})": p for p in [*outputs, sidecar]}
    if path.suffix.lower() == ".gltf" and not params.embed:
        named |= {f"split ({p.name} buffer)": p.with_suffix(".bin") for p in outputs}
    refuse_input_as_output(named, asset.extras.get("read_files") or [], distinct=False)
    with scratch_folder("rigslim-split-") as tmp:
        whole = tmp / f"lod{path.suffix}"
        writer.write_file(whole, asset, params, ctx)
        if outputs:
            split_levels(whole, outputs)
    steps.append({"stage": "write", "report": ctx.report})
    inputs = [Path(p) for p in ((ctx.document or {}).get("inputs") or {}).values() if isinstance(p, str)]
    source = Path((asset.provenance.get("gltf") or {}).get("path") or (inputs[0] if inputs else path))
    write_sidecar(sidecar, source=source, outputs=outputs, rows=level_rows(asset, steps), asset=asset,
                  header={"rigslim_version": rigslim.__version__, "written_by": "write: gltf, split: true"},
                  camera=switch_camera(steps))
    ctx.report["split"] = {"files": [str(p) for p in outputs], "sidecar": str(sidecar)}
    ctx.log(f"{len(outputs)} level files and {sidecar.name}")
