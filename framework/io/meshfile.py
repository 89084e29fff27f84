"""Triangle meshes from OBJ/OFF/PLY/STL (libigl) and the surface of MEDIT tetrahedral meshes."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from rigslim.errors import InputError
from rigslim.model.mesh import Mesh

MESH_SUFFIXES = (".obj", ".off", ".ply", ".stl", ".mesh")


def _check_file(path: Path) -> None:
    if not path.is_file():
        raise InputError("file not found" if not path.exists() else "not a file", source=path, field="path",
                         fix="check the path (relative paths are relative to the pipeline file)")


def read_mesh(path) -> Mesh:
    """Read a triangle mesh; ``.mesh`` (MEDIT) gives the boundary surface of its tetrahedra.

    Faces that are not triangles are rejected (libigl triangulates OBJ polygons
    on read for some writers, not all).
    """
    path = Path(path)
    _check_file(path)
    suffix = path.suffix.lower()
    if suffix == ".mesh":
        V, F, _ = read_medit_surface(path)
        return Mesh(V, F, source=str(path))
    if suffix not in MESH_SUFFIXES:
        raise InputError(f"unknown mesh format '{suffix}'", source=path, field="suffix",
                         fix="use one of " + ", ".join(MESH_SUFFIXES))
    if suffix == ".ply":
        V, F = read_ply(path)
        return Mesh(V, F, source=str(path))
    import igl

    from rigslim.device.native import native_stderr

    _check_polygons(path, suffix)
    with native_stderr() as said:
        try:
            V, F = igl.read_triangle_mesh(str(path))
            failed = None
        except Exception as e:  # libigl raises RuntimeError/ValueError with its own text
            failed = e
    if failed is not None:  # libigl's own diagnosis (printed to fd 2) is the useful part
        reason = said.first_line() or str(failed).replace(str(path), "the file")
        raise InputError(f"libigl could not read it ({reason})", source=path, field="contents",
                         fix="check that it is a valid triangle mesh")
    said.replay()
    if V.size == 0 or F.size == 0:
        raise InputError("no vertices or no triangles", source=path, field="contents",
                         fix="check that it is a valid, non-empty triangle mesh")
    return Mesh(V, F, source=str(path))


def read_ply(path) -> tuple[np.ndarray, np.ndarray]:
    """Vertices and triangles of a PLY file (ASCII or binary), read with ``plyfile``.

    libigl 2.6's PLY reader frees memory twice on malformed files (the
    process aborts), so PLY goes through plyfile, which raises Python
    errors. Polygons are split into fans ``(p0, p_i, p_{i+1})``; faces of
    fewer than 3 corners are refused.
    """
    from plyfile import PlyData, PlyParseError

    path = Path(path)
    _check_file(path)
    _check_ply_counts(path)
    try:
        with open(path, "rb") as f:
            ply = PlyData.read(f)
        vertex = ply["vertex"].data
        V = np.stack([np.asarray(vertex[c], np.float64) for c in ("x", "y", "z")], axis=1)
        face = ply["face"].data
        names = [n for n in ("vertex_indices", "vertex_index") if n in (face.dtype.names or ())]
        if not names:
            raise KeyError("face vertex_indices")
        polygons = face[names[0]]
    except (PlyParseError, KeyError, ValueError, TypeError, IndexError, EOFError, UnicodeDecodeError,
            MemoryError, OverflowError, AttributeError, struct_error()) as e:
        raise InputError(f"not a readable PLY triangle mesh ({type(e).__name__}: {e})", source=path,
                         field="contents", fix="check that it is a valid PLY mesh with vertex x, y, z and "
                         "face vertex_indices") from None
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", source=path, field="path", fix="check the path") from None
    if not len(V) or not len(polygons):
        raise InputError("no vertices or no faces", source=path, field="contents",
                         fix="check that it is a valid, non-empty triangle mesh")
    lengths = np.array([len(p) for p in polygons])
    if (lengths < 3).any():
        i = int(np.argmax(lengths < 3))
        raise InputError(f"face {i} has {lengths[i]} corners; a face needs at least 3", source=path,
                         field=f"face[{i}]", fix="repair or re-export the mesh")
    if (lengths == 3).all():
        F = np.stack([np.asarray(p, np.int64) for p in polygons])
    else:
        F = np.array([[p[0], p[j], p[j + 1]] for p in polygons for j in range(1, len(p) - 1)], np.int64)
    return V, F


def _check_ply_counts(path: Path) -> None:
    """Refuse element counts the file cannot hold (each property takes at least one byte), before
    plyfile allocates arrays of that many rows."""
    size = path.stat().st_size
    with open(path, "rb") as f:
        head = f.read(1 << 16)
    need, current = 0, None
    for number, line in enumerate(head.split(b"\n")[:2000], 1):
        tok = line.split()
        if tok[:1] == [b"end_header"]:
            break
        if tok[:1] == [b"element"] and len(tok) >= 3:
            try:
                current = int(tok[2])
            except ValueError:
                return  # plyfile reports the malformed header
            if current < 0:
                raise InputError(f"element '{tok[1].decode(errors='replace')}' has count {current}", source=path,
                                 field=f"line {number}", fix="repair or re-export the mesh")
        elif tok[:1] == [b"property"] and current is not None:
            need += current
            if need > size:
                raise InputError(f"the header promises more elements than the file's {size} bytes can hold",
                                 source=path, field=f"line {number}", fix="the file is truncated or its header "
                                 "is wrong; re-export it")


def struct_error():
    """``struct.error`` (plyfile raises it for truncated binary data)."""
    import struct

    return struct.error


def _check_polygons(path: Path, suffix: str) -> None:
    """Refuse OBJ/OFF faces with fewer than 3 corners (and NUL bytes) before libigl sees them.

    libigl 2.6's OBJ and OFF readers corrupt the heap (the process aborts)
    on a face of one corner, and silently drop faces of two; this scan
    names the line instead.
    """
    if suffix not in (".obj", ".off"):
        return
    try:
        data = path.read_bytes()
    except OSError as e:
        raise InputError(f"cannot read file ({e.strerror})", source=path, field="path", fix="check the path") from None

    def refuse(number: int, corners: int):
        raise InputError(f"the face on line {number} has {corners} corner{'s' if corners != 1 else ''}; a face needs "
                         "at least 3", source=path, field=f"line {number}", fix="repair or re-export the mesh")

    if b"\x00" in data:  # C string parsing would cut the line there (and meet a one-corner face)
        number = data[:data.index(b"\x00")].count(b"\n") + 1
        raise InputError(f"line {number} holds a NUL byte; OBJ and OFF are text", source=path, field=f"line {number}",
                         fix="repair or re-export the mesh")
    lines = data.splitlines()
    if suffix == ".obj":
        for number, line in enumerate(lines, 1):
            tok = line.split(b"#", 1)[0].split()
            if tok and tok[0] == b"f" and len(tok) < 4:
                refuse(number, len(tok) - 1)
        return
    # OFF: header ("OFF", counts), vertex lines, then faces "n i1 .. in"
    rows = [(n, t) for n, t in ((n, line.split(b"#", 1)[0].split()) for n, line in enumerate(lines, 1)) if t]
    if not rows:
        return
    if rows[0][1][0].upper().endswith(b"OFF"):
        rows[0] = (rows[0][0], rows[0][1][1:])
        if not rows[0][1]:
            rows = rows[1:]
    try:
        n_vertices, n_faces = int(rows[0][1][0]), int(rows[0][1][1])
    except (IndexError, ValueError):
        return  # libigl reports a malformed header itself
    for number, tok in rows[1 + max(n_vertices, 0):1 + max(n_vertices, 0) + max(n_faces, 0)]:
        try:
            corners = int(tok[0])
        except ValueError:
            continue
        if corners < 3:
            refuse(number, corners)


def read_medit_surface(path):
    """Read a MEDIT ``.mesh`` tetrahedral mesh and extract its boundary surface.

    Returns
    -------
    V : (m, 3) array
        Vertices used by the boundary surface (re-indexed).
    F : (f, 3) int64 array
        Boundary triangles, oriented outward.
    volume : dict
        ``{"V": all vertices, "T": tetrahedra, "surface_vertices": index of each
        surface vertex in the volume mesh}``, e.g. for bounded biharmonic weights.
    """
    path = Path(path)
    _check_file(path)
    import igl

    from rigslim.device.native import native_stderr

    with native_stderr() as said:
        try:
            VV, T, _ = igl.readMESH(str(path))
            failed = None
        except Exception as e:
            failed = e
    if failed is not None:
        reason = said.first_line() or str(failed).replace(str(path), "the file")
        raise InputError(f"libigl could not read it ({reason})", source=path, field="contents",
                         fix="give a MEDIT .mesh file with Vertices and Tetrahedra")
    said.replay()
    if T.size == 0:
        raise InputError("no tetrahedra", source=path, field="Tetrahedra",
                         fix="give a tetrahedral MEDIT mesh")
    if T.min() < 0 or T.max() >= len(VV):
        raise InputError(f"tetrahedra refer to vertices outside 1..{len(VV)}", source=path, field="Tetrahedra",
                         fix="repair or re-export the mesh")
    if not np.isfinite(VV).all():
        raise InputError("vertex positions contain NaN or inf", source=path, field="Vertices",
                         fix="repair or re-export the mesh")
    Fb, _, _ = igl.boundary_facets(T)
    # libigl's boundary facets of tets face inward for positively oriented tets: make them outward.
    Fb = _orient_outward(VV, Fb)
    used, inverse = np.unique(Fb, return_inverse=True)
    F = inverse.reshape(Fb.shape).astype(np.int64)
    return VV[used], F, {"V": VV, "T": T, "surface_vertices": used}


def _orient_outward(V: np.ndarray, F: np.ndarray) -> np.ndarray:
    """Flip all faces if the enclosed signed volume is negative."""
    a, b, c = V[F[:, 0]], V[F[:, 1]], V[F[:, 2]]
    signed_volume = np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6.0
    return F[:, ::-1].copy() if signed_volume < 0 else F
