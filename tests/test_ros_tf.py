"""TF on ROS: the twin bridge and the localisation stand-in publish the REP-105 tree.

The bridge publishes odom -> base_link (/tf) and base_link -> laser (/tf_static); the
localisation stand-in map -> odom (/tf) and map -> camera_link -> camera_optical_frame
(/tf_static, from the calibration and camera_info). A listener fed from the topics gives
the robot's true map pose and the camera's true pose.
"""

from __future__ import annotations

import math
import time

import numpy as np
import pytest
import rclpy
import tf2_msgs.msg  # noqa: F401  built by scripts/build_interfaces.sh: the stack needs it
from geometry_msgs.msg import PoseStamped, Twist

from stack import tf
from stack.geometry import Pose2D, yaw_from_quaternion
from stack.ros_lockstep import Participant
from stack.ros_tf import TfListener, from_msg, to_msg

pytestmark = [pytest.mark.ros, pytest.mark.usefixtures("private_ros_domain")]


def test_transform_message_round_trip():
    st = tf.StampedTransform(
        tf.MAP, tf.ODOM, 12.25, tf.Transform((1.0, -2.0, 0.5), tf.quaternion_from_rpy(0, 0, 1))
    )
    back = from_msg(to_msg(st))
    assert back.parent == tf.MAP and back.child == tf.ODOM
    assert math.isclose(back.stamp_s, 12.25)
    assert np.allclose(back.transform.translation, st.transform.translation)
    assert np.allclose(back.transform.rotation, st.transform.rotation)


@pytest.mark.slow
def test_twin_tree_has_the_rep105_frames_and_gives_the_true_poses(ros, tmp_path):
    from rclpy.parameter import Parameter

    from stack.nav.node_localisation import LocalisationNode
    from stack.perception.homography import save_calibration
    from twin.bridge_node import TwinBridge
    from twin.calibration import calibrate_twin
    from twin.config import TwinConfig
    from twin.twin import Twin

    cfg = TwinConfig.from_dict({"camera": {"width_px": 160, "height_px": 100}})
    twin = Twin(cfg, seed=0)
    cal_file = tmp_path / "calibration.yaml"
    save_calibration(cal_file, calibrate_twin(twin))
    camera_truth = twin.camera_pose()
    bridge = TwinBridge(twin)
    loc = LocalisationNode(parameter_overrides=[Parameter("calibration_file", value=str(cal_file))])
    probe = rclpy.create_node("tf_probe")
    listener = TfListener(Participant(probe, enabled=False))
    cmd = probe.create_publisher(Twist, "/cmd_vel", 10)
    truth: dict[float, Pose2D] = {}  # the bridge's true robot pose by stamp

    def on_truth(m: PoseStamped) -> None:
        p, stamp = m.pose, m.header.stamp.sec + m.header.stamp.nanosec * 1e-9
        truth[round(stamp, 6)] = Pose2D(
            p.position.x, p.position.y, yaw_from_quaternion(p.orientation)
        )

    probe.create_subscription(PoseStamped, "/twin/robot_pose", on_truth, 100)
    for n in (bridge, loc, probe):
        ros.add_node(n)
    buf = listener.buffer
    deadline = time.monotonic() + 30.0
    while time.monotonic() < deadline and (
        twin.time_s < 1.5
        or not buf.can_transform(tf.MAP, tf.LASER)
        or not buf.can_transform(tf.MAP, tf.CAMERA_OPTICAL)
    ):
        msg = Twist()
        msg.linear.x, msg.angular.z = 0.3, 0.4
        cmd.publish(msg)
        ros.spin_once(timeout_sec=0.05)
    try:
        assert {tf.MAP, tf.ODOM, tf.BASE_LINK, tf.LASER, tf.CAMERA_LINK, tf.CAMERA_OPTICAL} <= (
            buf.frames()
        )
        assert buf.parent_of(tf.BASE_LINK) == tf.ODOM and buf.parent_of(tf.ODOM) == tf.MAP
        assert buf.parent_of(tf.LASER) == tf.BASE_LINK
        assert buf.parent_of(tf.CAMERA_OPTICAL) == tf.CAMERA_LINK
        # the robot's map pose through the tree at the latest common time, against the
        # truth the bridge published for that time
        t = buf.latest_common_time(tf.MAP, tf.BASE_LINK)
        assert t is not None and t > 1.0
        pose = buf.lookup(tf.MAP, tf.BASE_LINK).to_pose2d()
        true = truth[round(t, 6)]
        assert math.hypot(pose.x_m - true.x_m, pose.y_m - true.y_m) < 1e-6
        assert abs(math.remainder(pose.yaw_rad - true.yaw_rad, math.tau)) < 1e-6
        assert twin.ground_truth().robot.yaw_rad != pytest.approx(0.0, abs=0.05)  # it turned
        # the laser sits on the lidar's mount
        laser = buf.lookup(tf.BASE_LINK, tf.LASER)
        assert np.allclose(laser.translation, twin.lidar_mount_m())
        # the camera's optical frame where the twin has its camera
        cam = buf.lookup(tf.MAP, tf.CAMERA_OPTICAL, 0.0)
        assert np.linalg.norm(np.array(cam.translation) - camera_truth.position_m) < 1e-3
        axes = np.array([cam.apply(e) for e in np.eye(3)]).T - np.array(cam.translation)[:, None]
        assert np.allclose(axes, camera_truth.rotation, atol=1e-4)
    finally:
        for n in (bridge, loc, probe):
            n.destroy_node()


def test_consumers_take_the_map_pose_through_tf_not_odom(ros):
    """With ``pose_source: tf`` (the hardware default) legs, observations and navigation
    put the robot where map -> odom -> base_link says, while /odom (offset from the map,
    as on a robot whose odometry drifted) would put it in another cell."""
    from nav_msgs.msg import Odometry
    from rclpy.parameter import Parameter
    from std_msgs.msg import Empty
    from tf2_msgs.msg import TFMessage
    from vigil_interfaces.msg import PersonObservation

    from stack.nav.node_navigation import NavigationNode
    from stack.perception.config import load_config_file
    from stack.perception.node_legs import LegsNode
    from stack.perception.node_observations import ObservationsNode
    from stack.ros_tf import TF_QOS, tf_message

    grid, _ = load_config_file("")
    cell_map, cell_odom = grid.cells[0], grid.cells[-1]
    in_map, in_odom = Pose2D(*grid.center(cell_map), 0.3), Pose2D(*grid.center(cell_odom), 0.3)
    map_odom = tf.map_to_odom(in_map, in_odom)
    mount = Pose2D(0.2, 0.05, 0.1)  # the robot's base_link -> laser, known only through TF
    tf_params = [Parameter("pose_source", value="tf")]
    legs = LegsNode(parameter_overrides=tf_params)
    obs = ObservationsNode(
        parameter_overrides=[*tf_params, Parameter("decision_period_s", value=0.0)]
    )
    nav = NavigationNode(parameter_overrides=tf_params)
    probe = rclpy.create_node("tf_source")
    pub_tf = probe.create_publisher(TFMessage, "/tf", TF_QOS)
    pub_odom = probe.create_publisher(Odometry, "/odom", 10)
    pub_request = probe.create_publisher(Empty, "/observations/request", 10)
    labels: list[str] = []
    probe.create_subscription(
        PersonObservation, "/observations", lambda m: labels.append(m.robot), 10
    )
    nodes = (legs, obs, nav, probe)
    for n in nodes:
        ros.add_node(n)
    try:
        deadline = time.monotonic() + 20.0
        while time.monotonic() < deadline and not (
            legs.pose and nav.core.pose and labels and labels[-1] == str(cell_map)
        ):
            stamp = probe.get_clock().now().to_msg()
            now = stamp.sec + stamp.nanosec * 1e-9
            odom = Odometry()
            odom.header.stamp = stamp
            odom.header.frame_id, odom.child_frame_id = "odom", "base_link"
            odom.pose.pose.position.x, odom.pose.pose.position.y = in_odom.x_m, in_odom.y_m
            odom.pose.pose.orientation.w = 1.0
            pub_odom.publish(odom)
            pub_tf.publish(
                tf_message(
                    [
                        tf.StampedTransform(tf.MAP, tf.ODOM, now, map_odom),
                        tf.StampedTransform(
                            tf.ODOM, tf.BASE_LINK, now, tf.Transform.from_pose2d(in_odom)
                        ),
                        tf.StampedTransform(
                            tf.BASE_LINK, tf.LASER, now, tf.Transform.from_pose2d(mount)
                        ),
                    ]
                )
            )
            pub_request.publish(Empty())
            for _ in range(5):
                ros.spin_once(timeout_sec=0.02)
        laser_in_map = in_map.compose(mount)  # legs place scans from the laser's own pose
        for pose, want in ((legs.pose, laser_in_map), (nav.core.pose, in_map)):
            assert pose is not None
            assert math.hypot(pose.x_m - want.x_m, pose.y_m - want.y_m) < 1e-6
            assert abs(pose.yaw_rad - want.yaw_rad) < 1e-6
        assert labels and labels[-1] == str(cell_map) != str(cell_odom)
    finally:
        for n in nodes:
            n.destroy_node()


def test_listener_skips_bad_transforms_and_keeps_the_good(ros):
    from geometry_msgs.msg import TransformStamped
    from tf2_msgs.msg import TFMessage

    node = rclpy.create_node("tf_bad_input")
    try:
        updates: list[int] = []
        listener = TfListener(Participant(node, enabled=False), on_update=lambda: updates.append(1))

        def ts(parent, child, q=(0.0, 0.0, 0.0, 1.0), x=0.0, sec=1):
            m = TransformStamped()
            m.header.frame_id, m.child_frame_id = parent, child
            m.header.stamp.sec = sec
            m.transform.translation.x = x
            r = m.transform.rotation
            r.x, r.y, r.z, r.w = q
            return m

        bad = [
            ts("odom", "base_link", q=(0.0, 0.0, 0.0, 0.0)),  # not a rotation
            ts("odom", "base_link", x=math.nan),
            ts("", "base_link"),
            ts("odom", "odom"),
            ts("map", "odom", x=2.0),
            ts("odom", "base_link", x=1.0),
            ts("base_link", "odom"),  # would close a loop
        ]
        listener._on_tf(TFMessage(transforms=bad))
        listener._on_static(TFMessage(transforms=[ts("/base_link", "laser", x=0.2)]))
        buf = listener.buffer
        assert updates == [1, 1]
        assert buf.parent_of("odom") == "map"  # the loop was refused
        assert buf.parent_of("laser") == "base_link"  # a leading slash is dropped
        assert math.isclose(buf.lookup("map", "laser").translation[0], 3.2)
    finally:
        node.destroy_node()


def test_map_pose_warns_when_the_chain_goes_stale():
    """Localisation that went quiet: lookups still succeed at the last common time, so
    without the stale check the consumer would silently get no new pose."""
    from stack.ros_tf import MapPose

    warnings: list[str] = []

    class Logger:
        def warning(self, text, **_kw):
            warnings.append(text)

    class FakeParticipant:  # what MapPose and TfListener use of stack.ros_lockstep.Participant
        def __init__(self):
            self.node = type("N", (), {"get_logger": lambda _self: Logger()})()
            self.t, self.timers = 0.0, []

        def now_s(self):
            return self.t

        def subscription(self, *_args, **_kw):
            pass

        def timer(self, period_s, callback):
            self.timers.append(callback)

    ls = FakeParticipant()
    poses: list[float] = []
    mp = MapPose(ls, lambda stamp, _pose: poses.append(stamp), timeout_s=1.0)
    buf = mp.buffer
    for t in (0.0, 0.5, 1.0):
        ls.t = t
        buf.set_transform(tf.StampedTransform(tf.MAP, tf.ODOM, min(t, 0.5), tf.Transform()))
        buf.set_transform(tf.StampedTransform(tf.ODOM, tf.BASE_LINK, t, tf.Transform()))
        mp._update()
        ls.timers[0]()
    assert not warnings  # 0.5 s behind: within the timeout
    ls.t = 3.0
    buf.set_transform(tf.StampedTransform(tf.ODOM, tf.BASE_LINK, 3.0, tf.Transform()))
    mp._update()
    ls.timers[0]()
    assert poses == [0.0, 0.5]  # no newer common time: no new pose ...
    assert warnings and "map -> odom" in warnings[-1]  # ... and the warning names the link
