"""Rebuild the real-character suite (examples/data/gltf/suite/) from Debian packages.

The converted .glb files are committed (CI and every helper use the same
bytes); this script documents and repeats how they were made:

1. ``apt-get download`` each source package into ``--work`` (skipped when the
   .deb is there) and extract it (``dpkg-deb -x``); assimp-testmodels is
   read from /usr/share/assimp/models (``tools/setup-testmodels.sh``);
2. convert: ``assimp export IN OUT.glb -fglb2`` (assimp-utils 5.2) for X, B3D
   and MD5; ``tools/suite/iqm2gltf.py`` for IQM (assimp 5.2 drops IQM
   skeletons); ``tools/suite/clips.py`` to merge one-animation-per-file
   sources into clips, split single timelines into the game's named clips,
   drop bind-pose clips and embed textures;
3. write ``suite.json`` (the index: faces, joints, clips, textures, which
   clips to fit and hold out, test times, camera azimuth, provenance) from the
   files themselves.

Usage::

    python tools/suite/build.py [--work /tmp/rigslim-suite] [--only NAME ...] [--index-only]
    python tools/suite/build.py --set holdout     # the hold-out characters (examples/data/gltf/holdout/)
"""

from __future__ import annotations

import argparse
import hashlib
import json
import shutil
import subprocess
import sys
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[1]
OUT = ROOT / "examples" / "data" / "gltf" / "suite"
ASSIMP_MODELS = Path("/usr/share/assimp/models")
PY = sys.executable
sys.path.insert(0, str(HERE))
from glb import read_accessor, read_glb  # noqa: E402

PACKAGES = {
    "assimp-testmodels": "5.2.5~ds0-1",
    "cube2-data": "1.3-1",
    "redeclipse-data": "1.6.0-1",
    "minetest-data": "5.6.1+dfsg+~1.9.0mt8+dfsg-2",
    "0ad-data": "0.0.26-1",
    "minetest-mod-3d-armor": "0.4.14-2",
    "minetest-mod-maidroid": "0.1.0-2",
}
CUBE2 = "usr/share/games/cube2/packages/models"
RE = "usr/share/games/redeclipse/data/actors"
MT = "usr/share/games/minetest/games/minetest_game/mods/player_api"
ZERO_AD = "usr/share/games/0ad/mods/public/public.zip"


@dataclass
class Character:
    """One suite character: how it is made, and what the index says about it."""

    name: str
    kind: str
    package: str
    source: str
    licence: str
    author: str
    build: str                      # name of the builder function below
    fit: list = field(default_factory=list)        # clips to fit (empty: the first clip's even frames)
    holdout: list = field(default_factory=list)    # clips held out for testing
    test: list = field(default_factory=list)       # [(clip, time s)] posed test renders
    front: float = 0.0                             # camera azimuth (degrees about +y) that sees the character's front
    notes: str = ""
    group: str = "suite"                           # "suite" (development) or "holdout" (validation only)


CHARACTERS = [
    Character("bcn_epileptic", "humanoid", "assimp-testmodels", "X/BCN_Epileptic.X",
              "BSD-3-Clause (assimp test models, the package's copyright file)", "assimp test models",
              "assimp_x", test=[("Epileptisch", 0.8), ("Epileptisch", 2.1)], front=0,
              notes="3 primitives, 1 material, UVs but no texture; weights not normalised by assimp "
                    "(sums 1 +- 1e-6); the issue's 5,126-face humanoid"),
    Character("wuson", "quadruped (bull)", "assimp-testmodels", "X/Testwuson.X",
              "BSD-3-Clause (assimp test models)", "assimp test models", "assimp_wuson",
              fit=["Wuson_Walk"], holdout=["Wuson_Run"], test=[("Wuson_Run", 0.3), ("Wuson_Walk", 1.2)],
              front=0, notes="the zero-length Wuson_Bind clip is dropped; the issue's 37-joint Walk/Run "
                                "character; 52 vertices with unnormalised weights"),
    Character("frankie", "quadruped (flying squirrel, with tail)", "cube2-data", f"{CUBE2}/frankie/Frankie.iqm",
              "CC-BY-3.0", "Blender Foundation, Yo Frankie! / Apricot project (cube2-data)", "iqm_frankie",
              fit=["run", "idle", "walk_back"], holdout=["kick", "glide"],
              test=[("run", 0.3), ("kick", 0.5)], front=0,
              notes="textured body, alpha-tested tail cards (alphaMode MASK), IQM converted by iqm2gltf.py"),
    Character("snoutx10k", "humanoid (armoured)", "cube2-data", f"{CUBE2}/snoutx10k/snoutx10k.iqm",
              "CC-BY-3.0", "John 'geartrooper' Siar (cube2-data)", "iqm_snout",
              fit=["forward", "idle", "taunt"], holdout=["dying", "swim"],
              test=[("forward", 1.0), ("dying", 0.8)], front=0,
              notes="two textured primitives (upper, lower); 75 joints"),
    Character("mrfixit", "humanoid", "assimp-testmodels", "IQM/mrfixit.iqm",
              "BSD-3-Clause (assimp test models)", "Sauerbraten's Mr. Fixit (assimp test models)", "iqm_mrfixit",
              test=[("idle", 1.0), ("idle", 3.0)], front=0,
              notes="one clip (idle, 101 frames): fit on even frames, test on odd ones; textured head and body"),
    Character("re_player", "humanoid", "redeclipse-data", f"{RE}/player/male/RE_Player_male.iqm",
              "CC-BY-SA-3.0", "Red Eclipse Team (redeclipse-data)", "iqm_re_player",
              fit=["idle", "walk", "jump"], holdout=["run", "dying"],
              test=[("run", 0.25), ("walk", 0.4)], front=0,
              notes="78 joints, one textured primitive; clip rates from actors/player/player.cfg"),
    Character("re_drone", "humanoid (robot)", "redeclipse-data", f"{RE}/drone/mesh.md5mesh",
              "CC-BY-SA-3.0", "Red Eclipse Team (redeclipse-data)", "md5_drone",
              fit=["left", "forward", "backward"], holdout=["death", "sword_attack"],
              test=[("forward", 0.2), ("sword_attack", 0.4)], front=90,
              notes="MD5 mesh + one md5anim per clip (assimp per clip, merged by clips.py); no normals "
                    "(viewers shade flat); the issue's 1,926-face drone"),
    Character("minetest_character", "humanoid (blocky, tiny)", "minetest-data", f"{MT}/models/character.b3d",
              "CC-BY-SA-3.0", "MirceaKitsune and Minetest contributors; texture Jordach", "b3d_minetest",
              fit=["stand", "walk", "sit"], holdout=["mine", "walk_mine"],
              test=[("walk", 0.3), ("walk_mine", 0.4)], front=180,
              notes="84 faces, 6 joints, one timeline split into player_api's frame ranges, played at its 30 fps; "
                    "the issue's 84-face blocky character"),
    Character("wolf", "quadruped (wolf, with tail)", "0ad-data", "art/meshes/skeletal/wolf.dae.cached.pmd",
              "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)", "pmd_wolf",
              fit=["walk", "idle", "attack"], holdout=["run", "death"],
              test=[("run", 0.2), ("attack", 1.0)], front=180,
              notes="in usr/share/games/0ad/mods/public/public.zip; 0 A.D.'s cached PMD/PSA converted by "
                    "pmd2gltf.py (skeleton from art/skeletons/wolf.xml); no texture (0 A.D. ships "
                    "its textures as DDS); one primitive, 696 faces"),
    Character("mangonel", "mechanical (trebuchet, with ropes)", "0ad-data",
              "art/meshes/structural/han_mangonel.dae.cached.pmd", "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)",
              "pmd_mangonel", fit=["attack"], test=[("attack", 1.0), ("attack", 2.0)], front=0,
              notes="in usr/share/games/0ad/mods/public/public.zip; rigid parts (beams, arm, counterweight) "
                    "and rope chains, 1-2 influences; `idle` is a held pose (0.1 s): "
                    "one moving clip, fit on even frames of attack, test on odd ones"),
]


#: Hold-out characters: built after the far-LOD, seam and guard work of issues 22 and 25 was done, to check
#: that it carries to characters nobody tuned on; never used to choose a method or a constant
#: (examples/data/gltf/holdout/, their own index holdout.json).
HOLDOUT = [
    Character("horse", "quadruped (horse, with tail and mane)", "0ad-data", "art/meshes/skeletal/horse.dae.cached.pmd",
              "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)", "pmd_horse",
              fit=["walk", "idle"], holdout=["gallop", "death"], test=[("gallop", 0.3), ("walk", 0.5)], front=180,
              notes="skeleton art/skeletons/horse.xml; one primitive, no texture (DDS)", group="holdout"),
    Character("deer", "quadruped (deer, thin legs, ears)", "0ad-data",
              "art/meshes/skeletal/deer_mesh.dae.cached.pmd", "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)", "pmd_deer",
              fit=["walk", "idle"], holdout=["run", "death"], test=[("run", 0.3), ("walk", 0.5)], front=180,
              notes="skeleton art/skeletons/deer.xml; 306 faces", group="holdout"),
    Character("giraffe", "quadruped (giraffe, long neck and legs)", "0ad-data",
              "art/meshes/skeletal/giraffe_adult.dae.cached.pmd", "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)",
              "pmd_giraffe", fit=["walk", "idle"], holdout=["run", "death"], test=[("run", 0.3), ("walk", 0.5)],
              front=180, notes="skeleton art/skeletons/giraffe.xml; 690 faces", group="holdout"),
    Character("re_female", "humanoid (female)", "redeclipse-data", f"{RE}/player/female/RE_Player_female.iqm",
              "CC-BY-SA-3.0", "Red Eclipse Team (redeclipse-data)", "iqm_re_female",
              fit=["idle", "walk", "jump"], holdout=["run", "dying"], test=[("run", 0.25), ("walk", 0.4)], front=0,
              notes="the male player's clips (one skeleton) on the female mesh; clip rates from player.cfg",
              group="holdout"),
]


def run(cmd: list) -> None:
    print("+", " ".join(str(c) for c in cmd), flush=True)
    subprocess.run([str(c) for c in cmd], check=True, stdout=subprocess.DEVNULL)


def package_root(work: Path, package: str) -> Path:
    """The extracted package (downloaded and extracted on first use)."""
    if package == "assimp-testmodels":
        if not ASSIMP_MODELS.exists():
            raise SystemExit("assimp-testmodels missing: run tools/setup-testmodels.sh")
        return ASSIMP_MODELS
    root = work / package
    if not root.exists():
        debs = sorted(work.glob(f"{package}_*.deb"))
        if not debs:
            subprocess.run(["apt-get", "download", package], cwd=work, check=True)
            debs = sorted(work.glob(f"{package}_*.deb"))
        run(["dpkg-deb", "-x", debs[-1], root])
    return root


def _small_image(src: Path, dst: Path, size: int = 512) -> Path:
    from PIL import Image

    img = Image.open(src)
    if max(img.size) > size:
        img = img.resize((size, size), Image.LANCZOS)
    if dst.suffix == ".png":
        img.save(dst, optimize=True)
    else:
        img.convert("RGB").save(dst, quality=88)
    return dst


def assimp_x(c: Character, work: Path, out: Path) -> None:
    run(["assimp", "export", ASSIMP_MODELS / c.source, out, "-fglb2"])


def assimp_wuson(c: Character, work: Path, out: Path) -> None:
    tmp = work / f"{c.name}.assimp.glb"
    run(["assimp", "export", ASSIMP_MODELS / c.source, tmp, "-fglb2"])
    run([PY, HERE / "clips.py", tmp, "-o", out, "--drop", "Wuson_Bind"])


def iqm_frankie(c: Character, work: Path, out: Path) -> None:
    d = package_root(work, c.package) / CUBE2 / "frankie"
    run([PY, HERE / "iqm2gltf.py", d / "Frankie.iqm", "-o", out, "--yaw", "180",
         "--texture", f"Body={d / 'flyingsquirrel_skin_col.jpg'}", "--texture", f"Tail={d / 'frankie_tail2.png'}",
         "--alpha", "Tail", "--anim", f"run={d / 'Frankie_Run.iqm'}", "--anim", f"idle={d / 'Frankie_Idle1.iqm'}",
         "--anim", f"kick={d / 'Frankie_Kick.iqm'}", "--anim", f"walk_back={d / 'Frankie_WalkBack.iqm'}",
         "--anim", f"glide={d / 'Frankie_Glide.iqm'}"])


def iqm_snout(c: Character, work: Path, out: Path) -> None:
    d = package_root(work, c.package) / CUBE2 / "snoutx10k"
    clips = [("forward", "forward"), ("idle", "idle"), ("taunt", "taunt"), ("dying", "dying"), ("swim", "swim")]
    run([PY, HERE / "iqm2gltf.py", d / "snoutx10k.iqm", "-o", out, "--yaw", "-90",
         "--texture", f"Upper={d / 'upper.jpg'}", "--texture", f"Lower={d / 'lower.jpg'}",
         *[x for n, f in clips for x in ("--anim", f"{n}={d / (f + '.md5anim.iqm')}")]])


def iqm_mrfixit(c: Character, work: Path, out: Path) -> None:
    d = ASSIMP_MODELS / "IQM"
    run([PY, HERE / "iqm2gltf.py", d / "mrfixit.iqm", "-o", out, "--yaw", "-90",
         "--texture", f"Body={d / 'Body.jpg'}", "--texture", f"Head={d / 'Head.jpg'}"])


def iqm_re_player(c: Character, work: Path, out: Path, body: str = "male") -> None:
    d = package_root(work, c.package) / RE / "player"
    clips = [("idle", "idle", 10), ("walk", "walk_forward", 30), ("jump", "jump0_forward", 30),
             ("run", "runcycle0", 40), ("dying", "dying", 21)]
    run([PY, HERE / "iqm2gltf.py", d / body / f"RE_Player_{body}.iqm", "-o", out,
         "--texture", f"RE_Player={d / 'diffuse.png'}",
         *[x for n, f, r in clips for x in ("--anim", f"{n}={d / (f + '.iqm')}@{r}")]])


def iqm_re_female(c: Character, work: Path, out: Path) -> None:
    iqm_re_player(c, work, out, body="female")


def md5_clips(d: Path, mesh: str, clips: list[tuple[str, str]], tmp: Path, out: Path, extra: list) -> None:
    """An MD5 model with one ``.md5anim`` per clip ``(clip, anim)``: assimp exports a copy of the mesh with each
    animation, and ``clips.py`` merges them into ``out`` by node name (``extra``: its further arguments)."""
    tmp.mkdir(parents=True, exist_ok=True)
    parts = []
    for name, anim in clips:
        shutil.copy(d / mesh, tmp / f"{name}.md5mesh")
        shutil.copy(d / f"{anim}.md5anim", tmp / f"{name}.md5anim")
        run(["assimp", "export", tmp / f"{name}.md5mesh", tmp / f"{name}.glb", "-fglb2"])
        parts.append((name, tmp / f"{name}.glb"))
    run([PY, HERE / "clips.py", parts[0][1], "-o", out, "--rename", f"anim={parts[0][0]}",
         *[x for n, p in parts[1:] for x in ("--merge", f"{n}={p}")], *extra])


def md5_drone(c: Character, work: Path, out: Path) -> None:
    d = package_root(work, c.package) / RE / "drone"
    tmp = work / "drone"
    tmp.mkdir(exist_ok=True)
    # (clip, md5anim, the game's rate in actors/drone/md5.cfg; the files say 24 fps)
    clips = [("left", "left", 16), ("forward", "forward", 16), ("backward", "backward", 16), ("death", "death", 8),
             ("sword_attack", "sword-attack1", 15)]
    skin = _small_image(d / "skin.jpg", tmp / "skin512.jpg")
    md5_clips(d, "mesh.md5mesh", [(name, anim) for name, anim, _ in clips], tmp, out,
              [*[x for n, _a, rate in clips for x in ("--retime", f"{n}={24 / rate:g}")],
               "--texture", f"0={skin}", "--texture", f"1={skin}"])


def b3d_minetest(c: Character, work: Path, out: Path) -> None:
    d = package_root(work, c.package) / MT
    tmp = work / "minetest.assimp.glb"
    run(["assimp", "export", d / "models" / "character.b3d", tmp, "-fglb2"])
    ranges = {"stand": (0, 79), "sit": (81, 160), "lay": (162, 166), "walk": (168, 187), "mine": (189, 198),
              "walk_mine": (200, 219)}
    # assimp keeps the B3D keys at their frame numbers 1..221 over the file's 60 frames per second;
    # player_api's frame f (Irrlicht counts from 0) is key f + 1, and it plays them at 30 per second
    run([PY, HERE / "clips.py", tmp, "-o", out, "--fps", "60",
         *[x for n, (a, b) in ranges.items() for x in ("--split", f"{n}={a + 1}:{b + 1}", "--retime", f"{n}=2")],
         "--texture", f"0={d / 'models' / 'character.png'}"])


def _zero_ad(work: Path, members: list[str]) -> Path:
    """Extract ``members`` of 0ad-data's public.zip into ``work/0ad`` (the package is downloaded if needed)."""
    import zipfile

    root = work / "0ad"
    missing = [m for m in members if not (root / m).exists()]
    if missing:
        with zipfile.ZipFile(package_root(work, "0ad-data") / ZERO_AD) as z:
            for m in missing:
                z.extract(m, root)
    return root


def pmd_wolf(c: Character, work: Path, out: Path) -> None:
    _pmd_quadruped(c, work, out, "wolf", [("walk", "wolf_walk"), ("run", "wolf_run"), ("attack", "wolf_attack_01"),
                                          ("idle", "wolf_idle_01"), ("death", "wolf_death_01")])


def pmd_mangonel(c: Character, work: Path, out: Path) -> None:
    psa = {n: f"art/animation/mechanical/han_mangonel_{n}.dae.cached.psa" for n in ("idle", "attack")}
    root = _zero_ad(work, [c.source, "art/skeletons/han_mangonel.xml", *psa.values()])
    run([PY, HERE / "pmd2gltf.py", root / c.source, root / "art/skeletons/han_mangonel.xml", "-o", out,
         "--name", "han_mangonel", *[x for n, p in psa.items() for x in ("--anim", f"{n}={root / p}")]])


def _pmd_quadruped(c: Character, work: Path, out: Path, skeleton: str, clips: list[tuple[str, str]]) -> None:
    psa = [f"art/animation/quadraped/{f}.dae.cached.psa" for _, f in clips]
    root = _zero_ad(work, [c.source, f"art/skeletons/{skeleton}.xml", *psa])
    run([PY, HERE / "pmd2gltf.py", root / c.source, root / f"art/skeletons/{skeleton}.xml", "-o", out,
         "--name", c.name, *[x for (n, _), p in zip(clips, psa, strict=True) for x in ("--anim", f"{n}={root / p}")]])


def pmd_horse(c: Character, work: Path, out: Path) -> None:
    _pmd_quadruped(c, work, out, "horse", [("walk", "horse_walk"), ("gallop", "horse_gallop"),
                                           ("idle", "horse_idle_01"), ("death", "horse_death")])


def pmd_deer(c: Character, work: Path, out: Path) -> None:
    _pmd_quadruped(c, work, out, "deer", [("walk", "deer_walk_01"), ("run", "deer_run_01"),
                                          ("idle", "deer_idle_01"), ("death", "deer_death_01")])


def pmd_giraffe(c: Character, work: Path, out: Path) -> None:
    _pmd_quadruped(c, work, out, "giraffe", [("walk", "giraffe_adult_walk"), ("run", "giraffe_adult_run"),
                                             ("idle", "giraffe_adult_idle_01"), ("death", "giraffe_adult_death")])


def describe(c: Character, path: Path) -> dict:
    """The index entry of one converted file, measured from the file."""
    doc, blob = read_glb(path)
    faces = vertices = 0
    influences = 0
    textured = False
    prims = 0
    for mesh in doc.get("meshes", []):
        for p in mesh["primitives"]:
            prims += 1
            n = doc["accessors"][p["attributes"]["POSITION"]]["count"]
            vertices += n
            faces += (doc["accessors"][p["indices"]]["count"] if "indices" in p else n) // 3
            if "WEIGHTS_0" in p["attributes"]:
                W = read_accessor(doc, blob, p["attributes"]["WEIGHTS_0"]).astype(np.float64)
                influences = max(influences, int((W > 1e-6).sum(axis=1).max()))
            mat = doc.get("materials", [])[p["material"]] if "material" in p else {}
            textured |= "baseColorTexture" in mat.get("pbrMetallicRoughness", {}) and "TEXCOORD_0" in p["attributes"]
    clips = []
    for a in doc.get("animations", []):
        t_max, keys = 0.0, 0
        for s in a["samplers"]:
            acc = doc["accessors"][s["input"]]
            t_max, keys = max(t_max, float(acc["max"][0])), max(keys, acc["count"])
        clips.append({"name": a.get("name", ""), "duration": round(t_max, 4), "keys": keys,
                      "channels": len(a["channels"])})
    names = [x["name"] for x in clips]
    for clip in c.fit + c.holdout + [t[0] for t in c.test]:
        if clip not in names:
            raise SystemExit(f"{c.name}: clip {clip!r} is not in {path.name} ({names})")
    fit = c.fit or names[:1]
    entry = {
        "name": c.name, "file": f"{c.group}/{path.name}", "kind": c.kind, "faces": faces, "vertices": vertices,
        "primitives": prims, "materials": len(doc.get("materials", [])), "textured": bool(textured),
        "joints": max((len(s["joints"]) for s in doc.get("skins", [])), default=0), "max_influences": influences,
        "clips": clips, "fit_clips": fit, "holdout_clips": c.holdout,
        "test_renders": [{"clip": k, "time": t} for k, t in c.test],
        "view": {"front_azimuth": c.front, "side_azimuth": c.front + 90, "elevation": 10},
        "source": {"package": c.package, "version": PACKAGES[c.package], "path": c.source, "builder": c.build},
        "licence": c.licence, "author": c.author, "notes": c.notes,
        "bytes": path.stat().st_size, "sha256": hashlib.sha256(path.read_bytes()).hexdigest(),
    }
    if not c.holdout:
        entry["single_clip_split"] = {"fps": 30, "fit_frames": "0::2", "test_frames": "1::2"}
    return entry


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--work", type=Path, default=Path("/tmp/rigslim-suite"), help="downloads and scratch files")
    ap.add_argument("--only", nargs="*", default=None, help="rebuild only these characters")
    ap.add_argument("--index-only", action="store_true", help="rewrite the index from the committed files")
    ap.add_argument("--set", choices=("suite", "holdout"), default="suite",
                    help="the development suite (suite/suite.json) or the hold-out set (holdout/holdout.json)")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    out = OUT if args.set == "suite" else OUT.parent / "holdout"
    out.mkdir(parents=True, exist_ok=True)
    entries = []
    for c in CHARACTERS if args.set == "suite" else HOLDOUT:
        path = out / f"{c.name}.glb"
        if not args.index_only and (args.only is None or c.name in args.only):
            tmp = args.work / f"{c.name}.glb"
            globals()[c.build](c, args.work, tmp)
            shutil.copy(tmp, path)
        entries.append(describe(c, path))
        e = entries[-1]
        print(f"{c.name}: {e['faces']} faces, {e['joints']} joints, {len(e['clips'])} clips, "
              f"textured {e['textured']}, {e['bytes'] / 1e6:.2f} MB")
    about = ("rigslim's real-character suite" if args.set == "suite" else
             "rigslim's hold-out characters (validation only: never used to choose a method or a constant)")
    index = {"version": 1, "about": f"{about}; see README.md (provenance) and tools/suite/build.py (how each "
                                    "file was made)",
             "packages": PACKAGES, "characters": entries}
    (out / f"{args.set}.json").write_text(json.dumps(index, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
