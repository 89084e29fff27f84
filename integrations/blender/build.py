"""Build the installable Blender extension zip: ``python integrations/blender/build.py [--output DIR]``.

``make blender-extension`` runs this. It checks ``rigslim_blender/blender_manifest.toml`` the way
Blender's extension validator does for the fields this extension uses (required keys and types,
the id, versions, tagline, license and permissions), zips the package folder (leaving out what
``[build] paths_exclude_pattern`` names) as ``DIR/rigslim-VERSION.zip``, and, when Blender's own
command-line tool is at hand (``--blender-ext PATH``, or the ``bpy`` module of ``.venv-blender``,
see tools/setup-blender.sh), runs its ``validate`` on the zip too. Problems are one line each and
exit code 2; nothing is written then.
"""

from __future__ import annotations

import argparse
import fnmatch
import os
import re
import subprocess
import sys
import tempfile
import tomllib
import zipfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
SOURCE = HERE / "rigslim_blender"
MANIFEST = SOURCE / "blender_manifest.toml"
REQUIRED = {"schema_version": str, "id": str, "version": str, "name": str, "tagline": str, "maintainer": str,
            "type": str, "blender_version_min": str, "license": list}
PERMISSIONS = {"files", "network", "clipboard", "camera", "microphone"}
SEMVER = re.compile(r"^\d+\.\d+\.\d+(?:[-+][0-9A-Za-z.-]+)?$")


def manifest_problems(manifest: dict) -> list[str]:
    """What Blender's validator would reject in the manifest (the subset of its checks this extension needs)."""
    out = []
    for key, kind in REQUIRED.items():
        if key not in manifest:
            out.append(f"{key}: missing")
        elif not isinstance(manifest[key], kind):
            out.append(f"{key}: must be a {kind.__name__}")
    if out:
        return out
    if not re.fullmatch(r"[A-Za-z_][A-Za-z0-9_]*", manifest["id"]) or manifest["id"].startswith("_"):
        out.append(f"id: '{manifest['id']}' must be an identifier (letters, digits, underscores, no leading _)")
    for key in ("version", "schema_version"):
        if not SEMVER.match(manifest[key]):
            out.append(f"{key}: '{manifest[key]}' is not a semantic version (X.Y.Z)")
    for key in ("blender_version_min", "blender_version_max"):
        if key in manifest and not re.fullmatch(r"\d+\.\d+\.\d+", manifest[key]):
            out.append(f"{key}: '{manifest[key]}' must be three numbers separated by '.'")
    tagline = manifest["tagline"]
    if not tagline.strip() or len(tagline) > 64 or tagline.rstrip()[-1:] in ".!?" or not tagline[0].isupper():
        out.append("tagline: at most 64 characters, starting with a capital, without a final punctuation mark")
    if manifest["type"] not in ("add-on", "theme"):
        out.append(f"type: '{manifest['type']}' must be add-on or theme")
    if not manifest["license"] or any(not str(x).startswith("SPDX:") for x in manifest["license"]):
        out.append("license: give SPDX identifiers, e.g. [\"SPDX:MIT\"]")
    perms = manifest.get("permissions", {})
    if not isinstance(perms, dict):
        out.append("permissions: must be a table of reasons")
    else:
        for key, why in perms.items():
            if key not in PERMISSIONS:
                out.append(f"permissions: '{key}' is not one of {sorted(PERMISSIONS)}")
            elif not isinstance(why, str) or not why.strip() or why.rstrip().endswith(".") or len(why) > 64:
                out.append(f"permissions.{key}: a reason of at most 64 characters without a final '.'")
    return out


def excluded(rel: str, patterns: list[str]) -> bool:
    """Whether a path relative to the package folder matches a ``paths_exclude_pattern`` entry (gitignore-like)."""
    parts = rel.split("/")
    for pat in patterns:
        if pat.endswith("/"):
            name = pat.strip("/")
            if any(fnmatch.fnmatch(p, name) for p in parts[:-1]) or (pat.startswith("/") and parts[0] == name):
                return True
        elif any(fnmatch.fnmatch(p, pat) for p in parts):
            return True
    return False


def package_files(patterns: list[str]) -> list[Path]:
    files = []
    for root, _dirs, names in os.walk(SOURCE):
        for name in names:
            path = Path(root) / name
            rel = path.relative_to(SOURCE).as_posix()
            if not excluded(rel, patterns) and not excluded(rel + ("/" if path.is_dir() else ""), patterns):
                files.append(path)
    return sorted(files)


def find_blender_ext(explicit: str | None) -> Path | None:
    if explicit:
        return Path(explicit)
    venv = HERE.parent.parent / ".venv-blender" / "lib"
    hits = sorted(venv.glob("python3*/site-packages/bpy/*/scripts/addons_core/bl_pkg/cli/blender_ext.py"))
    return hits[-1] if hits else None


def build(output: Path, blender_ext: Path | None) -> Path:
    with open(MANIFEST, "rb") as fh:
        try:
            manifest = tomllib.load(fh)
        except tomllib.TOMLDecodeError as exc:
            raise SystemExit(f"{MANIFEST}: not TOML ({exc})") from None
    problems = manifest_problems(manifest)
    if problems:
        raise SystemExit(f"{MANIFEST}: " + "; ".join(problems))
    patterns = manifest.get("build", {}).get("paths_exclude_pattern", [])
    output.mkdir(parents=True, exist_ok=True)
    target = output / f"{manifest['id']}-{manifest['version']}.zip"
    fd, tmp = tempfile.mkstemp(suffix=".zip", dir=output)
    os.close(fd)
    try:
        with zipfile.ZipFile(tmp, "w", zipfile.ZIP_DEFLATED) as zf:
            for path in package_files(patterns):
                zf.write(path, path.relative_to(SOURCE).as_posix())
        if blender_ext is not None:
            proc = subprocess.run([sys.executable, str(blender_ext), "validate", tmp], capture_output=True, text=True)
            if proc.returncode != 0:
                msg = (proc.stdout + proc.stderr).strip().splitlines()
                raise SystemExit(f"{target}: Blender's validator: {msg[-1] if msg else proc.returncode}")
        os.replace(tmp, target)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
    return target


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--output", default="dist", help="folder for the zip (default: dist)")
    ap.add_argument("--blender-ext", default=None, help="Blender's bl_pkg/cli/blender_ext.py (default: found in "
                    ".venv-blender, else skipped)")
    args = ap.parse_args(argv)
    try:
        ext = find_blender_ext(args.blender_ext)
        target = build(Path(args.output), ext)
    except SystemExit as exc:
        print(exc.code, file=sys.stderr)
        return 2
    print(f"{target} ({'validated by ' + str(ext) if ext else 'Blender validator not found: manifest checked here'})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
