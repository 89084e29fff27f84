"""The metrics document (``rigslim run --metrics FILE.json``): its schema versions and their readers.

Version 3 (written since issue 21) has the same layout as version 2 and one unit everywhere
(:mod:`rigslim.numerics.units`): every ``*_pct`` position and Hausdorff error is a percentage of the
world-space bounding-box diagonal of the reference in the first test frame (each metric also gives
``reference_diagonal_m``), and each has a twin in world units, ``*_m`` (metres for glTF):
``position_rms_m``, ``hausdorff_rms_m``, ``hausdorff_max_m``. The document's ``units`` says so. In
versions 1 and 2 the percentages were of the rest (bind-space) mesh's diagonal, which differs from the
world diagonal when the joints carry a scale (100x for assimp's centimetre FBX conversions);
:func:`upgrade` keeps their numbers and records that definition in ``units``.

Version 2 (written since rigslim 0.2) carries ``"schema_version": 2`` and gives every
evaluation the values of simplified levels as a list of records::

    {"name": "quartic-levels", "step": 2,
     "metrics": {"hausdorff_rms_pct": {...}, "hausdorff_max_pct": {...}},      # the finest level
     "levels": [{"name": "quartic-10pct", "faces": 1206,
                 "hausdorff_rms_pct": {"mean", "max", "per_frame"}, "hausdorff_max_pct": {...}}, ...]}

Version 1 (no ``schema_version``) flattened them into the metrics as ``KEY@LEVEL`` names
(``"hausdorff_rms_pct@quartic-10pct"``, ``"faces@quartic-10pct"``). :func:`upgrade` reads
either into version 2, so every reader (``rigslim report``, batch summaries) takes both.
"""

from __future__ import annotations

import copy
from typing import Any

__all__ = ["SCHEMA_VERSION", "UNITS", "flat_metrics", "merge_levels", "upgrade"]

#: The version :func:`rigslim.runtime.run.run_pipeline` writes.
SCHEMA_VERSION = 3
#: ``units`` of a version 3 document.
UNITS = {"pct": "percent of the world-space bounding-box diagonal of the reference in the first test frame",
         "m": "world units: metres for glTF, the mesh file's units otherwise"}
#: ``units`` given to an upgraded version 1 or 2 document (its percentages keep their old definition).
UNITS_V2 = {"pct": "percent of the rest (bind-space) mesh's bounding-box diagonal (schema 1-2)",
            "m": "world units: metres for glTF, the mesh file's units otherwise"}


def merge_levels(levels: list[dict[str, Any]], more: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """Merge level records by ``name`` (several metrics measure the same levels); keeps first-seen order."""
    by_name = {lv["name"]: lv for lv in levels}
    for record in more:
        if record["name"] in by_name:
            by_name[record["name"]].update({k: v for k, v in record.items() if k != "name"})
        else:
            by_name[record["name"]] = dict(record)
            levels.append(by_name[record["name"]])
    return levels


def _upgrade_evaluation(evaluation: dict[str, Any]) -> dict[str, Any]:
    metrics = evaluation.get("metrics")
    if not isinstance(metrics, dict) or not any(isinstance(k, str) and "@" in k for k in metrics):
        return evaluation
    plain: dict[str, Any] = {}
    levels: dict[str, dict[str, Any]] = {}
    for key, value in metrics.items():
        name, sep, level = str(key).partition("@")
        if sep:
            levels.setdefault(level, {"name": level})[name] = value
        else:
            plain[key] = value
    evaluation = dict(evaluation, metrics=plain)
    evaluation["levels"] = merge_levels(list(evaluation.get("levels") or []), list(levels.values()))
    return evaluation


def upgrade(document: dict[str, Any]) -> dict[str, Any]:
    """A copy of a metrics document (version 1, 2 or 3) in version 3.

    Parameters
    ----------
    document : dict
        As read from the JSON file; a document without ``schema_version`` is version 1.

    Returns
    -------
    dict
        ``schema_version`` 3; each evaluation's ``KEY@LEVEL`` metrics moved into its ``levels``; ``units``
        says what the percentages are of (for versions 1 and 2: the rest mesh's diagonal, numbers kept).
    """
    document = copy.copy(document)
    version = document.get("schema_version", 1)
    if not isinstance(version, int) or version < 3:
        document.setdefault("units", dict(UNITS_V2))
    else:
        document.setdefault("units", dict(UNITS))
    if isinstance(document.get("evaluations"), list):
        document["evaluations"] = [_upgrade_evaluation(ev) if isinstance(ev, dict) else ev
                                   for ev in document["evaluations"]]
    document["schema_version"] = SCHEMA_VERSION
    return document


def flat_metrics(evaluation: dict[str, Any]) -> dict[str, Any]:
    """An evaluation's metrics with its levels' values flattened as ``KEY@LEVEL`` (the version 1 view).

    Tables with one column per value (batch summaries) use this form.
    """
    flat = dict(evaluation.get("metrics") or {})
    for level in evaluation.get("levels") or []:
        for key, value in level.items():
            if key != "name":
                flat[f"{key}@{level['name']}"] = value
    return flat
