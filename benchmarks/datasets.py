"""Benchmark inputs: the bundled elephant, and the elephant subdivided with weights interpolated.

Midpoint subdivision (``igl.upsample``: each triangle into four, new vertices
at edge midpoints, old vertices unmoved) keeps the surface and the motion:
a new vertex's weights are the mean of its edge's endpoint weights, exactly
what linear interpolation of the weight functions gives.

| levels | vertices | triangles |
|---|---|---|
| 0 | 6,034 | 12,064 |
| 1 | 24,130 | 48,256 |
| 2 | ~96.5k | ~193k |
| 3 | ~386k | ~772k |

Example
-------
>>> from benchmarks.datasets import elephant
>>> asset = elephant(levels=1)   # doctest: +SKIP
"""

from __future__ import annotations

import json
import os
import platform
from pathlib import Path

import numpy as np
import scipy.sparse as sp

ROOT = Path(__file__).resolve().parents[1]
DATA = ROOT / "examples" / "data"
EXAMPLES = "0:457:45"
TEST = "5:457:7"


def elephant(levels: int = 0, examples: str = EXAMPLES, test: str = TEST):
    """The elephant asset, subdivided ``levels`` times (weights interpolated).

    Returns
    -------
    rigslim.model.asset.Asset
        mesh, skeleton handles, weights (csr, rows sum to 1), all 457 poses and
        the split (example frames ``0:457:45``, test frames ``5:457:7`` minus 180).
    """
    from rigslim.io import read_dmat, read_mesh, read_stacked_animation, read_tgf
    from rigslim.model.asset import Asset
    from rigslim.model.poses import FrameSplit
    from rigslim.model.weights import validate_weights

    mesh = read_mesh(DATA / "elephant.obj")
    handles = read_tgf(DATA / "elephant.tgf")
    W = validate_weights(read_dmat(DATA / "elephant-weights.dmat"), mesh.n_vertices, n_handles=handles.n)
    if levels > 0:
        mesh, W = subdivide(mesh, W, levels)
    poses = read_stacked_animation(DATA / "elephant-anim.dmat", n_handles=handles.n)
    split = FrameSplit.from_specs(examples, test, len(poses))
    return Asset(mesh=mesh, handles=handles, weights=W, poses=poses, split=split,
                 provenance={"inputs": {"mesh": f"elephant.obj subdivided {levels}x"}})


def subdivide(mesh, W, levels: int):
    """Midpoint-subdivide a mesh ``levels`` times, interpolating the weights linearly."""
    import igl

    from rigslim.model.mesh import Mesh

    V, F = mesh.V, mesh.F
    Wd = sp.csr_matrix(W).toarray()
    stacked = np.hstack([V, Wd])
    S, F2 = igl.upsample(stacked, F, levels)
    V2, W2 = S[:, :3], S[:, 3:]
    W2[np.abs(W2) < 1e-12] = 0.0
    return Mesh(V2, F2, source=f"{mesh.source} (subdivided {levels}x)"), sp.csr_matrix(W2)


def cpu_model() -> str:
    """The CPU's model name (``/proc/cpuinfo``), for the machine line of every results table."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def machine() -> dict:
    """``{"cpu", "nproc", "python"}`` of this machine."""
    return {"cpu": cpu_model(), "nproc": os.cpu_count(), "python": platform.python_version()}


def write_results(stem, doc: dict, markdown: str) -> None:
    """Write ``stem.json`` (the document) and ``stem.md`` (its table) atomically."""
    from rigslim.io.atomic import atomic_path

    stem = Path(stem)
    stem.parent.mkdir(parents=True, exist_ok=True)
    with atomic_path(stem.with_suffix(".json")) as tmp:
        tmp.write_text(json.dumps(doc, indent=2) + "\n")
    with atomic_path(stem.with_suffix(".md")) as tmp:
        tmp.write_text(markdown)


# --- the real-character suite (examples/data/gltf/suite/, index suite.json; provenance in its README) ---------

SUITE = DATA / "gltf" / "suite"


class SuiteCharacter:
    """One character of the real-character suite, as ``examples/data/gltf/suite/suite.json`` lists it.

    Attributes
    ----------
    name, path, kind : str, Path, str
    faces, vertices, joints, primitives : int
    clips : list of dict
        ``{"name", "duration" (s), "keys", "channels"}`` in file order.
    fit_clips, holdout_clips : list of str
        Clips to fit example poses on, and clips held out for testing (empty
        for one-clip characters: then ``single_clip_split`` gives fit and test
        frame specs of that clip at 30 fps).
    textured : bool
        Some primitive has a base-colour texture and UVs.
    test_renders : list of dict
        ``{"clip", "time"}``: poses to render and compare.
    view : dict
        ``front_azimuth`` / ``side_azimuth`` (degrees about +y, 0 = camera on +z), ``elevation``.
    entry : dict
        The whole index entry (licence, source package, sha256...).
    """

    def __init__(self, entry: dict, root: Path | None = None):
        self.entry = entry
        self.name = entry["name"]
        if root is None:                                   # the bundled indexes: files under examples/data/gltf
            self.path = SUITE.parent / entry["file"]
        else:                                              # an index elsewhere (tools/suite/sweep.py's): beside it
            nested = root / entry["file"]
            self.path = nested if nested.exists() else root / Path(entry["file"]).name
        for key in ("kind", "faces", "vertices", "joints", "primitives", "clips", "fit_clips", "holdout_clips",
                    "textured", "test_renders", "view"):
            setattr(self, key, entry[key])

    @property
    def clip_names(self) -> list[str]:
        return [c["name"] for c in self.clips]

    @property
    def multi_clip(self) -> bool:
        """Two or more clips, so that held-out clips can be tested."""
        return bool(self.holdout_clips)

    def read(self, clip=None, fps: float = 30.0, **kwargs):
        """The character as rigslim reads it (``rigslim.io.gltf.skin.read_gltf_skin``), posed over ``clip``."""
        from rigslim.io.gltf.skin import read_gltf_skin

        return read_gltf_skin(self.path, animation=clip if clip is not None else self.fit_clips[0], fps=fps,
                              **kwargs)

    def __repr__(self) -> str:
        return (f"SuiteCharacter({self.name!r}: {self.faces} faces, {self.joints} joints, "
                f"{len(self.clips)} clips)")


HOLDOUT = DATA / "gltf" / "holdout"


def suite(names=None, *, min_joints: int = 0, multi_clip: bool | None = None,
          textured: bool | None = None, group: str = "suite") -> list[SuiteCharacter]:
    """The suite's characters (index order), optionally filtered.

    Parameters
    ----------
    group : {"suite", "holdout", "all"}
        The development suite (``suite/suite.json``), the hold-out characters (``holdout/holdout.json``:
        built after the methods were chosen, never used to tune them), or both.
    names : iterable of str, optional
        Only these (unknown names raise ``KeyError`` listing the known ones).
    min_joints : int
        Only characters with at least this many joints (e.g. 30 for joint budgets).
    multi_clip, textured : bool, optional
        Only characters with (True) or without (False) held-out clips / a texture.

    Example
    -------
    >>> [c.name for c in suite(min_joints=30, multi_clip=True)]   # doctest: +SKIP
    ['wuson', 'frankie', 'snoutx10k', 're_player']
    """
    if group not in ("suite", "holdout", "all"):
        raise ValueError(f"group {group!r}: use suite, holdout or all")
    files = {"suite": [SUITE / "suite.json"], "holdout": [HOLDOUT / "holdout.json"]}
    files["all"] = files["suite"] + files["holdout"]
    chars = _named([SuiteCharacter(e) for f in files[group] for e in json.loads(f.read_text())["characters"]],
                   names, "no suite character {missing}")
    return [c for c in chars if c.joints >= min_joints and (multi_clip is None or c.multi_clip == multi_clip)
            and (textured is None or c.textured == textured)]


def index_characters(index: Path, names=None) -> list[SuiteCharacter]:
    """The characters of an index file in ``build.py``'s format that lies outside the repository, such as the
    ``index.json`` that ``tools/suite/sweep.py --out FOLDER`` writes, each file found beside the index.

    ``names``: only these (unknown names raise ``KeyError`` listing the known ones). A missing or malformed
    index raises ``ValueError`` naming the file.
    """
    index = Path(index)
    try:
        entries = json.loads(index.read_text())["characters"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise ValueError(f"{index}: not a character index with a 'characters' list ({type(e).__name__}: {e}); "
                         "build one with tools/suite/sweep.py --out FOLDER") from None
    return _named([SuiteCharacter(e, root=index.parent) for e in entries], names,
                  f"no character {{missing}} in {index}")


def _named(chars: list[SuiteCharacter], names, unknown: str) -> list[SuiteCharacter]:
    """``chars``, or only those called ``names`` in that order; unknown names raise ``KeyError`` with
    ``unknown`` (its ``{missing}`` filled) and the known names."""
    if names is None:
        return chars
    known = {c.name: c for c in chars}
    missing = [n for n in names if n not in known]
    if missing:
        raise KeyError(unknown.replace("{missing}", str(missing)) + f" (known: {', '.join(known)})")
    return [known[n] for n in names]
