"""The localisation stand-in: ``map -> odom`` on ``/tf`` and the camera's static frames.

The contract (REP-105) that any localisation fills on a robot, e.g. nav2's AMCL:
``map -> odom`` on ``/tf``, stamped with the odometry time it was computed for, such that
``map -> odom -> base_link`` is the robot's pose in the map. In the twin this node is that
localisation, perfect: it takes the true pose (``/twin/robot_pose``) and the odometry
(``/odom``) of the same tick and publishes ``map -> odom = T(true) * T(odom)^-1``. On a
robot, ``publish_map_odom`` is false and the robot's localisation publishes it.

Either way it publishes, once, on ``/tf_static``: ``map -> camera_link`` and
``camera_link -> camera_optical_frame``, from the camera calibration
(``calibration_file``) and the intrinsics of the first ``/camera/camera_info``
(:mod:`stack.perception.camera_pose`).

Parameters: ``lockstep``, ``publish_map_odom`` (true), ``calibration_file`` (""; none:
no camera frames), ``pose_topic``, ``odom_topic``, ``camera_info_topic``. A message that
cannot be used is logged and skipped.
"""

from __future__ import annotations

import numpy as np
from geometry_msgs.msg import PoseStamped
from nav_msgs.msg import Odometry
from rclpy.node import Node
from sensor_msgs.msg import CameraInfo

import stack.topics as topic
from stack import tf
from stack.cells import ConfigError
from stack.geometry import Pose2D, yaw_from_quaternion
from stack.perception.camera_pose import camera_transforms
from stack.perception.errors import CalibrationError
from stack.perception.homography import Calibration, load_calibration
from stack.ros_lockstep import Participant
from stack.ros_main import spin_node
from stack.ros_params import declare, declare_topics
from stack.ros_tf import tf_message, tf_publishers


def _stamp_s(header) -> float:
    return header.stamp.sec + header.stamp.nanosec * 1e-9


def _pose(p) -> Pose2D:
    return Pose2D(p.position.x, p.position.y, yaw_from_quaternion(p.orientation))


class LocalisationNode(Node):
    """Publishes map -> odom (twin) and the camera's static frames."""

    def __init__(self, **kwargs):
        super().__init__("localisation", **kwargs)
        v = declare(self, lockstep=False, publish_map_odom=True, calibration_file="")
        topics = declare_topics(
            self, pose=topic.TWIN_ROBOT_POSE, odom=topic.ODOM, camera_info=topic.CAMERA_INFO
        )
        lockstep, calibration_file = v.lockstep, v.calibration_file
        self.publish_map_odom = v.publish_map_odom
        self.calibration: Calibration | None = None
        if calibration_file:
            try:
                self.calibration = load_calibration(calibration_file)
            except (CalibrationError, OSError) as err:
                raise ConfigError("calibration_file", calibration_file, str(err)) from None
        self.ls = Participant(self, enabled=lockstep)
        self.pub_tf, self.pub_static = tf_publishers(self.ls, dynamic=self.publish_map_odom)
        self._odom: tuple[float, Pose2D] | None = None
        self._truth: tuple[float, Pose2D] | None = None
        self._published_s: float | None = None
        self.camera_published = False
        if self.publish_map_odom:
            self.ls.subscription(Odometry, topics["odom"], self.on_odom, 10)
            self.ls.subscription(PoseStamped, topics["pose"], self.on_pose, 10)
        if self.calibration is not None:
            self.ls.subscription(CameraInfo, topics["camera_info"], self.on_camera_info, 2)

    def on_odom(self, msg: Odometry) -> None:
        self._odom = (_stamp_s(msg.header), _pose(msg.pose.pose))
        self._publish_map_odom()

    def on_pose(self, msg: PoseStamped) -> None:
        self._truth = (_stamp_s(msg.header), _pose(msg.pose))
        self._publish_map_odom()

    def _publish_map_odom(self) -> None:
        """Once per tick, when the true pose and the odometry of that tick are in."""
        if self._odom is None or self._truth is None or self.pub_tf is None:
            return
        (t_odom, odom), (t_true, true) = self._odom, self._truth
        if abs(t_odom - t_true) > 1e-6 or self._published_s == t_odom:
            return
        if not (odom.is_finite() and true.is_finite()):
            self.get_logger().warning("non-finite pose or odometry: map -> odom skipped")
            return
        st = tf.StampedTransform(tf.MAP, tf.ODOM, t_odom, tf.map_to_odom(true, odom))
        self.pub_tf.publish(tf_message([st]))
        self._published_s = t_odom

    def on_camera_info(self, msg: CameraInfo) -> None:
        if self.camera_published or self.calibration is None or self.pub_static is None:
            return
        K = np.asarray(msg.k, float).reshape(3, 3)
        size = self.calibration.homography.image_size_px
        if size is not None and size != (msg.width, msg.height):
            self.get_logger().error(
                f"camera_info is {msg.width}x{msg.height} but the calibration was made at "
                f"{size[0]}x{size[1]}: no camera frames",
                throttle_duration_sec=10.0,
            )
            return
        try:
            map_link, link_optical = camera_transforms(
                self.calibration.homography.matrix, K, self.calibration.map_m
            )
        except (CalibrationError, ValueError, np.linalg.LinAlgError) as err:
            self.get_logger().error(f"camera frames from the calibration: {err}")
            return
        t = _stamp_s(msg.header)
        self.pub_static.publish(
            tf_message(
                [
                    tf.StampedTransform(tf.MAP, tf.CAMERA_LINK, t, map_link),
                    tf.StampedTransform(tf.CAMERA_LINK, tf.CAMERA_OPTICAL, t, link_optical),
                ]
            )
        )
        self.camera_published = True


def main(args: list[str] | None = None) -> None:
    spin_node(LocalisationNode, args)


if __name__ == "__main__":
    main()
