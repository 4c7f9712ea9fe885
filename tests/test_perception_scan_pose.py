"""stack.perception.scan_pose: a scan is read with the pose of its instant."""

import pytest

from stack.geometry import Pose2D
from stack.perception.errors import BadScanError
from stack.perception.scan_pose import ScanPosePairing


def test_a_scan_waits_for_its_pose_and_a_newer_one_sends_it_on():
    p = ScanPosePairing()
    assert p.on_scan(0.1, "s1") == []  # no pose yet: waits
    assert p.on_pose(0.08, Pose2D()) == []  # an older pose: still waits
    assert p.on_pose(0.12, Pose2D(1.0, 0.0, 0.0)) == ["s1"]
    assert p.on_scan(0.1, "s2") == ["s2"]  # its pose is here
    assert p.on_scan(0.2, "s3") == []
    assert p.on_scan(0.3, "s4") == ["s3"]  # s3's pose never came: on with the last one
    assert p.laser_pose(0.12, Pose2D(0.1, 0.0, 0.0)) == Pose2D(1.1, 0.0, 0.0)
    with pytest.raises(BadScanError, match="away from the scan"):
        p.laser_pose(1.0, Pose2D())
    with pytest.raises(BadScanError, match="no robot pose"):
        ScanPosePairing().laser_pose(0.0, Pose2D())
