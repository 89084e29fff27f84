"""Running pipelines: the document, its inputs, the run, the metrics document and progress, one job per module.

- :mod:`~rigslim.runtime.document`: the YAML validated and its steps parsed (:func:`load_pipeline`);
- :mod:`~rigslim.runtime.inputs`: ``inputs:`` read into an asset, ``poses:`` split (:func:`read_inputs`);
- :mod:`~rigslim.runtime.clips`: two-clip ``poses:`` (example frames from one clip, test frames from another);
- :mod:`~rigslim.runtime.run`: the steps run in order, outputs committed together (:func:`run_pipeline`);
- :mod:`~rigslim.runtime.metrics_document`: the metrics JSON (schema version 2) and its upgrades;
- :mod:`~rigslim.runtime.progress`: progress lines and bars on stderr.

The names below are those ``rigslim.runtime`` had as one module.
"""

from rigslim.runtime.document import ClipFrames, PipelineDoc, PoseSpec, Step, load_pipeline
from rigslim.runtime.inputs import ROLE_ORDER, read_inputs
from rigslim.runtime.run import RunResult, run_pipeline, write_metrics

__all__ = ["ROLE_ORDER", "ClipFrames", "PipelineDoc", "PoseSpec", "RunResult", "Step", "load_pipeline", "read_inputs",
           "run_pipeline", "write_metrics"]
