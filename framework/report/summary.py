"""The report's table rows: one :class:`EvaluationRow` per evaluation of the metrics documents read."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from rigslim.runtime.metrics_document import upgrade

#: Reduction stages whose seconds count as the evaluation's reduction time.
TIMED_STAGES = ("generate", "select", "solve", "decimate")


@dataclass
class EvaluationRow:
    """One evaluation of one metrics document, flattened for the table and the plots.

    Attributes
    ----------
    label : str
        Unique name in the report (the evaluation's name, prefixed by the run's
        name when two runs share evaluation names).
    method : str
        The solve step's plugin, else the decimate step's (``"input"`` when there is neither).
    selection : str or None
        The select step's plugin.
    k : int or None
    seconds : float
        Seconds of the generate/select/solve/decimate steps since the previous evaluation.
    frames : list of int
        Test frames of the run.
    position_per_frame, normal_per_frame : ndarray or None
        ``position_rms_pct`` and ``normal_rms_rad`` per test frame.
    metro : dict
        Metric keys that mention Metro or Hausdorff, with their mean (or value).
    metro_per_frame : ndarray or None
        ``hausdorff_rms_pct`` per test frame (Metro RMS distance, % of the diagonal).
    levels : dict
        Per simplified level (the evaluation's ``levels`` records): ``{level: {key: value}}``.
    histogram_input, histogram_reduced : list of int or None
        Vertices per number of non-zero weights.
    """

    label: str
    run: str
    evaluation: str
    source: str
    document: dict = field(repr=False)
    step: int | None
    method: str
    selection: str | None
    k: int | None
    seconds: float
    frames: list
    position_per_frame: np.ndarray | None
    normal_per_frame: np.ndarray | None
    metrics: dict = field(repr=False)
    metro: dict = field(default_factory=dict)
    metro_per_frame: np.ndarray | None = None
    levels: dict = field(default_factory=dict)
    histogram_input: list | None = None
    histogram_reduced: list | None = None

    def _stat(self, key, which):
        v = self.metrics.get(key)
        return float(v[which]) if isinstance(v, dict) and v.get(which) is not None else None

    @property
    def position_mean(self):
        return self._stat("position_rms_pct", "mean")

    @property
    def position_max(self):
        return self._stat("position_rms_pct", "max")

    @property
    def normal_mean(self):
        return self._stat("normal_rms_rad", "mean")

    @property
    def normal_max(self):
        return self._stat("normal_rms_rad", "max")

    def worst_frame(self) -> int | None:
        """The test frame with the largest position error (else normal, else Metro error)."""
        per = next((p for p in (self.position_per_frame, self.normal_per_frame, self.metro_per_frame)
                    if p is not None), None)
        if per is None or len(per) != len(self.frames) or not len(per):
            return self.frames[0] if self.frames else None
        return int(self.frames[int(np.argmax(per))])


def load_document(path) -> dict:
    """Read and check a metrics JSON document.

    Raises
    ------
    InputError
        When the file is missing, not JSON, has no ``evaluations`` list, or
        a part the report uses has the wrong type (:mod:`rigslim.report.input`).
    """
    from rigslim.report.input import read_metrics_document

    return read_metrics_document(path)  # UTF-8, bounded, typed (file + JSON path in every message)


def _per_frame(metrics, key):
    v = metrics.get(key)
    if isinstance(v, dict) and isinstance(v.get("per_frame"), list):  # null (not finite when written) -> NaN
        return np.asarray([np.nan if x is None else x for x in v["per_frame"]], dtype=np.float64)
    return None


def summarize(document: dict, source: str = "") -> list[EvaluationRow]:
    """One :class:`EvaluationRow` per evaluation of a metrics document.

    The method and k come from the last ``solve`` (and ``select``) step before
    the evaluation (``steps[i]`` is step i; ``steps[0]`` is reading the
    inputs); the time is the sum of the reduction steps' seconds since the
    previous evaluation. Documents of either schema version are read
    (:func:`rigslim.runtime.metrics_document.upgrade`).
    """
    original, document = document, upgrade(document)
    steps = document.get("steps") or []
    frames = list((document.get("frames") or {}).get("test") or [])
    rows = []
    for ev in document["evaluations"]:
        at = ev.get("step")
        before = steps[1:at] if isinstance(at, int) and 0 < at <= len(steps) else steps[1:]
        solve = next((s for s in reversed(before) if s.get("stage") == "solve"), None)
        select = next((s for s in reversed(before) if s.get("stage") == "select"), None)
        decimate = next((s for s in reversed(before) if s.get("stage") == "decimate"), None)
        seconds = 0.0
        for s in reversed(before):
            if s.get("stage") == "evaluate":
                break
            if s.get("stage") in TIMED_STAGES:
                seconds += float(s.get("seconds", 0.0))
        k = (solve or {}).get("k", (select or {}).get("k"))
        metrics = ev.get("metrics") or {}
        metro = {}
        # per-level values of a simplification: {"quartic-10pct": {"hausdorff_rms_pct": ..., "faces": ...}}
        levels = {str(lv["name"]): {k: v for k, v in lv.items() if k != "name"}
                  for lv in ev.get("levels") or [] if isinstance(lv, dict) and "name" in lv}
        for key, value in metrics.items():
            if "metro" in key.lower() or "hausdorff" in key.lower():
                metro[key] = (None if value["mean"] is None else float(value["mean"])) \
                    if isinstance(value, dict) and "mean" in value else value
        hist = ev.get("influence_histogram") or {}
        rows.append(EvaluationRow(
            label=str(ev.get("name", "evaluation")), run=str(document.get("name", "run")),
            evaluation=str(ev.get("name", "evaluation")), source=str(source), document=original, step=at,
            method=(solve or decimate or {}).get("plugin", "input"), selection=(select or {}).get("plugin"),
            k=int(k) if k is not None else None, seconds=seconds, frames=frames,
            position_per_frame=_per_frame(metrics, "position_rms_pct"),
            normal_per_frame=_per_frame(metrics, "normal_rms_rad"), metrics=metrics, metro=metro, levels=levels,
            metro_per_frame=_per_frame(metrics, "hausdorff_rms_pct"),
            histogram_input=hist.get("input"), histogram_reduced=hist.get("reduced")))
    return rows


def _unique_labels(rows: list[EvaluationRow]) -> None:
    seen: dict[str, int] = {}
    for r in rows:
        seen[r.label] = seen.get(r.label, 0) + 1
    for r in rows:
        if seen[r.label] > 1:
            r.label = f"{r.run} / {r.evaluation}"
    seen = {}
    for r in rows:
        if r.label in seen:
            seen[r.label] += 1
            r.label = f"{r.label} ({seen[r.label]})"
        else:
            seen[r.label] = 1
