"""The ROS bridge publishes every topic with the right type through real rclpy."""

import time

import pytest

rclpy = pytest.importorskip("rclpy")

from geometry_msgs.msg import PoseStamped, Twist  # noqa: E402
from nav_msgs.msg import OccupancyGrid, Odometry  # noqa: E402
from rclpy.executors import SingleThreadedExecutor  # noqa: E402
from rclpy.qos import DurabilityPolicy, QoSProfile  # noqa: E402
from rosgraph_msgs.msg import Clock  # noqa: E402
from sensor_msgs.msg import CameraInfo, Image, LaserScan  # noqa: E402

from twin.bridge_node import TwinBridge  # noqa: E402
from twin.config import TwinConfig  # noqa: E402
from twin.twin import Twin  # noqa: E402

TOPICS = {
    "/camera/image_raw": Image,
    "/camera/camera_info": CameraInfo,
    "/scan": LaserScan,
    "/odom": Odometry,
    "/map": OccupancyGrid,
    "/clock": Clock,
    "/twin/robot_pose": PoseStamped,
}


@pytest.mark.ros
def test_bridge_publishes_all_topics_and_obeys_cmd_vel():
    rclpy.init()
    try:
        cfg = TwinConfig.from_dict({"camera": {"width_px": 160, "height_px": 100}})
        bridge = TwinBridge(Twin(cfg, seed=0))
        probe = rclpy.create_node("probe")
        got: dict[str, object] = {}
        latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
        for name, kind in TOPICS.items():
            qos = latched if name == "/map" else 10
            probe.create_subscription(kind, name, lambda m, n=name: got.setdefault(n, m), qos)
        cmd = probe.create_publisher(Twist, "/cmd_vel", 10)
        ex = SingleThreadedExecutor()
        ex.add_node(bridge)
        ex.add_node(probe)
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and (len(got) < len(TOPICS) or bridge.twin.time_s < 1.0):
            msg = Twist()
            msg.linear.x = 0.3
            cmd.publish(msg)
            ex.spin_once(timeout_sec=0.05)
        for name, kind in TOPICS.items():
            assert isinstance(got.get(name), kind), name
        image = got["/camera/image_raw"]
        assert (image.width, image.height, image.encoding) == (160, 100, "rgb8")
        assert len(got["/scan"].ranges) == cfg.lidar.beams
        assert bridge.twin.ground_truth().robot_velocity[0] > 0.1  # /cmd_vel arrived
        # commands go stale after 0.5 s of simulated time: the base stops
        t_end = bridge.twin.time_s + 1.5
        while bridge.twin.time_s < t_end and time.monotonic() < deadline + 20.0:
            ex.spin_once(timeout_sec=0.05)
        assert abs(bridge.twin.ground_truth().robot_velocity[0]) < 0.01
        ex.shutdown()
        probe.destroy_node()
        bridge.destroy_node()
    finally:
        rclpy.try_shutdown()


@pytest.mark.ros
def test_lockstep_time_waits_for_every_participant():
    """In lock-step the twin stands still until each participant has processed what
    it was sent; a slow participant slows the twin, not the other way round."""
    from rclpy.parameter import Parameter

    from stack.ros_lockstep import Participant

    rclpy.init()
    try:
        cfg = TwinConfig.from_dict({"camera": {"width_px": 160, "height_px": 100}})
        bridge = TwinBridge(
            Twin(cfg, seed=0),
            parameter_overrides=[
                Parameter("lockstep", value=True),
                Parameter("participants", value=["slow"]),
            ],
        )
        ex = SingleThreadedExecutor()
        ex.add_node(bridge)
        for _ in range(100):  # nobody there: the twin does not start
            ex.spin_once(timeout_sec=0.01)
        assert bridge.twin.time_s == 0.0
        slow = rclpy.create_node("slow")
        part = Participant(slow, enabled=True)
        seen: list[float] = []
        hold = {"on": True}

        def on_odom(msg):
            seen.append(msg.header.stamp.sec + msg.header.stamp.nanosec * 1e-9)

        part.subscription(Odometry, "/odom", on_odom, 10)
        # a participant that stops acknowledging (its callbacks run, acks are lost)
        real_ack = part.ack
        part.ack = lambda: None if hold["on"] else real_ack()
        ex.add_node(slow)
        hold["on"] = False
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and bridge.twin.time_s < 0.5:
            ex.spin_once(timeout_sec=0.01)
        assert bridge.twin.time_s >= 0.5
        # every odometry message was processed before the next step: none skipped
        assert seen == pytest.approx([0.04 * k for k in range(len(seen))], abs=1e-6)
        hold["on"] = True  # acks stop: the twin must stop within one tick
        t_hold = bridge.twin.time_s
        for _ in range(200):
            ex.spin_once(timeout_sec=0.005)
        assert bridge.twin.time_s <= t_hold + 0.04 + 1e-9
        bridge.destroy_node()
        slow.destroy_node()
    finally:
        rclpy.try_shutdown()
