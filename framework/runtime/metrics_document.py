"""The metrics document (``rigslim run --metrics FILE.json``): its schema versions and their readers.

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

__all__ = ["SCHEMA_VERSION", "flat_metrics", "merge_levels", "upgrade"]

#: The version :func:`rigslim.runtime.run.run_pipeline` writes.
SCHEMA_VERSION = 2


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
    """A copy of a metrics document (version 1 or 2) in version 2.

    Parameters
    ----------
    document : dict
        As read from the JSON file; a document without ``schema_version`` is version 1.

    Returns
    -------
    dict
        ``schema_version`` 2; each evaluation's ``KEY@LEVEL`` metrics moved into its ``levels``.
    """
    document = copy.copy(document)
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
