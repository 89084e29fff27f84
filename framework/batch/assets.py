"""The assets of a batch and the pipeline each one runs.

``rigslim batch TEMPLATE.yaml ASSETS... --out DIR`` turns an ordinary pipeline
(the template) into one pipeline per asset:

- ASSETS are asset files, directories (searched recursively for
  :data:`ASSET_SUFFIXES`) or manifest CSV files whose ``asset`` column names
  the files (relative to the CSV's folder) and whose other columns are
  per-asset overrides (see :func:`apply_overrides`);
- in every string of the template, ``{input}`` becomes the asset's absolute
  path and ``{name}`` its name (the file's stem; see :func:`unique_names`);
- input paths of the template that are relative are made absolute (relative
  to the template's folder, as ``rigslim run`` reads them), and the result is
  written as ``DIR/<name>/pipeline.yaml``, so relative write paths land in
  ``DIR/<name>/`` and ``rigslim run DIR/<name>/pipeline.yaml`` reruns the asset
  exactly.
"""

from __future__ import annotations

import copy
import csv
import hashlib
import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from rigslim.errors import InputError, PipelineError, closest

#: File types a directory is searched for (glTF and the mesh readers' formats).
ASSET_SUFFIXES = (".glb", ".gltf", ".usd", ".usda", ".usdc", ".usdz", ".obj", ".off", ".ply", ".stl", ".mesh")

#: Manifest columns that are short names of input settings.
INPUT_ALIASES = {"clip": "animation", "fps": "fps"}

#: Manifest columns that are not overrides.
RESERVED_COLUMNS = ("asset", "name")


@dataclass
class AssetJob:
    """One asset of a batch.

    Parameters
    ----------
    path : absolute path of the asset file
    name : unique name; its outputs go to ``DIR/<name>/``
    overrides : manifest column -> raw cell text (empty cells are left out)
    source : where the asset was named ("a.csv row 3", "the command line", a directory)
    """

    path: Path
    name: str
    overrides: dict[str, str] = field(default_factory=dict)
    source: str = "the command line"
    manifest_dir: Path | None = None

    def as_dict(self) -> dict:
        return {"path": str(self.path), "name": self.name, "overrides": dict(self.overrides),
                "source": self.source, "manifest_dir": str(self.manifest_dir) if self.manifest_dir else None}

    @classmethod
    def from_dict(cls, d: dict) -> AssetJob:
        return cls(Path(d["path"]), d["name"], dict(d["overrides"]), d["source"],
                   Path(d["manifest_dir"]) if d.get("manifest_dir") else None)


def read_manifest(path: Path) -> list[AssetJob]:
    """Rows of a manifest CSV: ``asset`` (required), optional ``name``, override columns."""
    try:
        with open(path, newline="", encoding="utf-8-sig") as fh:
            reader = csv.DictReader(fh)
            header = [h.strip() for h in (reader.fieldnames or [])]
            rows = list(reader)
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise InputError(f"cannot read the manifest ({getattr(e, 'strerror', None) or e})", source=path,
                         field="file", fix="give a UTF-8 CSV file with an 'asset' column") from None
    if "asset" not in header:
        raise InputError("the manifest has no 'asset' column", source=path, field="header",
                         fix="start the CSV with a header line such as 'asset,k'")
    if len(set(header)) != len(header):
        raise InputError("the manifest repeats a column name", source=path, field="header",
                         fix="give every column once")
    jobs = []
    for i, row in enumerate(rows, 2):  # line 1 is the header
        row = {(k or "").strip(): (v or "").strip() if isinstance(v, str) else v for k, v in row.items()}
        if None in row or "" in row and row[""]:
            raise InputError(f"line {i} has more cells than the header", source=path, field=f"line {i}",
                             fix="quote cells that contain commas")
        asset = row.get("asset") or ""
        if not asset:
            raise InputError(f"line {i} names no asset", source=path, field=f"line {i}.asset",
                             fix="give the asset's path (relative to the manifest's folder)")
        p = Path(asset).expanduser()
        p = p if p.is_absolute() else path.parent / p
        overrides = {k: v for k, v in row.items() if k not in RESERVED_COLUMNS and k and v not in ("", None)}
        jobs.append(AssetJob(p.resolve(), row.get("name") or "", overrides, f"{path} line {i}",
                             path.parent.resolve()))
    return jobs


def collect_assets(items) -> list[AssetJob]:
    """Expand the command line's ASSETS into jobs with unique names, in the given order."""
    jobs: list[AssetJob] = []
    for item in items:
        p = Path(item).expanduser()
        if p.is_dir():
            found = sorted(q for q in p.rglob("*") if q.is_file() and q.suffix.lower() in ASSET_SUFFIXES
                           and not any(part.startswith(".") for part in q.relative_to(p).parts))
            if not found:
                raise InputError("the directory holds no asset files", source=p, field="ASSETS",
                                 fix="give files with suffix " + ", ".join(ASSET_SUFFIXES))
            jobs += [AssetJob(q.resolve(), "", {}, str(p)) for q in found]
        elif p.suffix.lower() == ".csv":
            if not p.is_file():
                raise InputError("manifest not found", source=p, field="ASSETS", fix="check the path")
            jobs += read_manifest(p)
        elif not p.is_file():       # refused here, before a cluster starts
            raise InputError("asset not found" if not p.exists() else "not a file or a folder", source=p,
                             field="ASSETS", fix="name asset files, folders of assets or a manifest .csv")
        else:
            jobs.append(AssetJob(p.resolve(), "", {}, "the command line"))
    if not jobs:
        raise InputError("no assets given", field="ASSETS", fix="name asset files, directories or a manifest CSV")
    seen: dict[Path, str] = {}
    unique = []
    for j in jobs:  # the same file named twice runs once (a manifest row wins: it may carry overrides)
        if j.path in seen:
            continue
        seen[j.path] = j.source
        unique.append(j)
    unique_names(unique)
    return unique


def unique_names(jobs: list[AssetJob]) -> None:
    """Name each job by its stem; stems shared by several files get ``-<6 hex digits of the path's hash>``.

    The suffix depends only on the file's path, so adding assets to a batch
    never renames the outputs of others (and resuming still finds them).
    """
    stems: dict[str, int] = {}
    for j in jobs:
        if not j.name:
            stems[j.path.stem] = stems.get(j.path.stem, 0) + 1
    names = set()
    for j in jobs:
        if not j.name:
            j.name = j.path.stem if stems[j.path.stem] == 1 else \
                f"{j.path.stem}-{hashlib.sha1(str(j.path).encode()).hexdigest()[:6]}"
        if j.name in names or j.name in ("", ".", "..") or "/" in j.name or j.name.startswith("."):
            raise InputError(f"asset name '{j.name}' is used twice or is not a folder name", source=j.source,
                             field="name", fix="give each asset a distinct 'name' in the manifest")
        names.add(j.name)


def load_template(path) -> dict:
    """Read the template YAML as a mapping (checked further by :func:`check_template`)."""
    path = Path(path)
    try:
        raw = yaml.safe_load(path.read_text())
    except OSError as e:
        raise PipelineError(f"cannot read the template ({e.strerror})", source=path, field="path",
                            fix="check the path") from None
    except yaml.YAMLError as e:
        mark = getattr(e, "problem_mark", None)
        where = f"line {mark.line + 1}, column {mark.column + 1}" if mark else "YAML"
        raise PipelineError(f"malformed YAML ({getattr(e, 'problem', None) or e})", source=path, field=where,
                            fix="fix the YAML syntax") from None
    if not isinstance(raw, dict):
        raise PipelineError("the template is not a mapping", source=path, field="top level",
                            fix="write an ordinary pipeline with 'inputs:' and 'steps:'")
    if "{input}" not in json.dumps(raw):
        raise PipelineError("the template never uses {input}", source=path, field="inputs",
                            fix="write the asset's place as '{input}', e.g. inputs: {gltf: '{input}'}")
    return raw


def _substitute(value, subs: dict[str, str]):
    if isinstance(value, str):
        for k, v in subs.items():
            value = value.replace("{" + k + "}", v)
        return value
    if isinstance(value, dict):
        return {k: _substitute(v, subs) for k, v in value.items()}
    if isinstance(value, list):
        return [_substitute(v, subs) for v in value]
    return value


def _is_path_input(role: str, value, inputs: dict) -> bool:
    """Whether an ``inputs`` entry names a file (a glTF clip name or a flag does not)."""
    if role == "normalize":
        return False
    if "gltf" in inputs and role in ("animation", "fps"):
        return isinstance(value, str) and value.lower().endswith(".dmat")
    return isinstance(value, (str, dict))


def _absolute(value, base: Path):
    if isinstance(value, str):
        p = Path(value).expanduser()
        return str(p if p.is_absolute() else (base / p).resolve())
    if isinstance(value, dict) and isinstance(value.get("path"), str):
        return {**value, "path": _absolute(value["path"], base)}
    return value


def _parse_value(text: str):
    """A manifest cell as YAML (``4``, ``true``, ``[0.1, 0.02]``); ``1e-6`` is a number too (YAML 1.1 says string)."""
    try:
        value = yaml.safe_load(text)
    except yaml.YAMLError:
        return text
    if isinstance(value, str):
        try:
            return float(value)
        except ValueError:
            pass
    return value


def _step_key(raw: dict) -> str | None:
    from rigslim.plugin.contract import STEP_STAGES

    keys = [k for k in raw if k in STEP_STAGES]
    return keys[0] if len(keys) == 1 else None


def _step_names(raw: dict, index: int) -> set[str]:
    key = _step_key(raw)
    if key is None:
        return set()
    names = {key, str(index)}
    if isinstance(raw[key], str) and key not in ("write", "report"):
        names.add(raw[key])
    names.add(str(raw.get("name") or (raw[key] if key not in ("evaluate", "write", "report")
                                      and isinstance(raw[key], str) else f"{key}{index}")))
    return names


def _plugin_fields(raw: dict) -> set[str]:
    """Parameter names of a step's plugin (empty when it cannot be looked up)."""
    from rigslim.plugin.contract import STEP_STAGES
    from rigslim.plugin.host import get_host

    key = _step_key(raw)
    if key is None or key in ("evaluate", "write", "report") or not isinstance(raw[key], str):
        return set()
    try:
        return set(get_host().get(STEP_STAGES[key], raw[key]).Params.model_fields)
    except Exception:  # an unknown plugin is reported by load_pipeline, with its fix
        return set()


def override_targets(doc: dict, column: str) -> list[tuple[str, Any]]:
    """Where a manifest column applies in a pipeline document.

    Returns ``[("inputs", role_or_role.key)]`` or ``[("step", (index, param)), ...]``;
    empty when the column names nothing.

    Columns are ``inputs.ROLE`` / ``inputs.ROLE.KEY``, the aliases ``clip``
    (the glTF clip, ``inputs.animation``) and ``fps``, ``STEP.PARAM`` (the
    ``--set`` syntax: STEP is a step's name, stage key, plugin or 1-based
    index) and a bare ``PARAM``, which sets that parameter on every step
    whose plugin takes it (``k`` sets the selection's k).
    """
    if column in INPUT_ALIASES:
        return [("inputs", INPUT_ALIASES[column])]
    if column.startswith("inputs.") and len(column) > 7:
        return [("inputs", column[7:])]
    steps = doc.get("steps") or []
    if "." in column:
        target, param = column.rsplit(".", 1)
        return [("step", (i, param)) for i, s in enumerate(steps, 1)
                if isinstance(s, dict) and target in _step_names(s, i)]
    return [("step", (i, column)) for i, s in enumerate(steps, 1)
            if isinstance(s, dict) and column in _plugin_fields(s)]


def check_columns(template: dict, jobs: list[AssetJob]) -> None:
    """Every override column of every manifest must apply to the template; else a one-line error."""
    seen = set()
    for j in jobs:
        for col in j.overrides:
            if col in seen:
                continue
            if not override_targets(template, col):
                names = sorted({n for i, s in enumerate(template.get("steps") or [], 1) if isinstance(s, dict)
                                for n in _step_names(s, i)})
                raise InputError(f"column '{col}' sets nothing in the template", source=j.source.rsplit(" line", 1)[0],
                                 field=f"column {col}",
                                 fix="name a parameter of a step (e.g. 'k', 'select.k'), 'clip', 'fps' or "
                                     f"'inputs.ROLE'; steps: {', '.join(names) or 'none'}"
                                     if "." not in col else closest(col.rsplit(".", 1)[0], names))
            seen.add(col)


def apply_overrides(doc: dict, overrides: dict[str, str], manifest_dir: Path | None) -> dict:
    """Set the manifest's per-asset values in a (substituted) pipeline document; returns a new one."""
    doc = copy.deepcopy(doc)
    for col, text in overrides.items():
        value = _parse_value(text)
        for kind, where in override_targets(doc, col):
            if kind == "inputs":
                inputs = doc.setdefault("inputs", {}) or {}
                doc["inputs"] = inputs
                role, _, key = where.partition(".")
                if isinstance(value, str) and manifest_dir is not None and (manifest_dir / value).exists():
                    value = str((manifest_dir / value).resolve())
                if key:
                    spec = inputs.get(role)
                    spec = {"path": spec} if isinstance(spec, str) else dict(spec or {})
                    spec[key] = value
                    inputs[role] = spec
                else:
                    inputs[role] = value
            else:
                index, param = where
                doc["steps"][index - 1][param] = value
    return doc


def asset_pipeline(template: dict, template_path: Path, job: AssetJob) -> dict:
    """The pipeline document of one asset: substituted, overridden, its input paths absolute."""
    doc = _substitute(template, {"input": str(job.path), "name": job.name})
    doc = apply_overrides(doc, job.overrides, job.manifest_dir)
    base = Path(template_path).resolve().parent
    inputs = doc.get("inputs")
    if isinstance(inputs, dict):
        doc["inputs"] = {role: _absolute(v, base) if _is_path_input(role, v, inputs) else v
                         for role, v in inputs.items()}
    return doc


def _usd_dependencies(path: Path) -> list[Path]:
    """Local files a USD layer composes (sublayers, references, payloads, textures), as USD resolves them."""
    try:
        from pxr import Sdf, UsdUtils

        layers, assets, _ = UsdUtils.ComputeAllDependencies(Sdf.AssetPath(str(path)))
    except Exception:       # noqa: BLE001 - no usd-core, or a file the reader will refuse in one line anyway
        return []
    found = [Path(layer.realPath) for layer in layers if layer.realPath] + [Path(a) for a in assets]
    return [p for p in dict.fromkeys(found) if p.is_file() and p.resolve() != path.resolve()]


def pipeline_hash(doc: dict) -> str:
    """sha256 of the pipeline document's canonical JSON (keys sorted)."""
    return hashlib.sha256(json.dumps(doc, sort_keys=True, default=str).encode()).hexdigest()


def input_files(path: Path) -> list[Path]:
    """The asset file, and for a ``.gltf`` the local files its buffers and images name (for a USD layer,
    the layers and assets it composes)."""
    files = [path]
    if path.suffix.lower() in (".usd", ".usda", ".usdc"):
        return files + _usd_dependencies(path)
    if path.suffix.lower() == ".gltf":
        try:
            js = json.loads(path.read_text())
        except (OSError, ValueError, UnicodeDecodeError):
            return files
        for kind in ("buffers", "images"):
            for item in js.get(kind) or []:
                uri = item.get("uri") if isinstance(item, dict) else None
                if isinstance(uri, str) and not uri.startswith("data:") and "://" not in uri:
                    from urllib.parse import unquote

                    q = path.parent / unquote(uri)
                    if q.is_file():
                        files.append(q)
    return files


def input_hash(path: Path) -> str:
    """sha256 over the asset's files (see :func:`input_files`), read in 1 MiB blocks."""
    h = hashlib.sha256()
    for f in input_files(path):
        with open(f, "rb") as fh:
            while block := fh.read(1 << 20):
                h.update(block)
    return h.hexdigest()
