"""Compliance checks of USD files: every ``UsdValidation`` validator, in every ``LOD`` variant.

Current ``usdchecker`` releases run USD's validation framework
(``pxr.UsdValidation``); ``pxr.UsdUtils.ComplianceChecker``, its older Python
implementation, is absent from usd-core 26.11 (the version rigslim installs). :func:`check_usd` runs every
registered validator (core, UsdGeom, UsdShade, UsdSkel, UsdUtils' package
rules...) on the composed stage once per variant of the model prim's ``LOD``
variant set (so each level is checked, not only the selected one), and the
old ComplianceChecker as well where the installed usd-core still has it.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from rigslim.io.usd.stage import diagnostics, open_stage, pxr_modules


def check_usd(path, *, levels: bool = True, warnings: bool = False) -> list[str]:
    """Problems the validators find in a file, one line each (empty: it passes).

    Parameters
    ----------
    path : path-like
    levels : bool
        Also validate each variant of every ``LOD`` variant set.
    warnings : bool
        Report warnings too (errors only by default, as ``usdchecker`` fails on errors).

    Returns
    -------
    list of str
        ``"[variant] validator: message"`` lines.
    """
    Usd = pxr_modules()[0]
    from pxr import UsdValidation

    path = Path(path)
    stage = open_stage(path)
    registry = UsdValidation.ValidationRegistry()
    context = UsdValidation.ValidationContext(registry.GetOrLoadAllValidators())
    wanted = {UsdValidation.ValidationErrorType.Error} | (
        {UsdValidation.ValidationErrorType.Warn} if warnings else set())
    selections: list[tuple[Any, str] | None] = [None]
    if levels:
        selections += [(prim.GetPath(), name) for prim in stage.Traverse()
                       if prim.GetVariantSets().HasVariantSet("LOD")
                       for name in prim.GetVariantSets().GetVariantSet("LOD").GetVariantNames()]
    out: list[str] = []
    for sel in selections:
        if sel is not None:
            with Usd.EditContext(stage, stage.GetSessionLayer()):
                stage.GetPrimAtPath(sel[0]).GetVariantSets().GetVariantSet("LOD").SetVariantSelection(sel[1])
        with diagnostics():
            errors = context.Validate(stage)
        label = "" if sel is None else f"[{sel[0]} LOD={sel[1]}] "
        for e in errors:
            if e.GetType() in wanted:
                out.append(f"{label}{e.GetValidator().GetMetadata().name}: {' '.join(e.GetMessage().split())}")
    out += _compliance_checker(path)
    return sorted(set(out), key=out.index)


def _compliance_checker(path: Path) -> list[str]:
    """``UsdUtils.ComplianceChecker``'s errors and failed checks, where usd-core still has it."""
    from pxr import UsdUtils

    checker_class = getattr(UsdUtils, "ComplianceChecker", None)
    if checker_class is None:
        return []
    checker = checker_class(arkit=False, skipARKitRootLayerCheck=False, rootPackageOnly=False, skipVariants=False,
                            verbose=False)
    with diagnostics():
        checker.CheckCompliance(str(path))
    return [f"ComplianceChecker: {' '.join(str(x).split())}" for x in checker.GetErrors() + checker.GetFailedChecks()]
