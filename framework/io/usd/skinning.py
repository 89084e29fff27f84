"""UsdSkel's own linear blend skinning of a file: the reference rigslim's reading of USD is tested against.

:func:`usdskel_points` poses every mesh :func:`rigslim.io.usd.read.read_usd_skin`
merged with ``UsdSkel.SkeletonQuery.ComputeSkinningTransforms`` and
``UsdSkel.SkinningQuery.ComputeSkinnedPoints`` (USD's C++ implementation,
float32 points, skeleton space), at the same time codes the reader sampled.
"""

from __future__ import annotations

import numpy as np

from rigslim.errors import InputError
from rigslim.io.usd.stage import diagnostics, pxr_modules


def usdskel_points(skin, time_codes=None) -> np.ndarray:
    """(p, m, 3) points of ``skin``'s meshes as UsdSkel skins them, one row block per :class:`MeshPart`.

    Parameters
    ----------
    skin : UsdSkin
        What :func:`read_usd_skin` returned (its stage, skeleton and parts).
    time_codes : (p,) array, optional
        Default ``skin.time_codes`` (NaN: the default time).

    Notes
    -----
    UsdSkel samples the skeleton's bound ``skel:animationSource``; a skin read
    with another ``animation`` has no UsdSkel reference and is refused.
    """
    Usd, _, UsdSkel, _, _, Vt = pxr_modules()
    from rigslim.io.usd.read import skel_bindings

    codes = skin.time_codes if time_codes is None else np.asarray(time_codes, np.float64)
    cache, bindings = skel_bindings(skin.stage, skin.path)
    binding = next(b for b in bindings if str(b.GetSkeleton().GetPrim().GetPath()) == skin.skeleton)
    skel_query = cache.GetSkelQuery(binding.GetSkeleton())
    anim = skel_query.GetAnimQuery()
    bound = str(anim.GetPrim().GetPath()) if anim else None
    if bound != skin.animation:
        raise InputError(f"UsdSkel poses {bound or 'the rest pose'}, the skin was read with {skin.animation}",
                         source=skin.path, field="animation", fix="compare with the bound skel:animationSource")
    queries = {str(q.GetPrim().GetPath()): q for q in binding.GetSkinningTargets()}
    out = np.empty((len(codes), skin.mesh.n_vertices, 3))
    for f, tc in enumerate(codes):
        t = Usd.TimeCode.Default() if np.isnan(tc) else Usd.TimeCode(float(tc))
        with diagnostics() as found:
            xforms = skel_query.ComputeSkinningTransforms(t)
        for part in skin.parts:
            q = queries[part.path]
            prim = q.GetPrim()
            points = Vt.Vec3fArray(prim.GetAttribute("points").Get(Usd.TimeCode.EarliestTime()))
            with diagnostics() as found:
                ok = q.ComputeSkinnedPoints(xforms, points, t)
            if not ok:
                raise InputError(f"UsdSkel could not skin {part.path} ({'; '.join(found) or 'no reason given'})",
                                 source=skin.path, field=part.path, fix="check the mesh's skel binding")
            out[f, part.start:part.start + part.count] = np.asarray(points, np.float64)
    return out
