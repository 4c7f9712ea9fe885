"""Moved: the run report is the package :mod:`vigil.report` (records, metrics, tables,
figures, video, html). These names stay importable from here for branches written
against the old module; new code imports :mod:`vigil.report`.
"""

from vigil.report import RunRecordError, read_jsonl, true_velocity_label, write_report
from vigil.report.video import VideoComposer

__all__ = ["RunRecordError", "VideoComposer", "read_jsonl", "true_velocity_label", "write_report"]
