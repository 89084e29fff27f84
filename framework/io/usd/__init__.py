"""USD / UsdSkel skinned characters in and out, through Pixar's ``usd-core`` (imported lazily).

- :mod:`rigslim.io.usd.stage`: opening a stage with one-line errors, matrix conventions, time codes.
- :mod:`rigslim.io.usd.read`: :func:`read_usd_skin`, the skinned meshes bound to one ``Skeleton``, its
  joints as handles, ``primvars:skel:jointIndices``/``jointWeights`` as sparse weights, and one
  ``SkelAnimation`` sampled at a frame rate.
- :mod:`rigslim.io.usd.write`: :func:`write_usd`, the source stage with reduced weights
  (``elementSize = k``) and levels of detail (a ``LOD`` variant set, or ``UsdLod`` items).
- :mod:`rigslim.io.usd.export`: :func:`export_usd`, a new UsdSkel character from any rigslim asset
  (a glTF or libigl input).
- :mod:`rigslim.io.usd.check`: :func:`check_usd`, every ``UsdValidation`` validator (what ``usdchecker``
  runs) on a file, in each of its ``LOD`` variants.

docs/usd.md describes the mapping between UsdSkel and rigslim's linear blend model.
"""

#: Suffixes of USD layers and packages.
USD_SUFFIXES = (".usd", ".usda", ".usdc", ".usdz")

__all__ = ["USD_SUFFIXES"]
