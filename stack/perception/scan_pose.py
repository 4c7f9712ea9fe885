"""Which robot pose a laser scan is read with (the legs node's rule, pure).

:mod:`stack.perception.node_legs` (ROS) and :mod:`vigil.inprocess` both keep one
:class:`ScanPosePairing`, so both transports pair scans and poses alike: a scan is read
with the pose of its instant; one that arrives before that pose waits for it (at most
one scan waits; a newer one sends the waiting one on with the last pose). The first scan
waits for the first pose too (through TF the pose comes a hop later).
"""

from __future__ import annotations

from typing import Generic, TypeVar

from stack.geometry import Pose2D
from stack.perception.errors import BadScanError

S = TypeVar("S")
MAX_POSE_AGE_S = 0.5  # a pose this far from the scan's stamp makes the scan unusable


class ScanPosePairing(Generic[S]):
    """The latest pose and the scan waiting for its own; each call returns the scans to
    read now, in order."""

    def __init__(self, max_pose_age_s: float = MAX_POSE_AGE_S):
        self.max_pose_age_s = max_pose_age_s
        self.pose: Pose2D | None = None
        self.pose_stamp_s = 0.0
        self._waiting: tuple[float, S] | None = None

    def on_pose(self, stamp_s: float, pose: Pose2D) -> list[S]:
        self.pose, self.pose_stamp_s = pose, stamp_s
        if self._waiting is not None and stamp_s >= self._waiting[0]:
            return [self._take()]
        return []

    def on_scan(self, stamp_s: float, scan: S) -> list[S]:
        if self.pose is None or self.pose_stamp_s + 1e-6 < stamp_s:
            out = [self._take()] if self._waiting is not None else []  # its pose never came
            self._waiting = (stamp_s - 1e-6, scan)
            return out
        return [scan]

    def laser_pose(self, stamp_s: float, mount: Pose2D) -> Pose2D:
        """The laser's pose in the map for a scan stamped ``stamp_s``.

        Raises:
            BadScanError: no pose yet, or the pose too far from the scan's instant.
        """
        if self.pose is None:
            raise BadScanError("no robot pose yet")
        if abs(stamp_s - self.pose_stamp_s) > self.max_pose_age_s:
            raise BadScanError(
                f"pose is {abs(stamp_s - self.pose_stamp_s):.2f} s away from the scan"
            )
        return self.pose.compose(mount)

    def _take(self) -> S:
        assert self._waiting is not None
        scan = self._waiting[1]
        self._waiting = None
        return scan
