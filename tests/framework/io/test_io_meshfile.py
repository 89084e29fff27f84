import numpy as np
import pytest

from rigslim.errors import InputError
from rigslim.io import read_medit_surface, read_mesh


def test_obj(data_dir):
    m = read_mesh(data_dir / "elephant.obj")
    assert (m.n_vertices, m.n_faces) == (6034, 12064)
    assert m.F.dtype == np.int64 and not m.V.flags.writeable


def test_medit_surface_is_closed_and_outward(tmp_path):
    # A cube split into 5 tetrahedra, written as MEDIT.
    V = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0], [0, 0, 1], [1, 0, 1], [1, 1, 1], [0, 1, 1]], float)
    T = np.array([[0, 1, 3, 4], [1, 2, 3, 6], [1, 4, 5, 6], [3, 4, 6, 7], [1, 3, 4, 6]])
    lines = ["MeshVersionFormatted 1", "Dimension 3", "Vertices", str(len(V))]
    lines += [f"{x} {y} {z} 0" for x, y, z in V]
    lines += ["Triangles", "0", "Tetrahedra", str(len(T))] + [" ".join(str(i + 1) for i in t) + " 0" for t in T]
    lines += ["End"]
    (tmp_path / "cube.mesh").write_text("\n".join(lines) + "\n")
    Vs, F, volume = read_medit_surface(tmp_path / "cube.mesh")
    assert len(F) == 12 and len(Vs) == 8 and volume["T"].shape == (5, 4)
    a, b, c = Vs[F[:, 0]], Vs[F[:, 1]], Vs[F[:, 2]]
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6 == pytest.approx(1.0)


def test_missing_and_unknown(tmp_path):
    with pytest.raises(InputError, match="not found"):
        read_mesh(tmp_path / "x.obj")
    (tmp_path / "x.xyz").write_text("1 2 3\n")
    with pytest.raises(InputError, match="unknown mesh format"):
        read_mesh(tmp_path / "x.xyz")


def test_garbage_obj(tmp_path):
    (tmp_path / "g.obj").write_text("this is not a mesh\n")
    with pytest.raises(InputError):
        read_mesh(tmp_path / "g.obj")
