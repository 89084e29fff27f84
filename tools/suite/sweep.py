"""Build the sweep characters: 41 animated characters for robustness sweeps, never committed, never tuned on.

The suite (``build.py``) is what methods and constants are chosen on and the hold-out set
(``build.py --set holdout``) is what they are checked on; these are for running every command on
characters nothing in the repository has seen (the sweep of 2026-12-03 found the USD clip and
``rigslim report`` defects of the changelog with them). They are built into ``--out`` from the same
Debian packages and with the same converters as the suite:

- ten 0 A.D. characters (``0ad-data``, CC-BY-SA-3.0, Wildfire Games): camel, tiger, bear, boar, rhino,
  croc, fox, elephant, a soldier (the short-tunic infantry body with hoplite and swordsman clips) and
  the lithobolos siege engine (rigid parts), each a cached PMD with its skeleton and five PSA clips
  (``pmd2gltf.py``);
- eleven more 0 A.D. characters, the second batch (``ZERO_AD_2``, built for the sweep of 2026-12-05): pig, mastiff,
  hippo, rabbit, goat, sheep, shark, hawk, chicken, the asian elephant and a woman in a dress (the biped
  infantry clips), 124 to 1,538 faces, 9 to 58 joints;
- eleven more, the third batch (``ZERO_AD_3``, built for the third sweep of 2026-12-05): lion, bull, wildebeest,
  donkey, zebra, polar bear, peacock, crow, seagull, the whale's back and fins and a man in a robe (the archer
  clips), 302 to 2,528 faces, 8 to 46 joints;
- three cube2 models (``cube2-data``): the shotgun and the minigun first-person guns (IQM, textured,
  rigid parts; ``iqm2gltf.py``) and the cloth flag (MD5 through ``assimp export``, texture embedded by
  ``clips.py``);
- four Red Eclipse files (``redeclipse-data``, CC-BY-SA-3.0): the pistol and the smg (MD5, rigid parts; the
  pistol's first clip holds one pose), a swaying palm tree and the player with all 62 clips (IQM).
- two blocky Minetest characters (``MINETEST_MODS``, built for the sweep of 2026-12-06): 3d_armor's player
  with its armour layer of separate quads over the body (found the early part removal of the changelog) and
  the maidroid robot (B3D through ``assimp export``, split by ``clips.py``).

``OUT/index.json`` lists each file as ``build.py``'s indexes do (faces, joints, clips, provenance).

Usage::

    python tools/suite/sweep.py --out /tmp/rigslim-sweep [--work /tmp/rigslim-suite] [--only NAME ...]
"""

from __future__ import annotations

import argparse
import json
import shutil
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import build as B  # noqa: E402

Q = "art/animation/quadraped"          # (sic: 0 A.D.'s folder name)
BI = "art/animation/biped/infantry"
CLIPS5 = ("walk", "run", "idle", "attack", "death")

#: name, kind, PMD, skeleton (art/skeletons/NAME.xml), [(clip, PSA)]
ZERO_AD = [
    ("camel", "quadruped (camel, long neck)", "art/meshes/skeletal/camel.dae.cached.pmd", "camelus",
     list(zip(CLIPS5, [f"{Q}/camel_{s}.dae.cached.psa" for s in ("walk", "run", "idle_01", "attack_melee_01",
                                                                  "death")], strict=True))),
    ("tiger", "quadruped (tiger, long tail)", "art/meshes/skeletal/tiger.dae.cached.pmd", "feline_blender",
     list(zip(CLIPS5, [f"{Q}/feline_{s}.dae.cached.psa" for s in ("walk", "run", "idle_01", "attack", "death")],
              strict=True))),
    ("bear", "quadruped (bear)", "art/meshes/skeletal/bear.dae.cached.pmd", "ursidae_armature",
     list(zip(CLIPS5, [f"{Q}/bear_{s}.dae.cached.psa" for s in ("walk", "run", "idle_01", "attack_01", "death_01")],
              strict=True))),
    ("boar", "quadruped (boar, tusks)", "art/meshes/skeletal/animal_boar.dae.cached.pmd", "boar",
     list(zip(CLIPS5, [f"{Q}/animal_boar_{s}_01.dae.cached.psa" for s in ("walk", "run", "idle", "attack", "death")],
              strict=True))),
    ("rhino", "quadruped (rhino, horn)", "art/meshes/skeletal/rhino.dae.cached.pmd", "rhino",
     list(zip(CLIPS5, [f"{Q}/rhino_{s}.dae.cached.psa" for s in CLIPS5], strict=True))),
    ("croc", "quadruped (crocodile, long tail, low legs)", "art/meshes/skeletal/Croc.dae.cached.pmd", "crocodile",
     list(zip(("walk", "run", "idle", "attack", "swim"),
              [f"{Q}/Croc_{s}.dae.cached.psa" for s in ("walk", "run", "idle1", "attack", "swim")], strict=True))),
    ("fox", "quadruped (fox, bushy tail, ears)", "art/meshes/skeletal/fox.dae.cached.pmd", "fox_armature",
     list(zip(("walk", "run", "idle", "death"), [f"{Q}/fox_{s}.dae.cached.psa" for s in ("walk", "run", "idle",
                                                                                            "death")], strict=True))),
    ("elephant", "quadruped (african elephant, trunk, ears)",
     "art/meshes/skeletal/elephant_african_bush.dae.cached.pmd", "elephantidae_african_bush",
     list(zip(CLIPS5, [f"{Q}/elephant_african_bush_{s}.dae.cached.psa"
                       for s in ("walk", "run", "idle_01", "attack_melee_01", "death")], strict=True))),
    ("soldier", "humanoid (0 A.D. infantry, tunic)", "art/meshes/skeletal/new/m_tunic_short.dae.cached.pmd", "biped",
     list(zip(CLIPS5, [f"{BI}/hoplite/walk_ready.dae.cached.psa", f"{BI}/hoplite/run_ready.dae.cached.psa",
                       f"{BI}/hoplite/idle_relax_01.dae.cached.psa",
                       f"{BI}/swordsman/attack_melee_2h_01.dae.cached.psa", f"{BI}/death_a.dae.cached.psa"],
              strict=True))),
    ("lithobolos", "mechanical (stone thrower, rigid parts)", "art/meshes/structural/hele_lithobolos.dae.cached.pmd",
     "hele_lithobolos", [("attack", "art/animation/mechanical/hele_lithobolos.dae.cached.psa"),
                         ("idle", "art/animation/mechanical/hele_lithobolos_idle.dae.cached.psa")]),
]
#: The second batch (built 2026-12-05 for the sweep of that day): 0 A.D. characters no earlier sweep used.
O = "art/animation/other"
ZERO_AD_2 = [
    ("pig", "quadruped (pig)", "art/meshes/skeletal/pig.dae.cached.pmd", "boar",
     [(c, f"{Q}/animal_pig_{c}_01.dae.cached.psa") for c in ("walk", "run", "idle", "feeding", "attack", "death")]),
    ("mastiff", "quadruped (war dog, spiked collar)", "art/meshes/skeletal/mastiff.dae.cached.pmd", "mastiff",
     [(c, f"{Q}/mastiff_{c}.dae.cached.psa") for c in ("run", "idle", "attack", "death")]),
    ("hippo", "quadruped (hippopotamus)", "art/meshes/skeletal/fauna_hippopotamus.dae.cached.pmd",
     "hippopotamus_armature",
     [(c, f"{Q}/hippopotamus_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("trot", "trot"),
                                                               ("idle", "idle_01"), ("attack", "attack"),
                                                               ("death", "death"))]),
    ("rabbit", "quadruped (rabbit, long ears, tiny)", "art/meshes/skeletal/rabbit_01.dae.cached.pmd", "deer",
     [(c, f"{Q}/rabbit_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("idle", "idle_01"), ("death", "death"))]),
    ("goat", "quadruped (goat, horns)", "art/meshes/skeletal/goat.dae.cached.pmd", "goat",
     [(c, f"{Q}/goat_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("idle", "idle_01"), ("death", "death"))]),
    ("sheep", "quadruped (sheep, fleece)", "art/meshes/skeletal/sheep.dae.cached.pmd", "sheep",
     [(c, f"{Q}/sheep_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("run", "run"), ("idle", "idle_01"),
                                                        ("death", "death"))]),
    ("shark", "fish (shark, swimming)", "art/meshes/skeletal/shark.dae.cached.pmd", "shark",
     [(c, f"{O}/shark_{c}.dae.cached.psa") for c in ("walk", "run", "idle")]),
    ("hawk", "bird (hawk, wings)", "art/meshes/skeletal/hawk.dae.cached.pmd", "hawk",
     [(c, f"{O}/hawk_{c}.dae.cached.psa") for c in ("flight", "glide")]),
    ("chicken", "bird (chicken, tiny)", "art/meshes/skeletal/chicken.dae.cached.pmd", "chicken",
     [(c, f"{Q}/chicken_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("run", "run_01"), ("idle", "idle_01"),
                                                          ("attack", "attack"), ("death", "death"))]),
    ("elephant_asian", "quadruped (asian elephant, trunk, tusks)",
     "art/meshes/skeletal/elephant_asian_male.dae.cached.pmd", "elephantidae_asian",
     [(c, f"{Q}/elephant_asian_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("run", "run"), ("idle", "idle_01"),
                                                                 ("attack", "attack_melee_01"), ("death", "death"))]),
    ("woman", "humanoid (0 A.D. woman, dress)", "art/meshes/skeletal/new/f_dress.dae.cached.pmd", "biped",
     list(zip(CLIPS5, [f"{BI}/hoplite/walk_ready.dae.cached.psa", f"{BI}/hoplite/run_ready.dae.cached.psa",
                       f"{BI}/hoplite/idle_relax_01.dae.cached.psa",
                       f"{BI}/swordsman/attack_melee_2h_01.dae.cached.psa", f"{BI}/death_a.dae.cached.psa"],
              strict=True))),
]
#: The third batch (built 2026-12-05, after the second): 0 A.D. characters no earlier sweep used.
ZERO_AD_3 = [
    ("lion", "quadruped (lion, mane)", "art/meshes/skeletal/animal_lion.dae.cached.pmd", "horse_old",
     [(c, f"{Q}/lion_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("run", "run"), ("idle", "idle_01"),
                                                       ("death", "death"))]),
    ("bull", "quadruped (bull, horns)", "art/meshes/skeletal/bull_a.dae.cached.pmd", "bovidae_skeleton",
     [(c, f"{Q}/bovidae_{s}.dae.cached.psa") for c, s in (("walk", "walk_relax"), ("run", "run"), ("idle", "idle_a"),
                                                          ("attack", "attack"), ("death", "death_a"))]),
    ("wildebeest", "quadruped (wildebeest, horns, beard)", "art/meshes/skeletal/wildebeest_adult.dae.cached.pmd",
     "bovidae_skeleton",
     [(c, f"{Q}/bovidae_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("feeding", "feeding"),
                                                          ("idle", "idle_b"), ("death", "death_b"))]),
    ("donkey", "quadruped (donkey, small)", "art/meshes/skeletal/donkey.dae.cached.pmd", "horse_old",
     [(c, f"{Q}/donkey_{c}_01.dae.cached.psa") for c in ("walk", "idle", "death")]),
    ("zebra", "quadruped (zebra, mane)", "art/meshes/skeletal/zebra.dae.cached.pmd", "zebra",
     [(c, f"{Q}/zebra_{c}.dae.cached.psa") for c in CLIPS5]),
    ("bear_polar", "quadruped (polar bear, 2,528 faces)", "art/meshes/skeletal/bear_polar.dae.cached.pmd",
     "ursidae_armature",
     [(c, f"{Q}/bear_{s}.dae.cached.psa") for c, s in (("walk", "walk"), ("run", "run"), ("idle", "idle_02"),
                                                       ("attack", "attack_02"), ("death", "death_01"))]),
    ("peacock", "bird (peacock, tail fan)", "art/meshes/skeletal/peacock.dae.cached.pmd", "peacock",
     [(c, f"{Q}/peacock_{c}.dae.cached.psa") for c in ("walk", "idle", "feeding", "death")]),
    ("crow", "bird (crow, wings)", "art/meshes/skeletal/crow.dae.cached.pmd", "hawk",
     [(c, f"{O}/crow_{c}.dae.cached.psa") for c in ("flight", "glide")]),
    ("seagull", "bird (seagull, wings)", "art/meshes/skeletal/seagull.dae.cached.pmd", "hawk",
     [(c, f"{O}/seagull_{s}.dae.cached.psa") for c, s in (("flight", "flight_01"), ("flight2", "flight_02"))]),
    ("whale_fin", "fish (whale back and fins, surfacing)", "art/meshes/skeletal/whale_fin.dae.cached.pmd", "whale",
     [(c, f"{O}/whale_fin_idle_{c}.dae.cached.psa") for c in "abcd"]),
    ("robe", "humanoid (0 A.D. infantry, robe)", "art/meshes/skeletal/new/m_robe.dae.cached.pmd", "biped",
     list(zip(CLIPS5, [f"{BI}/archer/walk_ready.dae.cached.psa", f"{BI}/archer/run_ready.dae.cached.psa",
                       f"{BI}/archer/idle_ready.dae.cached.psa", f"{BI}/archer/attack_ranged.dae.cached.psa",
                       f"{BI}/death_b.dae.cached.psa"], strict=True))),
]
CUBE2 = ["shotgun", "minigun", "flag"]
RED_ECLIPSE = ["re_pistol", "re_smg", "re_palm", "re_player_all"]
MINETEST_MODS = ["mt_armor", "mt_maidroid"]
#: player_api's frame ranges (Irrlicht counts from 0), which 3d_armor's character and the maidroid share.
MT_RANGES = {"stand": (0, 79), "sit": (81, 160), "lay": (162, 166), "walk": (168, 187), "mine": (189, 198),
             "walk_mine": (200, 219)}


def build_zero_ad(spec, work: Path, out: Path) -> dict:
    """One 0 A.D. character: its PMD, skeleton and PSA clips extracted from public.zip, ``pmd2gltf.py``."""
    name, kind, pmd, skeleton, clips = spec
    skel = f"art/skeletons/{skeleton}.xml"
    root = B._zero_ad(work, [pmd, skel, *[p for _, p in clips]])
    B.run([B.PY, B.HERE / "pmd2gltf.py", root / pmd, root / skel, "-o", out, "--name", name,
           *[x for clip, p in clips for x in ("--anim", f"{clip}={root / p}")]])
    c = B.Character(name, kind, "0ad-data", pmd, "CC-BY-SA-3.0", "Wildfire Games (0 A.D.)", "sweep",
                    fit=[clips[0][0]], holdout=[clip for clip, _ in clips[1:2]], test=[(clips[0][0], 0.3)])
    return B.describe(c, out) | {"skeleton": skel, "psa": [p for _, p in clips]}


def build_cube2(name: str, work: Path, out: Path) -> dict:
    """The shotgun and the minigun (IQM, ``iqm2gltf.py``) or the cloth flag (MD5 -> assimp -> ``clips.py``)."""
    models = B.package_root(work, "cube2-data") / B.CUBE2
    guns = models / "hudguns"
    if name == "shotgun":
        d = guns / "shotg"
        B.run([B.PY, B.HERE / "iqm2gltf.py", d / "shotgun.iqm", "-o", out, "--texture", f"shotgun={d / 'shotgun.jpg'}",
               "--texture", f"shell={d / 'shotgun_shell.jpg'}", "--anim", f"attack={d / 'shotgun_attack.md5anim.iqm'}",
               "--anim", f"idle={d / 'shotgun_idle.md5anim.iqm'}"])
        kind, source = "mechanical (first-person shotgun, textured)", "hudguns/shotg/shotgun.iqm"
        clips = ["attack", "idle"]
    elif name == "minigun":
        d = guns / "chaing"
        B.run([B.PY, B.HERE / "iqm2gltf.py", d / "chaing.iqm", "-o", out, "--texture", f"minigun={d / 'm134.jpg'}",
               "--anim", f"shoot={d / 'chaing_shoot.iqm'}", "--anim", f"idle={d / 'chaing_idle.iqm'}"])
        kind, source = "mechanical (minigun, rotating barrels, textured)", "hudguns/chaing/chaing.iqm"
        clips = ["shoot", "idle"]
    else:
        d, tmp = models / "ffflag", work / "ffflag"
        tmp.mkdir(parents=True, exist_ok=True)
        shutil.copy(d / "ffflag.md5mesh", tmp / "wave.md5mesh")
        shutil.copy(d / "ffflag.md5anim", tmp / "wave.md5anim")
        B.run(["assimp", "export", tmp / "wave.md5mesh", tmp / "wave.glb", "-fglb2"])
        B.run([B.PY, B.HERE / "clips.py", tmp / "wave.glb", "-o", out, "--rename", "anim=wave",
               "--texture", f"0={d / 'ffflag_cc.png'}"])
        kind, source, clips = "cloth (flag, textured)", "ffflag/ffflag.md5mesh", ["wave"]
    c = B.Character(name, kind, "cube2-data", source, "see the package's copyright file", "Cube 2: Sauerbraten",
                    "sweep", fit=clips[:1], holdout=clips[1:], test=[(clips[0], 0.3)])
    return B.describe(c, out)


def build_red_eclipse(name: str, work: Path, out: Path) -> dict:
    """Red Eclipse 1.6 (``redeclipse-data``, CC-BY-SA-3.0): two first-person weapons (MD5, rigid parts, a
    0 s idle first: ``lod`` once simplified the pistol for its rest pose only), a swaying palm tree (IQM) and
    the player with all 62 of its clips (IQM: the many-clip example thinning, docs/pipelines.md)."""
    data = B.package_root(work, "redeclipse-data") / "usr/share/games/redeclipse/data"
    if name == "re_pistol":
        d = data / "weapons/pistol"
        B.md5_clips(d, "pistol.md5mesh", [("idle", "pistol-idle"), ("shoot", "pistol-shoot"),
                                          ("reload", "pistol-reload")], work / name, out,
                    ["--texture", f"0={d / 'skin.png'}"])
        kind, source, clips = "mechanical (first-person pistol, rigid parts, 0 s idle)", "weapons/pistol", \
            ["idle", "shoot", "reload"]
    elif name == "re_smg":
        d = data / "weapons/smg"
        B.md5_clips(d, "smg.md5mesh", [("idle", "smg_idle"), ("reload", "smg_reload")], work / name, out,
                    ["--texture", f"0={d / 'diffuse.png'}"])
        kind, source, clips = "mechanical (first-person smg, rigid parts)", "weapons/smg", ["idle", "reload"]
    elif name == "re_palm":
        d = data / "dziq/palm_tree01a"
        B.run([B.PY, B.HERE / "iqm2gltf.py", d / "palm_tree01a.iqm", "-o", out,
               "--texture", f"leaves={data / 'dziq/meshtex/palm_tree_leaves.png'}", "--alpha", "leaves",
               "--texture", f"trunk={data / 'dziq/meshtex/palm_tree_trunk.jpg'}", "--anim", f"idle={d / 'idle.iqm'}"])
        kind, source, clips = "vegetation (palm tree swaying, 17 joints)", "dziq/palm_tree01a", ["idle"]
    else:
        d = data / "actors/player"
        anims = sorted(p for p in d.glob("*.iqm"))
        B.run([B.PY, B.HERE / "iqm2gltf.py", d / "male/RE_Player_male.iqm", "-o", out,
               "--texture", f"RE_Player={d / 'diffuse.png'}", *[x for p in anims for x in ("--anim", f"{p.stem}={p}")]])
        kind, source, clips = "humanoid (Red Eclipse player, all 62 clips)", "actors/player", [p.stem for p in anims]
    c = B.Character(name, kind, "redeclipse-data", source, "CC-BY-SA-3.0", "Red Eclipse Team (redeclipse-data)",
                    "sweep", fit=clips[:1], holdout=clips[1:2], test=[(clips[-1], 0.3)])
    return B.describe(c, out)


def build_minetest_mod(name: str, work: Path, out: Path) -> dict:
    """Two blocky B3D characters of Debian's Minetest mods (CC-BY-SA / LGPL, see each package's copyright file):
    3d_armor's player body with its armour and wielded-item layers (``minetest-mod-3d-armor``: 440 faces in
    three primitives, 124 of them separate two-triangle quads over the body's boxes, the layers a game shows
    only when armour is worn) and the maidroid robot (``minetest-mod-maidroid``, 84 faces). One timeline
    each, split at player_api's frame ranges as ``build.py``'s ``b3d_minetest`` does."""
    package, model = {"mt_armor": ("minetest-mod-3d-armor", "3d_armor/3d_armor/models/3d_armor_character.b3d"),
                      "mt_maidroid": ("minetest-mod-maidroid", "maidroid/maidroid/models/maidroid.b3d")}[name]
    src = B.package_root(work, package) / "usr/share/games/minetest/mods" / model
    tmp = work / f"{name}.assimp.glb"
    B.run(["assimp", "export", src, tmp, "-fglb2"])
    B.run([B.PY, B.HERE / "clips.py", tmp, "-o", out, "--fps", "60",
           *[x for n, (a, b) in MT_RANGES.items() for x in ("--split", f"{n}={a + 1}:{b + 1}", "--retime", f"{n}=2")]])
    kind = "humanoid (blocky, armour layer of quads)" if name == "mt_armor" else "humanoid (blocky robot)"
    c = B.Character(name, kind, package, model, "see the package's copyright file", "Minetest mod authors",
                    "sweep", fit=["stand", "walk"], holdout=["mine"], test=[("walk", 0.3)])
    return B.describe(c, out)


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, required=True, help="folder for the .glb files and index.json")
    ap.add_argument("--work", type=Path, default=Path("/tmp/rigslim-suite"), help="downloads and scratch files")
    ap.add_argument("--only", nargs="*", default=None, help="build only these characters")
    args = ap.parse_args(argv)
    args.work.mkdir(parents=True, exist_ok=True)
    args.out.mkdir(parents=True, exist_ok=True)
    entries = []
    for spec in [*ZERO_AD, *ZERO_AD_2, *ZERO_AD_3, *CUBE2, *RED_ECLIPSE, *MINETEST_MODS]:
        name = spec if isinstance(spec, str) else spec[0]
        if args.only is not None and name not in args.only:
            continue
        out = args.out / f"{name}.glb"
        if isinstance(spec, str):
            build = (build_red_eclipse if spec in RED_ECLIPSE else build_minetest_mod if spec in MINETEST_MODS
                     else build_cube2)
            e = build(name, args.work, out)
        else:
            e = build_zero_ad(spec, args.work, out)
        entries.append(e | {"file": out.name})      # beside the index (benchmarks.datasets.index_characters)
        print(f"{name}: {e['faces']} faces, {e['joints']} joints, {len(e['clips'])} clips, textured {e['textured']}")
    (args.out / "index.json").write_text(json.dumps({"version": 1, "about": "rigslim's sweep characters "
                                                     "(tools/suite/sweep.py)", "characters": entries}, indent=1) + "\n")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
