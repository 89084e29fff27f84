"""What ``rigslim report`` reads from glTF outputs: the reduced weights of a run, and its MSFT_lod levels.

- :func:`reduced_from_gltf`: a run whose ``write:`` step wrote a ``.glb``/``.gltf``
  is rendered from that file (no extra ``.npz`` step): the written file is read
  with the reader options of the run's input (welded the same way, so rows are
  the run's mesh vertices) and its ``JOINTS_n``/``WEIGHTS_n`` become the reduced weights.
- :func:`world_units_section`: the recorded errors of runs read from glTF in world
  units and % of the world-space diagonal (the metrics divide by the bind-space one).
- :func:`lod_section`: an HTML table of the ``MSFT_lod`` levels of every glTF a
  run wrote: per original node, each level's node, mesh, primitives (material),
  triangles and vertices.
"""

from __future__ import annotations

import html
from pathlib import Path

GLTF_SUFFIXES = (".glb", ".gltf")


def reduced_from_gltf(path, asset):
    """ReducedWeights of a glTF a run wrote, on the rows of the run's (welded) mesh.

    Parameters
    ----------
    path : path-like
        The written file.
    asset : Asset
        The run's inputs as re-read (``asset.extras["gltf"]`` is the input's GltfSkin).

    Returns
    -------
    ReducedWeights or None
        None when the input was not glTF (an export from OBJ/TGF/DMAT keeps the mesh order:
        then the file's weights are read unwelded).
    """
    from rigslim.io.gltf.skin import read_gltf_skin
    from rigslim.io.gltf.write import fixed_width_weights

    source = asset.extras.get("gltf")
    weld = source is not None and source.vertex_map is not None
    mesh = None
    if source is not None and len({s.mesh for s in source.slices}) == 1:
        mesh = source.slices[0].mesh
    skin = read_gltf_skin(path, weld=weld, mesh=mesh, skin=source.skin if source is not None else None)
    return fixed_width_weights(skin.weights)


def lod_rows(path) -> list[dict]:
    """One row per (original node, level): ``node``, ``level``, ``level_node``, ``mesh``, ``primitives``,
    ``materials``, ``triangles``, ``vertices``, ``joints`` (the level skin's: joint matrices per draw),
    ``influences`` (non-zero weights: vertices x influences), ``error_max_m`` / ``error_rms_m`` (the
    test-pose error the writer measured, ``extras.rigslim_lod``) and ``coverage`` (the ``MSFT_screencoverage``
    down to which the level shows); level 0 is the original mesh."""
    import numpy as np

    from rigslim.io.gltf.document import load_gltf, read_accessor
    from rigslim.io.gltf.lod import lod_nodes
    from rigslim.io.gltf.skin import skinning_sets

    doc = load_gltf(path)
    js = doc.json
    rows = []

    def mesh_row(node_index, level, level_node):
        node = js["nodes"][level_node]
        mi = node["mesh"]
        mesh = js["meshes"][mi]
        tris = verts = infl = 0
        for prim in mesh["primitives"]:
            if "indices" in prim:
                tris += js["accessors"][prim["indices"]]["count"] // 3
            verts += js["accessors"][prim["attributes"]["POSITION"]]["count"]
            for s in skinning_sets(prim["attributes"]):
                infl += int((np.asarray(read_accessor(doc, prim["attributes"][f"WEIGHTS_{s}"])) > 0).sum())
        measured = (node.get("extras") or {}).get("rigslim_lod") or ({} if level else {"error_max_m": 0.0,
                                                                                      "error_rms_m": 0.0})
        coverage = (js["nodes"][node_index].get("extras") or {}).get("MSFT_screencoverage") or []
        return {"node": js["nodes"][node_index].get("name", str(node_index)), "level": level,
                "level_node": level_node, "mesh": mesh.get("name", str(mi)), "primitives": len(mesh["primitives"]),
                "materials": [p.get("material") for p in mesh["primitives"]], "triangles": tris, "vertices": verts,
                "joints": len(js["skins"][node["skin"]]["joints"]) if "skin" in node else None, "influences": infl,
                "error_max_m": measured.get("error_max_m"), "error_rms_m": measured.get("error_rms_m"),
                "coverage": coverage[level] if level < len(coverage) else None}

    for i, ids in lod_nodes(js).items():
        if "mesh" not in js["nodes"][i]:
            continue
        rows.append(mesh_row(i, 0, i))
        rows += [mesh_row(i, j, n) for j, n in enumerate(ids, 1) if "mesh" in js["nodes"][n]]
    return rows


def written_gltfs(document: dict, base: Path | None = None) -> list[Path]:
    """glTF files the run's ``write:`` steps wrote (that still exist)."""
    out = []
    for s in document.get("steps") or []:
        p = str(s.get("path", ""))
        if s.get("stage") == "write" and p.lower().endswith(GLTF_SUFFIXES):
            path = Path(p)
            if not path.is_absolute() and base is not None:
                path = base / path
            if path.is_file():
                out.append(path)
    return out


def lod_section(documents) -> str:
    """The report's "Levels of detail" section (empty when no run wrote a glTF with MSFT_lod)."""
    from rigslim.errors import RigslimError

    parts = []
    for doc, _source in documents:
        base = Path(doc["pipeline"]).parent if doc.get("pipeline") else None
        for path in written_gltfs(doc, base):
            try:
                rows = lod_rows(path)
            except (RigslimError, KeyError, IndexError, OSError):
                continue
            if not rows:
                continue
            body = "".join(
                f"<tr><td>{html.escape(str(r['node']))}</td><td>{r['level']}</td><td>{html.escape(str(r['mesh']))}"
                f"</td><td>{r['primitives']}</td><td>{html.escape(', '.join(map(str, r['materials'])))}</td>"
                f"<td>{r['triangles']}</td><td>{r['vertices']}</td><td>{_cell(r['joints'])}</td>"
                f"<td>{r['influences']}</td><td>{_cell(r['error_max_m'])}</td><td>{_cell(r['error_rms_m'])}</td>"
                f"<td>{_cell(r['coverage'])}</td></tr>" for r in rows)
            parts.append(f"<h3>{html.escape(str(path))}</h3><div class=\"scroll\"><table><tr><th>node</th>"
                         "<th>level</th><th>mesh</th>"
                         f"<th>primitives</th><th>materials</th><th>triangles</th><th>vertices</th><th>joints</th>"
                         f"<th>influences</th><th>error max (m)</th><th>error RMS (m)</th><th>coverage</th></tr>"
                         f"{body}</table></div>")
    if not parts:
        return ""
    return ("<h2>Levels of detail</h2><div class=\"meta\">MSFT_lod chains of the glTF files the runs wrote: "
            "each original node and its own level nodes (level 0: the original mesh); joints: the level skin's "
            "(joint matrices per draw); influences: non-zero weights (vertices x influences); error: max and RMS "
            "test-pose distance to the full mesh; coverage: the MSFT_screencoverage down to which the level "
            "shows.</div>" + "".join(parts))


def _cell(x) -> str:
    """A table cell's number: 4 significant digits, or a dash for none."""
    if x is None:
        return "-"
    return f"{x:.4g}" if isinstance(x, float) else html.escape(str(x))


def world_diagonal(path) -> float:
    """Bounding-box diagonal of a skinned glTF posed at t = 0 in world space (``G(joint) IBM v``; glTF: metres)."""
    import numpy as np

    from rigslim.io.gltf.skin import read_gltf_skin
    from rigslim.numerics.blend import linear_blend

    skin = read_gltf_skin(path, weld=True, times=[0.0])
    P = linear_blend(skin.mesh.V, skin.weights, skin.poses.T[0])
    return float(np.linalg.norm(P.max(axis=0) - P.min(axis=0)))


def world_units_section(documents) -> str:
    """The report's "World units" table for runs read from glTF (empty otherwise).

    The pipeline metrics divide distances measured in posed (world) space by the bind-space mesh's
    diagonal (``mesh.bbox_diagonal`` of the document), which misleads when the joints carry a scale
    (assimp's FBX conversions: x100). Here each ``*_rms_pct`` mean becomes world units
    (``pct / 100 * bbox_diagonal``) and % of the world-space diagonal at t = 0.
    """
    from rigslim.errors import RigslimError

    rows = []
    for doc, source in documents:
        if int(doc.get("schema_version") or 1) >= 3:    # already in world units and % of the world diagonal
            continue
        gltf = (doc.get("inputs") or {}).get("gltf")
        diag = (doc.get("mesh") or {}).get("bbox_diagonal")
        if not gltf or not diag or not Path(gltf).is_file():
            continue
        try:
            world = world_diagonal(gltf)
        except (RigslimError, OSError, ValueError):
            continue
        for ev in doc.get("evaluations") or []:
            for key, value in (ev.get("metrics") or {}).items():
                if not key.startswith(("position_rms_pct", "hausdorff_rms_pct")) or \
                        not isinstance(value, (dict, float)):
                    continue
                mean = value.get("mean") if isinstance(value, dict) else value
                if mean is None:
                    continue
                metres = float(mean) / 100.0 * float(diag)
                run = html.escape(str(doc.get("name", source)))
                rows.append(f"<tr><td>{run}</td><td>{html.escape(str(ev.get('name')))}</td><td>{html.escape(key)}"
                            f"</td><td>{float(mean):.4g}</td><td>{metres:.4g}</td>"
                            f"<td>{100.0 * metres / world:.4g}</td><td>{world:.4g}</td></tr>")
    if not rows:
        return ""
    return ("<h2>World units</h2><div class=\"meta\">Runs read from glTF: the recorded errors (% of the bind-space "
            "diagonal) in world units (glTF: metres) and as % of the world-space diagonal of the input posed at "
            "t = 0.</div><div class=\"scroll\"><table><tr><th>run</th><th>evaluation</th><th>metric</th>"
            "<th>mean (% bind diagonal)</th>"
            "<th>mean (world units)</th><th>mean (% world diagonal)</th><th>world diagonal</th></tr>"
            + "".join(rows) + "</table></div>")
