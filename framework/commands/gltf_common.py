"""What the one-command glTF front ends share: input checks, the command session (the input read once, no
output naming an input, one output transaction), clip frames, the pipeline run, the ``--report`` document."""

from __future__ import annotations

import argparse
import contextlib
import copy
import json
import math
import re
import time
from pathlib import Path

import numpy as np
import yaml

from rigslim.errors import InputError, RigslimError

#: Version of the ``--report`` / ``--json`` documents of these commands.
REPORT_SCHEMA = "rigslim-gltf-command"


REPORT_SCHEMA_VERSION = 1


DEFAULT_FPS = 30.0


#: Files the one-command front ends read and write: glTF, and USD / UsdSkel (docs/usd.md).
GLTF_SUFFIXES = (".glb", ".gltf")
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")


def is_usd(path) -> bool:
    """Whether ``path`` names a USD layer or package (by suffix)."""
    return Path(path).suffix.lower() in USD_SUFFIXES


def _check_input(path, what: str = "input") -> Path:
    p = Path(path)
    if p.suffix.lower() not in GLTF_SUFFIXES + USD_SUFFIXES:
        raise InputError(f"'{p.suffix or p.name}' is not a glTF or USD file", source=p, field=what,
                         fix="give a .glb, .gltf, .usd, .usda, .usdc or .usdz file")
    if not p.is_file():
        raise InputError("file not found", source=p, field=what, fix="check the path")
    return p.resolve()


def _check_fps(fps: float) -> None:
    if not (fps > 0 and math.isfinite(fps)):
        raise InputError(f"--fps {fps:g} is not a positive frame rate", field="--fps", fix="give e.g. --fps 30")


def _check_output(path) -> Path:
    p = Path(path)
    if p.suffix.lower() not in GLTF_SUFFIXES + USD_SUFFIXES:
        raise InputError(f"output '{p.name}' is not a .glb, .gltf or USD file", source=p, field="-o",
                         fix="write to OUT.glb, OUT.gltf, OUT.usdc, OUT.usda or OUT.usdz")
    return p.resolve()


def input_section(path: Path, spec: dict) -> dict:
    """The pipeline's ``inputs``: ``{"gltf": spec}``, or ``{"usd": spec}`` for a USD file (no glTF skin index)."""
    if is_usd(path):
        return {"usd": {k: v for k, v in spec.items() if k != "skin"}}
    return {"gltf": spec}


def write_step(out: Path, **params) -> dict:
    """A ``write`` step with the glTF writer's parameters, or the USD writer's for a USD output.

    USD has no weight quantisation (float32 weights) and takes ``lod: variant`` for glTF's ``lod: true``.
    """
    if not is_usd(out):
        return {"write": str(out), **params}
    usd = {k: v for k, v in params.items() if k in ("clamp_negative", "keep_input_weights", "levels")}
    if params.get("lod"):
        usd["lod"] = "variant"
    return {"write": str(out), **usd}


def unnormalised_note(command: str, name: str, doc) -> str | None:
    """The stderr line for an input whose skin weights do not sum to 1 (assimp's FBX conversions: 0.82 to
    1.38): they are read normalised, so every output, level 0 included, deforms as the normalised skin does.
    The commands print it after a successful run, so that an error stays the only line."""
    if doc is None:                    # USD: its reader says so itself
        return None
    from rigslim.io.gltf.skin import unnormalised_weights

    off = unnormalised_weights(doc)
    if not off:
        return None
    return (f"rigslim {command}: {name}: the skin weights of {off['vertices']} vertices do not sum to 1 "
            f"({off['min']:.4g} to {off['max']:.4g}); they are read normalised (glTF requires it), so the output "
            f"deforms as the normalised skin does")


def no_motion(name: str, clip: str | None, duration: float, source=None, searched: bool = False) -> str:
    """Why a file gives fewer than 2 frames: no animation at all, or a clip of one pose (an SMD's 0 s clip).

    ``searched``: the command looked through every clip for motion (no ``--clip``); where the file (``source``,
    its loaded glTF document) has several clips, the line says that each of them holds one pose."""
    if clip is None:
        return f"{name} has no animation"
    clips = len(source.json.get("animations", [])) if searched and source is not None else 1
    if clips > 1:
        return f"each of {name}'s {clips} clips holds one pose only (the first, '{clip}', is {duration:g} s long)"
    return f"{name}'s clip '{clip}' holds one pose only ({duration:g} s long)"


def clip_frames(path: Path, clip, fps: float, doc=None, *, moving: bool = False) -> tuple[int, str | None, float]:
    """Frame count of a clip sampled at ``fps`` (1 without animation), its name and its duration.

    ``doc``: the file's loaded :class:`~rigslim.io.gltf.document.GltfDocument` (the commands pass the one
    they read once); without it, only the file's JSON is parsed when every sampler's input has its ``max``.
    An unknown clip is reported against ``--clip``. ``moving`` (the commands that fit on every clip): with
    no ``clip`` given, the first clip that holds at least 2 frames, where the first holds one pose only (a
    weapon's 0 s idle before its reload); the file has motion when any clip has.
    """
    if is_usd(path):
        from rigslim.io.usd.summary import clip_info

        return clip_info(path, clip, fps)
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.scene import animation_duration, find_animation

    light = False
    if doc is None:
        doc = _json_only(path)
        light = doc is not None
        if not light:
            doc = load_gltf(path)
    try:
        anim = find_animation(doc, clip)
    except InputError as e:
        raise _renamed(e, "--clip") from None
    if anim is None:
        return 1, None, 0.0

    def duration_of(i: int) -> float:
        if light:       # the largest key time, from the accessors' max (the reader checks the keys themselves)
            acc = doc.json["accessors"]
            return max([float(acc[smp["input"]]["max"][0]) for smp in doc.json["animations"][i]["samplers"]],
                       default=0.0)
        return animation_duration(doc, i)

    def frames_of(seconds: float) -> int:
        return int(np.floor(seconds * fps + 1e-3)) + 1

    duration = duration_of(anim)
    if moving and clip is None and frames_of(duration) < 2:
        for i in range(1, len(doc.json["animations"])):
            if frames_of(duration_of(i)) >= 2:
                anim, duration = i, duration_of(i)
                break
    name = doc.json["animations"][anim].get("name", str(anim))
    return frames_of(duration), name, duration


def _renamed(e: RigslimError, option: str) -> RigslimError:
    """``e`` with its field replaced by the command-line option the value came from."""
    e.field = option
    e.args = (e.one_line(),)
    return e


def _json_only(path: Path):
    """The document's JSON without its buffers or its schema check, when
    every animation sampler's input accessor has its ``max``; else None (the caller loads it fully; the
    pipeline's reader checks the whole file anyway)."""
    from rigslim.io.gltf.document import GltfDocument, parse_glb

    try:
        data = path.read_bytes()
        js = parse_glb(data, path)[0] if data[:4] == b"glTF" else json.loads(data)
        for anim in js.get("animations", []):
            for smp in anim.get("samplers", []):
                if "max" not in js["accessors"][smp["input"]]:
                    return None
        return GltfDocument(path, js, [])
    except Exception:        # anything odd: the full reader gives the proper one-line error
        return None


def _scene_order(js: dict) -> list[int]:
    """The default scene's nodes, depth first (every node when the file has no scene)."""
    nodes = js.get("nodes", [])
    scenes = js.get("scenes", [])
    if not scenes:
        return list(range(len(nodes)))
    scene = scenes[js.get("scene", 0)] if isinstance(js.get("scene", 0), int) else scenes[0]
    order, stack = [], list(reversed(scene.get("nodes", [])))
    while stack:
        i = stack.pop()
        order.append(i)
        stack.extend(reversed(nodes[i].get("children", [])))
    return order


def skins_used(js: dict) -> list[int]:
    """Skins that mesh nodes of the default scene use, in depth-first order of first use."""
    out = []
    for i in _scene_order(js):
        n = js["nodes"][i]
        if "skin" in n and "mesh" in n and n["skin"] not in out:
            out.append(n["skin"])
    return out


def skin_meshes(js: dict, skin: int | None) -> list[str]:
    """Names of the meshes that nodes of the default scene draw with ``skin`` (``mesh N`` where unnamed), in
    depth-first order, each once."""
    out: list[str] = []
    for i in _scene_order(js):
        n = js["nodes"][i]
        if "mesh" in n and n.get("skin") == skin:
            name = js["meshes"][n["mesh"]].get("name") or f"mesh {n['mesh']}"
            if name not in out:
                out.append(name)
    return out


def _gltf_input(path: Path, clip, fps: float, frames: int, skin: int | None = None) -> dict:
    spec = {"path": str(path), "fps": fps}
    if skin is not None:
        spec["skin"] = skin
    if clip is not None:
        spec["animation"] = clip
    if frames < 2:
        spec["times"] = [0.0, 0.0]      # rest pose only: one example and one (identical) test frame
    return spec


#: Most example poses the commands fit to (long clips are subsampled evenly).
MAX_EXAMPLE_POSES = 24


def every_clip_poses(src: Path, clip) -> dict:
    """The ``poses:`` of the commands that fit on every clip: :data:`MAX_EXAMPLE_POSES` example frames shared
    out over the clips (``clip``: that one only), held-out frames of each clip for the test
    (:mod:`rigslim.runtime.clips`). A USD input fits on its bound clip."""
    clips = "all" if clip is None or is_usd(src) else [clip]
    return {"examples": {"clips": clips, "count": MAX_EXAMPLE_POSES}, "test": {"clips": clips}}


def _poses(frames: int) -> dict:
    """Example frames ``0, s, 2s, ...`` (at most :data:`MAX_EXAMPLE_POSES`) and test frames halfway between."""
    if frames < 2:
        return {"examples": "0", "test": "1"}
    step = max(2, -(-frames // MAX_EXAMPLE_POSES))
    return {"examples": f"0:{frames}:{step}", "test": f"{max(1, step // 2)}:{frames}:{step}"}


#: The command-line option behind each field of the pipelines ``reduce`` and ``lod`` build: a step's stage
#: key (its plugin) or parameter, and the glTF/USD input's parameters. Errors the pipeline run reports
#: against these fields name the option instead (``steps[2].solve`` -> ``--solve``).
OPTION_OF_FIELD = {
    "reduce": {"select": "--select", "k": "-k", "by": "--select", "solve": "--solve", "evaluate": "--solve",
               "write": "-o", "quantize": "--quantize"},
    "lod": {"decimate": "--method", "targets": "--ratios", "max_bones": "--max-bones", "max_error": "--max-error",
            "prune_parts": "--keep-parts", "joint_budget": "--max-joints", "keep_joints": "--keep-joints",
            "joint_choice": "--joint-choice",
            "evaluate": "--measure", "write": "-o", "quantize": "--quantize", "pixel_error": "--pixel-error",
            "fov": "--fov", "resolution": "--resolution", "switch_error": "--switch-error"},
    "inputs": {"animation": "--clip", "times": "--clip", "fps": "--fps", "path": "IN", "skin": "IN"},
}

_STEP_FIELD = re.compile(r"steps\[(\d+)\](?:\.([\w-]+))?")


def option_for_field(command: str, pipeline: dict, field: str | None) -> str | None:
    """The command-line option a field of the command's pipeline comes from (None: no option sets it).

    ``steps[N].KEY``: the option of parameter KEY of step N, else of the step's stage key;
    ``inputs.gltf.animation`` (``inputs.usd.*``): ``--clip``, ``--fps``...; ``poses``: ``--clip``.
    """
    options = OPTION_OF_FIELD.get(command, {})
    field = field or ""
    m = _STEP_FIELD.match(field)
    if m:
        steps = pipeline.get("steps", [])
        index = int(m.group(1))
        stage = next(iter(steps[index - 1]), None) if 1 <= index <= len(steps) else None
        return options.get(m.group(2) or "") or options.get(stage or "")
    parts = field.split(".")
    if parts[0] == "inputs":
        return OPTION_OF_FIELD["inputs"].get(parts[2] if len(parts) > 2 else "path")
    if parts[0] == "poses":
        return "--clip"
    return None


def _as_option_error(e: RigslimError, command: str, pipeline: dict, label: str) -> None:
    """Rewrite in place an error the run reported against the in-memory pipeline so it names the option."""
    source = e.source or ""
    if source != label and not source.startswith(label + " "):
        return              # about a file (the input, an output): already names it
    field = e.field
    if source.startswith(label + " "):       # a plugin's failure: "LABEL steps[N] (stage)"
        field = source[len(label) + 1:].split(" ")[0] + (f".{e.field}" if e.field else "")
    option = option_for_field(command, pipeline, field)
    e.source = None if option else f"rigslim {command}"
    e.field = option or field
    e.args = (e.one_line(),)


def _run(pipeline: dict, args, console, saved=None) -> tuple[object, float]:
    """Run the pipeline document in memory; stage ``--save-pipeline`` (committed with the outputs): the
    document, or ``saved(document)`` where the command does part of the writing itself (``lod --split``).

    Errors the run reports against the document name the command-line option (:func:`option_for_field`).
    """
    from rigslim.io.atomic import atomic_path
    from rigslim.runtime.run import run_pipeline

    command = pipeline["name"].split("-", 1)[0]
    if getattr(args, "save_pipeline", None):
        with atomic_path(args.save_pipeline) as tmp:
            Path(tmp).write_text(yaml.safe_dump(saved(copy.deepcopy(pipeline)) if saved else pipeline,
                                                sort_keys=False))
    label = f"rigslim {command}"
    t0 = time.perf_counter()
    try:
        result = run_pipeline(Path(label), console=console, raw=copy.deepcopy(pipeline))
    except RigslimError as e:
        _as_option_error(e, command, pipeline, label)
        raise
    return result, time.perf_counter() - t0


def _chain(src: Path, out: Path, make, args, console, tmp: Path, doc=None, saved=None):
    """Run ``make(input, output, skin)`` pipelines once per skin, each reading the previous one's output.

    One skin: one run, ``skin`` None (the reader's default). ``tmp``: a
    :func:`~rigslim.io.atomic.scratch_folder` for the intermediate files; ``doc``: the input's loaded
    document; ``saved``: what ``--save-pipeline`` writes of a run's document (:func:`_run`). Returns
    ``[(pipeline, result, seconds), ...]``.
    """
    from rigslim.io.gltf.document import load_gltf

    skins = [] if is_usd(src) else skins_used((doc or load_gltf(src)).json)    # USD: the reader picks the skeleton
    if len(skins) <= 1:
        pipeline = make(src, out, None)
        return [(pipeline, *_run(pipeline, args, console, saved))]
    if is_usd(out):
        raise InputError(f"{src.name} has {len(skins)} skins; a USD output holds one skeleton's meshes",
                         source=src, field="-o", fix="write glTF, or convert one skin at a time with a pipeline "
                         "(inputs: gltf: {path: IN, skin: N})")
    runs, inp = [], src
    for i, s in enumerate(skins):
        dst = out if i == len(skins) - 1 else tmp / f"skin{s}{out.suffix}"
        pipeline = make(inp, dst, s)
        runs.append((pipeline, *_run(pipeline, args, console, saved)))
        inp = dst
    return runs


@contextlib.contextmanager
def command_session(args, inputs: list[Path], outputs: dict):
    """What each one-command front end runs in: its inputs read once, its outputs checked, one transaction.

    Inside :func:`rigslim.io.gltf.document.read_once`, the glTF inputs are loaded (and yielded, None for
    USD); no output (``outputs``: option -> path, plus ``--report`` and ``--save-pipeline``) may be an
    input or a file one references (:func:`rigslim.io.atomic.refuse_input_as_output`), nor two outputs
    one file; each output's folder must be writable; then every file the command writes is staged in one
    :func:`~rigslim.io.atomic.output_transaction` and committed together when the block ends without error
    (nothing is written otherwise).
    """
    from rigslim.io.atomic import check_output, output_transaction, refuse_input_as_output
    from rigslim.io.gltf.document import load_gltf, read_once
    from rigslim.runtime.run import referenced_files

    outs = dict(outputs)
    for option, path in outputs.items():       # a .gltf output brings its buffer, OUT.bin
        if Path(path).suffix.lower() == ".gltf":
            outs[f"{option} (its buffer)"] = Path(path).with_suffix(".bin")
    for option, attr in (("--report", "report"), ("--save-pipeline", "save_pipeline")):
        if getattr(args, attr, None):
            outs[option] = Path(getattr(args, attr))
    with read_once():
        docs = [None if is_usd(p) else load_gltf(p) for p in inputs]
        refuse_input_as_output(outs, list(inputs) + [f for d in docs if d is not None for f in referenced_files(d)])
        for path in outs.values():
            check_output(path)
        with output_transaction():
            yield docs


def _console(args):
    from rich.console import Console

    return Console(stderr=True, quiet=not args.verbose)


def _emit_report(args, doc: dict) -> None:
    """Stage the ``--report`` document (strict JSON: :func:`rigslim.io.jsonsafe.dumps_strict`)."""
    if getattr(args, "report", None):
        from rigslim.io.atomic import atomic_path
        from rigslim.io.jsonsafe import dumps_strict

        with atomic_path(args.report) as tmp:
            Path(tmp).write_text(dumps_strict(doc, indent=2, default=_jsonable) + "\n")


def _jsonable(x):
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, np.ndarray):
        return x.tolist()
    return str(x)


def _header(command: str) -> dict:
    import rigslim

    return {"schema": REPORT_SCHEMA, "schema_version": REPORT_SCHEMA_VERSION, "command": command,
            "rigslim_version": rigslim.__version__}


def _joint_count(path: Path, doc=None) -> int:
    """The most joints a skin of the file lists (``doc``: the file's loaded document)."""
    if is_usd(path):
        from rigslim.io.usd.summary import joint_count

        return joint_count(path)
    from rigslim.io.gltf.document import load_gltf

    skins = (doc or load_gltf(path)).json.get("skins", [])
    if not skins:
        raise InputError("the file has no skin", source=path, field="skins", fix="give a skinned glTF")
    return max(len(s.get("joints", [])) for s in skins)


def _common(p: argparse.ArgumentParser, clip: bool = True) -> None:
    if clip:
        p.add_argument("--clip", metavar="NAME", help="animation clip (name or index; default the first)")
        p.add_argument("--fps", type=float, default=DEFAULT_FPS, help="frame rate the clip is sampled at (30)")
    p.add_argument("-v", "--verbose", action="store_true", help="step details on stderr")
    p.add_argument("--report", metavar="FILE.json", help=f"write the {REPORT_SCHEMA} document here")
