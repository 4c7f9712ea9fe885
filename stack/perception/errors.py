"""Errors raised by the perception library.

Configuration errors reuse :class:`stack.cells.ConfigError`. The errors here are
about data: a frame, a scan or a calibration file that cannot be used. Nodes catch
them, log a warning, and publish "no person" / "unknown" instead of a position.
"""

from __future__ import annotations


class PerceptionError(RuntimeError):
    """Base class of the perception library's data errors."""


class BadFrameError(PerceptionError):
    """A camera frame that cannot be processed (empty, wrong type or shape, black)."""


class BadScanError(PerceptionError):
    """A laser scan that cannot be processed (wrong length, bad angles, no valid ranges)."""


class CalibrationError(PerceptionError):
    """A floor calibration that is missing, malformed or degenerate."""
