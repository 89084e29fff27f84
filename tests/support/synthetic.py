"""Small synthetic assets with known structure, for solver tests and examples.

- :func:`tube_asset`: an open cylinder bent by a chain of bones, with smooth
  (Gaussian, normalised) skinning weights on every bone;
- :func:`cage_asset`: a sphere inside a cube cage, with mean value
  coordinates (Ju, Schaefer & Warren 2005) and randomly moved cage poses.

Both are small enough for exact general-purpose QP references.
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp


def _rotation(axis, angle):
    axis = np.asarray(axis, dtype=np.float64)
    axis = axis / np.linalg.norm(axis)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(angle) * K + (1 - np.cos(angle)) * K @ K


def tube_asset(rings: int = 16, segments: int = 10, bones: int = 4, poses: int = 8, seed: int = 0):
    """An open tube along z, ``bones`` bones in a chain, Gaussian weights, random bends.

    Poses ``0..poses-3`` are examples, the last two are test poses.
    """
    from rigslim.model.asset import Asset
    from rigslim.model.handles import Handles
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import FrameSplit, Poses

    rng = np.random.default_rng(seed)
    length = float(bones)
    z = np.linspace(0.0, length, rings)
    th = np.linspace(0.0, 2 * np.pi, segments, endpoint=False)
    Z, TH = np.meshgrid(z, th, indexing="ij")
    V = np.stack([0.3 * np.cos(TH), 0.3 * np.sin(TH), Z], axis=-1).reshape(-1, 3)
    F = []
    for r in range(rings - 1):
        for s in range(segments):
            a, b = r * segments + s, r * segments + (s + 1) % segments
            c, d = a + segments, b + segments
            F += [[a, b, d], [a, d, c]]
    mesh = Mesh(V, np.array(F))
    joints = np.zeros((bones + 1, 3))
    joints[:, 2] = np.arange(bones + 1)
    handles = Handles.skeleton(joints, np.c_[np.arange(bones), np.arange(1, bones + 1)])
    centres = np.arange(bones) + 0.5
    W = np.exp(-((V[:, 2:3] - centres[None]) ** 2) / 0.5)
    W /= W.sum(axis=1, keepdims=True)
    T = np.zeros((poses, bones, 3, 4))
    for j in range(poses):
        R = np.eye(3)
        prev = np.eye(3, 4)
        for i in range(bones):
            R = R @ _rotation(rng.normal(size=3) * [1, 1, 0.3], rng.uniform(-0.6, 0.6))
            origin = prev[:, :3] @ joints[i] + prev[:, 3]
            T[j, i, :, :3] = R
            T[j, i, :, 3] = origin - R @ joints[i]
            prev = T[j, i]
    split = FrameSplit.from_specs(list(range(poses - 2)), [poses - 2, poses - 1], poses)
    return Asset(mesh=mesh, handles=handles, weights=sp.csr_matrix(W), poses=Poses(T), split=split)


def cage_asset(levels: int = 2, poses: int = 6, seed: int = 0):
    """A sphere (radius 1) in a triangulated cube cage (half-size 1.5), mean value coordinates,
    cage vertices moved randomly; poses ``0..poses-3`` are examples, the last two test poses."""
    import igl

    from rigslim.model.asset import Asset
    from rigslim.model.handles import Handles, cage_transforms
    from rigslim.model.mesh import Mesh
    from rigslim.model.poses import FrameSplit, Poses
    from rigslim.model.weights import validate_weights
    from rigslim.plugins.generators.mean_value import mean_value_coordinates

    rng = np.random.default_rng(seed)
    Vo = np.array([[1, 0, 0], [-1, 0, 0], [0, 1, 0], [0, -1, 0], [0, 0, 1], [0, 0, -1]], dtype=float)
    Fo = np.array([[0, 2, 4], [2, 1, 4], [1, 3, 4], [3, 0, 4], [2, 0, 5], [1, 2, 5], [3, 1, 5], [0, 3, 5]])
    V, F = igl.upsample(Vo, Fo, levels)
    V = V / np.linalg.norm(V, axis=1, keepdims=True)
    V[:, 2] *= 1.2
    mesh = Mesh(V, F)
    Cv = np.array([[x, y, z] for x in (-1.5, 1.5) for y in (-1.5, 1.5) for z in (-1.5, 1.5)])
    Cf = np.array([[0, 1, 3], [0, 3, 2], [4, 6, 7], [4, 7, 5], [0, 4, 5], [0, 5, 1],
                   [2, 3, 7], [2, 7, 6], [0, 2, 6], [0, 6, 4], [1, 5, 7], [1, 7, 3]])
    cage = Mesh(Cv, Cf)
    W = validate_weights(mean_value_coordinates(V, Cv, Cf), mesh.n_vertices, normalize=True)
    C = Cv[None] + rng.normal(scale=0.3, size=(poses, len(Cv), 3))
    C[0] = Cv
    split = FrameSplit.from_specs(list(range(poses - 2)), [poses - 2, poses - 1], poses)
    return Asset(mesh=mesh, handles=Handles.from_cage(cage), weights=W, poses=Poses(cage_transforms(C)),
                 split=split)
