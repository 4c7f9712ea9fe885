"""The perception nodes exchanging real messages over rclpy, in one process.

A synthetic person walks east through the region: frames to the camera node, scans
and odometry to the legs node; the observations node must answer a request with
the person's cell, "East higher" and the robot's cell. Bad messages in between
(an unsupported image encoding, a scan with NaN ranges) are logged and survived.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest

rclpy = pytest.importorskip("rclpy")
from nav_msgs.msg import Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.parameter import Parameter  # noqa: E402
from sensor_msgs.msg import Image, LaserScan  # noqa: E402
from std_msgs.msg import Empty  # noqa: E402
from vigil_interfaces.msg import CameraPerson, PersonObservation  # noqa: E402

from stack.cells import CellGrid  # noqa: E402
from stack.perception.homography import calibrate, save_calibration  # noqa: E402
from stack.perception.legs import Pose2D  # noqa: E402
from stack.perception.node_camera_people import CameraPeopleNode  # noqa: E402
from stack.perception.node_legs import LegsNode  # noqa: E402
from stack.perception.node_observations import ObservationsNode  # noqa: E402
from stack.perception.synthetic import (  # noqa: E402
    PinholeCamera,
    background_frame,
    floor_calibration_points,
    render_person_frame,
    simulate_scan,
    walking_legs,
)
from stack.ros_msgs import camera_from_msg, observation_from_msg  # noqa: E402

pytestmark = pytest.mark.ros

GRID = CellGrid()
CAMERA = PinholeCamera.mount_a(GRID)


def stamp(msg, t_s):
    msg.header.stamp.sec = int(t_s)
    msg.header.stamp.nanosec = int(round((t_s - int(t_s)) * 1e9))


def image_msg(frame_bgr, t_s, encoding="rgb8"):
    msg = Image()
    stamp(msg, t_s)
    msg.height, msg.width = frame_bgr.shape[:2]
    msg.encoding = encoding
    msg.step = msg.width * 3
    msg.data = frame_bgr[:, :, ::-1].tobytes()
    return msg


def scan_msg(scan, t_s):
    msg = LaserScan()
    stamp(msg, t_s)
    msg.angle_min = scan.angle_min_rad
    msg.angle_increment = scan.angle_increment_rad
    msg.angle_max = scan.angle_min_rad + scan.angle_increment_rad * (len(scan.ranges_m) - 1)
    msg.range_min, msg.range_max = scan.range_min_m, scan.range_max_m
    msg.ranges = [float(r) for r in scan.ranges_m]
    return msg


def odom_msg(pose, t_s):
    msg = Odometry()
    stamp(msg, t_s)
    msg.pose.pose.position.x, msg.pose.pose.position.y = pose.x_m, pose.y_m
    msg.pose.pose.orientation.z = math.sin(pose.yaw_rad / 2)
    msg.pose.pose.orientation.w = math.cos(pose.yaw_rad / 2)
    return msg


@pytest.fixture
def ros():
    rclpy.init()
    yield
    rclpy.try_shutdown()


def test_nodes_publish_the_planner_observation(ros, tmp_path):
    calib = tmp_path / "camera.yaml"
    save_calibration(calib, calibrate(*floor_calibration_points(CAMERA, GRID), (640, 400)))
    camera = CameraPeopleNode(parameter_overrides=[Parameter("calibration_file", value=str(calib))])
    legs = LegsNode()
    obs_node = ObservationsNode(parameter_overrides=[Parameter("decision_period_s", value=0.0)])
    probe = rclpy.create_node("probe")
    pub_img = probe.create_publisher(Image, "/camera/image_raw", 10)
    pub_scan = probe.create_publisher(LaserScan, "/scan", 10)
    pub_odom = probe.create_publisher(Odometry, "/odom", 10)
    pub_req = probe.create_publisher(Empty, "/observations/request", 10)
    persons: list[dict] = []
    observations: list[dict] = []
    for topic, cls, read, sink in (
        ("/perception/person", CameraPerson, camera_from_msg, persons),
        ("/observations", PersonObservation, observation_from_msg, observations),
    ):
        probe.create_subscription(cls, topic, lambda m, s=sink, f=read: s.append(f(m)), 10)
    executor = SingleThreadedExecutor()
    for node in (camera, legs, obs_node, probe):
        executor.add_node(node)

    def spin_until(cond, timeout_s=10.0):
        deadline = time.monotonic() + timeout_s
        while not cond() and time.monotonic() < deadline:
            executor.spin_once(timeout_sec=0.05)
        return cond()

    try:
        assert spin_until(lambda: pub_img.get_subscription_count() > 0 and
                          pub_req.get_subscription_count() > 0)  # fmt: skip
        rng = np.random.default_rng(0)
        background = background_frame(CAMERA, rng)
        robot = Pose2D(*GRID.center(3), math.pi)  # cell 3, facing west
        speed, y = 1.2, GRID.center(7)[1]
        for k in range(12):  # 1.1 s east at 1.2 m/s from x = 1.8 m, 10 fps
            t = 100.0 + 0.1 * k
            x = 1.8 + speed * 0.1 * k
            pub_odom.publish(odom_msg(robot, t))
            circles = [(*p, 0.06) for p in walking_legs((x, y), 0.0, t, speed)]
            scan = simulate_scan(robot, circles, rng, stamp_s=t)
            if k == 5:  # bad input: NaN ranges and an unsupported encoding
                ranges = scan.ranges_m.copy()
                ranges[::7] = np.nan
                msg = scan_msg(scan, t)
                msg.ranges = [float(r) for r in ranges]
                pub_scan.publish(msg)
                bad = image_msg(background, t, encoding="yuv422")
                pub_img.publish(bad)
            else:
                pub_scan.publish(scan_msg(scan, t))
                frame = render_person_frame(CAMERA, (x, y), rng, background=background)
                pub_img.publish(image_msg(frame, t))
            n = len(persons)
            assert spin_until(lambda n=n: len(persons) > n)
        assert persons[5]["warning"] and persons[5]["status"] == "person"  # one bad frame
        assert persons[-1]["status"] == "person" and persons[-1]["direction"] == "East"
        pub_req.publish(Empty())
        assert spin_until(lambda: observations)
        last = observations[-1]
        assert last["robot"] == "3"
        assert last["person"] == str(GRID.cell_at(*persons[-1]["position_m"]))
        assert last["person"] in ("7", "5")
        assert last["velocity"] == "East higher"
        assert abs(last["speed_mps"] - speed) < 0.3
    finally:
        executor.shutdown()
        for node in (camera, legs, obs_node, probe):
            node.destroy_node()
