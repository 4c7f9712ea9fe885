"""One message stamped in the future must not blind perception (issue 13): the camera
and legs nodes reject (and count) stamps far ahead of their clock, and keep working on
the messages after it."""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

from stack.cells import ConfigError
from stack.stamp_guard import FUTURE, NON_FINITE, PAST, StampGuard

rclpy = pytest.importorskip("rclpy")
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from rclpy.qos import ReliabilityPolicy  # noqa: E402
from sensor_msgs.msg import Image, LaserScan  # noqa: E402
from vigil_interfaces.msg import CameraPerson, LegTracks  # noqa: E402

from stack.cells import CellGrid  # noqa: E402
from stack.perception.homography import calibrate, save_calibration  # noqa: E402
from stack.perception.legs import Pose2D  # noqa: E402
from stack.perception.synthetic import (  # noqa: E402
    PinholeCamera,
    background_frame,
    floor_calibration_points,
    render_person_frame,
    simulate_scan,
    walking_legs,
)
from stack.ros_msgs import camera_from_msg, legs_from_msg  # noqa: E402

GRID = CellGrid()
CAMERA = PinholeCamera.mount_a(GRID)


# a ROS domain of its own (conftest.private_ros_domain)
pytestmark = pytest.mark.usefixtures("private_ros_domain")


def test_stamp_guard_rejects_and_counts():
    g = StampGuard(max_future_s=1.0)
    assert g.check(100.5, 100.0) is None and g.check(0.0, 100.0) is None  # old: allowed
    assert g.check(102.0, 100.0) == FUTURE
    assert g.check(math.nan, 100.0) == NON_FINITE and g.check(math.inf, 100.0) == NON_FINITE
    g2 = StampGuard(max_future_s=1.0, max_past_s=5.0)
    assert g2.check(94.0, 100.0) == PAST and g2.check(96.0, 100.0) is None
    assert g.rejected == {FUTURE: 1, NON_FINITE: 2}
    assert "+2.000 s" in g.describe("scan", 102.0, 100.0, FUTURE)
    for bad in (0.0, -1.0, math.nan, math.inf):
        with pytest.raises(ConfigError):
            StampGuard(max_future_s=bad)
    with pytest.raises(ConfigError):
        StampGuard(max_past_s=-1.0)


def set_stamp(msg, t_s):
    ns = int(round(t_s * 1e9))
    msg.header.stamp.sec, msg.header.stamp.nanosec = divmod(ns, 1_000_000_000)


@pytest.fixture
def ros_ex():
    rclpy.init()
    ex = SingleThreadedExecutor()
    yield ex
    ex.shutdown()
    rclpy.try_shutdown()


def spin(ex, cond, timeout_s=10.0):
    deadline = time.monotonic() + timeout_s
    while not cond() and time.monotonic() < deadline:
        ex.spin_once(timeout_sec=0.02)
    return cond()


@pytest.mark.ros
def test_a_future_frame_does_not_blind_the_camera_node(ros_ex, tmp_path):
    from stack.perception.node_camera_people import CameraPeopleNode

    calib = tmp_path / "camera.yaml"
    save_calibration(calib, calibrate(*floor_calibration_points(CAMERA, GRID), (640, 400)))
    node = CameraPeopleNode(parameter_overrides=[Parameter("calibration_file", value=str(calib))])
    probe = rclpy.create_node("probe")
    pub = probe.create_publisher(Image, "/camera/image_raw", 10)
    states: list[dict] = []
    probe.create_subscription(
        CameraPerson, "/perception/person", lambda m: states.append(camera_from_msg(m)), 50
    )
    for n in (node, probe):
        ros_ex.add_node(n)
    try:
        assert spin(ros_ex, lambda: pub.get_subscription_count() > 0)
        # frames are subscribed reliable (best effort dropped fragmented 640x400 frames)
        (sub,) = probe.get_subscriptions_info_by_topic("/camera/image_raw")
        assert sub.qos_profile.reliability == ReliabilityPolicy.RELIABLE
        rng = np.random.default_rng(0)
        background = background_frame(CAMERA, rng)
        y = GRID.center(7)[1]
        now = node.get_clock().now().nanoseconds * 1e-9
        stamps = [now - 1.0 + 0.1 * k for k in range(6)]
        stamps.insert(2, now + 3600.0)  # one frame an hour ahead
        for t in stamps:
            frame = render_person_frame(CAMERA, (2.0, y), rng, background=background)
            msg = Image()
            set_stamp(msg, t)
            msg.height, msg.width = frame.shape[:2]
            msg.encoding, msg.step = "rgb8", msg.width * 3
            msg.data = frame[:, :, ::-1].tobytes()
            pub.publish(msg)
            spin(ros_ex, lambda: False, 0.15)
        assert spin(ros_ex, lambda: len(states) >= 6)
        assert node.stamps.rejected == {FUTURE: 1}
        # the frames' own records: on a loaded machine the frame watchdog may also
        # report a silence between two frames (its record says "no camera frame")
        frames = [s for s in states if "no camera frame" not in (s.get("warning") or "")]
        after = [s for s in frames if s["stamp_s"] > stamps[1]]
        assert len(after) == 4  # every frame after the bad one was processed
        assert not any("frozen" in (s.get("warning") or "") for s in states)
    finally:
        for n in (node, probe):
            ros_ex.remove_node(n)
            n.destroy_node()


@pytest.mark.ros
def test_a_future_scan_and_pose_do_not_blind_the_legs_node(ros_ex):
    from stack.perception.node_legs import LegsNode

    node = LegsNode()
    probe = rclpy.create_node("probe")
    pub_scan = probe.create_publisher(LaserScan, "/scan", 10)
    pub_odom = probe.create_publisher(Odometry, "/odom", 10)
    legs: list[dict] = []
    probe.create_subscription(
        LegTracks, "/perception/legs", lambda m: legs.append(legs_from_msg(m)), 50
    )
    for n in (node, probe):
        ros_ex.add_node(n)
    try:
        assert spin(ros_ex, lambda: pub_scan.get_subscription_count() > 0)
        rng = np.random.default_rng(1)
        robot = Pose2D(*GRID.center(3), math.pi)
        now = node.get_clock().now().nanoseconds * 1e-9
        times = [now - 1.0 + 0.1 * k for k in range(8)]
        times.insert(3, now + 3600.0)
        for t in times:
            odom = Odometry()
            set_stamp(odom, t)
            odom.pose.pose.position.x, odom.pose.pose.position.y = robot.x_m, robot.y_m
            odom.pose.pose.orientation.z = math.sin(robot.yaw_rad / 2)
            odom.pose.pose.orientation.w = math.cos(robot.yaw_rad / 2)
            pub_odom.publish(odom)
            spin(ros_ex, lambda: False, 0.05)
            circles = [(*p, 0.06) for p in walking_legs((2.5, GRID.center(7)[1]), 0.0, t, 1.0)]
            scan = simulate_scan(robot, circles, rng, stamp_s=t if t < now else now)
            msg = LaserScan()
            set_stamp(msg, t)
            msg.angle_min, msg.angle_increment = scan.angle_min_rad, scan.angle_increment_rad
            msg.angle_max = scan.angle_min_rad + scan.angle_increment_rad * (len(scan.ranges_m) - 1)
            msg.range_min, msg.range_max = scan.range_min_m, scan.range_max_m
            msg.ranges = [float(r) for r in scan.ranges_m]
            pub_scan.publish(msg)
            spin(ros_ex, lambda: False, 0.1)
        assert spin(ros_ex, lambda: len(legs) >= 8)
        assert node.stamps.rejected == {FUTURE: 2}  # the scan and its pose
        assert len(legs) == 8  # every good scan, the ones after the bad one too
    finally:
        for n in (node, probe):
            ros_ex.remove_node(n)
            n.destroy_node()
