"""A kinematic model of the mecanum base, for tests and benchmarks without the twin.

Each body-frame velocity follows its command with a first-order lag,
``v' = (v_cmd - v) / tau``, integrated exactly over a step; the pose integrates the
body velocity rotated into the map frame. No slip, no wheel limits: the follower's own
caps are what limit the motion, which is what the tests check.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from stack.geometry import Pose2D
from stack.nav.follower import Twist2D


@dataclass
class KinematicBase:
    """Planar holonomic base with first-order velocity response.

    Attributes:
        pose: current pose in the map frame.
        velocity: current body-frame velocity.
        time_constant_s: lag of the velocity response [s], > 0.
    """

    pose: Pose2D
    velocity: Twist2D = Twist2D()
    time_constant_s: float = 0.15

    def __post_init__(self) -> None:
        if not self.time_constant_s > 0:
            raise ValueError(f"time_constant_s {self.time_constant_s!r} must be > 0")

    def step(self, cmd: Twist2D, dt_s: float) -> Pose2D:
        """Advance by ``dt_s`` under command ``cmd``; returns the new pose.

        Raises:
            ValueError: negative step.
        """
        if dt_s < 0:
            raise ValueError(f"dt_s {dt_s!r} must be >= 0")
        k = 1.0 - math.exp(-dt_s / self.time_constant_s)
        v = self.velocity
        self.velocity = Twist2D(
            v.vx_mps + k * (cmd.vx_mps - v.vx_mps),
            v.vy_mps + k * (cmd.vy_mps - v.vy_mps),
            v.wz_radps + k * (cmd.wz_radps - v.wz_radps),
        )
        # midpoint integration of the mean velocity over the step
        vx = 0.5 * (v.vx_mps + self.velocity.vx_mps)
        vy = 0.5 * (v.vy_mps + self.velocity.vy_mps)
        wz = 0.5 * (v.wz_radps + self.velocity.wz_radps)
        p = self.pose
        yaw_mid = p.yaw_rad + 0.5 * wz * dt_s
        c, s = math.cos(yaw_mid), math.sin(yaw_mid)
        self.pose = Pose2D(
            p.x_m + (c * vx - s * vy) * dt_s,
            p.y_m + (s * vx + c * vy) * dt_s,
            math.remainder(p.yaw_rad + wz * dt_s, 2.0 * math.pi),
        )
        return self.pose
