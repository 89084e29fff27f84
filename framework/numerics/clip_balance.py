"""Clip-balanced example poses: every clip counts in a weight fit by how far k-largest is from it.

The example poses of ``rigslim reduce`` are sampled from every clip of a
character, and the least-squares fits (``best-fit`` selection, the
``geometric`` and ``poisson`` energies) sum their squared errors over all of
them. A clip with large motion (a run) then outweighs a quiet one (an idle):
the pooled optimum can trade the idle's error for a smaller gain on the run,
and the idle is what the player sees most. Quality is judged clip by clip
(position RMS on each clip's held-out frames, against k-largest's), so the
fits weight each clip to match.

With ``E_c`` the squared position error of the k-largest weights (the k
largest input weights, renormalised) summed over clip c's ``n_c`` example
frames, every example frame f of clip c gets the weight

    w_f = 1 / sqrt(n_c E_c),    normalised to mean 1 over the examples,

which is one iteratively-reweighted least-squares step (from k-largest) for
the sum of the clips' RMS errors, ``sum_c sqrt(E_c(alpha) / n_c)``, whose
gradient is ``sum_c grad E_c / (2 sqrt(n_c E_c))``: each clip's frames count
in inverse proportion to the clip's total error. Clips whose k-largest error
is below ``FLOOR`` times the largest clip's (k-largest already exact there)
are weighted as if it were at that floor, so that a clip nothing can improve
does not swamp the others.

All these energies are sums over poses of squared norms of quantities linear
in the pose's transforms, so a frame weight ``w_f`` is applied by scaling that
pose's transforms by ``sqrt(w_f)`` (:func:`fit_transforms`). With one clip,
or frames not grouped by clip, the weights are all 1.

Measured on the real-character suite (docs/solvers.md, "Clip-balanced
fits"): against the pooled fit, the mean per-clip position RMS over
k-largest's fell at k = 2 and k = 3 in both the all-clips and the
held-out-clips configurations, and no clip went above k-largest.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from rigslim.numerics.blend import linear_blend
from rigslim.numerics.largest_entries import k_largest_weights

__all__ = ["FLOOR", "clip_balance_weights", "example_clips", "fit_transforms", "k_largest_matrix"]

#: Clips whose k-largest error is below this fraction of the largest clip's count as if at it.
FLOOR = 1e-3


def k_largest_matrix(A: sp.spmatrix, k: int) -> sp.csr_matrix:
    """The k largest entries of each row of ``A``, renormalised to sum to one (rows of zero sum kept), as a
    sparse matrix (:func:`rigslim.numerics.largest_entries.k_largest_weights`)."""
    return k_largest_weights(A, k).to_sparse()


def clip_balance_weights(V: np.ndarray, A: sp.spmatrix, T: np.ndarray, clip_of: np.ndarray, k: int,
                         floor: float = FLOOR) -> np.ndarray:
    """Per example frame, the clip-balanced weight ``w_f`` of the module docstring.

    Parameters
    ----------
    V : (m, 3) array
        Rest positions.
    A : (m, n) sparse matrix
        Input weights.
    T : (p, n, 3, 4) array
        Example-pose transforms.
    clip_of : (p,) int array
        Clip of each example frame (any labels).
    k : int
        Influences per vertex of the reduction.
    floor : float
        Relative floor of a clip's k-largest error.

    Returns
    -------
    (p,) array
        Mean 1; all ones for one clip, or when no vertex has more than k influences (k-largest is exact).
    """
    clip_of = np.asarray(clip_of)
    labels, clip = np.unique(clip_of, return_inverse=True)
    p = len(clip_of)
    A = sp.csr_matrix(A)
    A.eliminate_zeros()
    if len(labels) < 2 or A.nnz == 0 or int(np.diff(A.indptr).max()) <= k:
        return np.ones(p)       # one clip, or k-largest is the input on every vertex
    K = k_largest_matrix(A, k)
    err = np.array([np.sum((linear_blend(V, A, T[f]) - linear_blend(V, K, T[f])) ** 2) for f in range(p)])
    E = np.bincount(clip, weights=err, minlength=len(labels))
    if E.max() <= 0.0:
        return np.ones(p)
    E = np.maximum(E, floor * E.max())
    n = np.bincount(clip, minlength=len(labels))
    w = 1.0 / np.sqrt(n * E)[clip]
    return w / w.mean()


def example_clips(split) -> np.ndarray | None:
    """The clip (segment index) of each example frame of a :class:`~rigslim.model.poses.FrameSplit`, or None
    when its frames are not grouped by clip or all come from one."""
    segments = getattr(split, "segments", None)
    if not segments:
        return None
    ex = np.asarray(split.examples)
    clip = np.full(len(ex), -1)
    for i, s in enumerate(segments):
        clip[(ex >= s["start"]) & (ex < s["start"] + s["frames"])] = i
    if (clip < 0).any() or len(np.unique(clip)) < 2:
        return None
    return clip


def fit_transforms(asset, k: int, balance: str = "clips",
                   clip_scale: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """The example poses' transforms for a least-squares weight fit, each pose scaled by ``sqrt(w_f)``.

    Parameters
    ----------
    asset : Asset
        With mesh, weights, poses and split.
    k : int
        Influences per vertex.
    balance : {"clips", "frames"}
        ``clips``: the clip-balanced weights (module docstring); ``frames``: every example frame alike.
    clip_scale : (segments,) array, optional
        A further factor on the weights of each clip's frames (indexed like ``asset.split.segments``; the
        solvers' validated reweighting, :func:`rigslim.plugins.solvers.safeguards.failing_clips`); the
        weights are then normalised to mean 1 again.

    Returns
    -------
    T : (p, n, 3, 4) float64 array
    weights : (p,) array or None
        The frame weights, None where every frame counts alike.
    """
    T = np.ascontiguousarray(asset.example_poses().T, dtype=np.float64)
    clip = example_clips(asset.split) if balance == "clips" or clip_scale is not None else None
    if clip is None:
        return T, None
    w = clip_balance_weights(asset.mesh.V, asset.weights, T, clip, k) if balance == "clips" else np.ones(len(clip))
    if clip_scale is not None:
        w = w * np.asarray(clip_scale, dtype=np.float64)[clip]
        w = w / w.mean()
    if np.allclose(w, 1.0):
        return T, None
    return np.ascontiguousarray(T * np.sqrt(w)[:, None, None, None]), w
