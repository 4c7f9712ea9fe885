"""A person's movement direction from map positions, frame by frame (thesis 4.5).

The thesis compares the person's map position (x', y') with the previous one: the
larger axis of the displacement gives North/South/East/West, and when neither
|dx| nor |dy| is higher than a threshold the person is "Not moving", so that the
jitter of a standing person's foot pixel is not read as walking. The direction is
computed on every frame, not only at decision steps, so that a person who turns
round while the robot acts is seen doing so.

Comparing strictly consecutive frames makes the threshold depend on the frame
rate (at 15 fps a 0.5 m/s walk moves 3 cm per frame, less than the foot pixel's
jitter). :class:`DirectionConfig.window_s` therefore compares the current position
with the one about ``window_s`` earlier; ``window_s = 0`` is the thesis's
consecutive-frame rule.
"""

from __future__ import annotations

import collections
from dataclasses import dataclass

from stack.cells import Direction
from stack.config import Config, require


@dataclass(frozen=True)
class DirectionConfig(Config):
    """Attributes:
    jitter_threshold_m: displacement per axis at or below which the person is
        "Not moving" [m].
    window_s: time between the two positions compared [s]; 0 compares
        consecutive frames.
    """

    section = "direction"  # errors name keys "direction.<field>"

    jitter_threshold_m: float = 0.1
    window_s: float = 0.5

    def __post_init__(self) -> None:
        require(self.jitter_threshold_m >= 0.0, "jitter_threshold_m", self.jitter_threshold_m,
                "must be >= 0")  # fmt: skip
        require(self.window_s >= 0.0, "window_s", self.window_s, "must be >= 0")


def classify_displacement(dx_m: float, dy_m: float, threshold_m: float) -> Direction:
    """The direction of a map displacement (x east, y north).

    Args:
        dx_m, dy_m: displacement along x (east) and y (north) [m].
        threshold_m: if neither |dx| nor |dy| is higher than this: NOT_MOVING.

    Returns:
        The dominant cardinal direction, or NOT_MOVING.
    """
    if abs(dx_m) <= threshold_m and abs(dy_m) <= threshold_m:
        return Direction.NOT_MOVING
    if abs(dx_m) >= abs(dy_m):
        return Direction.EAST if dx_m > 0 else Direction.WEST
    return Direction.NORTH if dy_m > 0 else Direction.SOUTH


class DirectionEstimator:
    """Direction of one person from successive map positions.

    Args:
        config: threshold and comparison window.
    """

    def __init__(self, config: DirectionConfig = DirectionConfig()):
        self.config = config
        self._history: collections.deque[tuple[float, float, float]] = collections.deque()
        self._direction = Direction.NOT_MOVING

    @property
    def direction(self) -> Direction:
        """The latest direction (NOT_MOVING before two positions are known)."""
        return self._direction

    def reset(self) -> None:
        """Forget the person (lost, or a different person): direction NOT_MOVING."""
        self._history.clear()
        self._direction = Direction.NOT_MOVING

    def update(self, stamp_s: float, position_m: tuple[float, float]) -> Direction:
        """Add the position seen in one frame and return the direction now.

        Args:
            stamp_s: the frame's time [s]; must increase.
            position_m: (x', y') on the map [m].

        Returns:
            The direction from the position ``window_s`` ago (or the oldest kept,
            or the previous one when ``window_s`` is 0) to this one.

        Raises:
            ValueError: a stamp not later than the previous one.
        """
        if self._history and stamp_s <= self._history[-1][0]:
            raise ValueError(f"stamp {stamp_s} is not after the previous {self._history[-1][0]}")
        x, y = position_m
        self._history.append((stamp_s, float(x), float(y)))
        # Keep the newest entry at or before stamp - window as the reference.
        horizon = stamp_s - self.config.window_s
        while len(self._history) > 2 and self._history[1][0] <= horizon:
            self._history.popleft()
        if self.config.window_s == 0.0:
            while len(self._history) > 2:
                self._history.popleft()
        if len(self._history) < 2:
            self._direction = Direction.NOT_MOVING
            return self._direction
        _, x0, y0 = self._history[0]
        self._direction = classify_displacement(x - x0, y - y0, self.config.jitter_threshold_m)
        return self._direction
