"""Distance-2 colourings of mesh graphs."""

import numpy as np
import scipy.sparse as sp

from rigslim.plugins.solvers.coloring import (
    color_classes,
    color_graph,
    distance2_coloring,
    distance2_graph,
    is_valid_coloring,
)


def test_path_graph_distance2():
    path = sp.diags([1.0, 1.0], [-1, 1], shape=(7, 7))
    c = distance2_coloring(path)
    assert (c[:-1] != c[1:]).all() and (c[:-2] != c[2:]).all()
    assert c.max() + 1 == 3  # a path needs exactly 3 colours at distance 2


def test_elephant_distance2_coloring(elephant):
    mesh = elephant.mesh
    G = distance2_graph(mesh.adjacency)
    c = distance2_coloring(mesh.adjacency)
    assert is_valid_coloring(G, c)
    # The bilaplacian couples exactly vertices within two rings: its pattern lies in G.
    L = mesh.cotmatrix
    K = sp.coo_matrix(L.T @ L)
    off = K.row != K.col
    assert (np.asarray(G[K.row[off], K.col[off]]).ravel() > 0).all()
    ncol = c.max() + 1
    max_degree = int(np.diff(G.indptr).max())
    assert ncol <= max_degree + 1
    classes = color_classes(c)
    assert sum(len(s) for s in classes) == mesh.n_vertices
    assert all((c[s] == i).all() for i, s in enumerate(classes))


def test_color_graph_deterministic_and_seeded():
    A = sp.random(200, 200, density=0.03, random_state=4)
    A = ((A + A.T) > 0).astype(float)
    c1, c2 = color_graph(A, seed=1), color_graph(A, seed=1)
    assert (c1 == c2).all() and is_valid_coloring(A, c1)
    # the seed sets the priorities: another seed gives another, equally valid, colouring
    c3 = color_graph(A, seed=2)
    assert is_valid_coloring(A, c3) and (c3 != c1).any()
