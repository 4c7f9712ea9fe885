"""Planar geometry shared by every layer: the pose type and quaternion yaw.

Map frame (REP 103/105): x east, y north, z up, metres; yaw counter-clockwise from x,
radians. The twin, perception and navigation all use this one :class:`Pose2D`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np


@dataclass(frozen=True)
class Pose2D:
    """A planar pose: position [m] and heading [rad, counter-clockwise from x/east]."""

    x_m: float = 0.0
    y_m: float = 0.0
    yaw_rad: float = 0.0

    def compose(self, other: Pose2D) -> Pose2D:
        """This pose followed by ``other`` expressed in this pose's frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        return Pose2D(
            self.x_m + c * other.x_m - s * other.y_m,
            self.y_m + s * other.x_m + c * other.y_m,
            self.yaw_rad + other.yaw_rad,
        )

    def transform(self, points: np.ndarray) -> np.ndarray:
        """Map (N, 2) points given in this pose's frame to the parent frame."""
        c, s = math.cos(self.yaw_rad), math.sin(self.yaw_rad)
        rot = np.array([[c, -s], [s, c]])
        return np.asarray(points, dtype=float).reshape(-1, 2) @ rot.T + [self.x_m, self.y_m]

    def is_finite(self) -> bool:
        return all(math.isfinite(v) for v in (self.x_m, self.y_m, self.yaw_rad))


def yaw_from_quaternion(q: Any) -> float:
    """Yaw [rad] of a quaternion with fields x, y, z, w (rotation about z)."""
    return math.atan2(2.0 * (q.w * q.z + q.x * q.y), 1.0 - 2.0 * (q.y * q.y + q.z * q.z))
