"""Keeping the twin on the wall clock: which control periods are due, and how well it kept up.

In real-time mode (hardware in the loop) the twin's simulated time follows a monotonic
wall clock: each control period of simulated time is due at ``start + k * period`` of
wall time. The bridge's timer asks :meth:`Pacer.due` how many periods to step; when the
process fell behind (a camera render, another process on the core) it steps the physics
until it has caught up, and publishes each sensor once at the caught-up time: a camera
frame whose time passed while the physics caught up is *dropped*, as a real camera's
driver drops frames it could not send.

A behind of more than ``max_catchup_s`` is not caught up (the simulated world would jump):
the schedule slips (its start moves later) and the slip is counted. The real-time factor
is then below 1.

:class:`RealtimeStats` is what a run reports (``summary.json``'s ``realtime`` entry):
the factor (simulated over wall seconds), ticks later than ``late_s``, the largest lag,
slips, and camera frames delivered against those due. Pure code: no rclpy, no clock of
its own (every call passes the wall time).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass

REALTIME_FILE = "realtime.json"  # in the run folder: the stats, replaced each second
LATE_S = 0.1  # a control period stepped more than this after its wall time is late
MAX_CATCHUP_S = 1.0  # behind by more: the schedule slips instead of catching up


@dataclass
class RealtimeStats:
    """How well the twin kept the wall clock over a run (or so far)."""

    wall_s: float = 0.0  # wall time since the first tick
    sim_s: float = 0.0  # simulated time stepped since the first tick
    ticks: int = 0  # control periods stepped
    late_ticks: int = 0  # stepped more than late_s after they were due
    max_lag_s: float = 0.0  # the largest delay of a period's step behind its due time
    slips: int = 0  # times the schedule gave up catching up
    slipped_s: float = 0.0  # wall time given up by those slips
    frames: int = 0  # camera frames published
    frames_due: int = 0  # camera frames the configured rate asks for
    render_ms_median: float = 0.0  # the camera's render time per frame (real time:
    render_ms_max: float = 0.0  # on a thread of its own, twin.camera_thread)
    late_s: float = LATE_S

    @property
    def factor(self) -> float:
        """Simulated seconds per wall second (1.0: real time)."""
        return self.sim_s / self.wall_s if self.wall_s > 0 else 1.0

    @property
    def dropped_frames(self) -> int:
        return max(0, self.frames_due - self.frames)

    def to_json(self) -> dict:
        d = asdict(self)
        out = {k: round(v, 4) if isinstance(v, float) else v for k, v in d.items()}
        out["factor"] = round(self.factor, 4)
        out["dropped_frames"] = self.dropped_frames
        return out

    def line(self) -> str:
        """One line for a log."""
        return (
            f"real time: factor {self.factor:.3f} over {self.wall_s:.1f} s, "
            f"{self.late_ticks} of {self.ticks} ticks later than {self.late_s * 1e3:.0f} ms, "
            f"max lag {self.max_lag_s * 1e3:.0f} ms, {self.slips} slips, "
            f"frames {self.frames}/{self.frames_due}"
        )


class Pacer:
    """The wall-clock schedule of control periods (see the module's docstring).

    Period ``k`` simulates ``[k T, (k + 1) T)`` and is due once the wall clock has reached
    ``start + (k + 1) T``: the simulated time never runs ahead of the wall clock.
    """

    def __init__(
        self, period_s: float, late_s: float = LATE_S, max_catchup_s: float = MAX_CATCHUP_S
    ):
        if not (math.isfinite(period_s) and period_s > 0):
            raise ValueError(f"period_s: {period_s!r} must be a positive number")
        if not (math.isfinite(late_s) and late_s > 0):
            raise ValueError(f"late_s: {late_s!r} must be a positive number")
        if not (math.isfinite(max_catchup_s) and max_catchup_s >= period_s):
            raise ValueError(f"max_catchup_s: {max_catchup_s!r} must be at least the period")
        self.period_s = period_s
        self.max_catchup_s = max_catchup_s
        self.stats = RealtimeStats(late_s=late_s)
        self._origin: float | None = None  # the wall time of the first call
        self._start = 0.0  # the schedule's start: the origin plus every slip
        self._done = 0  # periods stepped

    def due(self, wall_s: float) -> int:
        """How many control periods to step now (0: none yet). Call :meth:`stepped`
        after each one."""
        if self._origin is None:
            self._origin = self._start = wall_s
            return 0
        behind = wall_s - self._due_at(self._done)
        if behind > self.max_catchup_s:  # too far behind: slip, do not jump the world
            self._start += behind
            self.stats.slips += 1
            self.stats.slipped_s += behind
        self._wall(wall_s)
        return max(0, math.floor((wall_s - self._start) / self.period_s + 1e-9) - self._done)

    def stepped(self, wall_s: float) -> None:
        """One control period was stepped at ``wall_s``."""
        if self._origin is None:
            self._origin = self._start = wall_s - self.period_s
        lag = max(0.0, wall_s - self._due_at(self._done))
        s = self.stats
        s.ticks += 1
        s.late_ticks += lag > s.late_s
        s.max_lag_s = max(s.max_lag_s, lag)
        self._done += 1
        s.sim_s = self._done * self.period_s
        self._wall(wall_s)

    def frame(self, sent: bool, due: int = 1) -> None:
        """The camera's period came ``due`` times since the last call; a frame was
        ``sent`` (or not)."""
        self.stats.frames_due += due
        self.stats.frames += int(sent)

    def _due_at(self, k: int) -> float:
        return self._start + (k + 1) * self.period_s

    def _wall(self, wall_s: float) -> None:
        assert self._origin is not None
        self.stats.wall_s = max(self.stats.wall_s, wall_s - self._origin)
