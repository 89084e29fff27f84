"""The ``rigslim`` command line.

``rigslim run PIPELINE.yaml [--metrics FILE.json] [--set STEP.PARAM=VALUE | STEP=PLUGIN]``
runs a pipeline; ``rigslim report METRICS.json [...] -o report.html`` writes an
HTML report of runs; ``rigslim plugins [NAME] [--json]`` lists loaded plugins (or one plugin's
parameters). Errors a
user can cause print one line and exit with status 2.
"""

from __future__ import annotations

import argparse
import os
import sys

from rigslim.commands.compare import cmd_compare
from rigslim.commands.gltf_common import _common
from rigslim.commands.inspect import cmd_inspect
from rigslim.commands.lod import cmd_lod
from rigslim.commands.lod_levels import add_level_arguments
from rigslim.commands.plugins import _cmd_plugins
from rigslim.commands.reduce import cmd_reduce
from rigslim.commands.report import _cmd_report
from rigslim.commands.run import _cmd_run
from rigslim.errors import RigslimError

EXIT_USER_ERROR = 2
#: A defect of rigslim (an exception no check turned into a one-line error).
EXIT_BUG = 1


def _traceback_wanted() -> bool:
    """``RIGSLIM_TRACEBACK`` set to anything but ``""``, ``0``, ``false``, ``no`` or ``off``."""
    return os.environ.get("RIGSLIM_TRACEBACK", "").strip().lower() not in ("", "0", "false", "no", "off")


def build_parser() -> argparse.ArgumentParser:
    import rigslim

    parser = argparse.ArgumentParser(prog="rigslim", description="Reduce skin weights and cage coordinates "
                                     "to k per vertex, and simplify articulated meshes.")
    parser.add_argument("--version", action="version", version=f"rigslim {rigslim.__version__}")
    sub = parser.add_subparsers(dest="command", required=True)
    run = sub.add_parser("run", help="run a YAML pipeline")
    run.add_argument("pipeline", help="pipeline YAML file")
    run.add_argument("--metrics", metavar="FILE.json", help="write the metrics document here")
    run.add_argument("--set", action="append", metavar="STEP.PARAM=VALUE",
                     help="override a step parameter, or with STEP=PLUGIN replace a step's plugin "
                          "(STEP: step name, stage key, plugin or 1-based index)")
    run.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    run.add_argument("--allow-external-uris", action="store_true",
                     help="let glTF buffer/image URIs name files outside the glTF's folder (trusted files only)")
    run.set_defaults(func=_cmd_run)
    report = sub.add_parser("report", help="HTML report of metrics JSON files (table, plots, renders)")
    report.add_argument("metrics", nargs="+", metavar="METRICS.json",
                        help="metrics documents of 'rigslim run', or one DIR/summary.csv of 'rigslim batch'")
    report.add_argument("-o", "--output", required=True, metavar="REPORT.html", help="write the report here")
    report.add_argument("--png-dir", metavar="DIR", help="also write the renders as PNG files here")
    report.add_argument("--frames", metavar="F1,F2", help="animation frames to render (default: the worst test frame)")
    report.add_argument("--size", default="320x270", metavar="WxH", help="size of each render (default 320x270)")
    report.add_argument("--backend", choices=["auto", "opengl", "numpy"], default="auto",
                        help="renderer (auto: OpenGL through EGL when available, else numpy)")
    report.add_argument("--projection", choices=["perspective", "orthographic"], default="perspective")
    report.add_argument("--azimuth", type=float, default=30.0, help="view direction around the up axis (degrees)")
    report.add_argument("--elevation", type=float, default=15.0, help="view elevation (degrees)")
    report.add_argument("--up-axis", type=int, choices=[0, 1, 2], default=1, help="world axis pointing up")
    report.add_argument("--title", help="page title")
    report.add_argument("--no-renders", action="store_true", help="table and plots only")
    report.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    report.add_argument("--allow-external-uris", action="store_true",
                        help="let glTF buffer/image URIs name files outside the glTF's folder (trusted files only)")
    report.set_defaults(func=_cmd_report)
    plugins = sub.add_parser("plugins", help="list loaded plugins, or one plugin's parameters")
    plugins.add_argument("name", nargs="?", metavar="NAME",
                         help="a plugin's name: its parameters with types, defaults and descriptions")
    plugins.add_argument("--json", action="store_true", help="machine-readable output")
    plugins.set_defaults(func=_cmd_plugins)
    from rigslim.commands.cli import add_commands  # reduce, lod, compare, inspect (docs/gltf.md)

    add_commands(sub)
    from rigslim.commands.batch import add_parser as add_batch_parser

    add_batch_parser(sub)
    return parser


class _Terminated(KeyboardInterrupt):
    """SIGTERM, unwound like Ctrl-C so that staged outputs are removed (docs/pipelines.md, Guarantees)."""


def _terminate(signum, frame):
    raise _Terminated


def main(argv=None) -> int:
    import os
    import signal
    import threading
    import warnings

    from rigslim.plugin.host import PluginLoadWarning

    parser = build_parser()
    args = parser.parse_args(argv)
    previous = None
    if threading.current_thread() is threading.main_thread():
        previous = signal.signal(signal.SIGTERM, _terminate)
    allow_before = os.environ.get("RIGSLIM_ALLOW_EXTERNAL_URIS")
    if getattr(args, "allow_external_uris", False):  # read by the glTF reader (rigslim.io.gltf)
        os.environ["RIGSLIM_ALLOW_EXTERNAL_URIS"] = "1"
    try:
        # Warnings (numpy's RuntimeWarnings...) are held until the command ends: shown after a success,
        # dropped when a one-line error explains what went wrong.
        with warnings.catch_warnings(record=True) as caught:
            code = args.func(args)
        for w in caught:
            if issubclass(w.category, PluginLoadWarning):  # a skipped plugin package: one line, no source line
                print(f"rigslim: warning: {w.message}", file=sys.stderr)
                continue
            warnings.showwarning(w.message, w.category, w.filename, w.lineno, line=w.line)
        return code
    except RigslimError as e:
        print(f"rigslim: error: {e.one_line()}", file=sys.stderr)
        if _traceback_wanted():  # a plugin's failure (PluginError) chains the original
            import traceback

            traceback.print_exception(e)
        return EXIT_USER_ERROR
    except KeyboardInterrupt as e:
        print("rigslim: interrupted; every output is either unchanged or complete", file=sys.stderr)
        return 143 if isinstance(e, _Terminated) else 130
    except OSError as e:  # an I/O error no reader or writer turned into a RigslimError: still one line
        where = f"{e.filename}: " if e.filename else ""
        print(f"rigslim: error: {where}{e.strerror or e} (fix: check the path, its permissions and the free space)",
              file=sys.stderr)
        return EXIT_USER_ERROR
    except Exception as e:  # noqa: BLE001 - a defect of rigslim's own: one line, the traceback on request
        from rigslim.errors import clip

        print(f"rigslim: error: {type(e).__name__}: {clip(str(e), 160)} (fix: a bug in rigslim: please report it; "
              f"RIGSLIM_TRACEBACK=1 prints the traceback)", file=sys.stderr)
        if _traceback_wanted():
            import traceback

            traceback.print_exception(e)
        return EXIT_BUG
    finally:
        if previous is not None:
            signal.signal(signal.SIGTERM, previous)
        if getattr(args, "allow_external_uris", False):
            if allow_before is None:
                os.environ.pop("RIGSLIM_ALLOW_EXTERNAL_URIS", None)
            else:
                os.environ["RIGSLIM_ALLOW_EXTERNAL_URIS"] = allow_before


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())


def add_commands(sub) -> None:
    """Register ``reduce``, ``lod``, ``compare`` and ``inspect`` on the ``rigslim`` subparsers."""
    p = sub.add_parser("reduce", help="reduce a skinned glTF's influences to k per vertex (one command)")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("-o", "--output", required=True, metavar="OUT.glb")
    p.add_argument("-k", type=int, default=4, help="influences per vertex (1..8; default 4)")
    p.add_argument("--select", default=None, metavar="NAME[:BY]",
                   help="influence selection: best-fit:error (default; best-fit alone means it too), best-fit:weight, "
                   "k-largest (the baseline)")
    p.add_argument("--by", choices=["error", "weight"], help="best-fit: keep the set of least example-pose error "
                   "or the largest fitted weights (same as --select best-fit:BY)")
    p.add_argument("--solve", default="geometric", help="weight solver (geometric, poisson, smooth, k-largest)")
    p.add_argument("--quantize", choices=["ubyte", "ushort", "float"], default="ubyte")
    p.add_argument("--save-pipeline", metavar="FILE.yaml", help="also write the pipeline this command runs")
    _common(p)
    p.set_defaults(func=cmd_reduce)

    p = sub.add_parser("lod", help="skinned LOD chain (MSFT_lod, or one file per level) in one command")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("-o", "--output", required=True, metavar="OUT.glb")
    p.add_argument("--ratios", default="0.5,0.25", help="fractions of the faces, decreasing (default 0.5,0.25)")
    p.add_argument("--max-bones", type=int, default=4, help="influences per vertex at every level (default 4)")
    p.add_argument("--method", default="quartic", help="decimator (quartic, mohr-gleicher, decoro-rusinkiewicz, "
                   "static-qslim: no error bound)")
    p.add_argument("--quantize", choices=["ubyte", "ushort", "float"], default="ubyte")
    p.add_argument("--max-error", default="1%", metavar="E",
                   help="stop a level where the error would pass E: %% of the world diagonal (1, 1%%), metres "
                        "(0.02m), or none (default 1%%)")
    p.add_argument("--keep-parts", action="store_true",
                   help="never remove a part whole: a level that the collapses cannot bring to its target stops "
                        "there (default: the smallest parts nearest to the rest go, within --max-error)")
    p.add_argument("--split", action="store_true", help="one file per level: OUT-50.glb, OUT-25.glb")
    p.add_argument("--measure", action="store_true", help="also measure each level (metro) on the test frames")
    add_level_arguments(p)
    p.add_argument("--save-pipeline", metavar="FILE.yaml", help="also write the pipeline this command runs")
    _common(p)
    p.set_defaults(func=cmd_lod)

    p = sub.add_parser("compare", help="test-pose Hausdorff distance of a skinned glTF to a reference")
    p.add_argument("reference", metavar="REF.glb")
    p.add_argument("candidate", metavar="CANDIDATE.glb")
    p.add_argument("--frames", metavar="a:b:c", help="frames of the clip at --fps (default: every frame)")
    p.add_argument("--level", type=int, default=0, help="MSFT_lod level of the candidate (0: full meshes)")
    p.add_argument("--samples", type=int, default=20000,
                   help="random surface samples per direction and frame (every vertex is measured too)")
    p.add_argument("--hausdorff-frames", type=int, metavar="N",
                   help="Hausdorff on N evenly spread frames, 0 = all (default: all; 3 above 500k triangles)")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _common(p)
    p.set_defaults(func=cmd_compare)

    p = sub.add_parser("inspect", help="skins, joints, clips, primitives, attributes and influences of a glTF")
    p.add_argument("input", metavar="IN.glb")
    p.add_argument("--json", action="store_true", help="print one JSON object")
    _common(p, clip=False)
    p.set_defaults(func=cmd_inspect)
