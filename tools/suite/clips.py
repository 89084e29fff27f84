"""Edit the clips of a converted .glb: merge clips from other files, split one clip into named clips, drop clips,
attach a base-colour texture.

assimp converts one animation per MD5 file and one timeline per B3D file, so
the suite's multi-clip characters are assembled here:

- ``--merge NAME=OTHER.glb``: the first animation of OTHER (the same
  skeleton converted with another animation) is added as clip NAME; its
  channels target this file's nodes with the same names;
- ``--split NAME=START:END`` with ``--fps F`` (frames, inclusive): the first
  animation is cut into clips at times ``START/F .. END/F`` (keys inside the
  window kept, the ends interpolated linearly or held for STEP), each clip's
  times starting at 0; the uncut animation is removed;
- ``--retime NAME=FACTOR``: scale a clip's key times (the file's frame rate
  is not the game's playback rate);
- ``--drop NAME``: remove a clip (e.g. a zero-length bind-pose clip);
- ``--texture MATERIAL_INDEX=IMAGE``: embed IMAGE as that material's base colour;
- the buffer is rebuilt with only the views still referenced.

Usage::

    python tools/suite/clips.py mesh.glb -o out.glb --merge walk=walk.glb --merge run=run.glb
    python tools/suite/clips.py character.glb -o out.glb --fps 30 --split stand=0:79 --split walk=168:187
"""

from __future__ import annotations

import argparse
import copy
import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from glb import GlbBuilder, read_accessor, read_glb  # noqa: E402

_SKIP = ("buffers", "bufferViews", "accessors", "images")


def _sampler_arrays(doc: dict, blob: bytes, anim: dict) -> list:
    """[(times, values, interpolation, target)] of an animation's channels."""
    out = []
    for ch in anim["channels"]:
        s = anim["samplers"][ch["sampler"]]
        t = read_accessor(doc, blob, s["input"])[:, 0].astype(np.float64)
        v = read_accessor(doc, blob, s["output"]).astype(np.float64)
        out.append((t, v, s.get("interpolation", "LINEAR"), dict(ch["target"])))
    return out


class Rebuilt:
    """A document whose accessors are re-emitted into a fresh buffer (only those still used)."""

    def __init__(self, doc: dict, blob: bytes):
        self.src, self.blob = doc, blob
        self.g = GlbBuilder(doc.get("asset", {}).get("generator", "unknown") + " + tools/suite/clips.py")
        self.g.doc["asset"] = copy.deepcopy(doc["asset"])
        for k, v in doc.items():
            if k not in _SKIP and k != "asset":
                self.g.doc[k] = copy.deepcopy(v)
        self.g.doc["animations"] = []
        self.map: dict[int, int] = {}
        self.retime: dict[str, float] = {}

    def copy_accessor(self, i: int) -> int:
        if i not in self.map:
            a = self.src["accessors"][i]
            arr = read_accessor(self.src, self.blob, i)
            bv = self.src["bufferViews"][a["bufferView"]]
            j = self.g.accessor(arr if a["type"] != "MAT4" else arr, target=bv.get("target"),
                                minmax="min" in a, normalized=a.get("normalized", False), matrix=a["type"] == "MAT4")
            for key in ("min", "max"):
                if key in a:
                    self.g.doc["accessors"][j][key] = a[key]
            self.map[i] = j
        return self.map[i]

    def finish(self) -> GlbBuilder:
        d = self.g.doc
        for mesh in d.get("meshes", []):
            for p in mesh["primitives"]:
                p["attributes"] = {k: self.copy_accessor(v) for k, v in p["attributes"].items()}
                if "indices" in p:
                    p["indices"] = self.copy_accessor(p["indices"])
                for t in p.get("targets", []):
                    for k in t:
                        t[k] = self.copy_accessor(t[k])
        for skin in d.get("skins", []):
            if "inverseBindMatrices" in skin:
                skin["inverseBindMatrices"] = self.copy_accessor(skin["inverseBindMatrices"])
        images = []
        for im in self.src.get("images", []):
            im = dict(im)
            if "bufferView" in im:
                bv = self.src["bufferViews"][im["bufferView"]]
                start = bv.get("byteOffset", 0)
                im["bufferView"] = self.g.view(self.blob[start:start + bv["byteLength"]])
            images.append(im)
        if images:
            d["images"] = images + d.get("images", [])[len(images):]
        if not d["animations"]:
            del d["animations"]
        return self.g

    def add_clip(self, name: str, channels: list) -> None:
        samplers, chans = [], []
        factor = self.retime.get(name, 1.0)
        for t, v, interp, target in channels:
            times = self.g.accessor((t * factor).astype(np.float32), minmax=True)
            values = self.g.accessor(v.astype(np.float32))
            samplers.append({"input": times, "output": values, "interpolation": interp})
            chans.append({"sampler": len(samplers) - 1, "target": target})
        self.g.doc["animations"].append({"name": name, "samplers": samplers, "channels": chans})


def _window(t: np.ndarray, v: np.ndarray, interp: str, t0: float, t1: float):
    """Keys of one channel inside [t0, t1], ends interpolated, times shifted to start at 0."""
    if interp == "CUBICSPLINE":
        raise ValueError("splitting CUBICSPLINE channels is not supported")

    def at(x):
        if x <= t[0]:
            return v[0]
        if x >= t[-1]:
            return v[-1]
        k = int(np.searchsorted(t, x, side="right")) - 1
        if interp == "STEP" or t[k + 1] == t[k]:
            return v[k]
        a = (x - t[k]) / (t[k + 1] - t[k])
        out = (1 - a) * v[k] + a * v[k + 1]
        if v.shape[1] == 4:                 # rotation: nlerp is what viewers do between keys
            if np.dot(v[k], v[k + 1]) < 0:
                out = (1 - a) * v[k] - a * v[k + 1]
            out = out / np.linalg.norm(out)
        return out

    inside = (t > t0 + 1e-6) & (t < t1 - 1e-6)
    times = np.concatenate([[t0], t[inside], [t1]]) - t0
    values = np.vstack([at(t0), v[inside], at(t1)])
    return times, values


def _merge(r: Rebuilt, name: str, other: Path) -> None:
    odoc, oblob = read_glb(other)
    names = {n.get("name"): i for i, n in enumerate(r.src["nodes"])}
    chans = []
    for t, v, interp, target in _sampler_arrays(odoc, oblob, odoc["animations"][0]):
        node_name = odoc["nodes"][target["node"]].get("name")
        if node_name not in names:
            raise ValueError(f"{other}: animated node {node_name!r} is not in the base file")
        chans.append((t, v, interp, {"node": names[node_name], "path": target["path"]}))
    r.add_clip(name, chans)


def _texture(g: GlbBuilder, material: int, image: Path, cache: dict) -> None:
    if image not in cache:
        data = image.read_bytes()
        mime = "image/png" if data[:8] == b"\x89PNG\r\n\x1a\n" else "image/jpeg"
        im = g.image(data, mime)
        sampler = g.add("samplers", {"magFilter": 9729, "minFilter": 9987, "wrapS": 10497, "wrapT": 10497})
        cache[image] = g.add("textures", {"source": im, "sampler": sampler})
    tex = cache[image]
    pbr = g.doc["materials"][material].setdefault("pbrMetallicRoughness", {})
    pbr["baseColorTexture"] = {"index": tex}
    pbr["baseColorFactor"] = [1.0, 1.0, 1.0, 1.0]


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("input", type=Path)
    ap.add_argument("-o", "--output", type=Path, required=True)
    ap.add_argument("--merge", action="append", default=[], metavar="NAME=OTHER.glb")
    ap.add_argument("--split", action="append", default=[], metavar="NAME=START:END")
    ap.add_argument("--fps", type=float, default=None, help="frames per second of the --split frame numbers")
    ap.add_argument("--rename", action="append", default=[], metavar="OLD=NEW")
    ap.add_argument("--retime", action="append", default=[], metavar="NAME=FACTOR",
                    help="multiply clip NAME's key times by FACTOR (e.g. the game's playback rate)")
    ap.add_argument("--drop", action="append", default=[], metavar="NAME")
    ap.add_argument("--texture", action="append", default=[], metavar="MATERIAL_INDEX=IMAGE")
    args = ap.parse_args(argv)
    if args.output.resolve() == args.input.resolve():
        ap.error("the output would overwrite the input")
    doc, blob = read_glb(args.input)
    r = Rebuilt(doc, blob)
    r.retime = {k: float(v) for k, v in (x.split("=", 1) for x in args.retime)}
    anims = doc.get("animations", [])
    renames = dict(x.split("=", 1) for x in args.rename)
    if args.split:
        if not args.fps:
            ap.error("--split needs --fps")
        source = _sampler_arrays(doc, blob, anims[0])
        for spec in args.split:
            name, _, rng = spec.partition("=")
            a, b = (float(x) / args.fps for x in rng.split(":"))
            r.add_clip(name, [(*_window(t, v, i, a, b), i, tgt) for t, v, i, tgt in source])
        anims = anims[1:]
    for a in anims:
        name = a.get("name", "")
        if name in args.drop:
            continue
        r.add_clip(renames.get(name, name), _sampler_arrays(doc, blob, a))
    for spec in args.merge:
        name, _, other = spec.partition("=")
        _merge(r, name, Path(other))
    g = r.finish()
    cache: dict = {}
    for spec in args.texture:
        m, _, image = spec.partition("=")
        _texture(g, int(m), Path(image), cache)
    g.write(args.output)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
