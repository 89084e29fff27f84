"""Graph colourings that make Gauss-Seidel sweeps parallel.

The local solver of [P10] updates one vertex at a time. The energies it
minimises couple vertices through ``L^T M^-1 L``, i.e. up to two rings
apart (docs/algorithms.md section 2), so vertices at graph distance >= 3 can be
updated at the same time: a *distance-2 colouring* of the mesh graph (no two
vertices within two edges share a colour) splits the vertices into batches
of independent updates.

Method
------
Colour classes are built one after another as maximal independent sets of
the still uncoloured vertices (Luby 1986, with fixed random priorities): a
vertex joins the current class when its priority beats every uncoloured,
not yet excluded neighbour's; its neighbours are then excluded from the
class; repeat until no candidate is left. Vectorised over vertices with
``np.maximum.reduceat`` on the CSR rows, so it runs at numpy speed on
meshes of millions of vertices. The number of colours is close to a greedy
colouring's (at most the maximum degree of the graph plus one).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def distance2_graph(adjacency) -> sp.csr_matrix:
    """Pattern of ``A + A^2`` without the diagonal: vertices within two edges.

    Parameters
    ----------
    adjacency : (m, m) sparse matrix
        Symmetric one-ring adjacency (``Mesh.adjacency``).

    Returns
    -------
    (m, m) csr_matrix of ones
    """
    A = sp.csr_matrix(adjacency, dtype=np.float64)
    A.data[:] = 1.0
    G = (A + A @ A).tocsr()
    G.setdiag(0.0)
    G.eliminate_zeros()
    G.data[:] = 1.0
    G.sort_indices()
    return G


def color_graph(graph, seed: int = 0) -> np.ndarray:
    """Colour a graph so that no two adjacent vertices share a colour.

    Parameters
    ----------
    graph : (m, m) sparse matrix
        Symmetric pattern; the diagonal is ignored.
    seed : int
        Seed of the random priorities (the colouring is deterministic for a seed).

    Returns
    -------
    (m,) int array
        Colour of each vertex, ``0..c-1``.
    """
    G = sp.csr_matrix(graph)
    m = G.shape[0]
    rows = np.repeat(np.arange(m), np.diff(G.indptr))
    off = rows != G.indices
    src, dst = rows[off], G.indices[off]
    # CSR of the off-diagonal pattern.
    order = np.argsort(src, kind="stable")
    src, dst = src[order], dst[order]
    counts = np.bincount(src, minlength=m)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    has = counts > 0
    prio = np.random.default_rng(seed).permutation(m).astype(np.int64) + 1
    color = np.full(m, -1, dtype=np.int64)
    c = 0
    while (color < 0).any():
        cand = color < 0
        while cand.any():
            # Priority of each neighbour that is still a candidate (0 otherwise).
            nb = np.where(cand[dst], prio[dst], 0)
            best = np.zeros(m, dtype=np.int64)
            if len(nb):
                best[has] = np.maximum.reduceat(nb, starts[has])
            win = cand & (prio > best)
            color[win] = c
            cand &= ~win
            # Neighbours of new members can no longer join this class.
            hit = np.zeros(m, dtype=bool)
            hit[dst[win[src]]] = True
            cand &= ~hit
        c += 1
    return color


def distance2_coloring(adjacency, seed: int = 0) -> np.ndarray:
    """Distance-2 colouring of a mesh graph (see module docstring).

    Example
    -------
    >>> import scipy.sparse as sp
    >>> path = sp.diags([1.0, 1.0], [-1, 1], shape=(5, 5))
    >>> c = distance2_coloring(path)
    >>> bool((c[:-1] != c[1:]).all() and (c[:-2] != c[2:]).all())
    True
    """
    return color_graph(distance2_graph(adjacency), seed=seed)


def color_classes(color: np.ndarray) -> list[np.ndarray]:
    """Vertex indices of each colour, in colour order."""
    order = np.argsort(color, kind="stable")
    bounds = np.flatnonzero(np.diff(color[order])) + 1
    return np.split(order, bounds)


def is_valid_coloring(graph, color: np.ndarray) -> bool:
    """True when no edge of ``graph`` (off the diagonal) joins two vertices of one colour."""
    G = sp.coo_matrix(graph)
    off = G.row != G.col
    return bool((color[G.row[off]] != color[G.col[off]]).all())
