"""Reject sensor messages stamped far from now (pure, no rclpy).

One frame or scan stamped in the future used to blind perception from then on: the
trackers keep the newest stamp they saw and drop every later message as "out of
order". A :class:`StampGuard` checks each stamp against the node's clock (simulated
time in lock-step, the ROS clock on the robot) before it reaches a tracker, and counts
what it rejects, so one bad message never poisons the ones after it and a clock skew
between machines shows up in the log instead of as silent blindness.
"""

from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass, field

from stack.cells import ConfigError

FUTURE = "stamped in the future"
PAST = "stamped too far in the past"
NON_FINITE = "non-finite stamp"


@dataclass
class StampGuard:
    """Accept stamps up to ``max_future_s`` ahead of now (and, if set, ``max_past_s`` behind).

    Attributes:
        max_future_s: how far ahead of the node's clock a stamp may be [s].
        max_past_s: how far behind [s]; 0: no limit (the default: an old stamp cannot
            poison later messages, trackers drop it as out of order, and replayed data
            with old stamps stays usable).
        rejected: reason -> count.
    """

    max_future_s: float = 1.0
    max_past_s: float = 0.0
    rejected: Counter = field(default_factory=Counter)

    def __post_init__(self) -> None:
        for name, least in (("max_future_s", 0.0), ("max_past_s", -1.0)):
            value = getattr(self, name)
            if not (isinstance(value, int | float) and math.isfinite(value) and value > least):
                rule = "> 0" if least == 0.0 else ">= 0 (0: no limit)"
                raise ConfigError(name, value, f"must be a finite number {rule}")

    def check(self, stamp_s: float, now_s: float) -> str | None:
        """None when the stamp is acceptable, else the reason (and it is counted)."""
        if not math.isfinite(stamp_s):
            reason = NON_FINITE
        elif stamp_s > now_s + self.max_future_s:
            reason = FUTURE
        elif self.max_past_s > 0 and stamp_s < now_s - self.max_past_s:
            reason = PAST
        else:
            return None
        self.rejected[reason] += 1
        return reason

    def describe(self, what: str, stamp_s: float, now_s: float, reason: str) -> str:
        """A log line naming the message, the offset and the running count."""
        total = sum(self.rejected.values())
        return (
            f"{what} {reason} ({stamp_s - now_s:+.3f} s from now {now_s:.3f} s): ignored "
            f"({total} rejected so far; a clock skew between machines?)"
        )
