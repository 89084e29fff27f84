"""``rigslim inspect IN.glb``: skins, joints, clips, primitives and influences."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.commands.gltf_common import _check_input, _emit_report, _header, _jsonable, command_session
from rigslim.io.jsonsafe import dumps_strict


def inspect(path: Path) -> dict:
    """Skins, joints, clips, meshes, primitives, attributes, influences and weight-sum defects of a file."""
    if Path(path).suffix.lower() in (".usd", ".usda", ".usdc", ".usdz"):
        return inspect_usd(path)
    from rigslim.io.gltf.document import load_gltf
    from rigslim.io.gltf.lod import lod_nodes
    from rigslim.io.gltf.scene import animation_duration
    from rigslim.io.gltf.skin import skinning_sets, weight_sums

    doc = load_gltf(path)
    js = doc.json
    out = _header("inspect") | {"path": str(path), "generator": js.get("asset", {}).get("generator"),
                                 "extensions_used": js.get("extensionsUsed", [])}
    out["skins"] = [{"index": i, "name": s.get("name"), "joints": len(s.get("joints", [])),
                     "joint_names": [js["nodes"][j].get("name") for j in s.get("joints", [])]}
                    for i, s in enumerate(js.get("skins", []))]
    out["animations"] = [{"index": i, "name": a.get("name"), "channels": len(a.get("channels", [])),
                          "seconds": animation_duration(doc, i)} for i, a in enumerate(js.get("animations", []))]
    meshes = []
    for mi, mesh in enumerate(js.get("meshes", [])):
        prims = []
        for pi, prim in enumerate(mesh.get("primitives", [])):
            attrs = prim.get("attributes", {})
            info = {"index": pi, "mode": prim.get("mode", 4), "material": prim.get("material"),
                    "attributes": {k: {"count": js["accessors"][a]["count"], "type": js["accessors"][a]["type"],
                                       "componentType": js["accessors"][a]["componentType"],
                                       "normalized": js["accessors"][a].get("normalized", False)}
                                   for k, a in sorted(attrs.items())},
                    "targets": len(prim.get("targets", []))}
            if "indices" in prim:
                info["triangles"] = js["accessors"][prim["indices"]]["count"] // 3
            if skinning_sets(attrs) and "POSITION" in attrs:
                total, nz = weight_sums(doc, attrs)
                dev = np.abs(total - 1.0)
                info["influences_histogram"] = np.bincount(nz).tolist()
                info["weight_sums"] = {"min": float(total.min(initial=1.0)), "max": float(total.max(initial=1.0)),
                                       "off_by_more_than_1e-3": int((dev > 1e-3).sum())}
            prims.append(info)
        meshes.append({"index": mi, "name": mesh.get("name"), "primitives": prims})
    out["meshes"] = meshes
    out["nodes_with_skin"] = [{"node": i, "name": n.get("name"), "mesh": n.get("mesh"), "skin": n["skin"]}
                              for i, n in enumerate(js.get("nodes", [])) if "skin" in n and "mesh" in n]
    out["lod"] = {str(i): ids for i, ids in lod_nodes(js).items()}
    out["materials"] = [m.get("name") for m in js.get("materials", [])]
    return out


def inspect_usd(path: Path) -> dict:
    """A USD file's skeletons, skinned meshes (points, faces, elementSize), animations, LOD variants, validation."""
    from rigslim.io.usd.check import check_usd
    from rigslim.io.usd.summary import describe

    return _header("inspect") | describe(path) | {"validation": check_usd(path)}


def _print_usd(info: dict) -> None:
    print(f"{info['path']} (upAxis {info['up_axis']}, {info['meters_per_unit']:g} m per unit, "
          f"{info['time_codes_per_second']:g} time codes per second)")
    for s in info["skeletons"]:
        print(f"skeleton {s['path']}: {s['joints']} joints, animation {s['animation'] or 'none (rest pose)'}")
        for m in s["meshes"]:
            print(f"  mesh {m['path']}: {m['points']} points, {m['faces']} faces ({m['triangles']} triangles), "
                  f"elementSize {m['element_size']} ({m['interpolation']})"
                  + (f", {m['blend_shapes']} blend shapes" if m["blend_shapes"] else ""))
    for a in info["animations"]:
        span = a["time_codes"]
        print(f"SkelAnimation {a['path']}: {a['joints']} joints, time codes "
              + (f"{span[0]:g}..{span[1]:g}" if span else "none (default values)"))
    for prim, names in info["lod_variants"].items():
        print(f"{prim}: LOD variants {', '.join(names)}")
    bad = info["validation"]
    print("validation: passes every USD validator" if not bad else f"validation: {len(bad)} problems")
    for line in bad[:20]:
        print(f"  {line}")


def cmd_inspect(args) -> int:
    src = _check_input(args.input)
    with command_session(args, [src], {}):
        info = inspect(src)
        _emit_report(args, info)
    if args.json:
        print(dumps_strict(info, indent=2, default=_jsonable))
        return 0
    if "skeletons" in info:
        _print_usd(info)
        return 0
    print(f"{info['path']} (generator: {info['generator']})")
    for s in info["skins"]:
        print(f"skin {s['index']} '{s['name']}': {s['joints']} joints")
    for a in info["animations"]:
        print(f"clip {a['index']} '{a['name']}': {a['seconds']:.3f} s, {a['channels']} channels")
    if not info["animations"]:
        print("no animations")
    for m in info["meshes"]:
        print(f"mesh {m['index']} '{m['name']}': {len(m['primitives'])} primitive(s)")
        for p in m["primitives"]:
            print(f"  primitive {p['index']}: material {p['material']}, {p.get('triangles', '?')} triangles, "
                  f"attributes {', '.join(p['attributes'])}" + (f", {p['targets']} morph targets" if p["targets"]
                                                                 else ""))
            if "influences_histogram" in p:
                h = p["influences_histogram"]
                ws = p["weight_sums"]
                print("    influences per vertex: " + ", ".join(f"{i}: {c}" for i, c in enumerate(h) if c)
                      + f"; weight sums {ws['min']:.4g}..{ws['max']:.4g}, "
                        f"{ws['off_by_more_than_1e-3']} vertices off by more than 1e-3")
    for node, ids in info["lod"].items():
        print(f"node {node}: MSFT_lod levels {ids}")
    return 0
